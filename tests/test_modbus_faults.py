"""Modbus faults: server killed and restarted, exception reply, wrong unit id, slow and
malformed replies. Tags go Bad with a reason; read() never raises; recovery is on its own."""

from __future__ import annotations

import asyncio
import logging
import signal
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from modbus_peers import (
    PLC_MAP,
    answering_server,
    free_port,
    needs_pymodbustcp,
    raw_server,
    read_request,
    registers_reply,
    reply,
    start_plc,
)

from connectors.base import Backoff, TagQuality
from connectors.modbus import ModbusTagClient
from connectors.modbus_server import RegisterServer
from connectors.registermap import RegisterMap

HERE = Path(__file__).resolve().parent
ONE = RegisterMap.parse("tag,table,address,type\nA,hr,0,float32\nB,hr,2,uint16\n")
MOD = "connectors.modbus"


def run(coro, timeout: float = 90.0):
    async def main():
        return await asyncio.wait_for(coro, timeout)

    return asyncio.run(main())


def _plc_process(port: int) -> subprocess.Popen:
    p = subprocess.Popen(
        [sys.executable, str(HERE / "modbus_peers.py"), str(port)],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert p.stdout is not None and p.stdout.readline().strip() == "ready"
    return p


@needs_pymodbustcp
def test_plc_killed_mid_run_and_restarted(caplog):
    """Tags Bad during the outage, Good again on their own; one warning, one recovery."""
    caplog.set_level(logging.INFO, logger=MOD)
    port = free_port()
    plc = _plc_process(port)
    regmap = RegisterMap.parse(PLC_MAP)

    async def main():
        c = ModbusTagClient(
            regmap, port=port, timeout=0.3, backoff=Backoff(base=0.05, cap=0.4, seed=1)
        )
        history: list[tuple[str, bool, str]] = []
        try:
            for _ in range(5):
                p = await c.poll()
                history.append(("before", p.good, p.reasons[0]))
                await asyncio.sleep(0.05)
            plc.send_signal(signal.SIGKILL)
            plc.wait(10)
            connects_before = c.connects
            for _ in range(20):
                p = await c.poll()
                history.append(("outage", p.good, p.reasons[0]))
                assert np.isnan(p.values).all()
                await asyncio.sleep(0.05)
            restarted = await asyncio.get_running_loop().run_in_executor(None, _plc_process, port)
            for _ in range(200):
                p = await c.poll()
                history.append(("after", p.good, p.reasons[0]))
                if p.good:
                    break
                await asyncio.sleep(0.05)
            for _ in range(5):
                p = await c.poll()
                history.append(("after", p.good, p.reasons[0]))
            return history, c.connects - connects_before, restarted, p
        finally:
            await c.close()

    try:
        history, reconnects, restarted, last = run(main())
    finally:
        plc.kill()
        if "restarted" in locals():
            restarted.kill()
            restarted.wait(10)
    assert all(ok for phase, ok, _ in history if phase == "before")
    outage = [(ok, why) for phase, ok, why in history if phase == "outage"]
    assert not any(ok for ok, _ in outage)
    assert all(why for _, why in outage)
    assert any("not connected" in why or "connection" in why for _, why in outage)
    assert history[-1][1] and last.good and last.values[0] == 12.5
    assert reconnects == 1
    warnings = [r for r in caplog.records if r.name == MOD and r.levelno == logging.WARNING]
    recovered = [r for r in caplog.records if r.name == MOD and "recovered" in r.getMessage()]
    assert len(warnings) == 1, [r.getMessage() for r in warnings]
    assert len(recovered) == 1


@needs_pymodbustcp
def test_exception_reply_makes_only_that_block_bad():
    """Reading an address the PLC does not have: exception 2, other blocks stay Good."""
    port = free_port()
    srv = start_plc(port, size=64)
    regmap = RegisterMap.parse(PLC_MAP + "FAR,hr,500,float32,ABCD,1,0,\n")

    async def main():
        c = ModbusTagClient(regmap, port=port, timeout=1.0)
        try:
            first = await c.read()
            second = await c.read()
            return first, second, c.connected
        finally:
            await c.close()

    try:
        first, second, connected = run(main())
    finally:
        srv.stop()
    got = {s.tag: s for s in second}
    assert got["FAR"].quality == TagQuality.BAD
    assert "exception reply 2" in got["FAR"].reason and "illegal data address" in got["FAR"].reason
    assert np.isnan(got["FAR"].value)
    assert got["F"].quality == TagQuality.GOOD and got["F"].value == 12.5
    assert all(s.quality == TagQuality.GOOD for s in second if s.tag != "FAR")
    assert connected  # an exception reply is an answer: the connection stays


def test_wrong_unit_id_our_server():
    """A server serving unit 1 asked for unit 7: an exception reply → Bad, no crash."""

    async def main():
        srv = RegisterServer(ONE, device_id=1)
        await srv.start()
        await srv.update({"A": 1.5, "B": 3})
        good = ModbusTagClient(ONE, port=srv.port, device_id=1)
        wrong = ModbusTagClient(ONE, port=srv.port, device_id=7, timeout=0.5)
        try:
            return await good.read(), await wrong.read()
        finally:
            await good.close()
            await wrong.close()
            await srv.stop()

    good, wrong = run(main())
    assert [s.value for s in good] == [1.5, 3]
    assert all(s.quality == TagQuality.BAD and "exception reply" in s.reason for s in wrong)


def test_reply_from_a_wrong_unit_id():
    """A gateway answering with another unit id than asked: Bad with the reason."""

    async def answer(tid, unit, pdu):
        return reply(tid, unit + 1, registers_reply(pdu, 0x4000))

    async def main():
        srv, port = await answering_server(answer)
        c = ModbusTagClient(ONE, port=port, device_id=3, timeout=0.3, backoff=Backoff(0.05, 0.1))
        try:
            return await c.read(), await c.read()
        finally:
            await c.close()
            srv.close()

    first, second = run(main())
    for s in first + second:
        assert s.quality == TagQuality.BAD, s
    assert "reply from unit id 4, not 3" in first[0].reason, first[0].reason


@pytest.mark.parametrize("delay", [None, 2.0], ids=["never-answers", "answers-late"])
def test_slow_server_times_out_and_backs_off(delay):
    """Accepts, then never answers (or too late): Bad per poll, late until no request has
    been answered in time for ``silent_after`` (0.5 s), then dropped; reconnects spaced out."""
    accepted: list[float] = []

    async def answer(tid, unit, pdu):
        if delay is None:
            return None
        await asyncio.sleep(delay)
        return reply(tid, unit, registers_reply(pdu))

    async def main():
        srv, port = await answering_server(
            answer, lambda: accepted.append(asyncio.get_running_loop().time())
        )
        c = ModbusTagClient(
            ONE, port=port, timeout=0.2, backoff=Backoff(0.1, 0.8, seed=2), silent_after=0.5
        )
        loop = asyncio.get_running_loop()
        polls = []
        try:
            t0 = loop.time()
            while loop.time() - t0 < 3.0:
                t = loop.time()
                samples = await c.read()
                polls.append((loop.time() - t, samples))
                await asyncio.sleep(0.05)
            return polls
        finally:
            await c.close()
            srv.close()

    polls = run(main())
    for took, samples in polls:
        assert took < 0.2 + 0.5  # one timeout at most, never one per block
        assert all(s.quality == TagQuality.BAD for s in samples)
    reasons = {s.reason for _, samples in polls for s in samples}
    assert any("timeout after 0.2 s" in r for r in reasons), reasons
    assert any("no request answered in time for" in r for r in reasons), reasons
    assert any("not connected" in r for r in reasons), reasons
    gaps = np.diff(accepted)
    assert 2 <= len(accepted) <= 12  # reconnects, but not one per poll (~45 polls)
    assert gaps.max() > 0.15  # backoff grows


def test_malformed_reply_is_bad_not_a_crash():
    """Garbage instead of a Modbus frame, then a short reply: Bad, connection renewed."""
    n = {"conn": 0}

    async def answer(tid, unit, pdu):
        if n["conn"] % 2:
            return b"\xde\xad\xbe\xef garbage, not modbus \x00\xff" * 3
        return reply(tid, unit, bytes([pdu[0], 6, 0x41, 0x48]))  # 3 registers claimed, 1 sent

    def connected():
        n["conn"] += 1

    async def main():
        srv, port = await answering_server(answer, connected)
        c = ModbusTagClient(ONE, port=port, timeout=0.3, backoff=Backoff(0.02, 0.05, seed=3))
        out = []
        try:
            for _ in range(12):
                out.append(await c.read())
                await asyncio.sleep(0.1)
            return out, c.connects
        finally:
            await c.close()
            srv.close()

    out, connects = run(main())
    for samples in out:
        assert all(s.quality == TagQuality.BAD and s.reason for s in samples)
    reasons = {s.reason for samples in out for s in samples}
    assert any(
        r.startswith("malformed reply reading hr 0+3: 81 bytes de ad be ef") for r in reasons
    )
    assert any("malformed reply reading hr 0+3: 11 bytes" in r for r in reasons), reasons
    assert connects >= 2


TWO_BLOCKS = RegisterMap.parse(
    "tag,table,address,type\nA,hr,0,uint16\nB,hr,1,uint16\nC,hr,10,uint16\nD,hr,11,uint16\n"
)


def tagged_reply(tid: int, unit: int, pdu: bytes) -> bytes:
    """A read-registers reply whose every word says which request and address it answers:
    100 * (transaction id % 600) + address."""
    fc, addr, count = struct.unpack(">BHH", pdu[:5])
    words = [100 * (tid % 600) + addr + k for k in range(count)]
    return reply(tid, unit, struct.pack(f">BB{count}H", fc, 2 * count, *words))


def test_a_late_answer_is_late_never_an_outage_nor_misfiled(caplog):
    """A device that answers one request late (past the 1 s timeout) while the client has
    already sent the next one (another block's): that poll's late block is Bad and late, the
    connection is kept (no reconnect, no failure logged), and the late answer, which arrives
    while the next request waits, is not taken for it: every Good word is the answer to its
    own address from the newest request. Before, the timeout dropped the connection (the next
    poll Bad "not connected", the source down for one late answer)."""
    caplog.set_level(logging.INFO, logger=MOD)
    caplog.set_level(logging.WARNING, logger="pymodbus.logging")  # its skipped frames
    seen: list[tuple[int, int]] = []  # (transaction id, start address) of each request

    async def answer(tid, unit, pdu):
        seen.append((tid, struct.unpack(">H", pdu[1:3])[0]))
        if len(seen) == 6:  # the third poll's second block (C, D): answered late
            await asyncio.sleep(1.6)
        return tagged_reply(tid, unit, pdu)

    async def main():
        srv, port = await answering_server(answer)
        c = ModbusTagClient(TWO_BLOCKS, port=port, timeout=1.0)
        try:
            polls = [await c.poll() for _ in range(5)]  # one after another, as a loop polls
            return polls, c.connects, getattr(c, "read_timeouts", None), c.available
        finally:
            await c.close()
            srv.close()

    polls, connects, timeouts, available = run(main())
    # the polls after the late one Good on the same connection (main: "not connected")
    assert all(p.good for p in polls[3:]) and connects == 1, [p.reasons for p in polls]
    assert polls[2].late.tolist() == [False, False, True, True]
    assert polls[2].quality.tolist() == [0, 0, 2, 2] and np.isnan(polls[2].values[2:]).all()
    assert polls[2].reasons[2].startswith("timeout after 1 s reading hr 10+2"), polls[2].reasons
    assert timeouts == 1 and available
    # silent_after is at least twice the timeout: one request late by all of it is no outage
    assert ModbusTagClient(TWO_BLOCKS, timeout=4.0).silent_after == 8.0
    # the late answer (to request 6: C, D) came while request 7 (A, B) waited: skipped by
    # its transaction id, not filed as A and B (or, on a machine so loaded that request 7
    # went out after it, ignored as an answer to nothing)
    skipped = [r.getMessage() for r in caplog.records if r.name == "pymodbus.logging"]
    assert any(
        "transaction_id=7 but got id=6, Skipping" in m or "IGNORING" in m for m in skipped
    ), skipped
    addr = {"A": 0, "B": 1, "C": 10, "D": 11}
    for k, p in enumerate(polls):
        for i, tag in enumerate(TWO_BLOCKS.names):
            if p.quality[i] != 0:
                continue
            v = int(p.values[i])
            assert v % 100 == addr[tag], (k, tag, v)  # its own address, no other block's
            start = 0 if addr[tag] < 10 else 10
            asked = [tid for tid, a in seen if a == start]
            # the newest request for its block at that poll: 2 requests per poll (none
            # for C, D after the late one in poll 3)
            assert v // 100 == asked[k] % 600, (k, tag, v, seen)
    assert not any(p.late.any() for p in polls[3:])
    msgs = [r.getMessage() for r in caplog.records if r.name == MOD]
    assert not any("bad" in m or "recovered" in m for m in msgs), msgs


def test_a_device_silent_past_silent_after_is_dropped_and_found_again(caplog):
    """The other side: a device that stops answering with its connection open is late until
    no request has been answered in time for ``silent_after``, then the connection is dropped
    (the source down: one warning), reconnected in the background (a new connection counts as
    an answer: late again, still down, until it answers), and Good again once it answers (one
    recovery)."""
    caplog.set_level(logging.INFO, logger=MOD)
    state = {"silent": False, "accepted": 0}

    async def answer(tid, unit, pdu):
        if state["silent"]:
            return None
        return tagged_reply(tid, unit, pdu)

    def accepted():
        state["accepted"] += 1

    async def main():
        srv, port = await answering_server(answer, accepted)
        c = ModbusTagClient(
            TWO_BLOCKS, port=port, timeout=0.2, silent_after=1.0, backoff=Backoff(0.05, 0.2)
        )
        loop = asyncio.get_running_loop()
        out = []
        try:
            out.append(("up", await c.poll()))
            state["silent"] = True
            t0 = loop.time()
            while loop.time() - t0 < 2.0:
                out.append(("silent", await c.poll()))
                await asyncio.sleep(0.05)
            state["silent"] = False
            for _ in range(100):
                p = await c.poll()
                out.append(("back", p))
                if p.good:
                    break
                await asyncio.sleep(0.05)
        finally:
            await c.close()
            srv.close()
        return out, c.connects

    out, connects = run(main())
    silent = [p for ph, p in out if ph == "silent"]
    assert silent[0].late.all() and "timeout after 0.2 s" in silent[0].reasons[0]
    dropped = [p for p in silent if "no request answered in time for" in p.reasons[0]]
    assert dropped and not dropped[0].late.any(), [p.reasons[0] for p in silent]
    # from there on down (Bad, and late again on the new connection until it answers)
    assert all(not p.good for p in silent[silent.index(dropped[0]) :])
    assert out[-1][1].good and connects >= 2 and state["accepted"] >= 2
    msgs = [r.getMessage() for r in caplog.records if r.name == MOD and r.levelno >= logging.INFO]
    assert sum("read blocks bad" in m for m in msgs) == 1, msgs
    assert sum("recovered" in m for m in msgs) == 1, msgs


def test_a_device_gone_while_a_request_waits_is_down_not_late():
    """A device that closes the connection while our request waits for its answer: the block
    is Bad "connection lost" and the source down (reconnected in the background), not late."""

    async def handler(r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
        await read_request(r)
        w.close()  # gone without an answer

    async def main():
        srv, port = await raw_server(handler)
        c = ModbusTagClient(TWO_BLOCKS, port=port, timeout=0.5, backoff=Backoff(5.0, 5.0))
        try:
            return await c.poll(), c.connected, c.available
        finally:
            await c.close()
            srv.close()

    p, connected, available = run(main())
    assert not p.late.any() and not connected and not available
    assert p.reasons[0] == "connection lost reading hr 0+2: closed without an answer", p.reasons
    assert p.reasons[2].startswith("not connected (dropped after: connection lost"), p.reasons
