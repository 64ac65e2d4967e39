"""Who may do what on our OPC UA server, tried with real asyncua clients on 127.0.0.1.

Anonymous sessions and viewers browse, read and subscribe but can neither acknowledge, shelve
nor confirm — by our methods, by Part 9's standard ones (i=9111 …) or through the AckRequest
tag; an operator can, and every action and refusal names its user. A connection without
security is refused when the server demands it; a user can be known by the client
certificate; the server certificate is made on first start (fingerprint) and kept after.
Part 9: an acknowledgement must name an EventId the condition sent; Confirm and AddComment.
"""

from __future__ import annotations

import asyncio

import pytest
from opcua_peers import Events, client, free_port, unit_status, users

from connectors.opcua_server import DiagOpcUaServer, ServerSecurity
from diag_plugin.status import NE107

pytestmark = pytest.mark.anyio


st = unit_status


@pytest.fixture(scope="module")
async def server(anyio_backend, keys):
    d = keys["dir"]
    sec = ServerSecurity(
        d / "own" / "srv.pem",
        d / "own" / "srv.key.pem",
        d / "trusted",
        users(keys),
        allow_anonymous=True,
        policies=("SignAndEncrypt", "Sign"),
    )
    srv = DiagOpcUaServer(port=free_port(), security=sec, max_shelve=600, confirmation=True)
    await srv.start()
    yield srv
    await srv.stop()


async def attempts(srv: DiagOpcUaServer, c, unit: str) -> dict[str, str]:
    """Try every operator action on ``unit``; what each answered ("Good" or the Bad code)."""
    from asyncua import ua

    obj = c.get_node(srv.node_id("Units", unit))
    cond = srv.node_id("Units", unit, "Alarm")
    eid = srv._units[unit].events.event_ids[-1]
    calls = {
        "Acknowledge": (obj, f"{srv.ns}:Acknowledge", []),
        "Shelve": (obj, f"{srv.ns}:Shelve", [ua.Variant(60.0, ua.VariantType.Double)]),
        "Part9.Acknowledge": (
            c.get_node(cond),
            ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge),
            [ua.Variant(eid, ua.VariantType.ByteString), ua.Variant(ua.LocalizedText("x"))],
        ),
        "Part9.TimedShelve": (
            c.get_node(cond),
            ua.NodeId(ua.ObjectIds.AlarmConditionType_ShelvingState_TimedShelve),
            [ua.Variant(60_000.0, ua.VariantType.Double)],
        ),
    }
    out = {}
    for name, (node, method, args) in calls.items():
        try:
            await node.call_method(method, *args)
            out[name] = "Good"
        except ua.UaStatusCodeError as exc:
            out[name] = type(exc).__name__
    try:
        tag = c.get_node(srv.node_id("Units", unit, "Alarm", "AckRequest"))
        await tag.write_value(True)
        out["AckRequest"] = "Good"
    except ua.UaStatusCodeError as exc:
        out["AckRequest"] = type(exc).__name__
    return out


async def test_anonymous_and_viewer_read_but_cannot_silence_an_alarm(server, keys):
    """The attack of issue 23: an anonymous client shelving a unit's alarm. Refused, for a
    viewer too; both read and get events; the log names who tried."""
    from asyncua import ua

    await server.publish(st("pump", NE107.NORMAL))
    await server.publish(st("pump", NE107.FAILURE))
    server.actions.clear()
    for who in (None, "bob"):
        c = await client(server.endpoint, keys["hmi"], who)
        try:
            ev = Events()
            sub = await c.create_subscription(50, ev)
            await sub.subscribe_alarms_and_conditions(
                c.nodes.server, ua.NodeId(ua.ObjectIds.AlarmConditionType)
            )
            health = c.get_node(server.node_id("Units", "pump", "DeviceHealth"))
            assert await health.read_value() == NE107.FAILURE
            got = await attempts(server, c, "pump")
            assert set(got.values()) == {"BadUserAccessDenied"}, (who, got)
            with pytest.raises(ua.UaStatusCodeError):  # nor the diagnosis values
                await health.write_value(ua.Variant(0, ua.VariantType.Int32))
        finally:
            await c.disconnect()
    assert server.alarms["pump"].state == "active-unacknowledged"
    refused = [a for a in server.actions if a.action == "refused"]
    assert {a.user for a in refused} == {"anonymous", "bob (viewer)"}
    assert len(refused) == 2 * 6 and not [a for a in server.actions if a.ok]


async def test_operator_may_and_is_named(server, keys):
    await server.publish(st("fan", NE107.NORMAL))
    await server.publish(st("fan", NE107.FAILURE))
    server.actions.clear()
    c = await client(server.endpoint, keys["hmi"], "alice")
    try:
        got = await attempts(server, c, "fan")
    finally:
        await c.disconnect()
    # our Acknowledge, then Shelve; Part 9's Acknowledge finds nothing left to acknowledge and
    # TimedShelve an alarm already shelved; the AckRequest write itself is accepted
    assert got == {
        "Acknowledge": "Good",
        "Shelve": "Good",
        "Part9.Acknowledge": "BadConditionBranchAlreadyAcked",
        "Part9.TimedShelve": "BadConditionAlreadyShelved",
        "AckRequest": "Good",
    }
    assert server.alarms["fan"].state == "shelved"
    done = [a for a in server.actions if a.ok]
    assert [a.action for a in done] == ["acknowledge", "shelve"]
    assert {a.user for a in server.actions} == {"alice (operator)"}


async def test_user_known_by_its_certificate(server, keys):
    """carol logs in with no user token at all: her application certificate says who she is."""
    await server.publish(st("mixer", NE107.NORMAL))
    await server.publish(st("mixer", NE107.OFF_SPEC))
    c = await client(server.endpoint, keys["carol"])
    try:
        obj = c.get_node(server.node_id("Units", "mixer"))
        assert await obj.call_method(f"{server.ns}:Acknowledge") is True
    finally:
        await c.disconnect()
    assert server.actions[-1].user == "carol (operator)"


async def test_unsecured_and_untrusted_connections_refused(server, keys):
    from asyncua import Client

    plain = Client(server.endpoint, timeout=5)
    with pytest.raises(Exception):  # noqa: B017 - no None endpoint: any refusal will do
        await plain.connect()
    with pytest.raises(Exception):  # noqa: B017 - BadCertificateUntrusted at CreateSession
        await client(server.endpoint, keys["stranger"], "alice")
    c = await client(server.endpoint, keys["hmi"], "alice", mode="Sign")  # Sign is offered
    await c.disconnect()


async def test_sign_and_encrypt_only_refuses_sign(anyio_backend, keys, tmp_path):
    d = keys["dir"]
    sec = ServerSecurity(tmp_path / "s.pem", tmp_path / "s.key.pem", d / "trusted", users(keys))
    srv = DiagOpcUaServer(port=free_port(), security=sec)
    await srv.start()
    try:
        with pytest.raises(Exception):  # noqa: B017 - no such endpoint
            await client(srv.endpoint, keys["hmi"], "alice", mode="Sign")
    finally:
        await srv.stop()


async def test_certificate_made_on_first_start_and_kept(anyio_backend, keys, tmp_path):
    from asyncua import Client

    from connectors.certs import certificate_der, fingerprint

    cert, key = tmp_path / "own" / "diag.pem", tmp_path / "own" / "diag.key.pem"
    sec = ServerSecurity(cert, key, keys["dir"] / "trusted", users(keys))
    srv = DiagOpcUaServer(port=free_port(), security=sec)
    await srv.start()
    try:
        assert srv.certificate_created and cert.exists() and key.exists()
        assert srv.fingerprint == fingerprint(certificate_der(cert))
        eps = await Client(srv.endpoint, timeout=5).connect_and_get_server_endpoints()
        assert {e.SecurityMode.name for e in eps} == {"SignAndEncrypt"}
        assert fingerprint(bytes(eps[0].ServerCertificate)) == srv.fingerprint
    finally:
        await srv.stop()
    again = DiagOpcUaServer(port=free_port(), security=sec)
    await again.start()
    await again.stop()
    assert not again.certificate_created and again.fingerprint == srv.fingerprint
    with pytest.raises(ValueError, match="loopback"):
        DiagOpcUaServer(
            "0.0.0.0", free_port(), security=ServerSecurity(cert, key, policies=("None",))
        )
    with pytest.raises(ValueError, match="loopback"):
        await DiagOpcUaServer("0.0.0.0", free_port()).start()  # no security: loopback only


async def test_part9_event_ids_confirm_and_comment(server, keys):
    """Acknowledge must name an EventId the condition sent; with confirmations on, the alarm
    waits for Confirm (Retain) after it clears; AddComment shows in the next event."""
    from asyncua import ua

    await server.publish(st("valve", NE107.NORMAL))
    await server.publish(st("valve", NE107.FAILURE))
    c = await client(server.endpoint, keys["hmi"], "alice")
    ev = Events()
    try:
        sub = await c.create_subscription(50, ev)
        await sub.subscribe_alarms_and_conditions(
            c.nodes.server, ua.NodeId(ua.ObjectIds.AlarmConditionType)
        )
        cond = c.get_node(server.node_id("Units", "valve", "Alarm"))
        part9 = ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge)
        confirm = ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Confirm)
        comment = ua.NodeId(ua.ObjectIds.ConditionType_AddComment)

        def args(eid: bytes, text: str) -> list:
            return [ua.Variant(eid, ua.VariantType.ByteString), ua.Variant(ua.LocalizedText(text))]

        with pytest.raises(ua.UaStatusCodeError, match="BadEventIdUnknown"):
            await cond.call_method(part9, *args(b"no such event", "x"))
        eid = server._units["valve"].events.event_ids[-1]
        await cond.call_method(part9, *args(eid, "on it"))
        a = server.alarms["valve"]
        assert a.acked and not a.confirmed and a.comment == "on it"
        await server.publish(st("valve", NE107.NORMAL))
        assert a.state == "normal" and a.retain  # cleared, not yet confirmed
        eid = server._units["valve"].events.event_ids[-1]
        await cond.call_method(comment, *args(eid, "valve replaced"))
        await cond.call_method(confirm, *args(eid, "checked"))
        assert a.confirmed and not a.retain
        with pytest.raises(ua.UaStatusCodeError, match="BadConditionBranchAlreadyConfirmed"):
            await cond.call_method(confirm, *args(server._units["valve"].events.event_ids[-1], ""))
        for _ in range(50):
            mine = [e for e in ev.items if e.SourceName == "valve"]
            if mine and getattr(mine[-1], "ConfirmedState/Id") is True:
                break
            await asyncio.sleep(0.05)
        last = mine[-1]
        assert last.Retain is False and getattr(last, "AckedState/Id") is True
        assert last.Comment.Text == "checked" and last.ClientUserId == "alice (operator)"
        assert any(e.Comment and e.Comment.Text == "valve replaced" for e in mine)
    finally:
        await c.disconnect()
    kinds = [a.action for a in server.actions if a.unit == "valve"]
    assert kinds[-5:] == ["acknowledge", "acknowledge", "comment", "confirm", "confirm"]
