"""A pump's start is not an alarm (issue 34, item 6; ISA-18.2 state-based alarming;
diagnose/settle.py, "A state change"; docs/how-to/unit-loops.md, "A state change settles").

Acceptance pass on a pumping station (docs/explanation/acceptance-pumps.md): at 1 min every
fault-free alarm episode followed an assist pump's start. The plant here is written for this
test: an assist pump started on demand with a hysteresis (its run feedback ``RUN2`` a discrete
state, ``[build] states``), the header pressure overshooting at each start and dipping at each
stop, the starting motor's current running up. Built on 4 days with a few starts and judged on
a seed it never saw: the starts' alarms become CHECK_FUNCTION naming the change, and a fault
starting right after a start is FAILURE from ``state_settle_max_s`` on.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pandas as pd
import pytest

from diag_plugin.diagnose.plant import Plant
from diag_plugin.diagnose.settle import quiet_parts, settle_guard
from diag_plugin.diagnose.unit import Unit
from diag_plugin.status import NE107
from diag_plugin.unitbuild.build import build_unit
from tests.test_unit_discrete import demand_and_run
from tests.test_unit_manual import _in_pieces_as_whole, without_key

CF, NORMAL = int(NE107.CHECK_FUNCTION), int(NE107.NORMAL)
CHANGE = re.compile(r"^RUN2 (\d) → (\d) at (\S+): settling after a state change")


def _station(days: float, seed: int, bias_at: int | None = None) -> pd.DataFrame:
    """1-min samples: a demand with a daily cycle; pump 2 assists above 260 m3/h and stops
    below 200 (``RUN2`` 0/1); at a start the header pressure overshoots 0.4 bar (the loop winds
    the speed back, 4 min) and pump 2's current runs up (2 A over 3 min), at a stop the
    pressure dips 0.2 bar. ``bias_at``: pump 1's current meter reads 3 A high from that
    sample on."""
    rng, t, demand, run2 = demand_and_run(days, seed)
    n = len(t)
    over, runup = np.zeros(n), np.zeros(n)
    for k in np.flatnonzero(np.diff(run2) != 0) + 1:
        d = np.arange(n - k)
        up = run2[k] == 1
        over[k:] += (1.0 if up else -0.5) * np.exp(-d / 5.0)
        if up:
            runup[k:] += 4.0 * np.exp(-d / 4.0)
    share = demand / (1 + run2)
    press = 5.0 - 2.5e-5 * share**2 + over + rng.normal(0, 0.01, n)
    i1 = 5 + 0.002 * share**2 / 0.8 + rng.normal(0, 0.3, n)
    i2 = run2 * (5 + 0.002 * share**2 / 0.8 + runup + rng.normal(0, 0.3, n))
    if bias_at is not None:
        i1[bias_at:] += 3.0
    flow = demand + rng.normal(0, 2, n)
    idx = pd.date_range("2026-06-01", periods=n, freq="60s", tz="UTC")
    return pd.DataFrame({"FLOW": flow, "PRESS": press, "I1": i1, "I2": i2, "RUN2": run2},
                        index=idx)  # fmt: skip


def _starts(x: pd.DataFrame) -> np.ndarray:
    return np.flatnonzero(np.diff(x["RUN2"].to_numpy()) > 0) + 1


def _raised(st: np.ndarray) -> np.ndarray:
    return (st != NORMAL) & (st != CF)


def _episodes(a: np.ndarray) -> np.ndarray:
    return np.flatnonzero(a & ~np.r_[False, a[:-1]])


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    """The unit built on 4 days, and the same unit without the state's settle (main)."""
    folder = tmp_path_factory.mktemp("station")
    window = _station(4, 1)
    res = build_unit("station", window, folder=folder, period="60s", far=0.01)
    unit = Unit.load(res.path, folder)
    plain = Unit.load(res.path, folder)
    plain.ev["state_settle_max_s"] = 0.0
    plain.settle = settle_guard(plain)
    return unit, plain, res, window


def test_the_build_says_how_long_a_state_change_may_settle(station):
    """Fails on main (no ``state_settle_max_s``)."""
    unit, _, res, window = station
    assert len(_starts(window)) >= 3
    max_s = unit.ev["state_settle_max_s"]
    assert max_s > 0
    said = unit.file.build["state_settle"]
    assert said.startswith(f"state_settle_max_s = {max_s:.0f} s: the 90% quantile (")
    assert "state change(s) that settled" in said and said in res.notes
    # the quiet time from the unit's own settings (the residual filter's delay among them)
    quiet = f"plus the quiet time ({unit.settle.quiet_n * 60:.0f} s)"
    assert unit.ev["lowpass"] == 0.2 and quiet in said, said
    states = [lp for lp in unit.settle.loops if lp.state]
    assert [lp.sp for lp in states] == ["RUN2"]


def test_a_pump_start_is_check_function_not_an_alarm(station):
    """Seed 7 (never used to build), no fault: two of its three starts raised the unit
    without the state's settle; now none does, their alarm samples CHECK_FUNCTION naming the
    change; elsewhere nothing changed. Fails on main, where the third start's alarm began 17
    min after it: the pressure's test reads the state 9 samples late (``RUN2[k-9]``) and its
    low-pass filter built the residual after the settle had closed (12 quiet samples: the lag
    plus the on-delay); the quiet time now holds the filter's delay too (19 samples)."""
    unit, plain, *_ = station
    x = _station(3, 7)
    starts = _starts(x)
    d, d0 = unit.reset().evaluate(x), plain.reset().evaluate(x)
    st, st0 = d.status.to_numpy(), d0.status.to_numpy()
    near = np.zeros(len(x), bool)
    for k in starts:
        near[k : k + 30] = True
    main, now = len(_episodes(_raised(st0) & near)), len(_episodes(_raised(st) & near))
    assert main >= 2 and now == 0, (main, now)  # without the guard the starts alarm
    assert len(_episodes(_raised(st))) < len(_episodes(_raised(st0)))
    why = d.why.to_numpy(dtype=object)
    said = np.array([bool(CHANGE.match(w)) for w in why])
    changed = st != st0
    assert changed.any() and said[changed].all() and (st[changed] == CF).all()
    first = CHANGE.match(why[np.argmax(said)])
    assert first.group(1, 2) in {("0", "1"), ("1", "0")}


def test_a_fault_right_after_a_start_is_failure_after_state_settle_max_s(station):
    """Pump 1's current meter 3 A high from 2 min after a start: CHECK_FUNCTION at most
    state_settle_max_s, then FAILURE (without the guard: FAILURE from soon after the onset).
    With the start's envelope (tests/test_unit_envelope.py) it ends sooner: the unit file
    less ``[envelope]`` holds it to the bound."""
    from tests.test_unit_envelope import _without_envelope

    unit, plain, *_ = station
    bare = _without_envelope(unit, "bare")
    k = _starts(_station(3, 7))[1]
    x = _station(3, 7, bias_at=k + 2).iloc[: k + 300]
    st0 = plain.reset().evaluate(x).status.to_numpy()
    late = k + int(np.ceil(unit.ev["state_settle_max_s"] / 60.0)) + 1
    assert late < k + 200
    assert _raised(st0[k + 20 :]).mean() > 0.9
    for u in (unit, bare):
        st = u.reset().evaluate(x).status.to_numpy()
        assert _raised(st[late:]).mean() > 0.9
    assert not _raised(st[k : late - 1]).any()  # no envelope: held to the bound
    first = np.flatnonzero(_raised(unit.reset().evaluate(x).status.to_numpy()[k:]))[0]
    assert k + first < late - 1


def test_replay_pieces_restart_and_plant_agree(station, tmp_path):
    """Through starts of seed 7: one replay, pieces through saved states, and the live
    loop's stacked path restarted mid-settle give the same statuses and messages."""
    unit, *_ = station
    x = _station(3, 7)
    k = _starts(x)[0]
    x = x.iloc[k - 100 : k + 200]
    one = _in_pieces_as_whole(unit, x, 37)
    assert one.why.map(lambda s: bool(CHANGE.match(s))).sum() > 0
    path = unit.file.path

    def fresh():
        return Plant({"station": Unit.load(path, path.parent)}, {})

    plant = fresh()
    opened = False
    for i, (ts, row) in enumerate(x.iterrows()):
        if 100 < i < 140 and not opened:
            state = json.loads(json.dumps(plant.to_state()))
            if state["settle"]["station"]["g"][0] == 1:  # a settle open: restart here
                opened = True
                plant = fresh()
                plant.load_state(state)
        s, ref = plant.cycle(ts, row.to_dict())[0], one.at(i)
        assert (s.status, s.faults, s.message) == (ref.status, ref.faults, ref.message), i
    assert opened


def test_a_unit_file_without_state_settle_max_s_is_mains(station):
    """A unit file written before the key: no state in the guard, main's statuses."""
    unit, plain, *_ = station
    old = without_key(unit, "state_settle_max_s", "old")
    assert old.ev["state_settle_max_s"] == 0
    assert old.settle is None or not any(lp.state for lp in old.settle.loops)
    x = _station(1.5, 8)
    assert np.array_equal(
        old.reset().evaluate(x).status.to_numpy(), plain.reset().evaluate(x).status.to_numpy()
    )


def test_a_state_change_is_a_step_a_grid_mean_included():
    """A state held, a switch (a historian's mean of the minute reads 0.5), held again: one
    step each way; a state read as a flicker of one sample is none."""
    from diag_plugin.diagnose.settle import SettleGuard, SettleLoop

    run = SettleLoop("RUN2", "RUN2", -1, 0.0, 0.0, 0.25, span=(0.0, 1.0), state=True)
    g = SettleGuard([run], 50, 5, 60.0, 2)
    x = np.r_[np.zeros(50), [0.5], np.ones(50), np.zeros(50), [1.0], np.zeros(49)]
    got = [(j, a, b, r) for j, a, b, r in g.steps(x[:, None])]
    assert got == [(0, 0.0, 1.0, 50), (0, 1.0, 0.0, 101)]


def test_accept_keeps_the_state_settle_and_the_paths_agree(station, tmp_path):
    """``diag unit accept`` of a later confirmed period keeps ``state_settle_max_s``; the
    accepted unit's replay and live loop agree through a start."""
    import shutil

    from diag_plugin.unitbuild.accept import accept

    unit, _, _, window = station
    work = tmp_path / "u"
    shutil.copytree(unit.file.path.parent, work)
    u = Unit.load(work / "station.unit.toml", work)
    x = _station(2, 9)
    x.index = x.index + pd.Timedelta(days=10)
    both = pd.concat([window, x])

    def read(a, b):
        yield both.iloc[both.index.searchsorted(a) : both.index.searchsorted(b)]

    accept(u, read, x.index[0], x.index[-1] + pd.Timedelta(seconds=60))
    after = Unit.load(work / "station.unit.toml", work)
    assert after.ev["state_settle_max_s"] == unit.ev["state_settle_max_s"]
    assert any(lp.state for lp in after.settle.loops)
    run = _station(3, 7)
    k = _starts(run)[0]
    run = run.iloc[k - 60 : k + 120]
    one = after.reset().evaluate(run)
    plant = Plant({"station": Unit.load(work / "station.unit.toml", work)}, {})
    opened = 0
    for i, (ts, row) in enumerate(run.iterrows()):
        a, ref = plant.cycle(ts, row.to_dict())[0], one.at(i)
        assert (a.status, a.faults, a.message) == (ref.status, ref.faults, ref.message), i
        opened += plant.to_state()["settle"]["station"]["g"][0]
    assert opened > 0  # the start opened a settle


def test_a_settle_ends_once_the_alarm_it_suppresses_has_dropped(station):
    """A settle ended at the quiet time even while the unit's alarm, held by its off-delay
    (``off_delay_s``), was still on: the hold's tail was raised after every start it had
    suppressed. At 1 s the hold (240 s then) outlasted a short quiet time: the station at
    1 s, imported off the grid and built through the CLI (quiet 163 s), raised 76 s after
    two of seed 7's changes (docs/how-to/unit-loops.md, "The settles at 1 s, off the grid").
    Here at 1 min, the alarm held 30 min (longer than the quiet time's parts, 19 samples)
    and the settle allowed twice its bound (so that the bound does not end it first): the
    quiet time is the hold's (``quiet_samples``, issue 34 item 6), and no suppressed
    alarm's tail is raised after its settle. Fails on main."""
    unit, *_ = station
    path = unit.file.path.parent / "held.unit.toml"
    text = re.sub(r"(?m)^off_delay_s = .*$", "off_delay_s = 1800.0", unit.file.path.read_text())
    longer = 2 * unit.ev["state_settle_max_s"]
    text = re.sub(r"(?m)^state_settle_max_s = .*$", f"state_settle_max_s = {longer}", text)
    path.write_text(text.replace('name = "station"', 'name = "held"'))
    held = Unit.load(path, path.parent)
    assert held.alarm_hold is not None and held.ev["off_delay"] == 30 == held.settle.quiet_n
    assert sum(quiet_parts(held)) < 30  # the hold, not the history a test reads
    x = _station(3, 7)
    st = held.reset().evaluate(x).status.to_numpy()
    near = np.zeros(len(x), bool)
    for k in _starts(x):
        near[k : k + 150] = True
    assert (st[near] == CF).sum() > 60  # the starts' alarms suppressed, the hold with them
    assert not _raised(st[near]).any()


@pytest.mark.slow
def test_at_1s_off_the_grid_a_change_s_alarm_ends_inside_its_settle(tmp_path):
    """The station at 1 s, read off the grid (±20 %, ``+02:00``, a row repeated), imported,
    built on 2 days and judged on a day of seed 7 through the CLI: the build's quiet time
    (163 s: no lag, the filter's 133 samples, the on-delay's 30) covers the alarm's hold
    (ISA-18.2's 60 s; 240 s before, longer than the quiet time, which the guard then waited
    for), and no change of the pump is raised (main before the guard waited: 2 of 4, 76 s
    each). ~1 min."""
    from tests.offgrid import off_grid, station_1s, write_csv
    from tests.test_any_plant_tour import diag

    g = ["--db", f"sqlite:///{tmp_path / 'h.db'}", "--rulebases", str(tmp_path / "rb")]
    runs = {"build": station_1s(2.0, 1), "free": station_1s(1.0, 7)}
    spans = {}
    for k, (name, run) in enumerate(runs.items()):
        run.index = run.index + pd.Timedelta(days=10 * k)
        write_csv(off_grid(run, 1.0, 5 + k), tmp_path / f"{name}.csv")
        rc, text = diag(g, "import", str(tmp_path / f"{name}.csv"), "--duplicates", "first")
        assert rc == 0, text
        spans[name] = [t.strftime("%Y-%m-%dT%H:%M:%SZ") for t in
                       (run.index[0], run.index[-1] + pd.Timedelta(seconds=1))]  # fmt: skip
    rc, text = diag(g, "unit", "build", "u", "--from", spans["build"][0], "--to",
                    spans["build"][1], "--far", "0.01")  # fmt: skip
    assert rc == 0, text
    unit = Unit.load(tmp_path / "rb" / "u.unit.toml", tmp_path / "rb")
    assert unit.ev["state_settle_max_s"] > 0 and unit.ev["off_delay"] == 60
    # the quiet time (the history a test reads, the filter's delay, the on-delay) covers the hold
    assert unit.settle.quiet_n == sum(quiet_parts(unit)) >= unit.ev["off_delay"]
    out = tmp_path / "free.out.csv"
    rc, text = diag(g, "diagnose", "u", "--from", spans["free"][0], "--to", spans["free"][1],
                    "--csv", str(out))  # fmt: skip
    assert rc == 0, text
    d = pd.read_csv(out, low_memory=False)
    ts = pd.to_datetime(d["ts"], utc=True)
    st = d["status"].to_numpy(int)
    free = runs["free"]
    changes = free.index[np.flatnonzero(np.diff(free["RUN2"].to_numpy()) != 0) + 1]
    assert len(changes) >= 2
    near = np.zeros(len(d), bool)
    for t in changes:
        near |= ((ts >= t) & (ts < t + pd.Timedelta(minutes=40))).to_numpy()
    said = d["why"].fillna("").astype(str).str.contains("settling after a state change")
    assert (said.to_numpy() & (st == CF)).sum() > 300  # the changes' alarms suppressed
    assert not _raised(st[near]).any()


# ------------------------------------------------- the bound (issue 34, H7)
# state_settle_max_s was 2 × the median settling time of the window's changes plus the quiet
# time; a fault present through a start kept a test on, so the settle ran to that bound (the
# air-handling unit 8.75 h, chiller 2 9.9 h: docs/explanation/acceptance-ahu.md, H7). Now the
# 90 % quantile of the window's settling times plus the quiet time.
SAID = re.compile(r"the 90% quantile \((\d+) s\) of the settling times of the (\d+) of the "
                  r"window's (\d+) state change\(s\) that settled \(([\d, ]+) s\), plus the "
                  r"quiet time")  # fmt: skip


def _said(unit) -> tuple[np.ndarray, float]:
    """The settled changes' times the note lists, and the quiet time (seconds)."""
    said = unit.file.build["state_settle"]
    got = SAID.search(said)
    assert got, said
    times = np.array([float(t) for t in got.group(4).split(",")])
    assert len(times) == int(got.group(2)) and 2 * len(times) >= int(got.group(3))
    assert float(got.group(1)) == np.quantile(times, 0.9, method="higher")
    return times, unit.settle.quiet_n * unit.period_s


def test_the_bound_is_a_high_quantile_of_the_window_s_settling_times(station):
    """The note lists the settled changes' times; the bound is their 90 % quantile (an
    observed time) plus the quiet time: shorter than 2 × their median plus the quiet time
    (main's rule). Fails on main (its note: ``2 × the median settling time``)."""
    unit, *_ = station
    times, quiet_s = _said(unit)
    bound = unit.ev["state_settle_max_s"]
    assert bound == np.quantile(times, 0.9, method="higher") + quiet_s
    assert bound < 2 * np.median(times) + quiet_s


@pytest.mark.parametrize("seed", [8, 9])
def test_a_fault_through_a_start_is_raised_once_the_start_has_settled(station, seed):
    """Pump 1's current meter 3 A high from 2 min after each of a run's first three starts
    (the runs cut 5 h after it): raised before main's rule (2 × the median of the window's
    settling times plus the quiet time) would have ended the settle, and from then on. Main
    held it CHECK_FUNCTION 56 min (its bound)."""
    unit, *_ = station
    times, quiet_s = _said(unit)
    mains = (2 * np.median(times) + quiet_s) / unit.period_s
    for k in _starts(_station(3, seed))[:3]:
        x = _station(3, seed, bias_at=k + 2).iloc[: k + 300]
        st = unit.reset().evaluate(x).status.to_numpy()
        raised = np.flatnonzero(_raised(st[k:]))
        assert raised.size and raised[0] < mains, (k, raised[:1], mains)
        assert _raised(st[k + raised[0] :]).mean() > 0.9


def test_a_settle_names_the_last_change_of_its_state():
    """A filter's wash, 0 → 1 (backwash) → 2 (filter-to-waste) → 0, its alarm latching the
    settle the first change opened (acceptance-filters.md): after the wash the why named
    ``F3_STATE 0 → 1 at …`` for the rest of the settle, the filter long back at 0. It names
    the last change and when, and since when the settle is open (its end unchanged)."""
    from diag_plugin.diagnose.settle import SettleGuard, SettleLoop

    state = SettleLoop("F3_STATE", "F3_STATE", -1, 0.0, 0.0, 0.5, span=(0.0, 2.0), state=True)
    x = np.r_[np.zeros(30), np.ones(12), np.full(15, 2.0), np.zeros(60)]
    n = len(x)
    index = pd.date_range("2026-03-25T09:00Z", periods=n, freq="1min")
    alarm = np.zeros(n, bool)
    alarm[33:60] = True  # from the on-delay after the wash began, to its off-delay after it
    sup_at = {}
    for pieces in ([n], [45, n - 45]):  # whole, and in two pieces (the state carried)
        g = SettleGuard([state], 100, 5, 60.0, 2)
        sups, whys, a = [], [], 0
        for m in pieces:
            s, w = g.transform(index[a : a + m], x[a : a + m, None], np.zeros((m, 1)),
                               alarm[a : a + m], alarm[a : a + m])  # fmt: skip
            sups.append(s)
            whys.append(w)
            a += m
        sup, why = np.concatenate(sups), np.concatenate(whys)
        sup_at[len(pieces)] = sup
        assert why[35] == "F3_STATE 0 → 1 at 2026-03-25T09:30Z: settling after a state change"
        assert why[50].startswith("F3_STATE 1 → 2 at 2026-03-25T09:42Z")
        assert why[60] == (
            "F3_STATE 2 → 0 at 2026-03-25T09:57Z: settling after a state change "
            "(the settle open since 2026-03-25T09:30Z)"
        )
        assert sup[33:60].all() and not sup[:33].any() and not sup[80:].any()
    assert np.array_equal(sup_at[1], sup_at[2])
