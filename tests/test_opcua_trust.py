"""Our OPC UA client trusts only servers in its trust list, and checks its node ids.

A rogue asyncua server with a certificate of its own (on 127.0.0.1) gets no session and no
password: the client refuses it after GetEndpoints, naming the fingerprint and saving the
certificate in ``rejected/``; moved into the trust folder, the next retry connects, with no
restart. A pinned certificate that does not match is refused the same way. ``nsu=`` node ids
resolve through the namespace array; an unknown node, namespace or a node that is no
variable is named (tag, node id, reason) and only that tag is Bad.
"""

from __future__ import annotations

import asyncio
import math

import pytest
from opcua_peers import free_port, security_of

from connectors.base import TagQuality
from connectors.certs import certificate_der, fingerprint, make_certificate
from connectors.opcua_client import OpcUaConfig, OpcUaReader
from connectors.opcua_server import NAMESPACE, DiagOpcUaServer

pytestmark = pytest.mark.anyio


class Recorder:
    """The rogue server's user manager: every login attempt it sees."""

    def __init__(self) -> None:
        self.logins: list[tuple[str | None, str | None]] = []

    def get_user(self, iserver, username=None, password=None, certificate=None):
        from asyncua.crypto.permission_rules import User, UserRole

        self.logins.append((username, password))
        return User(role=UserRole.User, name=username)


async def rogue_server(tmp_path, port: int):
    """A plain asyncua server (not ours) with its own certificate and one Double variable."""
    from asyncua import Server, ua

    cert = make_certificate(tmp_path / "rogue", "rogue", "urn:rogue", server=True, client=False)
    rec = Recorder()
    srv = Server(user_manager=rec)
    await srv.init()
    srv.set_endpoint(f"opc.tcp://127.0.0.1:{port}/rogue/")
    await srv.set_application_uri("urn:rogue")
    await srv.load_certificate(str(cert.certificate))
    await srv.load_private_key(str(cert.private_key))
    srv.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt])
    srv.set_identity_tokens([ua.UserNameIdentityToken])
    ns = await srv.register_namespace("urn:rogue:plant")
    var = await srv.nodes.objects.add_variable(ua.NodeId("F", ns), "F", 42.0)
    await srv.start()
    return srv, rec, cert, var


async def until(pred, timeout: float = 20.0) -> bool:
    end = asyncio.get_running_loop().time() + timeout
    while asyncio.get_running_loop().time() < end:
        if await pred():
            return True
        await asyncio.sleep(0.1)
    return False


async def test_rogue_server_gets_no_password_until_trusted(anyio_backend, tmp_path, caplog):
    port = free_port()
    srv, rec, rogue, var = await rogue_server(tmp_path, port)
    ours = make_certificate(tmp_path / "ours", "ours", "urn:diag-plugin:test:client")
    trusted = tmp_path / "pki" / "trusted"
    trusted.mkdir(parents=True)
    sec = security_of(ours, "diag", "plant-secret", trusted_dir=trusted)
    cfg = OpcUaConfig(
        f"opc.tcp://127.0.0.1:{port}/rogue/",
        {"F": var.nodeid.to_string()},
        security=sec,
        timeout=3.0,
        backoff_base=0.2,
        backoff_cap=0.5,
    )
    r = OpcUaReader(cfg)
    await r.start()
    try:
        assert not await r.wait_connected(3)
        (s,) = await r.read()
        fp = fingerprint(certificate_der(rogue.certificate))
        assert s.quality is TagQuality.BAD and "not trusted" in s.reason and fp in s.reason
        assert rec.logins == []  # no session, no password
        (saved,) = (tmp_path / "pki" / "rejected").iterdir()
        assert certificate_der(saved) == certificate_der(rogue.certificate)
        warned = [m.getMessage() for m in caplog.records if "not trusted" in m.getMessage()]
        assert len(warned) == 1, warned  # said once, not at every retry
        saved.rename(trusted / saved.name)  # the administrator trusts it: no restart
        assert await r.wait_connected(15)

        async def good() -> bool:
            (x,) = await r.read()
            return x.quality is TagQuality.GOOD and x.value == 42.0

        assert await until(good)
        assert rec.logins == [("diag", "plant-secret")]
    finally:
        await r.close()
        await srv.stop()


async def test_pinned_certificate_mismatch_refused(anyio_backend, tmp_path):
    port = free_port()
    srv, rec, rogue, var = await rogue_server(tmp_path, port)
    real = make_certificate(tmp_path / "real", "real", "urn:real", server=True, client=False)
    ours = make_certificate(tmp_path / "ours", "ours", "urn:diag-plugin:test:client")
    sec = security_of(ours, "diag", "plant-secret", server_certificate=real.certificate)
    r = OpcUaReader(
        OpcUaConfig(
            f"opc.tcp://127.0.0.1:{port}/rogue/", {"F": var.nodeid.to_string()}, security=sec
        )
    )
    await r.start()
    try:
        assert not await r.wait_connected(3)
        (s,) = await r.read()
        assert "not the pinned" in s.reason
        assert fingerprint(certificate_der(real.certificate)) in s.reason
        assert rec.logins == []
    finally:
        await r.close()
        await srv.stop()


async def test_nsu_node_ids_resolve_and_bad_ones_are_named(anyio_backend, caplog):
    srv = DiagOpcUaServer(port=free_port(), plant_tags=("F", "P2"))
    await srv.start()
    await srv.update_plant({"F": 12.5, "P2": 801.0})
    nodes = {
        "F": f"nsu={NAMESPACE};s=Plant.F",
        "P2": srv.node_id("Plant", "P2"),
        "GONE": srv.node_id("Plant", "P9"),
        "ELSEWHERE": "nsu=urn:no-such-namespace;s=Plant.F",
        "FOLDER": f"nsu={NAMESPACE};s=Plant",
    }
    for mode in ("poll", "subscription"):
        r = OpcUaReader(OpcUaConfig(srv.endpoint, nodes, mode=mode, period=0.1))
        await r.start()
        try:
            assert await r.wait_connected(15)

            async def ready(r: OpcUaReader = r) -> bool:
                got = {s.tag: s for s in await r.read()}
                return got["F"].good and got["P2"].good

            assert await until(ready)
            got = {s.tag: s for s in await r.read()}
            assert got["F"].value == 12.5 and got["P2"].value == 801.0
            assert set(r.bad_nodes) == {"GONE", "ELSEWHERE", "FOLDER"}
            assert r.bad_nodes["GONE"] == "BadNodeIdUnknown"
            assert "urn:no-such-namespace" in r.bad_nodes["ELSEWHERE"]
            assert "not a variable" in r.bad_nodes["FOLDER"]
            for tag in ("GONE", "ELSEWHERE", "FOLDER"):
                assert got[tag].quality is TagQuality.BAD and math.isnan(got[tag].value)
                assert nodes[tag] in got[tag].reason
        finally:
            await r.close()
    await srv.stop()
    named = [m.getMessage() for m in caplog.records if "tag GONE" in m.getMessage()]
    assert len(named) == 2 and "ns=2;s=Plant.P9" in named[0]  # once per reader
