"""An operator's set-point step is not an alarm (issue 34, items 5/6; diagnose/settle.py).

A heater with a cascade (:mod:`tests.spstep_plant`: a PI loop around a first-order process
with dead time, its output the set-point of a flow loop) built as a user would on a window
with three set-point steps, at 5 s and at 2 min, and judged on seeds it never saw: every
step's alarm becomes CHECK_FUNCTION with the step in its why, the other samples are as
without the guard, a fault that starts during a settle is FAILURE from ``settle_max_s`` on,
and a fault that moves the cascade set-point alarms as without the guard. The replay, the
live loop's stacked path, a restart mid-settle and a unit after ``diag unit accept`` agree.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pandas as pd
import pytest

from diag_plugin.diagnose.settle import SettleGuard, SettleLoop
from diag_plugin.diagnose.unit import Unit, concat
from diag_plugin.status import NE107
from diag_plugin.unitbuild.build import build_unit
from diag_plugin.unitbuild.loops import parse_loop
from tests import spstep_plant as sp

CF, NORMAL, FAILURE = int(NE107.CHECK_FUNCTION), int(NE107.NORMAL), int(NE107.FAILURE)
#: judged: steps at 3 h and 8 h of a 0.6-day run
STEPS = [(3 * 3600.0, 60.0), (8 * 3600.0, 70.0)]


@pytest.fixture(scope="module", params=[5, 120], ids=["5s", "2min"])
def heater(request, tmp_path_factory):
    """The heater's unit built on a window with three steps (2 days at 5 s, 6 days at 2 min),
    and the same unit without its guard (what main does: no ``settle_max_s``)."""
    period = request.param
    days = 2.0 if period == 5 else 6.0
    window = sp.at_period(sp.simulate(days, 1, steps=sp.TRAIN_STEPS), period)
    folder = tmp_path_factory.mktemp(f"heater{period}")
    res = build_unit("heater", window, folder=folder, period=f"{period}s", far=0.01,
                     loops=[parse_loop(lp) for lp in sp.LOOPS], force=True)  # fmt: skip
    unit = Unit.load(res.path, folder)
    plain = Unit.load(res.path, folder)
    plain.settle = None
    unit.window = window  # what accept reads again
    return period, unit, plain, res, folder


def _alarm(st: np.ndarray) -> np.ndarray:
    return (st != NORMAL) & (st != CF)


def _starts(a: np.ndarray) -> np.ndarray:
    return np.flatnonzero(a & ~np.r_[False, a[:-1]])


def test_the_build_says_what_it_chose(heater):
    period, unit, _, res, _ = heater
    settle = unit.ev["settle_max_s"]
    assert settle > 0 and unit.settle is not None
    note = [n for n in res.notes if n.startswith("settle_max_s")]
    assert note and "3 set-point step(s) in the window" in note[0], res.notes
    # the cascade set-point FLOW_SP rests and moves on: no operator's move within the band
    # (held pairs alone counted 273 at 5 s; tests/test_unit_settle_band.py has a schedule's)
    assert "within their loop test's band" not in note[0], note[0]
    assert unit.file.build["settle"] == note[0]
    # the guard watches the outer loop (its set-point a tag an operator steps) and the inner
    # one (its set-point the cascade's, which moves every sample and never steps)
    assert [lp.sp for lp in unit.settle.loops] == ["HEAT_TGT", "FLOW_SP"]


def test_steps_that_do_not_settle_are_censored_not_dropped(heater):
    """A step the window (or the next step) cuts off before it settles is censored: where
    fewer than half of the judged steps settled, their median is unknown and the build falls
    back to 4 × the quiet time instead of the median of the few that did (1 of 3: the
    fallback; 2 of 3: their median); the heater's whole window: its steps' median."""
    from diag_plugin.unitbuild.loops import SETTLE_FALLBACK, _max_and_how, settle_max

    _, unit, _, _, _ = heater
    value, how = settle_max(unit, unit.window)
    assert "× the median settling time" in how and value == unit.ev["settle_max_s"]
    fallback, said = _max_and_how("settle_max_s", "set-point step", [600.0], 3, unit)
    assert "1 of the window's 3 set-point steps settled" in said, said
    none, _ = _max_and_how("settle_max_s", "set-point step", [], 3, unit)
    assert fallback == none and "4 × the quiet time" in said.replace(f"{SETTLE_FALLBACK:g}", "4")
    kept, said2 = _max_and_how("settle_max_s", "set-point step", [600.0, 700.0], 3, unit)
    assert "median settling time (650 s) of 2" in said2 and kept != fallback


@pytest.mark.parametrize("seed", [2, 3])
def test_an_operators_step_is_check_function_not_an_alarm(heater, seed):
    """Unseen seeds, several steps a day: main raises an alarm at (nearly) every step; with
    the guard none, those samples CHECK_FUNCTION saying which step, the rest unchanged."""
    period, unit, plain, _, _ = heater
    x = sp.at_period(sp.simulate(1.0 if period == 5 else 2.0, seed), period)
    steps = x.index[sp.step_rows(x)]
    main = plain.reset().evaluate(x)
    d = unit.reset().evaluate(x)
    st0, st = main.status.to_numpy(), d.status.to_numpy()
    e0 = _starts(_alarm(st0))
    assert len(e0) >= len(steps) - 1 >= 3, (len(e0), len(steps))  # main: an alarm a step
    assert not _alarm(st).any(), d.intervals()[lambda t: t.status == "FAILURE"]
    why = d.why.to_numpy(dtype=object)
    settling = np.array(["settling" in w for w in why])
    changed = st != st0
    assert changed.any() and settling[changed].all()
    assert (st[changed] == CF).all()
    # only alarms became CHECK_FUNCTION: a sample main says NORMAL stays NORMAL outside a
    # settle that has suppressed an alarm (latched: no flicker within it)
    runs = np.split(np.arange(len(st)), np.flatnonzero(np.diff(settling.astype(int))) + 1)
    for r in runs:
        if settling[r[0]]:
            assert (st[r] == CF).all()
            assert _alarm(st0[r]).any() or _alarm(st0[max(r[0] - 1, 0) : r[0]]).any()
    # the why names the step: set-point, from, to, when, and the loop
    first = next(w for w in why if "settling" in w)
    m = re.match(r"HEAT_TGT (\d+) → (\d+) at (\S+): loop TEMP settling", first)
    assert m, first
    at = pd.Timestamp(m.group(3).replace("Z", "+00:00"))
    assert abs((at - steps[0]).total_seconds()) <= period, (at, steps[0])
    # outside the settles, the guard changes nothing
    assert (st[~settling] == st0[~settling]).all()


def test_a_fault_during_a_settle_is_failure_from_settle_max_on(heater):
    """A flow meter bias 2 min after a step: hidden at most settle_max_s, then FAILURE."""
    period, unit, plain, _, _ = heater
    onset = STEPS[1][0] + 120.0
    x = sp.at_period(sp.simulate(0.6, 4, "flow_bias", onset, steps=STEPS), period)
    d = unit.reset().evaluate(x)
    main = plain.reset().evaluate(x)
    t0 = x.index[0] + pd.Timedelta(seconds=onset)
    late = x.index >= x.index[0] + pd.Timedelta(seconds=STEPS[1][0] + unit.ev["settle_max_s"])
    st = d.status.to_numpy()
    assert (main.status.to_numpy()[late] == FAILURE).mean() > 0.9  # main sees the fault
    assert (st[late] == FAILURE).mean() > 0.9
    after = x.index >= t0
    assert (st[after] == FAILURE).mean() > 0.5  # most of the rest
    assert (st[after & ~late] != FAILURE).all()  # the settle: CHECK_FUNCTION, not NORMAL
    assert (st[after & ~late] == CF).mean() > 0.9


def test_a_fault_that_moves_the_cascade_set_point_still_alarms(heater):
    """Fouling, and a flow meter reading high, make the outer loop move the inner loop's
    set-point: no settle, the same statuses as without the guard, FAILURE."""
    period, unit, plain, _, _ = heater
    for fault, size in (("fouling", None), ("flow_bias", 3.0)):
        x = sp.at_period(sp.simulate(0.6, 5, fault, 5 * 3600.0, size, steps=STEPS), period)
        d = unit.reset().evaluate(x)
        main = plain.reset().evaluate(x)
        after = x.index >= x.index[0] + pd.Timedelta(hours=5)
        fsp = x["FLOW_SP"].to_numpy()
        before = fsp[(x.index >= x.index[0] + pd.Timedelta(hours=4)) & ~after]
        assert abs(np.median(fsp[after]) - np.median(before)) > 1.0  # the cascade moved
        assert (d.status.to_numpy()[after] == FAILURE).mean() > 0.9, fault
        assert not any("FLOW_SP" in w and "settling" in w for w in d.why), fault
        assert np.array_equal(d.status.to_numpy()[after], main.status.to_numpy()[after])


def test_replay_live_loop_and_restart_agree(heater):
    """The stacked live path, one by one, pieces with a restart (state through JSON)
    mid-settle: the same statuses, faults and messages as one replay."""
    from diag_plugin.diagnose.plant import Plant

    period, unit, _, _, folder = heater
    x = sp.at_period(sp.simulate(0.5, 6, "flow_bias", STEPS[1][0] + 120, steps=STEPS), period)
    x = x.iloc[: int(10 * 3600 / period)]
    one = unit.reset().evaluate(x)
    assert (one.why.str.contains("settling")).any()
    # pieces, each after a restart from the saved state (the settle carried across)
    unit.reset()
    parts, k = [], max(7, len(x) // 13)
    for a in range(0, len(x), k):
        state = json.loads(json.dumps(unit.to_state()))
        parts.append(unit.load_state(state).evaluate(x.iloc[a : a + k]))
    pd.testing.assert_frame_equal(one.to_frame(), concat(parts).to_frame())
    # the live loop: the stacked path, restarted mid-settle, and one by one
    fast = Plant.load([unit.file.path], folder)
    slow = Plant(Plant.load([unit.file.path], folder).units, batched=False)
    assert fast.fast == ["heater"] and slow.slow == ["heater"]
    mid = int((STEPS[1][0] + 600) / period)  # inside the settle
    for i, (ts, row) in enumerate(x.iterrows()):
        if i == mid:
            state = json.loads(json.dumps(fast.to_state()))
            assert state["settle"]["heater"]["g"][0] == 1  # a settle open
            fast = Plant.load([unit.file.path], folder).load_state(state)
        a, b = fast.cycle(ts, row.to_dict())[0], slow.cycle(ts, row.to_dict())[0]
        ref = one.at(i)
        assert (a.status, a.faults, a.message) == (ref.status, ref.faults, ref.message), i
        assert (b.status, b.faults, b.message) == (ref.status, ref.faults, ref.message), i


def test_accept_keeps_the_guard_and_the_paths_agree(heater, tmp_path):
    """``diag unit accept`` of a later confirmed period keeps ``settle_max_s``; the accepted
    unit's replay and live loop agree on a run with steps."""
    import shutil

    from diag_plugin.diagnose.plant import Plant
    from diag_plugin.unitbuild.accept import accept

    period, unit, _, _, folder = heater
    if period != 120:
        pytest.skip("one rate is enough for accept (its window needs its own run)")
    work = tmp_path / "u"
    shutil.copytree(folder, work)
    u = Unit.load(work / "heater.unit.toml", work)
    x = sp.at_period(sp.simulate(3.0, 7, steps=STEPS), period)
    x.index = x.index + pd.Timedelta(days=10)
    both = pd.concat([unit.window, x])

    def read(a, b):
        yield both.iloc[both.index.searchsorted(a) : both.index.searchsorted(b)]

    accept(u, read, x.index[0], x.index[-1] + pd.Timedelta(seconds=period))
    after = Unit.load(work / "heater.unit.toml", work)
    assert after.ev["settle_max_s"] == unit.ev["settle_max_s"] and after.settle is not None
    run = sp.at_period(sp.simulate(0.6, 8, steps=STEPS), period)
    one = after.reset().evaluate(run)
    plant = Plant.load([work / "heater.unit.toml"], work)
    for i, (ts, row) in enumerate(run.iterrows()):
        a, ref = plant.cycle(ts, row.to_dict())[0], one.at(i)
        assert (a.status, a.faults, a.message) == (ref.status, ref.faults, ref.message), i


def test_an_old_unit_file_has_no_guard(heater, tmp_path):
    """A unit file without ``settle_max_s`` (written before it): no guard, main's statuses
    (nor a settle's transient the oscillation hold knows: it has no bound for one)."""
    import shutil

    period, unit, _, _, folder = heater
    plain = Unit.load(unit.file.path, folder)
    plain.settle = plain.transients = None
    work = tmp_path / "old"
    shutil.copytree(folder, work)
    p = work / "heater.unit.toml"
    p.write_text(re.sub(r"(?m)^settle_max_s = .*\n", "", p.read_text()))
    old = Unit.load(p, work)
    assert old.ev["settle_max_s"] == 0 and old.settle is None
    x = sp.at_period(sp.simulate(0.6, 2, steps=STEPS), period)
    assert np.array_equal(
        old.reset().evaluate(x).status.to_numpy(), plain.reset().evaluate(x).status.to_numpy()
    )


# ---------------------------------------------------------------- the step itself
def _guard(max_n=50, quiet=5):
    loop = SettleLoop("SP", "PV", 0, -1.0, 1.0, 0.5)
    return SettleGuard([loop], max_n, quiet, 5.0, 2)


def test_a_step_is_a_held_set_point_that_jumps_and_holds_again():
    rng = np.random.default_rng(0)
    n = 200
    held = np.r_[np.full(80, 10.0), np.full(n - 80, 12.0)]  # an operator's step
    split = np.r_[np.full(80, 10.0), [11.0], np.full(n - 81, 12.0)]  # a mean splits it
    ramp = np.r_[np.full(80, 10.0), np.linspace(10.0, 12.0, 40), np.full(n - 120, 12.0)]
    cascade = 10.0 + np.cumsum(0.05 * rng.standard_normal(n))  # moves every sample …
    cascade[100:] += 2.0  # … and jumps by four bands (a fault moving it)
    found = {k: _guard().steps(v[:, None]) for k, v in
             {"held": held, "split": split, "ramp": ramp, "cascade": cascade}.items()}  # fmt: skip
    assert found["held"] == [(0, 10.0, 12.0, 80)]
    assert found["split"] == [(0, 10.0, 12.0, 80)]
    assert found["ramp"] == [] and found["cascade"] == []


def test_a_settle_suppresses_alarms_only_latched_and_ends():
    """No alarm: nothing changes. An alarm within the settle: CHECK_FUNCTION from it to the
    settle's end (quiet samples with the loop in band and no test on), then the unit's own
    status again; a fault lasting past ``max_n``: alarm again from there."""
    n = 120
    idx = pd.date_range("2026-03-07T10:00", periods=n, freq="5s", tz="UTC")
    sp_ = np.r_[np.full(20, 0.0), np.full(n - 20, -20.0)]
    r = np.zeros((n, 1))
    active = np.zeros(n, bool)
    g = _guard(max_n=60, quiet=5)
    sup, _ = g.transform(idx, sp_[:, None], r, active, active)
    assert not sup.any()  # no alarm: no change
    alarm = np.zeros(n, bool)
    alarm[25:30] = alarm[33:36] = True  # the step's alarm, off and on (no flicker)
    active = alarm.copy()
    r[20:40] = 3.0  # the loop out of band until 40
    g = _guard(max_n=60, quiet=5)
    sup, why = g.transform(idx, sp_[:, None], r, active, alarm)
    assert np.flatnonzero(sup).tolist() == list(range(25, 45))  # ends on the 5th in band
    assert why[25] == "SP 0 → -20 at 2026-03-07T10:01:40Z: loop PV settling"
    alarm[25:] = True  # a fault: suppressed to max_n, then the alarm
    g = _guard(max_n=60, quiet=5)
    sup, _ = g.transform(idx, sp_[:, None], r, alarm, alarm)
    assert np.flatnonzero(sup).tolist() == list(range(25, 20 + 60))
