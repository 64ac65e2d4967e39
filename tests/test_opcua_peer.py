"""Our OPC UA server against a client we did not write: node-opcua (npm), on 127.0.0.1.

The server offers only Basic256Sha256 SignAndEncrypt with user/password and a trust list.
node-opcua browses the units, reads a unit's status, receives AlarmConditionType events and
acknowledges through the unit's Acknowledge method, and — as an HMI does — through Part 9's
standard Acknowledge (i=9111) naming the event's EventId, after a ConditionRefresh brought
it the alarm raised before it subscribed; a viewer's acknowledgement is refused; an
untrusted client certificate, a wrong password and an anonymous login are refused. Our own
client connects with the same security.

node-opcua is installed by ``cd tests/peers/opcua && npm ci`` (``make test`` does it);
without it these tests skip locally and fail on CI.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import shutil
from pathlib import Path

import pandas as pd
import pytest
from helpers import REPO, free_port, requires
from opcua_peers import security_of

from connectors.base import TagQuality
from connectors.certs import CertPair, make_certificate, trust
from connectors.opcua_access import OpcUaUser
from connectors.opcua_client import OpcUaConfig, OpcUaReader
from connectors.opcua_server import DiagOpcUaServer, ServerSecurity
from connectors.passwords import hash_password
from diag_plugin.status import NE107, Quality, UnitStatus

PEER = REPO / "tests" / "peers" / "opcua"
HAVE_NODE = shutil.which("node") is not None and (PEER / "node_modules" / "node-opcua").is_dir()
need_node = requires("node-opcua (npm)", HAVE_NODE, "cd tests/peers/opcua && npm ci; node >= 18")

pytestmark = pytest.mark.anyio
USER, PASSWORD = "operator", "s3cret-pw"
VIEWER, VIEWER_PASSWORD = "watcher", "look-only-pw"


@pytest.fixture(scope="module")
def pki(tmp_path_factory) -> dict[str, CertPair | Path]:
    d = tmp_path_factory.mktemp("pki")
    server = make_certificate(
        d / "server", "server", "urn:diag-plugin:server", server=True, client=False
    )
    good = make_certificate(d / "clients", "peer", "urn:diag-plugin:test:peer")
    ours = make_certificate(d / "clients", "ours", "urn:diag-plugin:test:ours")
    stranger = make_certificate(d / "strangers", "peer", "urn:diag-plugin:test:peer")
    trust(good, d / "trusted")
    trust(ours, d / "trusted")
    trust(server, d / "trusted_servers")  # our client trusts this server
    return {"server": server, "good": good, "ours": ours, "stranger": stranger, "dir": d}


@pytest.fixture(scope="module")
async def server(anyio_backend, pki):
    s = pki["server"]
    users = (
        OpcUaUser(USER, "operator", hash_password(PASSWORD)),
        OpcUaUser(VIEWER, "viewer", hash_password(VIEWER_PASSWORD)),
    )
    sec = ServerSecurity(s.certificate, s.private_key, pki["dir"] / "trusted", users)
    srv = DiagOpcUaServer(port=free_port(), security=sec)
    await srv.start()
    await srv.publish(unit_status(NE107.NORMAL, 0.0))
    yield srv
    await srv.stop()


def unit_status(st: NE107, c: float) -> UnitStatus:
    return UnitStatus(
        "valve",
        pd.Timestamp.now(tz="UTC"),
        st,
        Quality.GOOD,
        residuals={"r1": 5.0 if st else 0.1},
        certainties={"f_S": c},
        coverage={"F": 1.0},
        detected=st != NE107.NORMAL,
        faults=["f_S"] if st != NE107.NORMAL else [],
    )


async def node_peer(
    srv: DiagOpcUaServer,
    cert: CertPair,
    tmp: Path,
    on_ready=None,
    password: str = PASSWORD,
    user: str = USER,
    **extra,
) -> list[dict]:
    """Run the node-opcua client script; ``on_ready`` runs once it subscribed to events."""
    args = {
        "url": srv.endpoint,
        "unit": "valve",
        "cert": "f_S",
        "certificateFile": str(cert.certificate),
        "privateKeyFile": str(cert.private_key),
        "applicationUri": cert.application_uri,
        "user": user,
        "password": password,
        "pkiDir": str(tmp / "node-pki"),
        "timeoutMs": 30000,
        **extra,
    }
    p = await asyncio.create_subprocess_exec(
        "node",
        str(PEER / "client.js"),
        json.dumps(args),
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
    )
    lines: list[dict] = []
    try:
        while line := await asyncio.wait_for(p.stdout.readline(), 40):
            if not line.startswith(b'{"step"'):
                continue  # node-opcua's own messages on stdout
            msg = json.loads(line)
            lines.append(msg)
            if msg["step"] == "ready" and on_ready is not None:
                await on_ready()
        await asyncio.wait_for(p.wait(), 10)
    finally:
        if p.returncode is None:
            p.kill()
            await p.wait()
    if p.returncode not in (0, 2):
        err = (await p.stderr.read()).decode()[-3000:]
        pytest.fail(f"node peer exited {p.returncode}: {lines} {err}")
    return lines


@need_node
async def test_node_opcua_browses_reads_and_gets_alarms(server, pki, tmp_path):
    async def raise_fault():
        await server.publish(unit_status(NE107.FAILURE, 0.9))

    lines = await node_peer(
        server, pki["good"], tmp_path, raise_fault, waitEvents=2, ackByMethod=True
    )
    steps = {m["step"]: m for m in lines}
    assert "error" not in steps, lines
    assert steps["connected"]["securityMode"] == "SignAndEncrypt"
    assert "valve" in steps["browse"]["units"]
    read = steps["read"]
    assert {"DeviceHealth", "Quality", "Certainty", "Alarm", "Acknowledge"} <= set(read["children"])
    assert read["values"]["DeviceHealth"] == {"value": 0, "status": "Good"}
    events = [m["event"] for m in lines if m["step"] == "event"]
    raised, acked = events[0], events[1]
    assert raised["EventType"] == "ns=0;i=2915"  # AlarmConditionType
    assert raised["SourceName"] == "valve" and raised["ConditionName"] == "Diagnosis"
    assert 801 <= raised["Severity"] <= 1000  # FAILURE: critical band
    assert raised["ActiveState.Id"] is True and raised["AckedState.Id"] is False
    assert raised["Retain"] is True
    assert steps["acknowledge"] == {"step": "acknowledge", "status": "Good", "changed": True}
    assert acked["AckedState.Id"] is True and acked["ActiveState.Id"] is True
    assert server.alarms["valve"].state == "active-acknowledged"
    await server.publish(unit_status(NE107.NORMAL, 0.0))
    assert server.alarms["valve"].state == "normal"


@need_node
async def test_node_opcua_acknowledges_by_part9_after_condition_refresh(server, pki, tmp_path):
    """An HMI's way: subscribe, ConditionRefresh (the alarm raised before is sent again between
    RefreshStart and RefreshEnd), Acknowledge (i=9111) with that event's EventId and a comment;
    the next event shows AckedState true with the comment and who acknowledged."""
    server.actions.clear()
    await server.publish(unit_status(NE107.FAILURE, 0.8))  # raised before the HMI subscribes
    lines = await node_peer(
        server, pki["good"], tmp_path, waitEvents=2, ackStandard=True, refresh=True
    )
    steps = {m["step"]: m for m in lines}
    assert "error" not in steps, lines
    assert steps["refresh"]["status"] == "Good"
    events = [m["event"] for m in lines if m["step"] == "event"]
    types = [e["EventType"] for e in events]
    start, end = types.index("ns=0;i=2787"), types.index("ns=0;i=2788")  # RefreshStart/End
    refreshed = [e for e in events[start:end] if e["SourceName"] == "valve"]
    assert refreshed and refreshed[0]["AckedState.Id"] is False and refreshed[0]["Retain"]
    assert refreshed[0]["ConditionId"].endswith("s=Units.valve.Alarm")
    assert steps["ackStandard"]["status"] == "Good", lines
    acked = [e for e in events if e["EventType"] == "ns=0;i=2915" and e["AckedState.Id"]]
    assert acked and acked[0]["Comment"] == "seen by the peer"
    assert acked[0]["ClientUserId"] == "operator (operator)"
    assert acked[0]["EventId"] != refreshed[0]["EventId"]  # every event its own id
    assert server.alarms["valve"].state == "active-acknowledged"
    (a,) = [a for a in server.actions if a.action == "acknowledge"]
    assert (a.user, a.via, a.ok) == ("operator (operator)", "OPC UA", True)
    await server.publish(unit_status(NE107.NORMAL, 0.0))


@need_node
async def test_node_opcua_viewer_cannot_acknowledge(server, pki, tmp_path):
    server.actions.clear()
    await server.publish(unit_status(NE107.FAILURE, 0.8))
    try:
        lines = await node_peer(
            server,
            pki["good"],
            tmp_path,
            user=VIEWER,
            password=VIEWER_PASSWORD,
            waitEvents=1,
            ackStandard=True,
            refresh=True,
        )
        for _ in range(50):  # the answer to the acknowledgement may come after the event
            if any(m["step"] == "ackStandard" for m in lines):
                break
            await asyncio.sleep(0.1)
        steps = {m["step"]: m for m in lines}
        assert "read" in steps, lines  # a viewer reads and subscribes
        assert server.alarms["valve"].state == "active-unacknowledged"
        refused = [a for a in server.actions if a.action == "refused"]
        assert refused and refused[0].user == f"{VIEWER} (viewer)", server.actions
        assert "9111" in refused[0].detail
    finally:
        await server.acknowledge("valve")
        await server.publish(unit_status(NE107.NORMAL, 0.0))


@need_node
async def test_anonymous_refused_when_not_allowed(server, pki, tmp_path):
    lines = await node_peer(server, pki["good"], tmp_path, anonymous=True)
    assert lines[-1]["step"] == "error", lines
    assert not any(m["step"] == "read" for m in lines)


@need_node
async def test_untrusted_client_certificate_refused(server, pki, tmp_path):
    lines = await node_peer(server, pki["stranger"], tmp_path)
    assert lines[-1]["step"] == "error", lines
    assert "BadCertificateUntrusted" in lines[-1]["message"]
    assert not any(m["step"] == "read" for m in lines)


@need_node
async def test_wrong_password_refused(server, pki, tmp_path):
    lines = await node_peer(server, pki["good"], tmp_path, password="guess")
    assert lines[-1]["step"] == "error", lines
    assert not any(m["step"] == "read" for m in lines)


@contextlib.asynccontextmanager
async def health_reader(server, pki, who: str, **cfg):
    """Our client, as ``pki[who]`` with the operator's password and the server trusted,
    reading the valve unit's DeviceHealth (started, closed after)."""
    sec = security_of(pki[who], USER, PASSWORD, trusted_dir=pki["dir"] / "trusted_servers")
    nodes = {"health": server.node_id("Units", "valve", "DeviceHealth")}
    r = OpcUaReader(OpcUaConfig(server.endpoint, nodes, security=sec, **cfg))
    await r.start()
    try:
        yield r
    finally:
        await r.close()


async def test_our_client_sign_and_encrypt_with_user(server, pki):
    async with health_reader(server, pki, "ours", timeout=4.0) as r:
        assert await r.wait_connected(20)
        (s,) = await r.read()
        assert s.quality is TagQuality.GOOD and s.value in (0, 1)


async def test_our_client_untrusted_certificate_stays_bad(server, pki):
    # we trust the server; it refuses us
    async with health_reader(server, pki, "stranger", backoff_cap=1.0) as r:
        assert not await r.wait_connected(3)
        (s,) = await r.read()
        assert s.quality is TagQuality.BAD and r.outages == 1
