"""Our OPC UA server seen through asyncua's client, logged in as an operator over
SignAndEncrypt: address space, alarm events per severity band, CHECK_FUNCTION neither raising
nor clearing an alarm, timed shelving (refused untimed or over the maximum, visible while
shelved, ending by itself), the AckRequest tag, restart keeping alarm state."""

from __future__ import annotations

import asyncio

import pandas as pd
import pytest
from opcua_peers import Events, free_port, pki, users
from opcua_peers import client as ua_client

from connectors.opcua_server import NAMESPACE, DiagOpcUaServer, ServerSecurity
from diag_plugin.status import NE107, Quality, UnitStatus

pytestmark = pytest.mark.anyio


def st(unit: str, status: NE107, c: float = 0.5, q: Quality = Quality.GOOD) -> UnitStatus:
    return UnitStatus(
        unit,
        pd.Timestamp.now(tz="UTC"),
        status,
        q,
        residuals={"r1": 1.0},
        symptoms={"r1": 1.0},
        certainties={"f1": c},
        coverage={"A": 0.9},
        detected=status != NE107.NORMAL,
        faults=["f1"] if status != NE107.NORMAL else [],
    )


MAX_SHELVE = 60.0
#: a server start's own limit where a test starts asyncua twice on a loaded machine (behaviour,
#: not speed, is what such a test checks)
START_UNDER_LOAD = 120.0


@pytest.fixture(scope="module")
async def env(anyio_backend, tmp_path_factory):
    keys = pki(tmp_path_factory.mktemp("pki"))
    d = keys["dir"]
    sec = ServerSecurity(
        d / "own" / "srv.pem", d / "own" / "srv.key.pem", d / "trusted", users(keys)
    )
    srv = DiagOpcUaServer(port=free_port(), security=sec, max_shelve=MAX_SHELVE)
    await srv.start()
    await srv.add_unit("u1", faults=["f1", "f2"], tests=["r1"], models=["A"])
    client = await ua_client(srv.endpoint, keys["hmi"], "alice")
    events = Events()
    sub = await client.create_subscription(50, events)
    from asyncua import ua

    await sub.subscribe_alarms_and_conditions(
        client.nodes.server, ua.NodeId(ua.ObjectIds.AlarmConditionType)
    )
    yield srv, client, events
    await client.disconnect()
    await srv.stop()


async def wait_events(events: Events, unit: str, n: int, timeout: float = 10.0) -> list:
    """The events of ``unit`` once there are ``n`` of them (or after ``timeout`` s)."""
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout
    mine: list = []
    while loop.time() < end:
        mine = [e for e in events.items if e.SourceName == unit]
        if len(mine) >= n:
            break
        await asyncio.sleep(0.05)
    return mine


# the tests with servers of their own run before the module's shared server and client
# exist: the shared client was found disconnected once in a fresh-clone suite (three
# workers on two cores) after them; a server's start blocking the event loop past the
# client's watchdog is the likely cause, and the shared client no longer waits through it


async def test_restart_keeps_alarm_state_and_units(anyio_backend):
    from asyncua import Client

    srv = DiagOpcUaServer(port=free_port(), plant_tags=("F",))  # no security: loopback only
    await srv.start()
    await srv.publish(st("v", NE107.FAILURE, 0.9))
    await srv.acknowledge("v")
    await srv.stop()
    await srv.publish(st("v", NE107.NORMAL))  # while stopped: dropped, no crash
    await srv.start()
    try:
        assert srv.alarms["v"].state == "active-acknowledged"
        async with Client(srv.endpoint, timeout=5) as c:
            node = c.get_node(srv.node_id("Units", "v", "Certainty", "f1"))
            assert (await node.read_browse_name()).Name == "f1"
            state = c.get_node(srv.node_id("Units", "v", "Alarm", "State"))
            await srv.publish(st("v", NE107.NORMAL))
            assert await state.read_value() == "normal"
    finally:
        await srv.stop()


async def test_the_action_log_in_memory_keeps_the_newest_actions_up_to_its_bound(anyio_backend):
    """Months of acknowledgements never grow :attr:`actions` past its bound (the newest 1000;
    the historian's event log keeps them all); the newest are kept, in order."""
    KEEP_ACTIONS = 1000

    srv = DiagOpcUaServer(port=free_port())
    await srv.start()
    try:
        await srv.publish(st("p", NE107.NORMAL))
        for i in range(KEEP_ACTIONS + 5):
            await srv.acknowledge("p", who=f"op{i}")
        assert len(srv.actions) == KEEP_ACTIONS
        assert srv.actions[0].user == "op5" and srv.actions[-1].user == f"op{KEEP_ACTIONS + 4}"
    finally:
        await srv.stop()


async def test_address_space(env):
    srv, client, _ = env
    ns = await client.get_namespace_index(NAMESPACE)
    assert ns == srv.ns
    unit = client.get_node(srv.node_id("Units", "u1"))
    names = {(await n.read_browse_name()).Name for n in await unit.get_children()}
    assert {
        "DeviceHealth",
        "StatusName",
        "Quality",
        "Detected",
        "Faults",
        "Message",
        "LastUpdate",
        "Certainty",
        "Residual",
        "Symptom",
        "Coverage",
        "Alarm",
        "Acknowledge",
        "Shelve",
        "Unshelve",
    } <= names
    certs = client.get_node(srv.node_id("Units", "u1", "Certainty"))
    assert {(await n.read_browse_name()).Name for n in await certs.get_children()} == {"f1", "f2"}
    plant = client.get_node(srv.node_id("Plant"))
    assert len(await plant.get_children()) == 7
    dv = await client.get_node(srv.node_id("Plant", "F")).read_data_value(raise_on_bad_status=False)
    assert dv.StatusCode.is_bad()  # nothing served yet: BadWaitingForInitialData
    with pytest.raises(KeyError):
        await srv.update_plant({"nope": 1.0})
    await srv.update_plant({"F": 3.0})
    dv = await client.get_node(srv.node_id("Plant", "F")).read_data_value()
    assert dv.Value.Value == 3.0 and dv.StatusCode.is_good()


@pytest.mark.parametrize(
    ("status", "lo", "hi"),
    [
        (NE107.FAILURE, 801, 1000),
        (NE107.OFF_SPEC, 601, 800),
        (NE107.MAINTENANCE_REQUIRED, 301, 400),
    ],
)
async def test_event_severity_bands(env, status, lo, hi):
    srv, _, events = env
    events.items.clear()
    await srv.publish(st("u2", status, 0.7))
    (ev,) = await wait_events(events, "u2", 1)
    assert lo <= ev.Severity <= hi
    assert ev.SourceName == "u2" and ev.Retain is True
    assert getattr(ev, "ActiveState/Id") is True and getattr(ev, "AckedState/Id") is False
    await srv.acknowledge("u2")
    await srv.publish(st("u2", NE107.NORMAL))
    evs = await wait_events(events, "u2", 3)
    assert getattr(evs[-1], "ActiveState/Id") is False and evs[-1].Retain is False
    assert srv.alarms["u2"].state == "normal"


async def test_certainty_rise_updates_severity_without_new_state(env):
    srv, _, events = env
    events.items.clear()
    await srv.publish(st("u3", NE107.FAILURE, 0.1))
    await srv.publish(st("u3", NE107.FAILURE, 0.1))  # no change: no event
    await srv.publish(st("u3", NE107.FAILURE, 1.0))
    await asyncio.sleep(0.2)
    evs = await wait_events(events, "u3", 2)
    assert [e.Severity for e in evs] == [821, 1000]


async def test_check_function_neither_raises_nor_clears(env):
    """CHECK_FUNCTION (inputs stale or Bad, a source out) is no fault: no alarm from NORMAL,
    and a standing alarm holds until the diagnosis is back."""
    srv, _, events = env
    events.items.clear()
    await srv.publish(st("u6", NE107.NORMAL))
    await srv.publish(st("u6", NE107.CHECK_FUNCTION, q=Quality.BAD))
    await asyncio.sleep(0.3)
    assert srv.alarms["u6"].state == "normal" and not await wait_events(events, "u6", 1, 0.5)
    await srv.publish(st("u6", NE107.FAILURE, 0.9))
    await srv.publish(st("u6", NE107.CHECK_FUNCTION, q=Quality.BAD))
    assert srv.alarms["u6"].state == "active-unacknowledged"
    await srv.publish(st("u6", NE107.NORMAL))
    assert srv.alarms["u6"].state == "return-to-normal-unacknowledged"


async def test_shelve_and_unshelve_methods(env):
    srv, client, events = env
    from asyncua import ua

    await srv.publish(st("u4", NE107.FAILURE, 0.9))
    await wait_events(events, "u4", 1)
    unit = client.get_node(srv.node_id("Units", "u4"))
    events.items.clear()
    # shelving is timed only, up to the maximum
    for secs in (0.0, -5.0, MAX_SHELVE + 1):
        with pytest.raises(ua.UaStatusCodeError, match="BadShelvingTimeOutOfRange"):
            await unit.call_method(f"{srv.ns}:Shelve", ua.Variant(secs, ua.VariantType.Double))
    assert srv.alarms["u4"].state == "active-unacknowledged"
    assert await unit.call_method(f"{srv.ns}:Shelve", ua.Variant(30.0, ua.VariantType.Double))
    assert srv.alarms["u4"].state == "shelved"
    (ev,) = await wait_events(events, "u4", 1)
    # still visible, as shelved: the condition is on and retained, flagged shelved
    assert ev.SuppressedOrShelved is True and ev.Retain is True
    assert getattr(ev, "ActiveState/Id") is True
    shelved = client.get_node(srv.node_id("Units", "u4", "Alarm", "Shelved"))
    assert await shelved.read_value() is True
    until = await client.get_node(srv.node_id("Units", "u4", "Alarm", "ShelvedUntil")).read_value()
    assert 25 < (until - pd.Timestamp.now(tz="UTC").to_pydatetime()).total_seconds() <= 30
    with pytest.raises(ua.UaStatusCodeError, match="BadConditionAlreadyShelved"):
        await unit.call_method(f"{srv.ns}:Shelve", ua.Variant(10.0, ua.VariantType.Double))
    assert await unit.call_method(f"{srv.ns}:Unshelve")
    assert srv.alarms["u4"].state == "active-unacknowledged"  # still on: annunciated again
    assert await unit.call_method(f"{srv.ns}:Acknowledge")
    with pytest.raises(ua.UaStatusCodeError, match="BadConditionBranchAlreadyAcked"):
        await unit.call_method(f"{srv.ns}:Acknowledge")  # nothing left to acknowledge
    assert srv.alarms["u4"].state == "active-acknowledged"
    done = [a for a in srv.actions if a.unit == "u4" and a.ok]
    assert [a.action for a in done] == ["shelve", "unshelve", "acknowledge"]
    assert all(a.user == "alice (operator)" and a.via == "OPC UA" for a in done)


async def test_shelving_ends_by_itself_and_a_fault_while_shelved_is_seen(env):
    srv, client, events = env
    from asyncua import ua

    await srv.publish(st("u7", NE107.MAINTENANCE_REQUIRED, 0.5))
    unit = client.get_node(srv.node_id("Units", "u7"))
    assert await unit.call_method(f"{srv.ns}:Shelve", ua.Variant(1.0, ua.VariantType.Double))
    await wait_events(events, "u7", 2)  # raised, shelved
    events.items.clear()
    await srv.publish(st("u7", NE107.NORMAL))
    await srv.publish(st("u7", NE107.FAILURE, 0.9))  # a new fault while shelved: an event
    evs = await wait_events(events, "u7", 2)
    assert [e.SuppressedOrShelved for e in evs[-2:]] == [True, True]
    assert srv.alarms["u7"].state == "shelved"
    await asyncio.sleep(1.1)
    await srv.publish(st("u7", NE107.FAILURE, 0.9))  # the next update ends the shelving
    assert srv.alarms["u7"].state == "active-unacknowledged"
    for _ in range(100):
        evs = [e for e in events.items if e.SourceName == "u7"]
        if evs and evs[-1].SuppressedOrShelved is False:
            break
        await asyncio.sleep(0.05)
    assert evs[-1].SuppressedOrShelved is False and getattr(evs[-1], "AckedState/Id") is False
    timer = [a for a in srv.actions if a.unit == "u7" and a.action == "unshelve"]
    assert timer and timer[-1].user == "timer"


async def test_ack_request_tag(env):
    srv, client, _ = env
    await srv.publish(st("u5", NE107.OFF_SPEC, 0.9))
    tag = client.get_node(srv.node_id("Units", "u5", "Alarm", "AckRequest"))
    await tag.write_value(True)
    for _ in range(50):
        if srv.alarms["u5"].state == "active-acknowledged":
            break
        await asyncio.sleep(0.05)
    assert srv.alarms["u5"].state == "active-acknowledged"
    assert await tag.read_value() is False  # the request is consumed


async def test_notices_are_maintenance_band_and_need_no_acknowledgement(env):
    """The plug-in's own conditions (a source out, the historian degraded): severity 350, no
    acknowledgement awaited, retained while on, normal again by themselves; their Active and
    Message variables and the historian's backlog read over OPC UA."""
    srv, client, events = env
    events.items.clear()
    await srv.notice("Historian", True, "historian degraded: database is locked")
    await srv.set_plugin_value("Historian", "Backlog", 1234)
    (ev,) = await wait_events(events, "Historian", 1)
    assert ev.Severity == 350 and ev.Retain is True and ev.ConditionName == "Notice"
    assert getattr(ev, "ActiveState/Id") is True and getattr(ev, "AckedState/Id") is True
    read = {
        k: await client.get_node(srv.node_id("Plugin", "Historian", k)).read_value()
        for k in ("Active", "Message", "Backlog")
    }
    assert read == {
        "Active": True,
        "Message": "historian degraded: database is locked",
        "Backlog": 1234,
    }
    await srv.notice("Historian", True, "historian degraded: database is locked")  # no change
    await srv.notice("Historian", False, "historian back after 30.0 s")
    evs = await wait_events(events, "Historian", 2)
    assert len(evs) == 2 and evs[-1].Retain is False
    assert getattr(evs[-1], "ActiveState/Id") is False


async def test_a_changed_value_is_shown_and_an_unchanged_one_is_not_written_again(env):
    """Every value that changes (a residual, NaN to a number and back) is what a client reads
    next; one that stays the same, NaN included, keeps the SourceTimestamp of its write."""
    import math

    srv, client, _ = env
    node = client.get_node(srv.node_id("Units", "u9", "Residual", "r1"))
    seen = []
    for r in (1.0, 2.5, 2.5, math.nan, math.nan, 4.0, 4.0):
        s = st("u9", NE107.NORMAL)
        s.residuals = {"r1": r}
        await srv.publish(s)
        dv = await node.read_data_value(raise_on_bad_status=False)
        seen.append((dv.Value.Value, dv.SourceTimestamp))
        await asyncio.sleep(0.01)  # a rewrite would carry a later SourceTimestamp
    values = [v for v, _ in seen]
    assert values[:3] == [1.0, 2.5, 2.5] and values[5:] == [4.0, 4.0]
    assert math.isnan(values[3]) and math.isnan(values[4])
    stamps = [t for _, t in seen]
    assert stamps[1] == stamps[2] and stamps[3] == stamps[4] and stamps[5] == stamps[6]
    assert stamps[0] < stamps[1] < stamps[3] < stamps[5]


async def test_a_stop_that_fails_in_the_library_still_stops_and_can_start_again(
    anyio_backend, monkeypatch, caplog
):
    """asyncua's own stop raising OSError (a socket already gone; injected here, a real
    server does it only by chance) is logged, the address space is dropped, and the same
    object starts again with its units."""
    from asyncua import Server

    srv = DiagOpcUaServer(port=free_port())
    # two starts of asyncua's standard address space in one test: at the default 30 s one
    # timed out in a clean-clone run at a load of 6-10 on 2 cores (2026-12-02); 5.8 s alone
    await srv.start(timeout=START_UNDER_LOAD)
    await srv.publish(st("p", NE107.FAILURE))
    real_stop = Server.stop

    async def broken_stop(self):
        await real_stop(self)
        raise OSError("socket already closed")

    monkeypatch.setattr(Server, "stop", broken_stop)
    await srv.stop()
    assert srv.server is None and "socket already closed" in caplog.text
    monkeypatch.setattr(Server, "stop", real_stop)
    await srv.start(timeout=START_UNDER_LOAD)
    try:
        assert srv.alarms["p"].state == "active-unacknowledged"
    finally:
        await srv.stop()
