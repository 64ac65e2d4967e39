"""Who gets a session on our OPC UA server at all, tried with real asyncua clients (issue 38).

- A user known only by a client certificate (carol, operator) has no password: logging in
  by her user name is refused whatever password is sent, so a stolen user name cannot
  acknowledge or shelve alarms. A known user with a wrong or empty password is refused too,
  and the right password and the certificate itself still work.
- A trust list that is empty (or a folder that does not exist yet) refuses every client
  certificate, as docs/reference/connectors.md promises: no session, whoever asks.
"""

from __future__ import annotations

import pytest
from opcua_peers import PASSWORDS, free_port, unit_status, users

from connectors.opcua_server import DiagOpcUaServer, ServerSecurity
from diag_plugin.status import NE107

pytestmark = pytest.mark.anyio


st = unit_status


async def connect(endpoint: str, cert, user: str | None, password: str | None):
    """A connected asyncua client over Basic256Sha256 SignAndEncrypt with ``cert``, logging in
    as ``user`` with ``password`` exactly as given (None: no user token)."""
    from asyncua import Client

    c = Client(endpoint, timeout=10)
    c.application_uri = cert.application_uri
    if user is not None:
        c.set_user(user)
        if password is not None:
            c.set_password(password)
    await c.set_security_string(
        f"Basic256Sha256,SignAndEncrypt,{cert.certificate},{cert.private_key}"
    )
    await c.connect()
    return c


async def test_a_certificate_only_user_cannot_log_in_by_name_with_any_password(
    anyio_backend, keys, tmp_path
):
    from asyncua import ua

    d = keys["dir"]
    sec = ServerSecurity(tmp_path / "srv.pem", tmp_path / "srv.key.pem", d / "trusted", users(keys))
    srv = DiagOpcUaServer(port=free_port(), security=sec)
    await srv.start()
    try:
        await srv.publish(st("pump", NE107.NORMAL))
        await srv.publish(st("pump", NE107.FAILURE))
        srv.actions.clear()
        refused = [
            ("carol", "anything"),  # the certificate-only operator, any password
            ("carol", ""),
            ("carol", None),
            ("alice", "not-alices-password"),
            ("alice", ""),
            ("alice", None),
            ("mallory", "x"),  # nobody of that name
        ]
        for user, password in refused:
            with pytest.raises(ua.uaerrors.BadUserAccessDenied):  # at ActivateSession
                c = await connect(srv.endpoint, keys["hmi"], user, password)
                try:  # had a session been given, this is what it could do
                    await c.get_node(srv.node_id("Units", "pump")).call_method(
                        f"{srv.ns}:Acknowledge"
                    )
                finally:
                    await c.disconnect()
        assert srv.alarms["pump"].state == "active-unacknowledged"
        assert not [a for a in srv.actions if a.ok]
    finally:
        await srv.stop()
    # the right password, and carol by her certificate, still get in (on a fresh server: after
    # these refusals this address and these names are backed off, issue 35 item 3)
    srv = DiagOpcUaServer(port=free_port(), security=sec)
    await srv.start()
    try:
        await srv.publish(st("pump", NE107.NORMAL))
        await srv.publish(st("pump", NE107.FAILURE))
        c = await connect(srv.endpoint, keys["hmi"], "alice", PASSWORDS["alice"])
        await c.disconnect()
        c = await connect(srv.endpoint, keys["carol"], None, None)
        try:
            node = c.get_node(srv.node_id("Units", "pump"))
            assert await node.call_method(f"{srv.ns}:Acknowledge") is True
        finally:
            await c.disconnect()
        assert srv.actions[-1].user == "carol (operator)" and srv.actions[-1].ok
    finally:
        await srv.stop()


@pytest.mark.parametrize("folder", ["empty", "missing"])
async def test_an_empty_trust_list_refuses_every_client(anyio_backend, keys, tmp_path, folder):
    from asyncua import ua

    trusted = tmp_path / "trusted"
    if folder == "empty":
        trusted.mkdir()
    sec = ServerSecurity(tmp_path / "srv.pem", tmp_path / "srv.key.pem", trusted, users(keys))
    srv = DiagOpcUaServer(port=free_port(), security=sec)
    await srv.start()
    try:
        for cert, user in ((keys["hmi"], "alice"), (keys["carol"], None)):
            password = PASSWORDS.get(user) if user else None
            with pytest.raises(ua.uaerrors.BadCertificateUntrusted):  # at CreateSession
                c = await connect(srv.endpoint, cert, user, password)
                await c.disconnect()
    finally:
        await srv.stop()


def test_a_failing_refusal_listener_still_refuses_and_users_cannot_be_changed(caplog):
    """The permission check refuses a viewer's write even when the listener that hears
    refusals raises (it is logged, never passed on to the server); a user is immutable, so a
    role cannot be raised after the server took it."""
    import dataclasses

    from asyncua import ua
    from asyncua.crypto.permission_rules import UserRole

    from connectors.opcua_access import Identity, OpcUaUser, Permissions
    from connectors.passwords import hash_password

    heard = []

    def listener(ident, what):
        heard.append((ident.label, what))
        raise RuntimeError("listener broke")

    perms = Permissions(on_refused=listener)
    bob = Identity(role=UserRole.User, name="bob", access="viewer")
    write = ua.NodeId(ua.ObjectIds.WriteRequest_Encoding_DefaultBinary)
    assert perms.check_validity(bob, write, b"") is False
    assert heard == [("bob (viewer)", "write")]
    assert "on_refused listener failed" in caplog.text
    u = OpcUaUser("bob", "viewer", hash_password("pw"))
    with pytest.raises(dataclasses.FrozenInstanceError):
        u.role = "operator"
