"""Modbus against peers we did not write: pyModbusTCP's server as a PLC, mbpoll as a SCADA."""

from __future__ import annotations

import asyncio
import re
import subprocess

import pandas as pd
import pytest
from modbus_peers import (
    PLC_MAP,
    PLC_VALUES,
    free_port,
    needs_mbpoll,
    needs_pymodbustcp,
    start_plc,
)

from connectors.base import TagQuality, WriteRefused
from connectors.modbus import ModbusTagClient
from connectors.modbus_server import (
    PLANT_TAGS,
    PlantServer,
    StatusServer,
    UnitLayout,
    default_plant_map,
)
from connectors.registermap import RegisterMap
from diag_plugin.status import NE107, Quality, UnitStatus


def run(coro, timeout: float = 60.0):
    async def main():
        return await asyncio.wait_for(coro, timeout)

    return asyncio.run(main())


@pytest.fixture
def plc_port():
    """The port of a pyModbusTCP PLC (``modbus_peers.start_plc``), stopped after the test."""
    port = free_port()
    srv = start_plc(port)
    yield port
    srv.stop()


@needs_pymodbustcp
def test_poll_pymodbustcp_plc_all_types_and_word_orders(plc_port):
    async def main():
        c = ModbusTagClient(RegisterMap.parse(PLC_MAP), port=plc_port, timeout=1.0)
        try:
            return await c.read()
        finally:
            await c.close()

    samples = run(main())
    got = {s.tag: s for s in samples}
    assert all(s.quality == TagQuality.GOOD for s in samples), [s.reason for s in samples]
    for tag, want in PLC_VALUES.items():
        assert got[tag].value == pytest.approx(want, rel=1e-6), tag


@needs_pymodbustcp
def test_writes_to_the_plc_only_on_the_allow_list(plc_port):
    from pyModbusTCP.client import ModbusClient

    async def main():
        c = ModbusTagClient(
            RegisterMap.parse(PLC_MAP), port=plc_port, allow=["SP", "PUMP", "TRIP", "CNT"]
        )
        try:
            await c.read()
            ok = await c.write({"SP": 33.25, "PUMP": 0, "TRIP": 0})
            ro = await c.write({"CNT": 5})  # allowed, but an input register
            with pytest.raises(WriteRefused, match="F"):
                await c.write({"SP": 1.0, "F": 99.0})  # nothing written at all
            after = {s.tag: s.value for s in await c.read()}
            return ok, ro, after
        finally:
            await c.close()

    ok, ro, after = run(main())
    raw = ModbusClient(host="127.0.0.1", port=plc_port, auto_open=True, timeout=2)
    assert raw.read_holding_registers(0, 2) == [0x4148, 0x0000]  # F untouched: 12.5
    raw.close()
    assert ok == {"SP": "ok", "PUMP": "ok", "TRIP": "ok"}
    assert "read-only" in ro["CNT"]
    assert after["SP"] == 33.25 and after["PUMP"] == 0 and after["TRIP"] == 0
    assert after["RUN"] == 1  # the other bit of the status word kept
    assert after["F"] == 12.5


def _mbpoll(port: int, *args: str) -> list[float]:
    out = subprocess.run(
        [
            "mbpoll",
            "-m",
            "tcp",
            "-a",
            "1",
            "-p",
            str(port),
            "-0",
            "-1",
            "-o",
            "2",
            *args,
            "127.0.0.1",
        ],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert out.returncode == 0, out.stdout + out.stderr
    return [float(v) for v in re.findall(r"^\[\d+\]:\s+(\S+)", out.stdout, flags=re.M)]


def _status() -> UnitStatus:
    return UnitStatus(
        unit="V1",
        ts=pd.Timestamp("2026-01-01 12:00:00", tz="UTC"),
        status=NE107.FAILURE,
        quality=Quality.GOOD,
        residuals={"r1": 3.5, "r2": -12.25, "r3": 0.0},
        certainties={"f1": 0.0, "f7": 0.875, "f17": 0.25},
        coverage={"A": 0.5},
        faults=["f7"],
    )


@needs_mbpoll
def test_mbpoll_reads_status_words_and_float_residuals_abcd():
    """The documented layout: status word at base+0, residuals float32 ABCD (mbpoll -B)."""
    st = _status()

    async def main():
        srv = StatusServer([UnitLayout("V0", ["f1"], ["r1"]), UnitLayout.from_status(st)])
        await srv.start()
        try:
            await srv.publish(st, alarm=2)
            loop = asyncio.get_running_loop()
            words = await loop.run_in_executor(
                None, _mbpoll, srv.port, "-t", "4", "-r", "100", "-c", "5"
            )
            res = await loop.run_in_executor(
                None, _mbpoll, srv.port, "-t", "4:float", "-B", "-r", "150", "-c", "3"
            )
            cert = await loop.run_in_executor(
                None, _mbpoll, srv.port, "-t", "4:float", "-B", "-r", "110", "-c", "3"
            )
            coils = await loop.run_in_executor(
                None, _mbpoll, srv.port, "-t", "0", "-r", "100", "-c", "4"
            )
            # without -B (CDAB, mbpoll's default) the same registers give other numbers
            swapped = await loop.run_in_executor(
                None, _mbpoll, srv.port, "-t", "4:float", "-r", "150", "-c", "1"
            )
            return words, res, cert, coils, swapped
        finally:
            await srv.stop()

    words, res, cert, coils, swapped = run(main())
    assert words == [1, 0, 0b010, 2, 0]  # FAILURE, Good, bit 1 = f7, alarm 2, 1st update
    assert res == [3.5, -12.25, 0.0]
    assert cert == [0.0, 0.875, 0.25]
    assert coils == [0, 0, 1, 0]  # ack, f1, f7, f17
    assert swapped != [3.5]


@needs_mbpoll
def test_mbpoll_acknowledge_coil_reaches_the_live_loop():
    async def main():
        seen: list[str] = []
        srv = StatusServer([UnitLayout("V1", ["f1"], ["r1"])], on_ack=seen.append)
        await srv.start()
        try:

            def write(table: str, value: str) -> subprocess.CompletedProcess:
                """mbpoll writes ``value`` at reference 0 of ``table`` (0 coils, 4 registers)."""
                cmd = ["mbpoll", "-m", "tcp", "-a", "1", "-p", str(srv.port), "-0", "-t", table]
                cmd += ["-r", "0", "127.0.0.1", value]
                return subprocess.run(cmd, capture_output=True, text=True, timeout=30)

            out = await asyncio.to_thread(write, "0", "1")
            unit = await asyncio.wait_for(srv.acks.get(), 5)
            # a write anywhere else is refused with an exception reply
            bad = await asyncio.to_thread(write, "4", "3")
            await asyncio.sleep(0.05)
            return (
                out,
                unit,
                seen,
                bad,
                srv.refused_writes,
                srv.values[srv.regmap.names.index("V1.ack")],
            )
        finally:
            await srv.stop()

    out, unit, seen, bad, refused, ack_after = run(main())
    assert out.returncode == 0, out.stdout + out.stderr
    assert unit == "V1" and seen == ["V1"]
    assert bad.returncode != 0 or "rror" in bad.stdout + bad.stderr
    assert refused == 1
    assert ack_after == 0  # self-clearing


@needs_mbpoll
def test_plant_server_serves_the_simulated_valve_to_mbpoll_and_our_client():
    from diag_plugin.simulate import simulate_valve

    df = simulate_valve(0.01, seed=3)
    row = df.iloc[5]

    async def main():
        srv = PlantServer()
        await srv.start()
        c = ModbusTagClient(default_plant_map(), port=srv.port)
        try:
            await srv.set_row(row)
            ours = {s.tag: s.value for s in await c.read()}
            loop = asyncio.get_running_loop()
            theirs = await loop.run_in_executor(
                None, _mbpoll, srv.port, "-t", "3:float", "-B", "-r", "0", "-c", "7"
            )
            return ours, theirs
        finally:
            await c.close()
            await srv.stop()

    ours, theirs = run(main())
    for i, tag in enumerate(PLANT_TAGS):
        assert ours[tag] == pytest.approx(row[tag], rel=1e-6), tag
        assert theirs[i] == pytest.approx(row[tag], rel=1e-5), tag
