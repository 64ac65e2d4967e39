"""Our OPC UA client against our OPC UA server on 127.0.0.1 (no mocks).

Polling and subscription, quality propagation (Good/Uncertain/Bad), unit status and alarm
over the wire, writes refused outside the allow-list, and a server stopped mid-run and
restarted: the client's tags go Bad, then Good again on their own.
"""

from __future__ import annotations

import asyncio
import math
from datetime import UTC, datetime

import pandas as pd
import pytest
from helpers import free_port

from connectors.base import TagQuality, TagSample, WriteRefused
from connectors.opcua_client import OpcUaConfig, OpcUaReader, quality_of
from connectors.opcua_server import DEFAULT_PLANT_TAGS, DiagOpcUaServer
from diag_plugin.status import NE107, Quality, UnitStatus

pytestmark = pytest.mark.anyio


def status(st: NE107 = NE107.FAILURE, q: Quality = Quality.GOOD, c: float = 0.9) -> UnitStatus:
    return UnitStatus(
        "valve",
        pd.Timestamp.now(tz="UTC"),
        st,
        q,
        residuals={"r1": 4.5, "r2": -0.2},
        symptoms={"r1": 1.0, "r2": 0.0},
        certainties={"f_S": c, "f_X": 0.1},
        coverage={"F": 0.98},
        detected=st != NE107.NORMAL,
        faults=["f_S"] if st == NE107.FAILURE else [],
    )


@pytest.fixture(scope="module")
async def server(anyio_backend):
    srv = DiagOpcUaServer(port=free_port())
    await srv.start()
    yield srv
    await srv.stop()


def plant_nodes(srv: DiagOpcUaServer) -> dict[str, str]:
    return {t: srv.node_id("Plant", t) for t in DEFAULT_PLANT_TAGS}


async def until(pred, timeout: float = 15.0, step: float = 0.1) -> bool:
    """Wait until ``pred()`` is true (or ``timeout`` s)."""
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout
    while loop.time() < end:
        if pred():
            return True
        await asyncio.sleep(step)
    return pred()


def test_quality_of_status_codes():
    from asyncua import ua

    assert quality_of(ua.StatusCode(ua.StatusCodes.Good)) is TagQuality.GOOD
    assert quality_of(ua.StatusCode(ua.StatusCodes.UncertainLastUsableValue)) is (
        TagQuality.UNCERTAIN
    )
    assert quality_of(ua.StatusCode(ua.StatusCodes.BadCommunicationError)) is TagQuality.BAD
    assert quality_of(None) is TagQuality.GOOD


def test_plant_tags_are_simulator_tags():
    from diag_plugin.simulate import TAGS

    assert set(DEFAULT_PLANT_TAGS) <= set(TAGS)


async def mixed_plant(srv: DiagOpcUaServer) -> None:
    t = datetime.now(UTC)
    await srv.update_plant(
        {
            "F": 12.5,
            "CV": TagSample("CV", 40.0, t, TagQuality.UNCERTAIN),
            "X": TagSample("X", 39.0, t, TagQuality.BAD),
            "P0": 1.0,
            "P1": 500.0,
            "P2": 300.0,
            "T1": 80.0,
        }
    )


@pytest.mark.parametrize("mode", ["poll", "subscription"])
async def test_reader_quality_propagation(server, mode):
    await mixed_plant(server)
    r = OpcUaReader(OpcUaConfig(server.endpoint, plant_nodes(server), mode=mode, period=0.1))
    await r.start()
    try:
        assert await r.wait_connected(15)

        async def by_tag():
            return {s.tag: s for s in await r.read()}

        got: dict[str, TagSample] = {}

        async def ready():
            got.update(await by_tag())
            return got["F"].good and got["F"].value == 12.5

        loop = asyncio.get_running_loop()
        end = loop.time() + 10
        while not await ready() and loop.time() < end:
            await asyncio.sleep(0.1)
        assert got["F"].quality is TagQuality.GOOD and got["F"].value == 12.5
        assert got["CV"].quality is TagQuality.UNCERTAIN and got["CV"].value == 40.0
        assert got["X"].quality is TagQuality.BAD and math.isnan(got["X"].value)
        assert got["X"].reason  # the StatusCode name
        assert got["T1"].value == 80.0
    finally:
        await r.close()


async def test_unit_status_and_alarm_over_the_wire(server):
    await server.publish(status(NE107.FAILURE, Quality.GOOD, 0.9))
    nodes = {
        "health": server.node_id("Units", "valve", "DeviceHealth"),
        "cert": server.node_id("Units", "valve", "Certainty", "f_S"),
        "res": server.node_id("Units", "valve", "Residual", "r1"),
        "sev": server.node_id("Units", "valve", "Alarm", "Severity"),
        "ack": server.node_id("Units", "valve", "Alarm", "AckRequest"),
    }
    r = OpcUaReader(OpcUaConfig(server.endpoint, nodes, outputs=("ack",)))
    await r.start()
    try:
        assert await r.wait_connected(15)
        s = {x.tag: x for x in await r.read()}
        assert s["health"].value == NE107.FAILURE and s["health"].good
        assert s["cert"].value == pytest.approx(0.9) and s["res"].value == 4.5
        assert 801 <= s["sev"].value <= 1000
        assert server.alarms["valve"].state == "active-unacknowledged"
        # an anonymous session may read, never acknowledge (operators only)
        assert "BadUserAccessDenied" in (await r.write({"ack": 1.0}))["ack"]
        assert server.alarms["valve"].state == "active-unacknowledged"
        await server.acknowledge("valve")
        assert server.alarms["valve"].state == "active-acknowledged"
        # the diagnosis cannot be trusted: values carry Uncertain/Bad
        await server.publish(status(NE107.CHECK_FUNCTION, Quality.BAD))
        s = {x.tag: x for x in await r.read()}
        assert s["health"].value == NE107.CHECK_FUNCTION
        assert s["health"].quality is TagQuality.UNCERTAIN
        assert s["cert"].quality is TagQuality.BAD
        await server.publish(status(NE107.OFF_SPEC, Quality.UNCERTAIN, 0.5))
        s = {x.tag: x for x in await r.read()}
        assert s["cert"].quality is TagQuality.UNCERTAIN and s["cert"].value == 0.5
        assert 601 <= s["sev"].value <= 800
        await server.publish(status(NE107.NORMAL))
        assert server.alarms["valve"].state == "normal"
    finally:
        await r.close()


async def test_writes_outside_allow_list_refused(server):
    nodes = plant_nodes(server) | {"ack": server.node_id("Units", "valve", "Alarm", "AckRequest")}
    r = OpcUaReader(OpcUaConfig(server.endpoint, nodes, outputs=("ack",)))
    await r.start()
    try:
        assert await r.wait_connected(15)
        with pytest.raises(WriteRefused, match="F"):
            await r.write({"F": 1.0})
        with pytest.raises(WriteRefused):
            await r.write({"ack": 1.0, "CV": 3.0})  # all or nothing
    finally:
        await r.close()


@pytest.mark.parametrize("mode", ["poll", "subscription"])
async def test_server_restart_bad_then_good(mode, caplog):
    srv = DiagOpcUaServer(port=free_port())
    await srv.start()
    await srv.update_plant(dict.fromkeys(DEFAULT_PLANT_TAGS, 1.0))
    cfg = OpcUaConfig(
        srv.endpoint,
        plant_nodes(srv),
        mode=mode,
        period=0.1,
        timeout=1.0,
        backoff_base=0.2,
        backoff_cap=1.0,
    )
    r = OpcUaReader(cfg)
    await r.start()
    latest: dict[str, TagSample] = {}

    async def all_quality(q: TagQuality, timeout: float) -> bool:
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout
        while loop.time() < end:
            latest.update({s.tag: s for s in await r.read()})
            if all(s.quality is q for s in latest.values()):
                return True
            await asyncio.sleep(0.1)
        return False

    try:
        assert await all_quality(TagQuality.GOOD, 15)
        await srv.stop()
        assert await all_quality(TagQuality.BAD, 15), latest
        await asyncio.sleep(1.5)  # a few failed reconnects: logged once, not per attempt
        await srv.start()
        await srv.update_plant(dict.fromkeys(DEFAULT_PLANT_TAGS, 2.0))
        assert await all_quality(TagQuality.GOOD, 20), latest
        for _ in range(50):  # the values written after the restart arrive
            latest.update({s.tag: s for s in await r.read()})
            if latest["F"].value == 2.0:
                break
            await asyncio.sleep(0.1)
        assert latest["F"].value == 2.0
        assert r.outages == 1
        ((start, end),) = r.gaps  # the first connect is no outage; the restart is one
        assert end is not None and end > start
        msgs = [m.getMessage() for m in caplog.records if m.name == "connectors.opcua_client"]
        assert sum("unavailable" in m for m in msgs) == 1, msgs
        assert sum("restored" in m for m in msgs) == 1, msgs
    finally:
        await r.close()
        await srv.stop()


class CancelSwallowingReader(OpcUaReader):
    """Stands in for asyncua's nested ``wait_for``: a cancel that arrives while the answer is
    already in is dropped, and the connect completes as if nothing had been asked."""

    connecting: asyncio.Event

    async def _connect(self) -> None:
        async def slow() -> None:
            await asyncio.sleep(0.3)
            await OpcUaReader._connect(self)

        inner = asyncio.ensure_future(slow())
        self.connecting.set()
        try:
            await asyncio.shield(inner)
        except asyncio.CancelledError:
            await inner


async def test_close_returns_when_the_library_swallows_the_cancel(server, caplog):
    r = CancelSwallowingReader(OpcUaConfig(server.endpoint, plant_nodes(server), timeout=2.0))
    r.connecting = asyncio.Event()
    await r.start()
    await r.connecting.wait()
    async with asyncio.timeout(10):  # hung for good before close() woke the connected loop
        await r.close()
    assert r.outages == 0 and not await r.wait_connected(0.1)
    msgs = [m.getMessage() for m in caplog.records if m.name == "connectors.opcua_client"]
    assert not any("unavailable" in m or "lost" in m for m in msgs), msgs


@pytest.fixture
def threaded_server():
    """Our OPC UA server on an event loop of its own thread: it answers while the test's
    loop is held (as a loaded machine holds a live loop between two of its steps)."""
    import threading
    import time

    loop = asyncio.new_event_loop()
    srv = DiagOpcUaServer(port=free_port())
    ready = threading.Event()

    def serve() -> None:
        asyncio.set_event_loop(loop)
        loop.run_until_complete(srv.start())
        loop.run_until_complete(srv.update_plant(dict.fromkeys(DEFAULT_PLANT_TAGS, 3.0)))
        ready.set()
        loop.run_forever()

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    assert ready.wait(60)
    # hold(s): the server's loop busy for s seconds (a slow server, or one on a loaded machine)
    srv.hold = lambda seconds: loop.call_soon_threadsafe(time.sleep, seconds)
    yield srv
    asyncio.run_coroutine_threadsafe(srv.stop(), loop).result(30)
    loop.call_soon_threadsafe(loop.stop)
    thread.join(30)


async def test_a_read_answered_as_its_timeout_runs_out_is_a_timeout(threaded_server, caplog):
    """The reader's loop held past the read timeout while the server answers: the answer and
    the timeout land in one loop iteration, as on a loaded machine. Before, asyncua's nested
    ``wait_for`` made that a ``CancelledWithResultError``, which escaped ``read()`` (the live
    loop logged "scada: poll failed: CancelledError()"), and a read that timed out dropped
    the connection. Now the read returns the tags Bad with a reason naming the server, the
    tags, the timeout and the wait; the session is kept and the next read is Good."""
    import time

    srv = threaded_server
    r = OpcUaReader(OpcUaConfig(srv.endpoint, plant_nodes(srv), timeout=0.2))
    await r.start()
    try:
        assert await r.wait_connected(30)

        async def good() -> bool:  # a read on a loaded machine may itself be late: retried
            for _ in range(100):
                samples = await r.read()
                if all(s.quality is TagQuality.GOOD and s.value == 3.0 for s in samples):
                    return True
                await asyncio.sleep(0.1)
            return False

        assert await good()
        timeouts = getattr(r, "read_timeouts", 0)  # (main has no such counter)
        held = []
        for _ in range(3):
            task = asyncio.ensure_future(r.read())
            await asyncio.sleep(0)  # the Read request goes out
            # the loop held past the read's timeout (0.2 s), not past asyncua's watchdog probe's
            # (0.5 s); the server answers meanwhile
            time.sleep(0.35)
            await asyncio.wait({task})
            assert not task.cancelled(), "a CancelledError escaped read()"
            held.append(task.result())
        for samples in held:
            assert all(s.quality is TagQuality.BAD for s in samples), samples
            why = samples[0].reason
            assert why.startswith(f"no answer from {srv.endpoint} to the Read of 7 tags"), why
            assert "(F, CV, X, P0, P1 and 2 more) within the 0.2 s timeout" in why, why
            assert float(why.split("(waited ")[1].split(" s)")[0]) >= 0.35, why
        assert r.read_timeouts - timeouts == 3
        assert await good() and r.connected and r.outages == 0
    finally:
        await r.close()
    msgs = [m.getMessage() for m in caplog.records if m.name == "connectors.opcua_client"]
    assert not any("unavailable" in m for m in msgs), msgs


async def good_read(r: OpcUaReader, value: float = 3.0) -> bool:
    """A read of every tag Good with ``value`` (retried: on a loaded machine a read may itself
    be late)."""
    for _ in range(100):
        if all(s.quality is TagQuality.GOOD and s.value == value for s in await r.read()):
            return True
        await asyncio.sleep(0.1)
    return False


async def test_a_late_watchdog_answer_keeps_the_session(threaded_server, caplog):
    """asyncua's watchdog reads the server's state every interval and waits as long as the
    interval for the answer; a probe without an answer in time drops the session. Its interval
    came from the reads' timeout (0.5 s at 0.1 s): a server held 1.2 s (busy, or on a loaded
    machine; our stand-in server shares the live loop's event loop) dropped the session at
    every hold, 3 of 3, the source "unavailable" and back. Now the watchdog waits
    ``silent_after`` (5 s): the reads during the hold are late (Bad), the session is kept."""
    srv = threaded_server
    r = OpcUaReader(OpcUaConfig(srv.endpoint, plant_nodes(srv), timeout=0.1))
    await r.start()
    try:
        assert await r.wait_connected(30)
        assert await good_read(r)
        for _ in range(2):
            srv.hold(1.2)
            loop = asyncio.get_running_loop()
            end = loop.time() + 1.6
            while loop.time() < end:  # polled as the live loop polls, through the hold
                await r.read()
                await asyncio.sleep(0.1)
            assert r.outages == 0, "a late watchdog answer dropped the session"
        assert r.read_timeouts >= 1  # the reads during the holds were late
        assert await good_read(r) and r.connected and r.outages == 0
    finally:
        await r.close()
    msgs = [m.getMessage() for m in caplog.records if m.name == "connectors.opcua_client"]
    assert not any("unavailable" in m for m in msgs), msgs


async def test_a_server_silent_past_silent_after_is_lost_and_found_again(threaded_server):
    """The other side of the watchdog: a server that stops answering (the connection still
    open) for longer than ``silent_after`` is a lost connection (tags Bad "no connection"),
    and the reader reconnects by itself once it answers again."""
    srv = threaded_server
    r = OpcUaReader(OpcUaConfig(srv.endpoint, plant_nodes(srv), timeout=0.1, silent_after=0.5))
    await r.start()
    try:
        assert await r.wait_connected(30)
        assert await good_read(r)
        srv.hold(3.0)
        assert await until(lambda: r.outages == 1, timeout=2.8)
        assert all("no connection" in s.reason for s in await r.read())
        assert await good_read(r) and r.connected and r.outages == 1
        assert r.gaps[0][1] is not None
    finally:
        await r.close()
