"""A restart catches up on what it missed (issue 34, item 5/6, live): the embedded default
saves and restores its units' state; the samples the historian holds for the time the
plug-in was down are diagnosed before the first cycle — the alarm episodes logged with
their times, the units going on from the caught-up state — and a gap without samples, a
gap too long and a catch-up cut by its time-out are said. A start without a state warms the
units up on the historian's last lead-in instead of starting cold; a historian that does not
answer in time (a locked table) means a cold start, said, the first cycle on time. Real
parts: a SQLite historian and the PostgreSQL server on 127.0.0.1:5432 (a scratch database
each test, ``conftest.pg_url``), our Modbus PLC server polled by the Modbus client of
``diag run --config``."""

from __future__ import annotations

import asyncio
import copy
import json
import re
import time
from pathlib import Path

import pandas as pd
import pytest
from helpers import Out, free_port
from test_live import PLANT_TOML as LIVE_TOML

from connectors.modbus_server import PLANT_TAGS
from diag_plugin.diagnose.plant import Plant
from diag_plugin.live.catchup import CatchUp, _step, catch_up, warm_up
from diag_plugin.simulate import FaultSpec, simulate_valve
from historian.store import Historian

STEP = pd.Timedelta(seconds=10)
N_PRE = 1500  # fault-free samples before the stop (the history replay's lead-in needs them)
ONSET, END = 100, 300  # the fault in the gap: samples after the stop


@pytest.fixture(scope="module")
def unit_dir(tmp_path_factory) -> Path:
    from diag_plugin.examples.build import build_valve_unit

    d = tmp_path_factory.mktemp("catchup")
    (d / "rb").mkdir()
    build_valve_unit(d / "rb", simulate_valve(1, seed=5), "test")
    return d


def plant_of(d: Path) -> Plant:
    return Plant.load([d / "rb" / "valve_unit.unit.toml"], d / "rb")


def scenario(
    t_stop: pd.Timestamp, n_gap: int, onset: int = ONSET, end: int = END
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """N_PRE samples up to ``t_stop``, then ``n_gap``; fault f14 (P0 sensor) from sample
    ``onset`` to ``end`` after the stop (negative: before it)."""
    t0 = t_stop - (N_PRE - 1) * STEP
    fault = FaultSpec("f14", -0.3, onset=t_stop + onset * STEP, end=t_stop + end * STEP)
    frame = simulate_valve((N_PRE + n_gap) * 10 / 86400, seed=7, start=t0, faults=[fault])
    frame = frame[list(PLANT_TAGS)]
    return frame.iloc[:N_PRE], frame.iloc[N_PRE : N_PRE + n_gap]


def stopped_plant(d: Path, pre: pd.DataFrame) -> Plant:
    """The plant of a run that stopped after ``pre`` (its state is what a restart restores)."""
    plant = plant_of(d)
    for ts, row in zip(pre.index, pre.to_dict("records"), strict=True):
        plant.cycle(ts, row)
    return plant


def reference(plant: Plant, gap: pd.DataFrame) -> list[tuple]:
    """The episodes an uninterrupted plug-in would have had: the gap's rows fed one by one to
    a copy of the stopped plant (never through the historian)."""
    ref = copy.deepcopy(plant)
    res = CatchUp(plant.last_ts, gap.index[-1], 10.0)
    on: dict = {}
    open_: dict = {}
    for ts, row in zip(gap.index, gap.to_dict("records"), strict=True):
        for s in ref.cycle(ts, row):
            _step(s.unit, int(s.status), s.faults, s.tags, int(s.quality), ts, on, open_, res)
    return [(e.unit, e.start, e.end, e.status) for e in res.episodes], ref


def said(res: CatchUp) -> str:
    """The catch-up's (or warm-up's) log lines, one text."""
    return "\n".join(line for _, line, _ in res.lines())


def historian_with(url: str, *frames: pd.DataFrame) -> None:
    """Samples stored by another collector."""
    h = Historian.open(url)
    for f in frames:
        h.write_samples(f)
    h.close()


T_STOP = pd.Timestamp("2026-03-01 04:00", tz="UTC")


def test_a_short_gap_is_replayed_on_the_live_plant(unit_dir, db_url):
    """A gap shorter than the lead-in: every missed cycle through the live plant from the
    restored state — the episodes of an uninterrupted run, the same state after it."""
    pre, gap = scenario(T_STOP, 700)
    plant = stopped_plant(unit_dir, pre)
    want, ref = reference(plant, gap)
    assert want and all(e[2] is not None for e in want), want  # over before the restart
    fault_on = T_STOP + ONSET * STEP
    assert fault_on <= want[0][1] <= T_STOP + END * STEP, want
    url = db_url
    historian_with(url, pre, gap)
    res = catch_up(plant, url, gap.index[-1], 10.0)
    assert res.mode == "replayed" and res.rows == res.total == len(gap), res
    assert [(e.unit, e.start, e.end, e.status) for e in res.episodes] == want
    assert plant.last_ts == gap.index[-1]
    assert json.dumps(plant.to_state()) == json.dumps(ref.to_state())
    text = said(res)
    a, b = want[0][1], want[0][2]
    assert f"from {a:%Y-%m-%d %H:%M:%S} to {b:%Y-%m-%d %H:%M:%S}" in text, text
    assert "not raised now" in text and "700 missed cycles" in text, text


@pytest.mark.parametrize("late_s", [0.0, 4.4, 4.9, 5.0, 6.0, 9.9])
def test_cycles_stamped_off_the_grid_are_all_caught_up(unit_dir, db_url, late_s):
    """A live cycle is stamped with its poll's time, late under load: every missed cycle is
    still caught up, from the grid row after the one the last cycle's sample went into (its
    start was ``since + period`` rounded up, which skipped the first missed cycle when the
    stamps were late by less than half a period: 699 of 700 at 4.4 s late on 10 s)."""
    pre, gap = scenario(T_STOP, 700)
    late = pd.Timedelta(seconds=late_s)
    pre.index, gap.index = pre.index + late, gap.index + late
    plant = stopped_plant(unit_dir, pre)
    historian_with(db_url, pre, gap)
    res = catch_up(plant, db_url, gap.index[-1], 10.0)
    # the rows of the gap's samples: each sample on its nearest grid point (half up)
    rows = (gap.index + STEP / 2).floor(STEP)
    assert res.mode == "replayed" and res.first == rows[0] and res.last == rows[-1], res
    assert res.rows == res.total == len(gap), res
    assert res.gap_start == rows[0]
    # restarted before the last sample: nothing of it (its row's samples are after ``until``)
    plant = stopped_plant(unit_dir, pre)
    res = catch_up(plant, db_url, gap.index[-2], 10.0)
    assert res.rows == res.total == len(gap) - 1 and res.last == rows[-2], res


def test_a_cycle_early_in_the_next_row_is_caught_up(unit_dir, db_url):
    """The killed run's one cycle after its last save, stamped 6 s after it on a 10 s grid
    (the next row's sample), restarted at once: it is caught up, not said to be "no cycle
    missed" because ``until`` came before ``since + period``."""
    pre, gap = scenario(T_STOP, 1)
    gap.index = gap.index - pd.Timedelta(seconds=4)
    plant = stopped_plant(unit_dir, pre)
    historian_with(db_url, pre, gap)
    res = catch_up(plant, db_url, gap.index[-1], 10.0)
    assert res.mode == "replayed" and res.rows == res.total == 1, res
    assert res.first == T_STOP + STEP


def test_a_long_gap_is_replayed_as_diag_diagnose_and_the_units_warm_up(unit_dir, db_url):
    """A gap longer than the lead-in: its episodes by the replay's path (the same as an
    uninterrupted run's), the live plant warmed up on the last lead-in before now."""
    pre, gap = scenario(T_STOP, 2500)
    plant = stopped_plant(unit_dir, pre)
    want, _ = reference(plant, gap)
    url = db_url
    historian_with(url, pre, gap)
    res = catch_up(plant, url, gap.index[-1], 10.0)
    assert res.mode == "history", res
    assert [(e.unit, e.start, e.end, e.status) for e in res.episodes] == want
    assert res.rows == res.lead < len(gap) and res.first == gap.index[-res.lead]
    assert plant.last_ts == gap.index[-1]
    # beyond the limit: only the warm-up, the gap said not diagnosed
    plant = stopped_plant(unit_dir, pre)
    res = catch_up(plant, url, gap.index[-1], 10.0, max_gap_s=3600)
    assert res.mode == "warm-up" and not res.episodes and res.rows == res.lead
    text = said(res)
    assert f"{gap.index[0]:%Y-%m-%d %H:%M:%S} to" in text and "is not diagnosed" in text, text


def test_an_alarm_across_the_stop_and_one_still_on_at_the_end(unit_dir, db_url):
    """A fault from before the stop into the gap: on at the gap's first sample in both ways
    (the history replay reads its lead-in before the stop, so its delays are where the live
    run's were); a fault still on at the end: no end, said, left to the first cycle."""
    pre, gap = scenario(T_STOP, 2500, onset=-150, end=200)
    plant = stopped_plant(unit_dir, pre)
    want, _ = reference(plant, gap)
    assert want[0][1] == gap.index[0], want  # alarming when it stopped
    url = db_url
    historian_with(url, pre, gap)
    res = catch_up(copy.deepcopy(plant), url, gap.index[-1], 10.0)
    assert res.mode == "history", res
    assert [(e.unit, e.start, e.end, e.status) for e in res.episodes] == want
    assert res.episodes[0].at_gap_start
    text = said(res)
    assert f"on at the gap's start {gap.index[0]:%Y-%m-%d %H:%M:%S} to" in text, text
    # the gap ends while the fault is on
    short = gap.iloc[:100]
    want, _ = reference(plant, short)
    res = catch_up(plant, url, short.index[-1], 10.0)
    assert res.mode == "replayed" and [(e.unit, e.start, e.end) for e in res.episodes] == [
        w[:3] for w in want
    ]
    assert res.episodes[-1].end is None
    text = said(res)
    assert "still on at the end of the catch-up" in text and "not raised now" not in text, text


def test_the_restart_gap_begins_after_the_samples_caught_up(tmp_path):
    """The writer marks the time since the previous run's last cycle as a restart gap; the
    samples the catch-up found there (another collector's) move its start after them."""
    import numpy as np

    from diag_plugin.live.writer import LAST_FILE, HistorianWriter

    spill = tmp_path / "spill"
    spill.mkdir()

    async def run(caught: bool):
        last = {"ts": int(T_STOP.value // 1000), "period_us": 10_000_000}
        (spill / LAST_FILE).write_text(json.dumps(last), encoding="utf-8")
        w = HistorianWriter(f"sqlite:///{tmp_path / 'h.db'}", ["F"], spill_dir=spill, cycle=10)
        await w.start()
        if caught:
            w.samples_until(T_STOP + 100 * STEP)
        w.put(T_STOP + 101 * STEP, np.ones(1), np.zeros(1, np.uint8))
        await w.close()
        return w.restart_gap

    assert asyncio.run(run(False)) == (T_STOP + STEP, T_STOP + 101 * STEP)
    assert asyncio.run(run(True)) is None


def test_a_run_of_one_cycle_leaves_no_false_restart_gap(tmp_path):
    """The gap is judged on the data's period, never on the cycle: a run that stopped after
    one cycle (its period unseen; the embedded plant's samples are 10 s apart at a 0.04 s
    cycle) followed by one going on at the next sample marks no gap and stores no Bad
    sample between them; going on 60 s later, the gap is marked at the first missed sample
    on the period the second run's own steps show."""
    import numpy as np

    from diag_plugin.live.writer import HistorianWriter

    spill = tmp_path / "spill"
    url = f"sqlite:///{tmp_path / 'h.db'}"
    one, good = np.ones(1), np.zeros(1, np.uint8)

    async def run(times: list[pd.Timestamp]) -> tuple | None:
        w = HistorianWriter(url, ["F"], spill_dir=spill, cycle=0.04)
        await w.start()
        for ts in times:
            w.put(ts, one, good)
        await w.close()
        return w.restart_gap

    assert asyncio.run(run([T_STOP])) is None
    assert asyncio.run(run([T_STOP + STEP, T_STOP + 2 * STEP])) is None
    assert asyncio.run(run([T_STOP + 8 * STEP, T_STOP + 9 * STEP])) == (
        T_STOP + 3 * STEP,
        T_STOP + 8 * STEP,
    )
    h = Historian.open(url)
    got = h.read_samples("F")
    h.close()
    want = [T_STOP + k * STEP for k in (0, 1, 2, 3, 8, 9)]
    assert list(got.index) == want, got
    assert got.isna().tolist() == [False, False, False, True, False, False], got


def test_a_gap_without_samples_is_said_and_the_state_kept(unit_dir, db_url):
    pre, gap = scenario(T_STOP, 300)
    plant = stopped_plant(unit_dir, pre)
    before = json.dumps(plant.to_state())
    url = db_url
    historian_with(url, pre)  # nobody collected while we were down
    res = catch_up(plant, url, gap.index[-1], 10.0)
    assert res.mode == "empty" and res.rows == 0 and set(res.no_samples) == set(plant.tags)
    assert json.dumps(plant.to_state()) == before
    text = said(res)
    assert (
        f"holds no samples of {', '.join(plant.tags)} from {gap.index[0]:%Y-%m-%d %H:%M:%S} "
        f"to {gap.index[-1]:%Y-%m-%d %H:%M:%S}"
    ) in text, text
    # samples of a part of the gap only: the range without them is said
    historian_with(url, gap.iloc[150:])
    res = catch_up(plant, url, gap.index[-1], 10.0)
    assert res.mode == "replayed" and res.first == gap.index[150] and res.rows == 150
    text = said(res)
    assert (
        f"no samples from {gap.index[0]:%Y-%m-%d %H:%M:%S} to "
        f"{gap.index[149]:%Y-%m-%d %H:%M:%S}: the units jumped over it"
    ) in text, text


def test_the_time_out_cuts_the_catch_up_and_says_what_is_left(unit_dir, db_url):
    pre, gap = scenario(T_STOP, 700)
    url = db_url
    historian_with(url, pre, gap)
    plant = stopped_plant(unit_dir, pre)
    res = catch_up(plant, url, gap.index[-1], 10.0, deadline=time.monotonic())
    assert res.timed_out and res.rows < res.total == len(gap), res
    assert plant.last_ts == (res.last or pre.index[-1])
    text = said(res)
    assert "catch-up stopped at its time-out" in text and "is not diagnosed" in text, text


#: test_live's plant.toml at the unit's own period (10 s: one cycle in a short run)
PLANT_TOML = LIVE_TOML.replace("cycle = 0.05", "cycle = 10\ncatch_up_timeout = {timeout}")


def _config(
    unit_dir: Path, tmp_path: Path, timeout: float, historian: str = "sqlite:///cfg.db"
) -> tuple[Path, int]:
    from connectors.modbus_server import default_plant_map

    rb = tmp_path / "rb"
    rb.mkdir()
    for f in (unit_dir / "rb").iterdir():
        (rb / f.name).write_bytes(f.read_bytes())
    rows = ["tag,table,address,type"] + [
        f"{t.tag},{t.table},{t.address},{t.type}" for t in default_plant_map().tags
    ]
    (tmp_path / "plc.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
    port = free_port()
    text = PLANT_TOML.format(timeout=timeout, port=port, modbus=free_port())
    text = text.replace('historian = "sqlite:///cfg.db"', f"historian = {json.dumps(historian)}")
    (tmp_path / "plant.toml").write_text(text, encoding="utf-8")
    return tmp_path / "plant.toml", port


def _run(cfg, port: int, row: dict, after=None) -> str:
    from connectors.modbus_server import PlantServer
    from diag_plugin.live.config import run_config

    out = Out()

    async def main() -> int:
        async with PlantServer(port=port) as plc:
            await plc.set_row(row)
            return await run_config(cfg, duration=0.5, out=out, after=after)

    assert asyncio.run(main()) == 0, out.text
    return out.text


def test_diag_run_restarted_after_downtime_logs_the_missed_alarm(unit_dir, tmp_path, db_url):
    """`diag run --config` (Modbus PLC, SQLite historian) restarted with a state of 2 h ago
    and another collector's samples meanwhile: the episode logged with its times, in the
    event log at them; the first cycle goes on from the caught-up state."""
    from diag_plugin.live.config import load_config
    from diag_plugin.live.state import save_state

    path, port = _config(unit_dir, tmp_path, 60, db_url)
    cfg = load_config(path)
    now = pd.Timestamp.now(tz="UTC").floor("10s")
    pre, gap = scenario(now - 700 * STEP, 700)
    gap = gap[gap.index <= now - STEP]
    plant = stopped_plant(tmp_path, pre)
    want, _ = reference(plant, gap)
    save_state(plant, cfg.state)
    historian_with(cfg.historian, pre, gap)
    out = _run(cfg, port, gap.iloc[-1].to_dict())
    assert f"state {cfg.state} restored" in out, out
    for unit, a, b, _ in want:
        assert (
            f"{unit}: while diag run was down: alarm condition FAILURE faults"
        ) in out and f"from {a:%Y-%m-%d %H:%M:%S} to {b:%Y-%m-%d %H:%M:%S}" in out, out
    m = re.search(rf"(\d+) missed cycles from {gap.index[0]:%Y-%m-%d %H:%M:%S}", out)
    assert m and int(m.group(1)) == len(gap), out  # not the grid points after the last sample
    assert "stopped after 1 cycles" in out, out
    h = Historian.open(cfg.historian)
    ev = h.events(unit="valve_unit")
    h.close()
    for _, a, b, status in want:
        at_a = ev[ev["ts"] == a]
        assert len(at_a) == 1 and int(at_a["status"].iloc[0]) == status, ev
        assert "while diag run was down" in at_a["message"].iloc[0]
        at_b = ev[ev["ts"] == b]
        assert len(at_b) == 1 and int(at_b["status"].iloc[0]) == 0, ev
    saved = json.loads(cfg.state.read_text(encoding="utf-8"))
    assert saved["cycles"] == N_PRE + int(m.group(1)) + 1  # caught up, then the live cycle


def test_diag_run_first_cycle_does_not_wait_past_the_time_out(unit_dir, tmp_path):
    """A catch-up that needs longer than ``catch_up_timeout``: cut there, said, and the live
    loop runs its cycle from where it got."""
    from diag_plugin.live.config import load_config
    from diag_plugin.live.state import save_state

    path, port = _config(unit_dir, tmp_path, 0.001)
    cfg = load_config(path)
    now = pd.Timestamp.now(tz="UTC").floor("10s")
    pre, gap = scenario(now - 700 * STEP, 700)
    plant = stopped_plant(tmp_path, pre)
    save_state(plant, cfg.state)
    historian_with(cfg.historian, pre, gap)
    out = _run(cfg, port, gap.iloc[-1].to_dict())
    assert "catch-up stopped at its time-out" in out, out
    assert "stopped after 1 cycles" in out, out
    saved = json.loads(cfg.state.read_text(encoding="utf-8"))
    assert N_PRE + 1 <= saved["cycles"] < N_PRE + 700, saved["cycles"]


def test_embedded_default_saves_and_restores_its_state(tmp_path):
    """`diag run` without a config: the state saved in its data folder on stop, restored at
    the next start and said; the scenario resumes after the state's cycle (every sample
    stored once, none skipped); a changed unit file is refused and said."""
    import numpy as np

    from diag_plugin.live.embedded import STATE_FILE, run_embedded

    data = tmp_path / "diag-data"
    state = data / STATE_FILE

    def once() -> str:
        out = Out()
        ports = {k: free_port() for k in ("plc_port", "modbus_port", "opcua_port")}
        rc = asyncio.run(run_embedded(data, cycle=0.04, duration=2.0, tty=False, out=out, **ports))
        assert rc == 0, out.text
        return out.text

    out = once()
    assert f"state {state}: none yet, units start fresh" in out, out
    first = json.loads(state.read_text(encoding="utf-8"))
    assert first["cycles"] >= 1 and list(first["versions"]) == ["valve_unit"]
    out = once()
    assert f"state {state} restored: 1 units go on where they stopped" in out, out
    assert f"embedded scenario resumes at its sample {first['cycles']} of run 1" in out, out
    second = json.loads(state.read_text(encoding="utf-8"))
    assert second["cycles"] > first["cycles"]
    h = Historian.open(f"sqlite:///{data / 'plant.db'}")
    live = h.read_samples("P0", start=pd.Timestamp(first["ts"]) - (first["cycles"] - 1) * STEP)
    h.close()
    assert len(live) == second["cycles"], (len(live), second["cycles"])
    assert (np.diff(live.index.asi8) == STEP.value // 1000).all()  # µs: one run, no gap
    unit = data / "rulebases" / "valve_unit.unit.toml"
    unit.write_text(unit.read_text(encoding="utf-8") + "# edited\n", encoding="utf-8")
    out = once()
    assert "not restored (units changed since the state was saved: valve_unit)" in out, out
    assert "resumes" not in out, out


def test_a_killed_run_is_caught_up_from_its_journal(tmp_path):
    """`diag run --config` killed with SIGKILL between two state saves: the next start stores
    the killed run's journal first, then diagnoses its cycles after the last save (and the
    restart's own wait) from the historian before its first cycle."""
    import os
    import signal
    import subprocess

    from helpers import diag_run_polling, plant_toml, valve_plant
    from test_live_sources import start_plc

    d = tmp_path
    valve_plant(d)
    port = free_port()
    cfg = plant_toml(d, port, "sqlite:///k.db", cycle=0.2, flush_every=50, extra="state_every = 8")
    state = cfg.with_suffix(".state.json")
    plc, _ = start_plc(port)
    try:
        run, argv, env = diag_run_polling(d, cfg)
        deadline = time.monotonic() + 60
        while not state.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        time.sleep(1.0)  # a few cycles after a save (the next is 8 cycles on)
        os.kill(run.pid, signal.SIGKILL)
        killed = pd.Timestamp.now(tz="UTC")
        run.wait(10)
        saved = json.loads(state.read_text(encoding="utf-8"))
        again = subprocess.run(
            [*argv, "--duration", "1"], cwd=d, env=env, capture_output=True, text=True, timeout=120
        )
    finally:
        plc.kill()
        plc.wait()
    out = again.stdout
    assert again.returncode == 0, out + again.stderr
    assert "recovered from its journal" in out and f"state {state} restored" in out, out
    t_s = pd.Timestamp(saved["ts"])
    assert f"catch-up: the state is of {t_s:%Y-%m-%d %H:%M:%S} UTC" in out, out
    with Historian(f"sqlite:///{d / 'k.db'}") as h:
        f = h.read_samples("F", with_quality=True)
    after = f[(f.index > t_s) & (f.index < killed) & (f["quality"] == 0)]
    assert len(after), (t_s, killed, f.tail())  # the killed run's cycles after its last save
    m = re.search(r"(\d+) missed cycles from (\S+ \S+) to", out)
    assert m, out
    first = pd.Timestamp(m.group(2), tz="UTC")
    # the first sample after the save, on its grid point (± half a cycle; the log gives
    # whole seconds)
    assert -0.1 <= (after.index[0] - first).total_seconds() < 1.2, (first, after.index[0])
    live = int(re.search(r"stopped after (\d+) cycles", out).group(1))
    end = json.loads(state.read_text(encoding="utf-8"))
    assert end["cycles"] == saved["cycles"] + int(m.group(1)) + live, (end["cycles"], out)


def statuses(plant: Plant, rows: pd.DataFrame) -> list[tuple]:
    """Each row's (unit, NE 107 status, faults) from ``plant``."""
    out = []
    for ts, row in zip(rows.index, rows.to_dict("records"), strict=True):
        out.extend((s.unit, int(s.status), tuple(s.faults)) for s in plant.cycle(ts, row))
    return out


def test_a_fresh_start_warms_up_on_the_historians_last_lead_in(unit_dir, db_url):
    """No state (first start, or the unit files changed): the fresh plant warmed up on the
    historian's last lead-in goes on as the plant that ran all along — alarming with it from
    the first cycle through a fault that began before the start — where a cold plant counts
    its on-delay again; the log says what was read."""
    pre, after = scenario(T_STOP, 300, onset=-150, end=100)  # the fault on across the start
    running = stopped_plant(unit_dir, pre)
    historian_with(db_url, pre)
    warm = plant_of(unit_dir)
    res = warm_up(warm, db_url, T_STOP, 10.0)
    assert res.mode == "fresh" and not res.timed_out and res.rows == res.lead, res
    assert res.lead > 1000 and res.first == pre.index[-res.lead] and res.last == T_STOP
    want = statuses(running, after)
    assert want[0][1] == 1 and want[0][2], want[:3]  # FAILURE, isolated, at the first cycle
    assert statuses(warm, after) == want
    cold = statuses(plant_of(unit_dir), after)
    assert cold[0][1] != 1 and cold != want, cold[:3]  # cold: the on-delay counts again
    text = said(res)
    assert (
        f"warm-up: no state to go on from: the units warmed up on the historian's last "
        f"{res.lead} samples ({res.first:%Y-%m-%d %H:%M:%S} to {T_STOP:%Y-%m-%d %H:%M:%S})"
    ) in text, text


def test_a_warm_up_cut_or_without_samples_starts_cold_and_says_so(unit_dir, db_url):
    pre, _ = scenario(T_STOP, 0)
    historian_with(db_url, pre)
    cold = json.dumps(plant_of(unit_dir).to_state())
    plant = plant_of(unit_dir)
    res = warm_up(plant, db_url, T_STOP, 10.0, deadline=time.monotonic())
    assert res.timed_out and json.dumps(plant.to_state()) == cold
    text = said(res)
    assert "stopped at its time-out after 0: the units start cold" in text, text
    # the historian's last samples a day before now: nothing in the lead-in, cold
    res = warm_up(plant, db_url, T_STOP + pd.Timedelta("1D"), 10.0)
    assert res.rows == 0 and json.dumps(plant.to_state()) == cold, res
    text = said(res)
    assert "the historian holds no samples of the units' tags from" in text, text
    assert "the units start cold (warming up live)" in text, text


def test_diag_run_without_a_state_starts_warm(unit_dir, tmp_path, db_url):
    """`diag run --config` with no state file and the historian holding the last hours: the
    units warm up before the first cycle, said; the first cycle goes on from there (the
    state saved on stop counts the warm-up's cycles)."""
    from diag_plugin.live.config import load_config

    path, port = _config(unit_dir, tmp_path, 60, db_url)
    cfg = load_config(path)
    now = pd.Timestamp.now(tz="UTC").floor("10s")
    pre, _ = scenario(now, 0)
    historian_with(cfg.historian, pre)
    out = _run(cfg, port, pre.iloc[-1].to_dict())
    assert f"state {cfg.state}: none yet, units start fresh" in out, out
    m = re.search(
        r"warm-up: no state to go on from: the units warmed up on the historian's last "
        r"(\d+)(?: of the lead-in's \d+)? samples",
        out,
    )
    assert m, out
    saved = json.loads(cfg.state.read_text(encoding="utf-8"))
    assert saved["cycles"] == int(m.group(1)) + 1 and int(m.group(1)) > 1000, saved["cycles"]
    assert "stopped after 1 cycles" in out, out


@pytest.mark.postgres
def test_a_locked_historian_means_a_cold_start_on_time(unit_dir, tmp_path, pg_url):
    """The PostgreSQL historian's samples table locked by another session (ACCESS
    EXCLUSIVE, as a long maintenance job takes it): the warm-up's read waits, the first
    cycle does not — cold, said, after ``catch_up_timeout`` — and the lock released after it,
    the run stops cleanly. With a restored state the same: the units go on from it."""
    import psycopg

    from diag_plugin.live.config import load_config
    from diag_plugin.live.state import save_state

    path, port = _config(unit_dir, tmp_path, 2, pg_url)
    cfg = load_config(path)
    # the history ends 5 min before now: with the state saved at its end, the catch-up has
    # a gap to read however soon the second run starts (within a sample period of the
    # state's time there is nothing to read, and no time-out to say: failed on a quiet
    # machine, passed under load)
    now = pd.Timestamp.now(tz="UTC").floor("10s") - pd.Timedelta(minutes=5)
    pre, _ = scenario(now, 0)
    historian_with(cfg.historian, pre)
    dsn = pg_url.replace(
        "postgresql://postgres@127.0.0.1:5432/", "host=127.0.0.1 port=5432 user=postgres dbname="
    )

    def locked() -> tuple[str, float]:
        """A run with the table locked; the lock released after its first cycle (or after
        60 s, should the loop wait on it: then too late for the assertion)."""
        import threading

        lock = psycopg.connect(dsn)
        lock.execute("LOCK TABLE samples IN ACCESS EXCLUSIVE MODE")
        released = threading.Lock()
        first: list[float] = []

        def release() -> None:
            with released:
                if not lock.closed:
                    lock.rollback()

        timer = threading.Timer(60, release)

        async def after(loop, i, statuses) -> None:
            if i == 0:
                first.append(time.monotonic())
                await asyncio.to_thread(release)

        t0 = time.monotonic()
        timer.start()
        try:
            out = _run(cfg, port, pre.iloc[-1].to_dict(), after=after)
        finally:
            timer.cancel()
            with released:
                lock.close()
        return out, first[0] - t0

    out, first = locked()
    assert (
        "warm-up: no state to go on from; stopped at its time-out: the historian did not "
        "answer within 2 s (slow or locked): the units start cold" in out
    ), out
    assert "stopped after 1 cycles" in out, out
    assert first < 2 + 30, first  # the start-up and the 2 s bound, not the lock's 60 s
    plant = stopped_plant(tmp_path, pre)
    save_state(plant, cfg.state)
    out, _ = locked()
    assert f"state {cfg.state} restored" in out, out
    assert (
        "catch-up stopped at its time-out: the historian did not answer within 2 s (slow or "
        f"locked); the units go on from their state of {pre.index[-1]:%Y-%m-%d %H:%M:%S}" in out
    ), out


@pytest.mark.postgres
def test_a_bounded_historian_read_fails_on_a_locked_table_instead_of_hanging(pg_url):
    """``Historian(timeout=...)``, as the catch-up's thread opens it: a read waiting on a lock
    fails at the bound (PostgreSQL's statement_timeout), so the thread left behind by a loop
    that stopped waiting ends too; unbounded, the same read waits for the lock."""
    import threading

    import psycopg

    pre, _ = scenario(T_STOP, 0)
    historian_with(pg_url, pre.iloc[-10:])
    dsn = pg_url.replace(
        "postgresql://postgres@127.0.0.1:5432/", "host=127.0.0.1 port=5432 user=postgres dbname="
    )
    with psycopg.connect(dsn) as lock:
        lock.execute("LOCK TABLE samples IN ACCESS EXCLUSIVE MODE")
        h = Historian(pg_url, timeout=1.0)
        t0 = time.monotonic()
        with pytest.raises(Exception, match="statement timeout"):
            h.read_samples("P0")
        assert time.monotonic() - t0 < 15
        h.close()
        waited: list[float] = []

        def unbounded() -> None:
            with Historian(pg_url) as h2:
                t = time.monotonic()
                h2.read_samples("P0")
                waited.append(time.monotonic() - t)

        th = threading.Thread(target=unbounded)
        th.start()
        th.join(3)
        assert th.is_alive()  # still waiting on the lock
        lock.rollback()
        th.join(30)
        assert waited, "the unbounded read did not finish after the lock was released"
