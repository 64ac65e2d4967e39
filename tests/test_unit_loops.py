"""Loops, naming and alarms (issue 34, items 4, 6, 7) on a 7-tag line built by hand
(:mod:`tests.line7`: a flow loop whose names follow no convention, a tank, a manual valve).

The unit is built as a user would: the line's CSV and tags CSV (the loop declared in its
``loop`` and ``role`` columns) imported into SQLite, ``diag unit build --loops-from``. Faults
are scored on seeds never used to build (101, 102). Nothing in the line was tuned to the unit:
it was written from its physics once. Every goal here is asserted; none is marked xfail.
"""

from __future__ import annotations

import json
import re
import shutil
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from diag_plugin.diagnose.unit import Unit, concat
from diag_plugin.diagnose.unitloops import (
    Deadband,
    EpisodeHold,
    ReleaseHold,
    RunningSpread,
    resolved_evaluation,
)
from diag_plugin.diagnose.unittags import rank
from diag_plugin.regressors import InputSpec
from diag_plugin.unitbuild.build import CHATTER_WINDOW_S
from diag_plugin.unitbuild.loops import Loop, loops_from_tags_csv, parse_loop
from historian.errors import UserError
from tests import line7
from tests.test_any_plant_tour import diag, fmt, import_csv

TRAIN_DAYS = 6.0
ONSET = int(86400 / line7.PERIOD_S)  # the faults start after a day
SEEDS = (101, 102)


@pytest.fixture(scope="module")
def line(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("line7")
    g, text = line7.cli_build(tmp, TRAIN_DAYS)
    unit = Unit.load("line", tmp / "rb")
    runs = {
        (fault, seed): unit.reset().evaluate(line7.simulate(2.0, seed, fault))
        for fault in (None, *line7.AT_FAULT, "manual_moved")
        for seed in SEEDS
    }
    return json.loads(text), unit, runs, g


def _episodes(alarm: np.ndarray) -> np.ndarray:
    a = np.asarray(alarm, bool)
    return np.flatnonzero(a & ~np.r_[False, a[:-1]])


def _named(d, k: int = 3) -> list[str]:
    """The tags most often in the top three over the alarm samples after the onset."""
    top = d.top_tags.iloc[ONSET:]
    names = pd.concat([top[f"top{i}"] for i in (1, 2, 3)])
    return names[names != ""].value_counts().index[:k].tolist()


# ---------------------------------------------------------------- the build
def test_the_declared_loop_is_built_with_its_set_point_actuator_and_spread_test(line):
    res, unit, *_ = line
    tests = {t["test"]: t for t in res["tests"]}
    pv = tests["FEED_FLOW"]
    assert pv["method"] == "track" and pv["tracks"] == "FEED_TARGET"
    assert pv["actuator"] == "VALVE_A" and pv["declared"]
    spread = tests["FEED_FLOW_spread"]
    assert spread["statistic"] == "spread" and spread["actuator"] == "VALVE_A"
    assert "set-point" in res["skipped"]["FEED_TARGET"]
    # the valve is predicted from what drives it, never from the flow its loop holds
    assert tests["VALVE_A"]["inputs"] and not any(
        i.startswith("FEED_FLOW") for i in tests["VALVE_A"]["inputs"]
    )
    spec = unit.file.test("FEED_FLOW_spread")
    assert spec.statistic == "spread" and spec.set_point == "FEED_TARGET"
    assert "FEED_TARGET" not in unit.cmodel.tags  # a set-point is never a tag at fault
    ev = unit.file.evaluation
    assert ev["on_delay_s"] == 45.0 and ev["off_delay_s"] >= 240.0 and ev["deadband"] > 0
    assert unit.ev["off_delay"] == int(np.ceil(ev["off_delay_s"] / line7.PERIOD_S))


# ---------------------------------------------------------------- detection and naming
@pytest.mark.parametrize("fault", list(line7.AT_FAULT))
def test_each_fault_is_detected_and_its_tag_named_in_the_top_three(line, fault):
    """Detected on more than 17 % of the samples after the onset beyond what the seed's
    fault-free run alarms there (was: 20 % in all, main's fault-free runs alarming on 3–4 %
    of them; the pair step's out-flow test cut those to 1 %, and the pressure drift's share
    with them, 22.0 → 19.8 % and 23.2 → 20.2 %, its part over the fault-free run 18.9 % and
    19.0 % on both; docs/how-to/unit-loops.md, branch ``i34-pair3``)."""
    _, _, runs, _ = line
    for seed in SEEDS:
        d = runs[(fault, seed)]
        det = (d.detected.iloc[ONSET:] == 1).mean()
        free = (runs[(None, seed)].detected.iloc[ONSET:] == 1).mean()
        assert det - free > 0.17, (fault, seed, det, free)
        assert line7.AT_FAULT[fault] in _named(d), (fault, seed, _named(d))


def test_stiction_is_named_on_the_valve_by_the_spread_of_its_loop_error(line):
    _, _, runs, _ = line
    for seed in SEEDS:
        d = runs[("stiction", seed)]
        after = d.symptoms["FEED_FLOW_spread"].iloc[ONSET:]
        before = d.symptoms["FEED_FLOW_spread"].iloc[:ONSET]
        # at the budget of 0.01 alarms per hour the spread test's threshold is extrapolated
        # (7 tests share it): it fires on part of the cycle only (9–16 % of the samples)
        assert (after == 1).mean() > 0.05 and (before != 0).mean() < 0.01
        # the level of the loop's error stays inside its band: stiction is not its level
        assert (d.symptoms["FEED_FLOW"].iloc[ONSET:] != 0).mean() < 0.05
        top1 = d.top_tags["top1"].iloc[ONSET:]
        assert top1[top1 != ""].value_counts().index[0] == "VALVE_A"


def test_a_flow_meter_bias_names_the_meter_not_the_manual_valve(line):
    _, _, runs, _ = line
    for seed in SEEDS:
        named = _named(runs[("flow_bias", seed)])
        # in the top three (third on seed 101 since the loop's sensor lost the plane of its
        # loop test's axis, second before: docs/how-to/unit-loops.md, the regression)
        assert "FEED_FLOW" in named and "HAND_VALVE" not in named, named


def test_the_loops_sensor_does_not_head_a_deviation_it_did_not_cause(line):
    """The manual valve moved to a position never seen: the flow loop holds its meter at the
    set-point, and the meter reads right. Ranked over the plane of its direction and its
    loop test's axis, the loop's sensor headed the tags named on these seeds (FEED_FLOW,
    OUT_FLOW, …); on one direction, as every other tag, it does not (issue 34 item 4).

    Judged over ten seeds, not one: with the valve's, the level's and the hand valve's tests
    unknown (the valve outside what the unit learned), the meter's and the out-flow's
    directions are exactly opposite on the tests that remain, so which of the two heads is a
    near tie on any one seed (seed 103: FEED_FLOW / OUT_FLOW first on 202 / 237 of 439 alarm
    samples without the loop-held flow's balance, 343 / 309 with it;
    docs/how-to/unit-loops.md, "The balance in its integral form"). Headed by FEED_FLOW on
    2 of the alarmed seeds 101–110 before the balance (101, 108) and with it (103, 108).
    Seeds the change was not chosen on (it was chosen on the chemical plant's tuning seeds)."""
    from diag_plugin.bench.matched import ranked_tags

    _, unit, _, _ = line
    headed, alarmed = [], 0
    for seed in range(101, 111):
        d = unit.reset().evaluate(line7.simulate(2.0, seed, "manual_moved"))
        rows = np.flatnonzero(d.detected.to_numpy() == 1)
        rows = rows[rows >= ONSET]
        if rows.size <= 20:
            continue
        alarmed += 1
        named = ranked_tags(d.contributions, rows)
        if named and named[0] == "FEED_FLOW":
            headed.append(seed)
    # at least half the seeds alarmed (main: 9 of 10; with the pair step, whose out-flow
    # test reads the level and the hand valve, 7: 2,663 → 584 alarm samples after the onset
    # over the ten seeds, the meter heading none; docs/how-to/unit-loops.md, ``i34-pair3``)
    assert alarmed >= 5, alarmed
    assert len(headed) <= 2, headed


def test_fault_free_runs_are_quiet(line):
    _, _, runs, _ = line
    for seed in SEEDS:
        d = runs[(None, seed)]
        assert (d.detected == 1).mean() < 0.05, seed


# ---------------------------------------------------------------- ISA-18.2
def test_no_fault_chatters_more_than_3_episodes_in_10_minutes(line):
    """A chattering alarm (more than 3 episodes of one fault in 10 minutes) fails."""
    _, _, runs, _ = line
    w = int(CHATTER_WINDOW_S / line7.PERIOD_S)
    for key, d in runs.items():
        ep = _episodes(d.detected.to_numpy() == 1)
        worst = max(((ep >= e) & (ep < e + w)).sum() for e in ep) if ep.size else 0
        assert worst <= 3, (key, worst)


def test_a_sticking_valve_on_the_line_is_at_most_3_alarms_a_day(line):
    """ISA-18.2: a standing fault is a standing alarm — at most 3 unit alarm episodes a day
    while the valve sticks (as the jacketed vessel in tests/test_unit_stiction.py), with no
    loss of detection (today's share of samples in alarm after the onset kept). A strict
    xfail until 2026-12-03: reached with the loop's own tests raising the spread release and
    T² released on the loops' long spread (i34-stick3: seed 101 still 4) and the pair step
    on declared flows (i34-pair3: the unit built here from the tags CSV, seed 101 fewer
    early episodes) together; docs/how-to/unit-loops.md, "Both together"."""
    _, _, runs, _ = line
    today = {101: 0.70, 102: 0.43}  # detected after the onset on main (b58dc32)
    for seed in SEEDS:
        after = runs[("stiction", seed)].detected.to_numpy()[ONSET:] == 1
        days = after.size * line7.PERIOD_S / 86400
        assert after.mean() >= today[seed], (seed, after.mean())
        assert _episodes(after).size <= 3 * days, (seed, _episodes(after).size, after.mean())


def test_pieces_and_one_pass_agree_with_the_alarm_hold_and_spread(line):
    _, unit, _, _ = line
    f = line7.simulate(1.5, 103, "stiction", onset_days=0.5)
    one = unit.reset().evaluate(f).to_frame()
    unit.reset()
    parts = []
    for a in range(0, len(f), 977):
        state = json.loads(json.dumps(unit.to_state()))  # the live loop's restart
        parts.append(unit.load_state(state).evaluate(f.iloc[a : a + 977]))
    pd.testing.assert_frame_equal(one, concat(parts).to_frame())


def test_delays_in_seconds_mean_the_same_time_at_any_rate():
    ev = {"on_delay": 30, "off_delay": 30, "on_delay_s": 45.0, "off_delay_s": 240.0}
    assert [resolved_evaluation(ev, p)["on_delay"] for p in ("1s", "15s", "1min")] == [45, 3, 1]
    assert [resolved_evaluation(ev, p)["off_delay"] for p in ("1s", "15s", "1min")] == [240, 16, 4]
    assert resolved_evaluation({**ev, "on_delay_s": 0.0}, "1s")["on_delay"] == 30


def test_a_deadband_keeps_a_hovering_residual_one_alarm():
    rng = np.random.default_rng(3)
    r = 1.0 + 0.03 * rng.standard_normal((400, 1))  # hovering at its threshold 1
    lo, hi = np.array([-1.0]), np.array([1.0])
    plain = Deadband(0.0, 1).transform(r, lo, hi)[:, 0]
    band = Deadband(0.1, 1).transform(r, lo, hi)[:, 0]
    assert _episodes(plain == 1).size > 50 and _episodes(band == 1).size <= 2
    d = Deadband(0.1, 1)
    pieces = np.r_[d.transform(r[:133], lo, hi)[:, 0], d.transform(r[133:], lo, hi)[:, 0]]
    assert np.array_equal(pieces, band)


def test_running_spread_and_episode_hold_carry_their_state():
    rng = np.random.default_rng(4)
    x = rng.standard_normal((300, 2))
    x[50:60, 1] = np.nan
    one = RunningSpread(40, 2).transform(x)
    s = RunningSpread(40, 2)
    assert np.allclose(np.r_[s.transform(x[:101]), s.transform(x[101:])], one, equal_nan=True)
    # one sample at a time (the live loop's fast path) gives the rolling medians' answer,
    # through the first quarter-window (unknown) and a gap longer than the window's
    x[120:170, 0] = np.nan
    one = RunningSpread(40, 2).transform(x)
    s = RunningSpread(40, 2)
    rows = np.vstack([s.transform(x[i : i + 1]) for i in range(len(x))])
    assert np.allclose(rows, one, equal_nan=True) and np.isnan(rows[:9]).all()
    assert np.isnan(one[50:60, 1]).all() and abs(np.nanmean(one[200:, 0]) - 1.0) < 0.3
    share, act = rng.random((300, 3)), rng.random(300) > 0.3
    h = EpisodeHold(3)
    whole = EpisodeHold(3).transform(share, act)
    assert np.allclose(np.r_[h.transform(share[:77], act[:77]), h.transform(share[77:], act[77:])],
                       whole, equal_nan=True)  # fmt: skip


def test_a_spread_alarm_is_released_on_its_long_window():
    """A spread test on stays on while its long window's spread is above its release; it
    drops where that spread falls back (or where it was never on); pieces agree."""
    s = np.zeros((12, 3))
    s[1, 1] = s[1, 2] = 1.0  # both spread columns on at row 1, then off (their short MAD)
    s[8, 0] = 1.0  # a level test, not held
    s[5, 2] = np.nan  # unknown: stays unknown, the hold goes on
    long = np.full((12, 2), 5.0)
    long[9:, 0] = 1.0  # column 1's long spread back under its release from row 9
    h = ReleaseHold(10, np.array([1, 2]), np.array([2.0, 2.0]))
    out = h.transform(s.copy(), long)
    assert out[1:9, 1].tolist() == [1.0] * 8 and (out[9:, 1] == 0).all()
    assert (out[[1, 2, 3, 4, 6, 7, 8, 9, 10, 11], 2] == 1).all() and np.isnan(out[5, 2])
    assert out[0].tolist() == [0.0, 0.0, 0.0] and out[9, 0] == 0
    h = ReleaseHold(10, np.array([1, 2]), np.array([2.0, 2.0]))
    parts = [h.transform(s[a : a + 4].copy(), long[a : a + 4]) for a in range(0, 12, 4)]
    assert np.array_equal(np.vstack(parts), out, equal_nan=True)
    # never on: never held, however wide the long window
    assert (ReleaseHold(10, np.array([1]), np.array([2.0])).transform(np.zeros((5, 3)),
            np.full((5, 1), 9.0)) == 0).all()  # fmt: skip


def test_a_loops_own_test_raises_its_spread_release_and_the_combined_test_is_released():
    """One of the loop's own tests on where the loop's long spread is above its release
    raises the spread test's hold (the spread column held, the test's own symptom as it
    was); where the long spread is under it, or within a settle's bound, it does not; the
    combined test, once on, stays on while a loop's long spread is above its release; a
    state saved before either starts them from rest."""
    s = np.zeros((12, 3))
    s[2, 0] = -1.0  # the loop's level test on (column 0), the spread test (column 2) off
    long = np.full((12, 1), 5.0)
    long[8:, 0] = 1.0  # back under the release from row 8
    h = ReleaseHold(10, np.array([2]), np.array([2.0]), [np.array([0])])
    out = h.transform(s.copy(), long)
    assert out[2:8, 2].tolist() == [1.0] * 6 and (out[8:, 2] == 0).all() and out[:2, 2].sum() == 0
    assert out[:, 0].tolist() == s[:, 0].tolist()  # its own symptom not held
    parts = ReleaseHold(10, np.array([2]), np.array([2.0]), [np.array([0])])
    got = np.vstack([parts.transform(s[a : a + 5].copy(), long[a : a + 5]) for a in (0, 5, 10)])
    assert np.array_equal(got, out)
    # the long spread under the release where the level test is on: not raised
    low = np.where(np.arange(12)[:, None] < 3, 1.0, 5.0)
    h = ReleaseHold(10, np.array([2]), np.array([2.0]), [np.array([0])])
    assert (h.transform(s.copy(), low)[:, 2] == 0).all()
    # within a settle's bound after it opens: not raised
    opens = np.zeros((12, 1), np.int64)
    opens[1, 0] = 4
    h = ReleaseHold(10, np.array([2]), np.array([2.0]), [np.array([0])])
    assert (h.transform(s.copy(), long, opens)[:, 2] == 0).all()
    # a test not of the loop (column 1) raises nothing
    s1 = np.zeros((12, 3))
    s1[2, 1] = 1.0
    h = ReleaseHold(10, np.array([2]), np.array([2.0]), [np.array([0])])
    assert (h.transform(s1, long)[:, 2] == 0).all()
    # the combined test: on at rows 1-2, held to row 7
    t2 = np.zeros(12)
    t2[1:3] = 1.0
    h = ReleaseHold(10, np.array([2]), np.array([2.0]), [np.array([0])])
    assert h.combined(t2, long).tolist() == [0.0] + [1.0] * 7 + [0.0] * 4
    state = json.loads(json.dumps(h.to_state()))
    state.pop("t2")  # saved before it
    h.load_state(state)
    assert not h.t2_held.any() and h.held.tolist() == [False]


def test_a_pinned_valve_neither_raises_nor_keeps_its_loops_release():
    """A loop's valve pinned at an edge (within ``PINNED`` of its span from the same edge
    on this sample and the one before) makes the loop's long spread unknown until a
    release window after it last sat there: a hold raised before drops, the loop's own
    tests raise none, the combined test is not held; a valve that reaches the edge and
    moves on is not pinned; pieces and a state through JSON give the one pass."""
    n, w = 40, 10
    raw = np.random.default_rng(3).normal(0.0, 5.0, (n, 1))  # a wide loop error
    act = np.full((n, 1), 50.0)
    act[10:15] = 100.0  # at the edge from row 10, pinned on rows 11-14
    act[30] = 0.0  # at the other edge once, moving on: never pinned
    s = np.zeros((n, 3))
    s[5, 2] = 1.0  # the spread test on at row 5, then off
    t2_in = np.zeros(n)
    t2_in[5] = 1.0  # the combined test on at row 5
    s[16, 0] = s[27, 0] = -1.0  # the loop's level test on at rows 16 and 27

    def run(parts):
        h = ReleaseHold(w, np.array([2]), np.array([0.3]), [np.array([0])], [("V", 0.0, 100.0)])
        out, longs, t2 = [], [], []
        for a, b in parts:
            if a:  # a restart between pieces: the state through JSON
                st = json.loads(json.dumps(h.to_state()))
                h = ReleaseHold(w, np.array([2]), np.array([0.3]), [np.array([0])],
                                [("V", 0.0, 100.0)])  # fmt: skip
                h.load_state(st)
            long = h.long_spread(raw[a:b], act[a:b])
            longs.append(long)
            out.append(h.transform(s[a:b].copy(), long))
            t2.append(h.combined(t2_in[a:b], long))
        return np.vstack(out), np.vstack(longs), np.concatenate(t2)

    out, long, t2 = run([(0, n)])
    assert np.isnan(long[11:24, 0]).all() and np.isfinite(long[[9, 10, 24, 30, 31], 0]).all()
    assert (long[5:11] > 0.3).all() and (long[24:] > 0.3).all()  # wide where known
    assert out[5:11, 2].tolist() == [1.0] * 6 and (out[11:27, 2] == 0).all()  # dropped at 11
    assert out[27:, 2].tolist() == [1.0] * (n - 27)  # raised by the level test once known
    assert t2[5:11].tolist() == [1.0] * 6 and (t2[11:] == 0).all()
    for parts in ([(0, 7), (7, 13), (13, n)], [(0, 12), (12, 25), (25, n)]):
        got = run(parts)
        assert all(
            np.array_equal(a, b, equal_nan=True) for a, b in zip(got, (out, long, t2), strict=True)
        )
    # a unit without its valve's span (None): nothing pinned, the release as before
    h = ReleaseHold(w, np.array([2]), np.array([0.3]), [np.array([0])], [None])
    assert np.isfinite(h.long_spread(raw, h.valve_readings(lambda t: act[:, 0], n))[4:]).all()


def test_the_loops_own_tests_keep_the_line_s_sticking_valve_one_alarm(line):
    """Seed 102's sticking valve: the valve's and the meter's tests and T² carry the alarm for
    hours before the short spread fires, while the loop error's long spread is already
    above its release; held from there, one standing alarm (4 episodes without: 1.81 h, 5.27
    h, 5.69 h, 6.04 h), and the detection after the onset up (78 % without)."""
    _, _, runs, _ = line
    after = runs[("stiction", 102)].detected.to_numpy()[ONSET:] == 1
    assert _episodes(after).size <= 2 and after.mean() > 0.9, (_episodes(after), after.mean())


def test_the_live_fast_path_carries_the_loops_release_across_a_restart(line):
    """The stacked path restarted from its saved state (JSON) mid-run through the sticking
    valve gives the statuses of one uninterrupted run; the combined test was held there
    (on where T² was under its limit) and the spread test raised by the loop's own tests."""
    from helpers import plant_statuses, same_status

    from diag_plugin.diagnose.plant import Plant

    _, unit, _, g = line
    rb = g[g.index("--rulebases") + 1]
    run = line7.simulate(0.35, 103, "stiction", onset_days=0.05)
    whole = plant_statuses(Plant.load([unit.file.path], rb), run)["line"]
    first = Plant.load([unit.file.path], rb)
    half = len(run) // 2
    a = plant_statuses(first, run.iloc[:half])["line"]
    state = json.loads(json.dumps(first.to_state()))
    b = plant_statuses(Plant.load([unit.file.path], rb).load_state(state), run.iloc[half:])
    for i, (p, q) in enumerate(zip(whole, a + b["line"], strict=True)):
        same_status(p, q, i)
    # the combined test on where T² is under its limit for longer than its off-delay holds
    high, off = unit.cmodel.high, unit.ev["off_delay"]
    under = [
        (m := re.search(r"combined test on \(T² ([-+.0-9e]+)\)", p.message)) is not None
        and float(m.group(1)) <= high
        for p in whole
    ]
    longest = max(len(r) for r in "".join("x" if u else " " for u in under).split() or [""])
    assert longest > 4 * off, (longest, off)


def test_the_line_writes_a_release_and_an_older_file_without_it_behaves_as_before(line, tmp_path):
    """``diag unit build`` writes the release window (the loop error's 34 independent samples)
    and the spread test's release (the build's largest long-window spread); a unit file
    without them (written before) loads without a release and alarms as before: one alarm a
    stick-slip cycle; with it, a fifth of the episodes or fewer."""
    _, unit, runs, _ = line
    assert unit.release_hold is not None
    assert 3600 < unit.ev["release_window_s"] < 4 * 3600
    spread = unit.file.test("FEED_FLOW_spread")
    assert spread.release is not None and 0 < spread.release < spread.high
    text = unit.file.path.read_text(encoding="utf-8")
    old = "\n".join(ln for ln in text.splitlines() if not ln.startswith("release_window_s"))
    old = re.sub(r", release = [-+.0-9e]+", "", old)
    assert "release" not in old
    for f in unit.file.path.parent.iterdir():
        if f.suffix == ".toml" and f != unit.file.path:
            shutil.copy(f, tmp_path / f.name)
    (tmp_path / unit.file.path.name).write_text(old, encoding="utf-8")
    before = Unit.load("line", tmp_path)
    assert before.release_hold is None
    after = before.reset().evaluate(line7.simulate(2.0, 101, "stiction")).detected.to_numpy()
    now = runs[("stiction", 101)].detected.to_numpy()
    held, loose = _episodes(now[ONSET:] == 1).size, _episodes(after[ONSET:] == 1).size
    # seed 101: 37 without the release, 3 with it before the loop-held flow's balance, 4 with
    # both (the xfail's <= 3 a day is the goal, not this test's)
    assert loose > 10 and held <= loose / 5, (loose, held)


def test_the_release_stands_clear_of_a_long_spread_that_hardly_moves(line):
    """The release is the build's largest long-window spread, and at least its median × 1.6
    (three of the window's 20 % standard errors): on the line's own window the largest
    (its loop error's long spread varies, 2.94 against a median of 1.75 at 15 s); on the
    same window with the loop's measurement replaced by its set-point and white noise (the
    long spread flatter: a level held at 1 s varies within a per cent or two) the floor,
    where the largest alone sat a hair above the median and a run at another operating point
    stayed above it for hours (the chemical plant at 1 s,
    docs/explanation/chemplant-benchmark.md "At 1 s")."""
    from diag_plugin.diagnose.unitloops import RunningSpread, spread_samples
    from diag_plugin.unitbuild.build import RELEASE_PRECISION, RELEASE_SE, release_thresholds

    _, unit, _, _ = line
    window_s = unit.ev["release_window_s"]
    frame = line7.simulate(TRAIN_DAYS, seed=1)
    floor = 1 + RELEASE_SE * RELEASE_PRECISION
    assert floor == pytest.approx(1.6)
    j = unit.tests.index("FEED_FLOW_spread")

    def long_spread(f):
        raw = unit.reset().raw_residuals(f).to_numpy(float)[:, [j]]
        unit.reset()
        return RunningSpread(spread_samples(window_s, unit.period), 1).transform(raw)[:, 0]

    got = release_thresholds(unit, frame, window_s)["FEED_FLOW_spread"]
    x = long_spread(frame)
    assert got == pytest.approx(np.nanmax(x), rel=1e-5) and np.nanmax(x) > floor * np.nanmedian(x)
    assert got == pytest.approx(unit.file.test("FEED_FLOW_spread").release, rel=1e-5)
    flat = frame.copy()
    noise = np.random.default_rng(5).normal(0.0, 0.05, len(flat))
    flat["FEED_FLOW"] = flat["FEED_TARGET"] + noise  # the loop's error: white noise alone
    y = long_spread(flat)
    # flat: the largest (1.52) under the floor (1.6 × the median 1.29), which binds
    assert np.nanmedian(y) < np.nanmax(y) < floor * np.nanmedian(y)
    got = release_thresholds(unit, flat, window_s)["FEED_FLOW_spread"]
    assert got == pytest.approx(floor * np.nanmedian(y), rel=1e-5)


def test_the_live_fast_path_releases_a_spread_alarm_as_the_replay_does(line):
    """The stacked path (one row a cycle) holds the sticking valve's spread alarm on the
    long window as the unit does: the same statuses through the onset and the hold."""
    from helpers import plant_statuses, same_status

    from diag_plugin.diagnose.plant import Plant

    _, unit, _, g = line
    rb = g[g.index("--rulebases") + 1]
    run = line7.simulate(0.35, 103, "stiction", onset_days=0.05)
    fast = Plant.load([unit.file.path], rb)
    slow = Plant(Plant.load([unit.file.path], rb).units, batched=False)
    assert fast.fast == ["line"] and slow.slow == ["line"]
    x, y = plant_statuses(fast, run)["line"], plant_statuses(slow, run)["line"]
    for i, (p, q) in enumerate(zip(x, y, strict=True)):
        same_status(p, q, i, exact=False)
    # the hold acted: the spread test on where its own short window was back under its high
    high = unit.file.test("FEED_FLOW_spread").high
    held = [k for k, p in enumerate(x) if p.status.name in ("OFF_SPEC", "FAILURE")
            and p.residuals["FEED_FLOW_spread"] < 0.9 * high]  # fmt: skip
    assert len(held) > 500, len(held)  # 1,075 of 1,344 alarm samples (2026-12-03)


# ---------------------------------------------------------------- declaring loops
def test_loop_specs_and_their_errors(tmp_path):
    assert parse_loop("FT1=FT1_TARGET:V1") == Loop("FT1", "FT1_TARGET", "V1")
    assert parse_loop("T 4 = T 4 goal") == Loop("T 4", "T 4 goal", None)
    for bad in ("FT1", "FT1=:V1", "=SP", "FT1=SP:", "A=A:B"):
        with pytest.raises(UserError, match="--loop"):
            parse_loop(bad)
    p = tmp_path / "tags.csv"
    p.write_text("name,unit,loop,role\nF,m3/h,a,pv\nS,m3/h,a,sp\nV,%,a,valve\n")
    with pytest.raises(UserError, match=r"tags.csv:4: role 'valve' of V"):
        loops_from_tags_csv(p)
    p.write_text("name,loop,role\nF,a,pv\nV,a,out\n")
    with pytest.raises(UserError, match=r"tags.csv:2: loop a has no sp tag"):
        loops_from_tags_csv(p)
    p.write_text("name,unit\nF,m3/h\n")
    assert loops_from_tags_csv(p) == []


def test_a_loop_tag_not_in_the_data_is_refused_with_its_file_and_line(tmp_path):
    """A tags CSV's loop naming a tag the data do not hold (a misspelt valve) names the file
    and the line, as its other errors do; ``--loop`` names the option. On main: `loop
    ColPress=1.5:CW_VLV_X: tag(s) CW_VLV_X not in the data`, no file, no line (the column
    acceptance pass, docs/explanation/acceptance-column.md)."""
    from diag_plugin.unitbuild.loops import checked_loops

    p = tmp_path / "tags.csv"
    p.write_text(
        "name,unit,loop,role,set_point\nP,bar,press,pv,1.5\nT,degC,,,\nCW_VLV_X,%,press,out,\n"
    )
    with pytest.raises(UserError, match=r"tags.csv:4: loop P=1.5:CW_VLV_X: tag\(s\) CW_VLV_X"):
        checked_loops(loops_from_tags_csv(p), ["P", "T", "CW_VLV"])
    with pytest.raises(UserError, match=r"--loop 'P=NO_SP:V': loop P=NO_SP:V: tag\(s\) NO_SP"):
        checked_loops([parse_loop("P=NO_SP:V")], ["P", "V"])
    assert checked_loops(loops_from_tags_csv(p), ["P", "CW_VLV_X"]) == [
        Loop("P", "1.5", "CW_VLV_X")
    ]


def test_a_decimal_comma_in_a_tags_csv_is_refused_at_its_line(tmp_path):
    """A set-point written with a decimal comma (``1,5``) splits the row into one cell more
    than the header: the error names the file and the line as the tags CSV's other errors
    do, and says what to write (was pandas' words: `cannot read the tags CSV: Error
    tokenizing data. C error: Expected 5 fields in line 3, saw 6`; the column pass)."""
    p = tmp_path / "tags.csv"
    p.write_text("name,unit,loop,role,set_point\nP,bar,press,pv,\nS,bar,press,sp,1,5\n")
    with pytest.raises(UserError, match=r"tags.csv:3: 6 cells where the header has 5 .*1\.5"):
        loops_from_tags_csv(p)


def test_a_loop_naming_an_unknown_tag_is_refused(line):
    *_, g = line
    rc, text = diag(g, "unit", "build", "x", "--from", "2026-03-02", "--to", "2026-03-03",
                    "--loop", "FEED_FLOW=NO_SUCH:VALVE_A")  # fmt: skip
    assert rc == 2 and "NO_SUCH not in the data" in text, text


def test_a_fresh_start_says_it_is_warming_up_not_what_is_wrong(line):
    """Started fresh, the built line is CHECK_FUNCTION while its tests wait for their lags'
    history (the outlet's 38-sample dead time) and the spread window — and says so, counting
    down, on the live loop's fast path as one by one; never an input blamed for it."""
    from diag_plugin.diagnose.plant import Plant

    _, unit, _, g = line
    rb = g[g.index("--rulebases") + 1]
    fast = Plant.load([unit.file.path], rb)
    slow = Plant(Plant.load([unit.file.path], rb).units, batched=False)
    assert fast.fast == ["line"] and slow.slow == ["line"]
    depth = int(unit.test_depth.max())
    assert depth >= 10  # the line's dead times: a warm-up worth saying
    rows = line7.simulate(0.3, 150).iloc[: depth + 5]
    left = []
    for k, (ts, row) in enumerate(rows.iterrows()):
        a, b = fast.cycle(ts, row.to_dict())[0], slow.cycle(ts, row.to_dict())[0]
        assert (a.status, a.message) == (b.status, b.message), k
        if k < depth:
            assert a.status.name == "CHECK_FUNCTION", k
            assert a.message.startswith("warming up, "), a.message
            assert "within what the unit learned" not in a.message, a.message
            left.append(float(a.message.split()[2]))
        else:
            assert "warming up" not in a.message, (k, a.message)
    assert left[0] == depth * line7.PERIOD_S and np.all(np.diff(left) <= 0), left


# ---------------------------------------------------------------- a loop's two fault modes


def test_a_loops_actuator_and_sensor_each_have_a_second_direction(line):
    """The valve: its level direction leaves its spread test out, its second direction is
    the spread test alone (sticking); the loop's sensor: its second direction is its own
    with the loop test at zero (compensated by its loop). A deviation exactly along either
    is explained in full by that tag (share 1, named first); with one mixed direction the
    valve's level or the compensated sensor explained part of it only."""
    _, unit, _, _ = line
    cm = unit.cmodel
    tests = unit.tests
    valve, meter = cm.tags.index("VALVE_A"), cm.tags.index("FEED_FLOW")
    spread, loop = tests.index("FEED_FLOW_spread"), tests.index("FEED_FLOW")
    assert cm.xi[spread, valve] == 0.0 and cm.process[spread, valve] > 0.0
    assert np.count_nonzero(cm.process[:, valve]) == 1
    assert cm.xi[loop, meter] != 0.0 and cm.process[loop, meter] == 0.0
    others = np.arange(len(tests)) != loop
    np.testing.assert_array_equal(cm.process[others, meter], cm.xi[others, meter])
    for k, direction in ((valve, cm.xi[:, valve]), (valve, cm.process[:, valve]),
                         (meter, cm.process[:, meter])):  # fmt: skip
        share = cm.shares_of(3.0 * direction[None, :])[0]
        assert share[k] == pytest.approx(1.0, abs=1e-9), (cm.tags[k], share[k])
        assert share[k] >= np.nanmax(share) - 1e-9


def test_a_declared_loops_set_point_that_never_moved_is_still_its_loops_test(tmp_path):
    """A set-point tag constant over the window (a window between two of the operators'
    moves): the declared loop is still built on it, and the build says so. On main the
    loop was dropped without a word and the flow was modelled from the other tags."""
    from diag_plugin.unitbuild.build import build_unit

    run = line7.simulate(0.5, seed=3)
    sp = run["FEED_TARGET"].to_numpy()
    moves = np.flatnonzero(np.diff(sp) != 0) + 1
    window = run.iloc[: moves[0]]  # the set-point held over the whole window
    assert window["FEED_TARGET"].nunique() == 1 and len(window) >= 400
    res = build_unit("held", window, folder=tmp_path, period="15s", far=0.01, workers=1,
                     loops=[Loop("FEED_FLOW", "FEED_TARGET", "VALVE_A")])  # fmt: skip
    tests = {t.test: t for t in res.tests}
    pv = tests["FEED_FLOW"]
    assert pv.method == "track" and pv.tracks == "FEED_TARGET" and pv.declared
    assert pv.actuator == "VALVE_A" and "FEED_FLOW_spread" in tests
    assert any("FEED_TARGET did not move over the window" in n for n in res.notes)
    # the operators' next set-points, never seen in the window: the loop's test follows them
    unit = Unit.load("held", tmp_path)
    d = unit.evaluate(run)
    settled = np.ones(len(run), bool)
    for m in moves:
        settled[m : m + 40] = False  # 10 min for the loop to reach the new set-point
    after = np.arange(len(run)) >= moves[0]
    assert (d.symptoms["FEED_FLOW"].fillna(0).to_numpy()[after & settled] == 0).all()


def test_accept_reports_a_spread_tests_one_threshold_as_the_file_holds_it(tmp_path, capsys):
    """A loop's spread test has a high threshold only. ``diag unit accept`` reports each
    test's thresholds as the unit file then holds them: the spread test's low is null (JSON)
    and it is printed as ``high …``. On main the JSON gave it the learning's symmetric low
    (-25.637 for a file with none) and the text printed ``+nan … +26.102 → -25.637 …``."""
    from diag_plugin.cli import main
    from diag_plugin.diagnose.unitfile import UnitFile

    g = ["--db", f"sqlite:///{tmp_path / 'h.db'}", "--rulebases", str(tmp_path / "rb")]
    run = line7.simulate(1.0, seed=5)
    line7.tags_csv().to_csv(tmp_path / "tags.csv", index=False)
    import_csv(g, run, tmp_path / "line.csv", tags=tmp_path / "tags.csv")
    mid = run.index[len(run) // 2]
    rc, text = diag(g, "unit", "build", "half", "--from", fmt(run.index[0]), "--to", fmt(mid),
                    "--loops-from", str(tmp_path / "tags.csv"), "--far", "0.05")  # fmt: skip
    assert rc == 0, text
    end = fmt(run.index[-1] + pd.Timedelta("15s"))
    assert main([*g, "unit", "accept", "half", "--from", fmt(mid), "--to", end, "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    spread = res["thresholds"]["FEED_FLOW_spread"]
    assert spread["low"] is None and spread["high"] > 0, spread
    held = {
        t.name: (t.low, t.high) for t in UnitFile.load(tmp_path / "rb" / "half.unit.toml").tests
    }
    for name, lim in res["thresholds"].items():
        assert (lim["low"], lim["high"]) == held[name], (name, lim, held[name])
    assert main([*g, "unit", "rollback", "half"]) == 0
    capsys.readouterr()
    assert main([*g, "unit", "accept", "half", "--from", fmt(mid), "--to", end]) == 0
    out = capsys.readouterr().out
    assert "nan" not in out and re.search(r"FEED_FLOW_spread: .* thresholds high \+", out), out


# ---------------------------------------------------------------- a compensated sensor bias


def test_a_compensated_meter_bias_is_named_on_the_meter_not_on_its_valve(line):
    """A bias of the loop's meter, compensated: the valve moves and the tests beyond it (the
    outlet flow, modelled from the set-point) move the way the same bias moves them; the
    valve moved three times as far as its model's gain on the set-point says. The meter
    explains it in full and is named first; on its one compensated direction the valve's
    own axis (the valve, the supply pressure its model reads) explained more, 0.95 against
    0.88 (with the gain measured over less than a set, 2.18 %/(m³/h) where the valve's
    characteristic gives 5.1, :func:`~diag_plugin.learn.thresholds.gain_step`). A move of
    the valve alone (a biased valve, a supply pressure change), or tests beyond it moved the
    other way, stays with the valve: ranked first, though the meter's compensated direction,
    the valve's move per unit of bias nearly four times the outlet's, explains most of it.
    And the credit is a test of fit: the same two moves with the level's test moved too (a
    deviation the bias does not explain: more than a fault-free sample leaves), or with a
    test unknown (the tests that would contradict the bias not there), are not credited."""
    cm, tests, valve, meter = _meter_and_valve(line)
    va, lv = tests.index("VALVE_A"), tests.index("TANK_LEVEL")
    comp = cm.process[:, meter].copy()
    assert comp[va] != 0.0 and np.count_nonzero(np.delete(comp, va)) >= 1
    bias = comp.copy()
    bias[va] *= 3.0
    share = cm.shares_of(bias[None, :])[0]
    assert share[meter] == pytest.approx(1.0, abs=1e-9), dict(zip(cm.tags, share, strict=True))
    assert rank(share[None, :])[0, 0] == meter
    alone = np.zeros(len(tests))
    alone[va] = bias[va]
    share = cm.shares_of(alone[None, :])[0]
    assert share[meter] < share[valve], dict(zip(cm.tags, share, strict=True))
    assert rank(share[None, :])[0, 0] == valve
    other_way = -bias
    other_way[va] = bias[va]
    share = cm.shares_of(other_way[None, :])[0]
    assert share[meter] < share[valve], dict(zip(cm.tags, share, strict=True))
    # the level's test 6 standard deviations off as well, or unknown: the meter's own
    # (one-dimensional) contributions, as without the credit
    plain = replace(cm, compensated=None)
    for z in (
        bias + 6.0 * np.eye(len(tests))[lv],
        np.where(np.arange(len(tests)) == lv, np.nan, bias),
    ):
        share = cm.shares_of(z[None, :])[0]
        assert share[meter] == pytest.approx(plain.shares_of(z[None, :])[0][meter], abs=1e-12)
        assert share[meter] < 1.0 - 1e-6, dict(zip(cm.tags, share, strict=True))


def _meter_and_valve(line):
    """The line's combined model, its tests, and the columns of its hand valve and meter."""
    unit = line[1]
    cm = unit.cmodel
    return cm, unit.tests, cm.tags.index("VALVE_A"), cm.tags.index("FEED_FLOW")


def test_a_meter_bias_its_loop_cannot_take_is_named_on_the_meter(line):
    """A bias of the loop's meter that the loop takes only in part (its valve at a limit):
    the tests beyond the valve move the way the bias moves them, the rest of the bias is
    the loop's error (the reading above its set-point, as the bias says), and the valve's
    test moves by what the limit left. The meter explains it in full and is named first
    (without the credit 0.96 of ``T²``, 0.92 with the valve's gain measured over less than
    a set: its one-dimensional directions leave the loop's error and the valve's stop
    out). A loop error of the other sign (the true flow above its set-point, the tests
    beyond saying it is below) is not a bias: the meter keeps its one-dimensional
    contributions there, as with the credit off. Found on the chemical plant's
    cooler-outlet drift (tuning seed 103: its valve reached 100 %)."""
    cm, tests, valve, meter = _meter_and_valve(line)
    va, lp = tests.index("VALVE_A"), tests.index("FEED_FLOW")
    comp = cm.process[:, meter].copy()
    assert comp[lp] == 0.0 and comp[va] != 0.0  # compensated: its loop test held at zero
    beyond = comp.copy()
    beyond[va] = 0.0
    z = 8.0 * beyond
    z[lp] = 6.0  # the part of the bias the loop could not take: the reading above its SP
    z[va] = 0.5 * 8.0 * comp[va]  # the valve stopped at a limit, half way
    share = cm.shares_of(z[None, :])[0]
    assert share[meter] == pytest.approx(1.0, abs=1e-9), dict(zip(cm.tags, share, strict=True))
    assert rank(share[None, :])[0, 0] == meter
    assert share[valve] < share[meter]
    plain = replace(cm, compensated=None)
    assert plain.shares_of(z[None, :])[0][meter] < 0.98  # its one-dimensional directions
    other_way = z.copy()
    other_way[lp] = -6.0
    share = cm.shares_of(other_way[None, :])[0]
    assert share[meter] == pytest.approx(plain.shares_of(other_way[None, :])[0][meter], abs=1e-12)


#: a flow-meter bias seed the credit's test of fit was not chosen on (chosen on 101–104)
HELD_OUT = 113


def test_a_flow_meter_bias_is_named_first_more_often_once_compensated(line):
    """The 7-tag line's flow-meter bias (the loop compensates it, the tank drains less) on a
    seed the rule was not chosen on: the meter held first on more than a third of its alarm
    samples and on at least one alarm episode (main: 17.5 %, the valve the rest, and none
    of its 7 episodes), in the top three on the fixture's seeds as before."""
    _, unit, runs, _ = line
    d = unit.reset().evaluate(line7.simulate(2.0, HELD_OUT, "flow_bias"))
    alarm = (d.detected.to_numpy() == 1)[ONSET:]
    top1 = d.top_tags["top1"].to_numpy()[ONSET:]
    first = top1[alarm & (top1 != "")]
    assert (first == "FEED_FLOW").mean() > 1 / 3, pd.Series(first).value_counts(normalize=True)
    ends = len(alarm) - 1 - _episodes(alarm[::-1])[::-1]
    held = []  # each episode's name: the tag held first on most of its samples
    for a, b in zip(_episodes(alarm), ends, strict=True):
        names = pd.Series(top1[a : b + 1])
        held.append(names[names != ""].value_counts().index[0])
    assert "FEED_FLOW" in held, held
    for seed in SEEDS:
        assert "FEED_FLOW" in _named(runs[("flow_bias", seed)])


def test_the_meters_credit_changes_nothing_on_the_fault_free_runs(line):
    """The credit fires only where the data say the meter moved: on the fault-free runs
    (seeds 101, 102: a few alarms each, the level's test unknown over seed 102's) every
    contribution and every held name is what the ranking gives without it. Before the test
    of fit it took one of seed 102's two alarm episodes (``OUT_FLOW``) for the meter."""
    _, unit, runs, _ = line
    cm = unit.cmodel
    assert cm.compensated is not None  # the meter and its valve's test: a pair
    saved = cm.compensated
    for seed in SEEDS:
        d = runs[(None, seed)]
        cm.compensated = None
        try:
            without = unit.reset().evaluate(line7.simulate(2.0, seed))
        finally:
            cm.compensated = saved
        assert (d.detected.to_numpy() == 1).any()
        pd.testing.assert_frame_equal(d.top_tags, without.top_tags)
        pd.testing.assert_frame_equal(d.contributions, without.contributions)


# ---------------------------------------------------------------- named first (the how-to's table)

#: the seed of the how-to's table (``python -m tests.line7``)
TABLE_SEED = 101


def _held_first(d) -> pd.Series:
    """The share of the alarm samples after the onset on which each tag is held first."""
    alarm = (d.detected.to_numpy() == 1)[ONSET:]
    top1 = d.top_tags["top1"].to_numpy()[ONSET:]
    return pd.Series(top1[alarm & (top1 != "")]).value_counts(normalize=True)


def test_a_flow_meter_bias_is_named_first_on_the_meter(line):
    """The flow-meter bias is held first on the meter on most of its alarm samples, not on
    the valve its loop moves (seed 101: the meter 88 %, the valve 7 %). With the valve's gain
    on the set-point measured over less than one of its model's sets (2.18 %/(m³/h) where
    the data's slope is 5.1) the meter's compensated direction said the valve moves half as
    far as it does, and the valve's own axis took the deviation: 25 %, the valve 74 % (the
    audit of issue 34; :func:`~diag_plugin.learn.thresholds.gain_step`,
    :func:`~diag_plugin.learn.thresholds.judged_weight`)."""
    _, _, runs, _ = line
    first = _held_first(runs[("flow_bias", TABLE_SEED)])
    assert first.get("FEED_FLOW", 0.0) > 0.5, first
    assert first.index[0] == "FEED_FLOW", first


def test_a_loop_held_flow_gets_the_tanks_balance_as_a_second_test(line):
    """The line's tags CSV says ``FEED_FLOW`` is a flow (``m3/h``, "feed flow meter") and
    ``TANK_LEVEL`` a level; its loop holds the flow, so its loop test never sees a bias of the
    meter. The build gives it the tank's balance (:mod:`~diag_plugin.unitbuild.balance`):
    the out-flow and the level's rate over several samples (one 15 s sample's change is the
    level's noise), none of the loop's set-point, valve or the valve's supply pressure.
    Main (no balance for a loop-held flow): no such test."""
    res, unit, _, _ = line
    tests = {t["test"]: t for t in res["tests"]}
    assert "FEED_FLOW_balance" in tests, sorted(tests)
    bal = tests["FEED_FLOW_balance"]
    assert bal["tag"] == "FEED_FLOW" and bal["balance"], bal
    reads = {t for i in bal["inputs"] for t in InputSpec.parse(i).tags}
    assert "OUT_FLOW" in reads and not reads & {"FEED_TARGET", "VALVE_A", "SUPPLY_P"}, bal
    rates = [InputSpec.parse(i) for i in bal["inputs"] if i.startswith("rate(TANK_LEVEL")]
    assert rates and rates[0].param is not None and rates[0].param > 1, bal
    # the integral form (branch i34-balance2): the out-flow over the rate's own window, and
    # the rate's coefficient corrected for the level's noise (least squares shrink it ~11 %)
    assert f"mean(OUT_FLOW,{rates[0].param:g})[k]" in bal["inputs"], bal
    noise = unit.models["FEED_FLOW_balance"].model.input_noise
    assert noise is not None and noise[bal["inputs"].index(str(rates[0]))] > 0, noise


def test_the_balance_holds_through_a_hand_valve_step_it_never_saw(line):
    """The hand valve moved 44 → 78 % (never seen): the tank drains along its time constant
    (over an hour), its level's rate 4 × any the build saw. The balance sees the out-flow
    and the level's rate over one window and the rate's coefficient unshrunk, so it raises
    no symptom in the two hours after the step. With the out-flow's current value against
    a trailing rate (feff548) the rate lags the out-flow by half its window and the
    shrunk coefficient leaves 11 % of the drain unexplained: seed 101's balance raised 54
    samples of symptom from 1.5 min after the step on (docs/how-to/unit-loops.md, branch
    i34-balance2)."""
    _, _, runs, _ = line
    for seed in SEEDS:
        s = runs[("manual_moved", seed)].symptoms["FEED_FLOW_balance"].iloc[ONSET : ONSET + 480]
        assert (s.fillna(0) != 0).sum() == 0, (seed, s[s.fillna(0) != 0])


def test_a_flow_meter_bias_is_named_on_the_meter_on_both_seeds(line):
    """With the tank's balance the meter's bias is held first on the meter on both fixture
    seeds (measured 94 % and 95 %; main: seed 102's bias held first on the valve, 84 %, the
    meter 0 %, docs/how-to/unit-loops.md "The 7-tag line")."""
    _, _, runs, _ = line
    for seed in SEEDS:
        first = _held_first(runs[("flow_bias", seed)])
        assert first.get("FEED_FLOW", 0.0) > 0.8, (seed, first)


def test_the_isolated_faults_hold_the_meter_whose_bias_its_loop_compensated(line):
    """The isolated faults (``faults``: the alarm event, the HMI's fault tag) name the meter
    where its loop took its bias, not the supply pressure alone. The compensated bias fires
    the valve's test (``VALVE_A = f(FEED_TARGET, SUPPLY_P)``) and, where it crosses, the
    out-flow's and the balance's; the valve's test alone is the supply pressure's exact
    column, and the meter's column held only its loop test (quiet once compensated) and the
    balance, so the ranking's first tag was not added: ``SUPPLY_P`` alone on 94 % of seed
    101's alarm samples, the meter on 6 %, where the ranking held the meter first on 99.6 %
    (:func:`~diag_plugin.diagnose.unittags.compensating_tests`). Both seeds: the meter in
    ``faults`` on most alarm samples (seed 101 99.6 %, 102 84 %) and the pressure alone on
    next to none (0 %, 0.2 %)."""
    _, unit, runs, _ = line
    col = unit.matrix.entries[:, unit.matrix.faults.index("FEED_FLOW")]
    reach = dict(zip(unit.matrix.tests, col.tolist(), strict=True))
    assert reach["VALVE_A"] == "1" and reach["OUT_FLOW"] == "1", reach
    for seed in SEEDS:
        d = runs[("flow_bias", seed)]
        alarm = (d.detected.to_numpy() == 1)[ONSET:]
        faults = d.faults.to_numpy()[ONSET:][alarm]
        first = d.top_tags["top1"].to_numpy()[ONSET:][alarm]
        has = np.array(["FEED_FLOW" in str(f).split("|") for f in faults])
        assert has.mean() > 0.8, (seed, pd.Series(faults).value_counts().head())
        alone = np.mean(faults == "SUPPLY_P")  # main: 94 % (seed 101), 73 % (102)
        assert alone < 0.01, (seed, pd.Series(faults).value_counts().head())
        assert has[first == "FEED_FLOW"].mean() > 0.8, (seed, pd.Series(faults).value_counts())


def test_the_valve_model_gain_on_its_set_point_is_the_valves_slope_as_judged(line):
    """The gain the directions are built from is the model's slope over its sets, not over a
    set's flat core, in the terms of the residual the unit judges. Two claims:

    * over one set spacing (:func:`~diag_plugin.learn.thresholds.gain_step`), each moved
      sample weighed alike, the valve's model's gain on the flow set-point is the data's
      slope within 20 % (least squares over the build window, 5.1 %/(m³/h); the valve's
      characteristic, ``100 / (cv √(p − 1))``, 4.4–6.1 over the window's pressures; the
      grid 4.94). Over 5 % of the input's sd, a set's flat core: 2.18.
    * the gain the unit file holds is that step's move of the valve test's residual *as
      the unit judges it*, per unit of set-point, in the window's typical divisor: each
      moved sample's change through :meth:`~diag_plugin.diagnose.unit.Unit.residual` (the
      sample put on the unmoved prediction, so its residual is the move alone, divided by
      the answering level's scale and the local spread), times the mean divisor over the
      window. It is not the raw slope by design (6.32 here against the grid's 4.94 and the
      data's 5.12): the valve's grid is steepest where its rules' spread is narrowest,
      which the unit divides by (:func:`~diag_plugin.learn.thresholds.judged_weight`)."""
    from diag_plugin.diagnose.residuals import supported
    from diag_plugin.learn.thresholds import gain_step, model_gains
    from diag_plugin.regressors import DesignBuilder, parse_specs

    _, unit, _, _ = line
    frame = line7.simulate(TRAIN_DAYS, seed=1)
    x = np.column_stack([frame["FEED_TARGET"], frame["SUPPLY_P"], np.ones(len(frame))])
    slope = np.linalg.lstsq(x, frame["VALVE_A"].to_numpy(), rcond=None)[0][0]
    grid = model_gains(unit, frame)["VALVE_A"]["FEED_TARGET"]
    assert abs(grid - slope) < 0.2 * slope, (grid, slope)

    test, m = unit.file.test("VALVE_A"), unit.models["VALVE_A"]
    d = DesignBuilder(m.inputs, m.output, period=m.period).transform(unit._model_frame(frame))
    cols = [i for i, sp in enumerate(parse_specs(m.inputs)) if sp.tags[0] == "FEED_TARGET"]
    step = gain_step(m.model, cols, float(np.nanstd(d.X[:, cols[0]])))
    moved_x = d.X.copy()
    moved_x[:, cols] += step
    at, moved = m.model.predict_detail(d.X), m.model.predict_detail(moved_x)
    y = supported(at, unit.ev["min_support"])  # each sample on its unmoved prediction
    scale = test.ymax if unit.ev["scale"] == "max" and test.ymax else m.span
    per_pct = scale / 100.0  # the residual's % of span back in the valve's units
    judged = -unit.residual(test, y, moved) * per_pct / step  # the move, divided as judged
    divisor = 1.0 / unit.residual(test, y + per_pct, at)  # 1 % of span, divided as judged
    typical = float(np.nanmean(divisor[np.isfinite(y)]))
    held = unit.file.combined.gains["VALVE_A"]["FEED_TARGET"]
    assert held == pytest.approx(float(np.nanmean(judged)) * typical, rel=0.01), (held, grid)


@pytest.mark.xfail(
    strict=True,
    reason="the supply-pressure drift is held first on VALVE_A on 93 % of its alarm samples "
    "(seed 101, 2026-12-02; SUPPLY_P 0 %, third of the top three): the drifting pressure "
    "moves only the valve's test, which the valve's level direction moves alone too (the "
    "two directions parallel), and the valve's plane with its loop test's axis and the "
    "ranking's ties go to the valve; docs/how-to/unit-loops.md, 'The 7-tag line'",
)
def test_a_pressure_drift_is_named_first_on_the_pressure_transmitter(line):
    """The supply-pressure transmitter's drift held first on ``SUPPLY_P`` on most of its
    alarm samples (the how-to's table, seed 101; 77 % before 34b2edd, whose valve direction
    mixed its level and its spread test)."""
    _, _, runs, _ = line
    first = _held_first(runs[("pressure_drift", TABLE_SEED)])
    assert first.get("SUPPLY_P", 0.0) > 0.5, first


def test_a_pressure_drift_is_isolated_as_the_transmitter_or_its_valve(line):
    """What the xfail above asks of the ranking the isolated faults give as the residuals
    allow: the drift moves the valve's test alone, whose exact column is the transmitter's,
    and the ranking's first tag (the valve) is added, ``SUPPLY_P|VALVE_A`` — the pair a
    DAMADICS-style matrix calls indistinguishable. Measured: ``SUPPLY_P`` in ``faults`` on
    95 % (seed 101) and 88 % (102) of the alarm samples after the onset, never the valve
    alone."""
    _, _, runs, _ = line
    for seed in SEEDS:
        d = runs[("pressure_drift", seed)]
        alarm = (d.detected.to_numpy() == 1)[ONSET:]
        faults = d.faults.to_numpy()[ONSET:][alarm]
        has = np.array(["SUPPLY_P" in str(f).split("|") for f in faults])
        assert has.mean() > 0.8, (seed, pd.Series(faults).value_counts().head())
        assert not (faults == "VALVE_A").any(), (seed, pd.Series(faults).value_counts().head())


def test_the_live_loop_carries_a_pinned_valve_across_a_restart(tmp_path):
    """The tank's inflow surge pins its level valve at 100 %: the live plant, restarted from
    its saved state (JSON) while the valve is pinned, gives the statuses of one uninterrupted
    run, the replay's too; the state it saved holds the pinned valve's window."""
    from helpers import plant_statuses, same_status

    from diag_plugin.diagnose.plant import Plant
    from diag_plugin.unitbuild.build import build_unit
    from tests.test_unit_build import _tank

    res = build_unit("tank", _tank(6, 1, [40.0, 45.0, 50.0, 55.0]), folder=tmp_path,
                     period="60s", far=0.01)  # fmt: skip
    unit = Unit.load(res.path, tmp_path)
    assert unit.release_hold is not None and unit.release_hold.valves[0] is not None
    run = _tank(1, 2, [62.0], surge=80.0)
    whole = plant_statuses(Plant({"tank": unit.reset()}), run)["tank"]
    d = unit.reset().evaluate(run)
    assert [p.faults for p in whole] == [d.at(i).faults for i in range(len(run))]
    cut = int(len(run) * 0.8)  # the valve at 100 % since the surge
    assert run["LIC101.OUT"].iloc[cut - 5 : cut].eq(100.0).all()
    first = Plant({"tank": unit.reset()})
    a = plant_statuses(first, run.iloc[:cut])["tank"]
    state = json.loads(json.dumps(first.to_state()))
    assert any(left > 0 for p in state["pinned"] for left in p["left"]), state["pinned"]
    b = plant_statuses(Plant({"tank": unit.reset()}).load_state(state), run.iloc[cut:])["tank"]
    for i, (p, q) in enumerate(zip(whole, a + b, strict=True)):
        same_status(p, q, i)
