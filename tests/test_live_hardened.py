"""``diag run --config`` against what a plant does to it (issue 23), all peers real, on 127.0.0.1.

- A PLC (our pymodbus ``PlantServer``) whose values freeze, then send NaN and ±Inf: the
  samples are stored Uncertain (stale) and Bad (not finite), the unit goes CHECK_FUNCTION
  naming the tags behind its unknown tests — never a fault — and the frozen source is
  reported once each way. Before the first diagnosis the status registers say
  CHECK_FUNCTION/Uncertain ("initialising"), not NORMAL/Good.
- The historian's SQLite file write-locked by a second process for 30 s: the loop keeps
  polling, every sample polled meanwhile is in the historian afterwards exactly once,
  "historian degraded" and "back" once each, both in the historian's own event log.
- The same for 600 cycles at 0.05 s (ten minutes of 1 s cycles) with a small buffer, so the
  spill folder takes the overflow; the run ends while the lock is still held, its leftovers
  go to the spill and the next start stores them.
- PostgreSQL (a private instance, never the shared server) stopped and restarted mid-run.
- Commissioning checks at load: a unit input no source reads, a busy port, an unreadable
  certificate, a bad password hash: exit 2 with file:line: key, no traceback.
"""

from __future__ import annotations

import asyncio
import math
import os
import re
import shutil
import socket
import subprocess
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from helpers import Locker, Out, free_port, plant_toml, require, run_diag, valve_plant

ROWS = 205  # the first row of a stretch every trained rule covers (see test_live_sources)


@pytest.fixture(scope="module")
def plant_dir(tmp_path_factory):
    """The example unit trained on a fault-free day; the PLC's register map as a CSV."""
    d = tmp_path_factory.mktemp("hardened")
    return d, valve_plant(d)


def run(
    cfg_path: Path,
    plc,
    rows: pd.DataFrame,
    decide,
    duration: float = 900.0,
    late: list[bool] | None = None,
):
    """``run_config`` with the PLC serving one row per cycle; ``decide(loop, i, statuses)``
    returns the next row (None: leave the PLC as it is) or raises StopIteration to stop.
    Returns (exit code, output, timeline of (ts, status, quality, message)). ``late``: gets
    per cycle whether its poll was late (``LiveLoop.late``: no answer within the cycle's
    deadline, whose answer, read before the next row was served, is the next cycle's sample;
    or within the PLC's own timeout: a loaded machine). ``duration`` only bounds a hang: the
    plan stops the run (a loaded machine took 130 s for 250 cycles of 0.1 s)."""
    from diag_plugin.live.config import load_config, run_config

    cfg = load_config(cfg_path)
    out = Out()
    timeline: list[tuple] = []

    async def after(loop, i, statuses) -> None:
        (s,) = statuses
        timeline.append((s.ts, s.status.name, s.quality.name, s.message))
        if late is not None:
            late.append(loop.late is not None and bool(loop.late.any()))
        try:
            row = decide(loop, i, statuses)
        except StopIteration:
            loop.stop()
            return
        if row is not None:
            await plc.set_row(row)

    async def main() -> int:
        await plc.set_row(rows.iloc[ROWS].to_dict())
        return await run_config(cfg, duration=duration, out=out, after=after)

    return asyncio.run(main()), out.text, timeline


def run_with_plc(port: int, cfg_path: Path, rows: pd.DataFrame, decide, late=None):
    """:func:`run` (in a thread) against our PLC server on ``port``."""
    from connectors.modbus_server import PlantServer

    async def serve():
        async with PlantServer(port=port) as plc:
            return await asyncio.to_thread(run, cfg_path, plc, rows, decide, late=late)

    return asyncio.run(serve())


def samples(url: str, tag: str) -> pd.DataFrame:
    from historian.store import Historian

    h = Historian.open(url)
    try:
        return h.read_samples(tag, with_quality=True)
    finally:
        h.close()


def events(url: str) -> pd.DataFrame:
    from historian.store import Historian

    h = Historian.open(url)
    try:
        return h.events()
    finally:
        h.close()


# ---------------------------------------------------------------- frozen and absurd values
def test_frozen_plc_and_nan_inf_make_check_function_never_a_fault(plant_dir):

    d, frame = plant_dir
    port = free_port()
    url = f"sqlite:///{d / 'frozen.db'}"
    cfg = plant_toml(d, port, url, cycle=0.1, extra="stale_after = 1.0\n")
    phase: dict[int, str] = {}
    # the unit holds its last symptoms (Uncertain) for its on-delay (30 samples) before an
    # unknown test makes it CHECK_FUNCTION: the stale and absurd phases last longer than that
    plan = [("up", 40), ("frozen", 60), ("up2", 50), ("absurd", 50), ("up3", 50)]
    bounds = np.cumsum([n for _, n in plan])

    def decide(loop, i, statuses):
        k = int(np.searchsorted(bounds, i, side="right"))
        if k >= len(plan):
            raise StopIteration
        name = plan[k][0]
        phase[i] = name
        row = frame.iloc[ROWS + i].to_dict()
        if name == "frozen":
            return None  # the PLC keeps answering with its last values, all "Good"
        if name == "absurd":
            row.update(F=math.nan, X=math.inf, P1=-math.inf)
        return row

    late: list[bool] = []
    rc, text, timeline = run_with_plc(port, cfg, frame, decide, late)
    assert rc == 0, text
    # the row cycle i read is the one decide(i - 1) served, unless its poll or the one
    # before was late (a loaded machine): then it read none, or one served earlier or later
    # (the late poll's request may reach the PLC before or after the next row): left out
    seen = [
        None if late[i] or (i > 0 and late[i - 1]) else phase.get(i - 1, "up")
        for i in range(len(timeline))
    ]
    ts_seen = {p: {timeline[i][0] for i, q in enumerate(seen) if q == p} for p, _ in plan}
    unsure = {timeline[i][0] for i, q in enumerate(seen) if q is None}
    by_phase: dict[str, list] = {}
    for i, (_, st, q, msg) in enumerate(timeline):
        if seen[i] is not None:
            by_phase.setdefault(seen[i], []).append((st, q, msg))
    statuses = {st for _, st, _, _ in timeline}
    assert not statuses & {"FAILURE", "OFF_SPEC", "MAINTENANCE_REQUIRED"}, timeline
    assert [st for st, _, _ in by_phase["up"][-5:]] == ["NORMAL"] * 5, by_phase["up"]
    frozen = by_phase["frozen"]
    assert {st for st, _, _ in frozen[-10:]} == {"CHECK_FUNCTION"}, frozen
    assert "stale: unchanged for" in frozen[-1][2] and "unknown tests" in frozen[-1][2]
    assert [st for st, _, _ in by_phase["up2"][-5:]] == ["NORMAL"] * 5, by_phase["up2"]
    absurd = by_phase["absurd"]
    assert {st for st, _, _ in absurd[-10:]} == {"CHECK_FUNCTION"}, absurd
    assert "F Bad: not a finite number" in absurd[-1][2], absurd[-1]
    assert [st for st, _, _ in by_phase["up3"][-5:]] == ["NORMAL"] * 5, by_phase["up3"]
    assert text.count("source plc: all 7 tags frozen") == 1, text
    assert text.count("source plc: values moving again") == 1, text
    # stored as the loop saw them: frozen samples Uncertain, absurd ones Bad (±Inf kept)
    f, x = samples(url, "F"), samples(url, "X")
    assert len(f) == len(timeline) and (f["quality"] == 1).sum() >= 20
    stale_ts = f.index[f["quality"] == 1]
    assert set(stale_ts) <= ts_seen["frozen"] | unsure
    bad_x = x[x["quality"] == 2]
    inf_ts = set(x.index[np.isposinf(x["value"])])
    # every cycle that read an absurd row stored X +Inf, Bad, and no other did (a late
    # poll's cycle stores its tags Bad without a value)
    assert ts_seen["absurd"] <= inf_ts <= ts_seen["absurd"] | unsure
    assert len(ts_seen["absurd"]) >= 40 and inf_ts <= set(bad_x.index)
    lates = {timeline[i][0] for i, x_late in enumerate(late) if x_late}
    assert set(bad_x.index) - inf_ts <= lates and bad_x["value"].drop(list(inf_ts)).isna().all()
    assert f.loc[sorted(inf_ts), "value"].isna().all()
    ev = events(url)
    assert ev["message"].str.contains("all 7 tags frozen").sum() == 1


def test_stale_limits_come_from_each_tags_history(tmp_path):
    """A tag that changes every 10 s sample is stale after 10 periods; one that steps every
    minute after 3 minutes; one that never changed in its history never."""
    from diag_plugin.live.stale import StaleDetector
    from historian.livestore import LiveStore
    from historian.store import Historian

    url = f"sqlite:///{tmp_path / 'h.db'}"
    idx = pd.date_range("2026-01-01", periods=600, freq="10s", tz="UTC")
    rng = np.random.default_rng(7)
    h = Historian.open(url)
    h.write_samples(
        pd.DataFrame(
            {
                "moving": rng.normal(size=600),
                "stepping": np.repeat(rng.normal(size=100), 6),
                "constant": np.full(600, 3.0),
            },
            index=idx,
        )
    )
    h.close()
    store = LiveStore(url)
    runs = store.unchanged_runs(["moving", "stepping", "constant", "new"])
    store.close()
    assert set(runs) == {"moving", "stepping", "constant"}
    det = StaleDetector(["moving", "stepping", "constant", "new"]).fit(runs)
    assert det.limit_[0] == pytest.approx(100.0)  # 10 periods of 10 s
    assert det.limit_[1] == pytest.approx(150.0)  # 3 × the 50 s runs
    assert det.limit_[2] == np.inf and np.isnan(det.limit_[3])
    good = np.zeros(4, np.uint8)
    v = np.array([1.0, 2.0, 3.0, 4.0])
    for t in range(0, 200, 10):  # everything frozen for 200 s
        stale, _ = det.update(float(t), v, good)
    assert stale.tolist() == [True, True, False, False]  # "new" never seen changing


# ---------------------------------------------------------------- the historian away


def exactly_once(url: str, timeline: list[tuple], restarts: int = 0) -> pd.DataFrame:
    f = samples(url, "F")
    polled = [t for t, *_ in timeline]
    # besides what was polled, each restart's gap is marked by one Bad sample without value
    mark = f[~f.index.isin(polled)]
    assert len(mark) == restarts, mark
    assert (mark["quality"] == 2).all() and mark["value"].isna().all(), mark
    f = f[f.index.isin(polled)]
    assert f.index.is_unique and len(f) == len(polled), (len(f), len(polled))
    assert set(f.index) == set(polled)
    return f


def test_sqlite_write_locked_30_s_by_another_process(plant_dir):

    d, frame = plant_dir
    port = free_port()
    db = d / "locked30.db"
    url = f"sqlite:///{db}"
    cfg = plant_toml(d, port, url, cycle=0.1)
    state: dict = {}

    def decide(loop, i, statuses):
        if i == 20:
            state["lock"] = Locker(db)
            state["t"] = time.monotonic()
        if "lock" in state and "released" not in state and time.monotonic() - state["t"] > 30:
            state["lock"].release()
            state["released"] = i
        w = loop.historian
        if "released" in state and not w.degraded and w.backlog < 50 and i > state["released"]:
            raise StopIteration
        return frame.iloc[ROWS + i % 400].to_dict()

    try:
        rc, text, timeline = run_with_plc(port, cfg, frame, decide)
    finally:
        if "lock" in state and state["lock"].p.poll() is None:
            state["lock"].p.kill()
    assert rc == 0, text
    f = exactly_once(url, timeline)
    # polling went on through the lock: no hole between the samples of consecutive cycles
    # anywhere near the 30 s the database was away (the old loop froze for the whole lock)
    gaps = np.diff(f.index.asi8) / 1e9
    assert gaps.max() < 5.0, gaps.max()
    during = [t for t, *_ in timeline[20 : state["released"]]]
    assert len(during) > 100  # cycles polled while the lock was held
    assert text.count("historian degraded") == 1 and text.count("historian back after") == 1
    assert "database is locked" in text
    ev = events(url)
    assert ev["message"].str.contains("historian degraded").sum() == 1
    assert ev["message"].str.contains("historian back after").sum() == 1


def test_ten_minutes_of_cycles_locked_spill_and_exit_while_locked(plant_dir):
    """600 cycles at 0.05 s with room for 40 in memory: the rest goes to the spill folder;
    the run ends while the lock is still held (its leftovers spilled at exit), the next start
    stores everything, once."""
    from connectors.modbus_server import PlantServer

    d, frame = plant_dir
    port = free_port()
    db = d / "locked600.db"
    url = f"sqlite:///{db}"
    cfg = plant_toml(d, port, url, cycle=0.05, extra="buffer_samples = 280\n")
    spill = Path(f"{db}.spill")
    state: dict = {}

    def decide_first(loop, i, statuses):
        if i == 10:
            state["lock"] = Locker(db)
        if i >= 610:
            raise StopIteration  # stopped with the database still locked
        return frame.iloc[ROWS + i % 400].to_dict()

    def decide_second(loop, i, statuses):
        w = loop.historian
        if i > 20 and not w.degraded and w.backlog < 50 and not list(spill.glob("*.npz")):
            raise StopIteration
        return frame.iloc[ROWS + i % 400].to_dict()

    async def serve():
        async with PlantServer(port=port) as plc:
            first = await asyncio.to_thread(run, cfg, plc, frame, decide_first)
            assert list(spill.glob("spill-*.npz")), "nothing spilled"
            # a clean stop leaves no journal: everything it held is spilled
            assert not list(spill.glob("journal-*.bin")), list(spill.iterdir())
            state["lock"].release()
            second = await asyncio.to_thread(run, cfg, plc, frame, decide_second)
            return first, second

    try:
        (rc1, text1, t1), (rc2, text2, t2) = asyncio.run(serve())
    finally:
        if "lock" in state and state["lock"].p.poll() is None:
            state["lock"].p.kill()
    assert rc1 == 0 and rc2 == 0, text1 + text2
    assert text1.count("historian degraded") == 1
    assert "older ones go to" in text1 and "historian away at exit" in text1
    m = [x for x in text1.splitlines() if x.startswith("stopped after")][0]
    assert "samples spilled" in m and " 0 samples spilled" not in m, m
    assert not list(spill.glob("*.npz")), "spill left behind"
    assert not list(spill.glob("journal-*.bin")), "journal left behind"
    assert "recovered from its journal" not in text1 + text2  # no crash, nothing to recover
    exactly_once(url, t1 + t2, restarts=1)
    m2 = [x for x in text2.splitlines() if x.startswith("stopped after")][0]
    assert " 0 replayed" not in m2, m2


# ---------------------------------------------------------------- PostgreSQL, privately
def _pg_bin(name: str) -> str | None:
    found = shutil.which(name)
    if found:
        return found
    for p in sorted(Path("/usr/lib/postgresql").glob(f"*/bin/{name}"), reverse=True):
        return str(p)
    return None


class PrivatePostgres:
    """A PostgreSQL instance of our own (initdb in a temporary folder, a free port), so
    stopping it touches nobody else's tests."""

    def __init__(self) -> None:
        import tempfile

        self.initdb, self.pg_ctl = _pg_bin("initdb"), _pg_bin("pg_ctl")
        # its own folder in /tmp: pytest's temporary folders are closed to other users
        self.folder = Path(tempfile.mkdtemp(prefix="diag-test-pg-"))
        self.dir = self.folder / "pgdata"
        self.sock = self.folder / "sock"
        self.port = free_port()
        self.as_root = os.geteuid() == 0

    def _cmd(self, *args: str) -> subprocess.CompletedProcess:
        cmd = list(args)
        if self.as_root:  # initdb and postgres refuse to run as root
            cmd = ["runuser", "-u", "postgres", "--", *cmd]
        return subprocess.run(cmd, capture_output=True, text=True, timeout=120)

    def init(self) -> None:
        self.sock.mkdir(parents=True)
        if self.as_root:
            shutil.chown(self.sock, "postgres")
            shutil.chown(self.folder, "postgres")
        r = self._cmd(self.initdb, "-D", str(self.dir), "-U", "postgres", "-A", "trust")
        assert r.returncode == 0, r.stderr

    def start(self) -> None:
        opts = f"-p {self.port} -k {self.sock} -c listen_addresses=127.0.0.1 -c fsync=off"
        log = str(self.folder / "server.log")  # the server's output, not our pipes
        r = self._cmd(self.pg_ctl, "-D", str(self.dir), "-o", opts, "-l", log, "-w", "start")
        assert r.returncode == 0, r.stdout + r.stderr

    def stop(self) -> None:
        self._cmd(self.pg_ctl, "-D", str(self.dir), "-m", "fast", "-w", "stop")

    def remove(self) -> None:
        self.stop()
        shutil.rmtree(self.folder, ignore_errors=True)

    @property
    def url(self) -> str:
        return f"postgresql://postgres@127.0.0.1:{self.port}/postgres"


def test_postgresql_stopped_and_restarted(plant_dir, tmp_path):

    require(
        "PostgreSQL binaries (initdb, pg_ctl)",
        bool(_pg_bin("initdb") and _pg_bin("pg_ctl"))
        and (os.geteuid() != 0 or bool(shutil.which("runuser"))),
        "apt-get install postgresql",
    )
    d, frame = plant_dir
    pg = PrivatePostgres()
    try:
        pg.init()
        pg.start()
    except BaseException:
        pg.remove()
        raise
    port = free_port()
    cfg = plant_toml(d, port, pg.url, cycle=0.1, extra=f'spill = "{tmp_path / "pg.spill"}"\n')
    state: dict = {}

    def decide(loop, i, statuses):
        if i == 20:
            pg.stop()
            state["t"] = time.monotonic()
        if "t" in state and "up" not in state and time.monotonic() - state["t"] > 15:
            pg.start()
            state["up"] = i
        w = loop.historian
        if "up" in state and i > state["up"] and not w.degraded and w.backlog < 50:
            raise StopIteration
        return frame.iloc[ROWS + i % 400].to_dict()

    try:
        rc, text, timeline = run_with_plc(port, cfg, frame, decide)
        assert rc == 0, text
        assert text.count("historian degraded") == 1 and text.count("historian back after") == 1
        f = exactly_once(pg.url, timeline)
        assert (np.diff(f.index.asi8) / 1e9).max() < 5.0
        assert len(timeline[20 : state["up"]]) > 80  # polled while the database was down
        ev = events(pg.url)
        assert ev["message"].str.contains("historian degraded").sum() == 1
    finally:
        pg.remove()


# ---------------------------------------------------------------- commissioning at load
def test_commissioning_checks_name_file_line_key(plant_dir):
    from connectors.passwords import verify_password

    d, _ = plant_dir
    ok = plant_toml(d, free_port(), f"sqlite:///{d / 'c.db'}", cycle=1.0)
    text = ok.read_text()
    cases = []
    # a unit input no source reads: the register map lacks P2
    (d / "plc_no_p2.csv").write_text(
        "\n".join(x for x in (d / "plc.csv").read_text().splitlines() if not x.startswith("P2,"))
    )
    cases.append(
        (
            text.replace('map = "plc.csv"', 'map = "plc_no_p2.csv"'),
            "units = ",
            "plant.units: ",
            "input tags P2 are read by no source",
        )
    )
    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen()
    taken = busy.getsockname()[1]
    cases.append(
        (
            text.replace("modbus_port = 0", f"modbus_port = {taken}"),
            "modbus_port = ",
            "outputs.modbus_port: ",
            f"127.0.0.1:{taken} is busy",
        )
    )
    (d / "garbage.pem").write_text("-----BEGIN CERTIFICATE-----\nnot base64\n")
    (d / "key.pem").write_text("x")
    cases.append(
        (
            text + '\n[opcua]\ncertificate = "garbage.pem"\nprivate_key = "key.pem"\n',
            "certificate = ",
            "opcua.certificate: unreadable certificate",
            "garbage.pem",
        )
    )
    cases.append(
        (
            text + '\n[opcua]\n\n[[user]]\nname = "alice"\nrole = "operator"\n'
            'password_hash = "plain-text"\n',
            "password_hash = ",
            "user.password_hash: expected scrypt$",
            "",
        )
    )
    cases.append(
        (
            text + '\n[opcua]\nsecurity = ["None"]\nhost = "0.0.0.0"\n',
            "security = ",
            "opcua.security: 'None' only on a loopback host",
            "",
        )
    )
    try:
        for toml, key, where, what in cases:
            p = d / "commission.toml"
            p.write_text(toml, encoding="utf-8")
            line = next(n for n, x in enumerate(toml.splitlines(), 1) if x.startswith(key))
            r = run_diag(d, "run", "--config", str(p), "--plain", "--duration", "1", timeout=120)
            assert r.returncode == 2, r.stdout + r.stderr
            assert f"commission.toml:{line}: {where}" in r.stderr, r.stderr
            assert what in r.stderr, r.stderr
            assert "Traceback" not in r.stderr + r.stdout
    finally:
        busy.close()
    r = run_diag(d, "run", "--hash-password", stdin="correct horse\n", timeout=120)
    assert r.returncode == 0 and verify_password(r.stdout.strip(), "correct horse")


def test_status_registers_say_initialising_before_the_first_diagnosis():
    """The Modbus status registers before any diagnosis: CHECK_FUNCTION/Uncertain, not the
    NORMAL/Good of zeroed registers (read by pymodbus, a client we did not write)."""
    from pymodbus.client import ModbusTcpClient

    from connectors.modbus_server import StatusServer, UnitLayout

    async def main():
        srv = StatusServer([UnitLayout("u1", ["f1"], ["r1"]), UnitLayout("u2")], port=0)
        await srv.start()
        try:
            c = ModbusTcpClient("127.0.0.1", port=srv.port)
            assert await asyncio.to_thread(c.connect)
            regs = []
            for base in (0, 100):
                rr = await asyncio.to_thread(c.read_holding_registers, base, count=2)
                regs.append(list(rr.registers))
            c.close()
            return regs
        finally:
            await srv.stop()

    assert asyncio.run(main()) == [[2, 1], [2, 1]]


def test_a_modbus_only_plant_still_raises_and_acknowledges_its_alarms(plant_dir, tmp_path):
    """plant.toml without the OPC UA server (``opcua_port = 0``, a Modbus-only SCADA): the
    unit's ISA-18.2 alarm is still raised (event line, event log, ``U.alarm`` = 1) and a
    Modbus client's write to the ack coil acknowledges it (``U.alarm`` = 2). On main the
    alarm lived only in the OPC UA server: ``U.alarm`` read 0 through a FAILURE, no alarm
    event was logged and the ack coil did nothing."""
    from pymodbus.client import AsyncModbusTcpClient

    from connectors.modbus_server import PlantServer
    from diag_plugin.simulate import FaultSpec, simulate_valve

    d, _ = plant_dir
    start = pd.Timestamp("2026-03-01", tz="UTC")
    rows = simulate_valve(
        0.1, seed=23, start=start,
        faults=[FaultSpec("f14", -0.3, onset=start + pd.Timedelta(seconds=400))],
    )  # fmt: skip
    port, modbus = free_port(), free_port()
    url = f"sqlite:///{tmp_path / 'modbus_only.db'}"
    cfg = plant_toml(d, port, url, cycle=0.05)
    text = cfg.read_text().replace("modbus_port = 0", f"modbus_port = {modbus}")
    assert "opcua_port = 0" in text
    cfg.write_text(text, encoding="utf-8")
    state: dict = {}

    async def scada() -> None:
        mb = AsyncModbusTcpClient("127.0.0.1", port=modbus)
        await mb.connect()
        try:
            state["raised"] = (await mb.read_holding_registers(3, count=1)).registers[0]
            await mb.write_coil(0, True)  # valve_unit is unit 0: its ack coil
            for _ in range(100):
                word = (await mb.read_holding_registers(3, count=1)).registers[0]
                if word == 2:
                    break
                await asyncio.sleep(0.05)
            state["acked"] = word
        finally:
            mb.close()
        state["done"] = time.monotonic()

    async def serve():
        from diag_plugin.live.config import load_config, run_config

        out = Out()
        async with PlantServer(port=port) as plc:
            await plc.set_row(rows.iloc[0].to_dict())

            async def after(loop, i, statuses):
                view = loop.stats.units.get("valve_unit")
                raised = view is not None and view.alarm == "active-unacknowledged"
                if "task" not in state and raised:
                    state["task"] = asyncio.get_running_loop().create_task(scada())
                if ("done" in state and time.monotonic() - state["done"] > 0.5) or i > 2000:
                    loop.stop()
                    return
                await plc.set_row(rows.iloc[min(i + 1, len(rows) - 1)].to_dict())

            rc = await run_config(load_config(cfg), duration=180, out=out, after=after)
            if "task" in state:
                await state["task"]
            return rc, out.text

    rc, out = asyncio.run(serve())
    assert rc == 0, out
    assert "task" in state, out  # the alarm was raised
    assert state["raised"] == 1 and state["acked"] == 2, state
    msgs = list(events(url)["message"])
    joined = "\n".join(msgs)
    assert any("alarm raised: FAILURE" in m for m in msgs), joined
    assert any(
        re.search(r"alarm acknowledged by Modbus client 127\.0\.0\.1:\d+ over Modbus", m)
        for m in msgs
    ), joined


# ---------------------------------------------------------------- a secured plant.toml
def test_secured_plant_actions_over_opcua_and_modbus_land_in_one_event_log(plant_dir, tmp_path):
    """plant.toml with [opcua] security and users: the server certificate is made on first
    start and its fingerprint printed; when the unit's alarm is raised a viewer's shelve is
    refused, a Modbus client acknowledges through the ack coil, an operator shelves for 1 s
    (10 s is over max_shelve) and the shelving ends by itself — all in the historian's event
    log with who did it and how."""
    from asyncua import ua
    from opcua_peers import PASSWORDS, client, pki
    from pymodbus.client import AsyncModbusTcpClient

    from connectors.modbus_server import PlantServer
    from connectors.passwords import hash_password
    from diag_plugin.simulate import FaultSpec, simulate_valve

    d, _ = plant_dir
    keys = pki(tmp_path / "pki")
    start = pd.Timestamp("2026-03-01", tz="UTC")
    rows = simulate_valve(
        0.1,
        seed=22,
        start=start,
        faults=[FaultSpec("f14", -0.3, onset=start + pd.Timedelta(seconds=400))],
    )
    port, modbus, opcua = free_port(), free_port(), free_port()
    url = f"sqlite:///{tmp_path / 'secured.db'}"
    cfg = plant_toml(d, port, url, cycle=0.05)
    text = cfg.read_text().replace("modbus_port = 0", f"modbus_port = {modbus}")
    text = text.replace("opcua_port = 0", f"opcua_port = {opcua}")
    text += f"""
[opcua]
security = ["SignAndEncrypt"]
certificate = "{tmp_path / "own" / "diag.pem"}"
private_key = "{tmp_path / "own" / "diag.key.pem"}"
trusted = "{keys["dir"] / "trusted"}"
max_shelve = 5

[[user]]
name = "alice"
role = "operator"
password_hash = "{hash_password(PASSWORDS["alice"])}"

[[user]]
name = "bob"
role = "viewer"
password_hash = "{hash_password(PASSWORDS["bob"])}"
"""
    cfg.write_text(text, encoding="utf-8")
    state: dict = {}

    async def operators(loop) -> None:
        srv = loop.opcua
        unit = srv.node_id("Units", "valve_unit")
        bob = await client(srv.endpoint, keys["hmi"], "bob")
        try:
            with pytest.raises(ua.UaStatusCodeError):
                await bob.get_node(unit).call_method(
                    f"{srv.ns}:Shelve", ua.Variant(3.0, ua.VariantType.Double)
                )
        finally:
            await bob.disconnect()
        mb = AsyncModbusTcpClient("127.0.0.1", port=modbus)
        await mb.connect()
        await mb.write_coil(0, True)  # valve_unit is unit 0: its ack coil
        mb.close()
        for _ in range(100):
            if srv.alarms["valve_unit"].state == "active-acknowledged":
                break
            await asyncio.sleep(0.05)
        alice = await client(srv.endpoint, keys["hmi"], "alice")
        try:
            cond = alice.get_node(srv.node_id("Units", "valve_unit", "Alarm"))
            timed = ua.NodeId(ua.ObjectIds.AlarmConditionType_ShelvingState_TimedShelve)
            with pytest.raises(ua.UaStatusCodeError, match="BadShelvingTimeOutOfRange"):
                await cond.call_method(timed, ua.Variant(10_000.0, ua.VariantType.Double))
            await cond.call_method(timed, ua.Variant(1_000.0, ua.VariantType.Double))
        finally:
            await alice.disconnect()
        state["done"] = time.monotonic()

    def decide(loop, i, statuses):
        if "task" not in state and loop.opcua.alarms["valve_unit"].state == "active-unacknowledged":
            state["task"] = asyncio.get_running_loop().create_task(operators(loop))
        if "done" in state and time.monotonic() - state["done"] > 2.5:
            raise StopIteration
        if i > 2000:
            raise StopIteration
        return rows.iloc[min(i + 1, len(rows) - 1)].to_dict()

    async def serve():
        async with PlantServer(port=port) as plc:
            await plc.set_row(rows.iloc[0].to_dict())
            from diag_plugin.live.config import load_config, run_config

            out = Out()

            async def after(loop, i, statuses):
                try:
                    row = decide(loop, i, statuses)
                except StopIteration:
                    loop.stop()
                    return
                await plc.set_row(row)

            rc = await run_config(load_config(cfg), duration=180, out=out, after=after)
            if "task" in state:
                await state["task"]  # its assertions
            return rc, out.text

    rc, out = asyncio.run(serve())
    assert rc == 0, out
    assert "done" in state, out
    assert "(created now), SHA-256 " in out and "policies SignAndEncrypt" in out, out
    msgs = list(events(url)["message"])
    joined = "\n".join(msgs)
    assert any("alarm raised: FAILURE" in m for m in msgs), joined
    assert any("bob (viewer) refused" in m for m in msgs), joined
    # the audit names the Modbus client's address (ip:port of its connection)
    assert any(
        re.search(r"alarm acknowledged by Modbus client 127\.0\.0\.1:\d+ over Modbus", m)
        for m in msgs
    ), joined
    assert any("shelve by alice (operator) over OPC UA refused: 10 s" in m for m in msgs), joined
    assert any("alarm shelved by alice (operator) over OPC UA (for 1 s" in m for m in msgs), joined
    assert any("shelving over" in m or "unshelved by timer" in m for m in msgs), joined
