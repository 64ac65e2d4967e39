"""A hand valve is the operator's choice, not a process variable (issue 34, item 5;
docs/how-to/unit-loops.md, "A hand valve").

The 7-tag line (:mod:`tests.line7`) built as a user would, its tags CSV giving ``HAND_VALVE``
the role ``manual``: the valve is never tested, stays an input, and its span is written in
the unit file. Moved to 78 % (learned 40–47 %) on seeds never used to build (101, 102), the
unit is CHECK_FUNCTION naming the valve, never a fault; the tests not reading it keep judging;
``diag unit accept`` of a day there widens the span and the unit answers; rollback restores
it. A second plant unlike the line (:mod:`tests.heater`: no loop, no tank, a steam valve set
by hand with a noisy position reading) shows the same.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pandas as pd
import pytest

from diag_plugin.diagnose.plant import Plant
from diag_plugin.diagnose.unit import Unit, concat
from diag_plugin.diagnose.unitfile import UnitError, UnitFile
from diag_plugin.status import NE107
from tests import heater, line7
from tests.test_any_plant_tour import diag, fmt, import_csv

ONSET = int(86400 / line7.PERIOD_S)  # the faults start after a day
SEEDS = (101, 102)
DAY = pd.Timedelta(days=1)
SAID = re.compile(
    r"^HAND_VALVE(\[k-\d+\])? = 78 outside what the unit learned \(40 … 47\) since 2026-03-0"
)


def _tags_csv(tmp, role: str = "manual", loop: str = ""):
    tc = line7.tags_csv()
    tc.loc[tc["name"] == "HAND_VALVE", ["loop", "role"]] = [loop, role]
    tc.to_csv(tmp / "tags.csv", index=False)
    return tmp / "tags.csv"


def _moved(seed: int, start_day: float) -> pd.DataFrame:
    """Two days of the line with the hand valve at 78 % throughout, from ``start_day`` days
    after the build window's start."""
    f = line7.simulate(2.0, seed, "manual_moved", onset_days=0.0)
    return f.set_axis(f.index + pd.Timedelta(days=start_day))


@pytest.fixture(scope="module")
def line(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("manual")
    g = ["--db", f"sqlite:///{tmp / 'h.db'}", "--rulebases", str(tmp / "rb")]
    frame = line7.simulate(6.0, seed=1)
    tags = _tags_csv(tmp)
    import_csv(g, frame, tmp / "line.csv", tags=tags)
    import_csv(g, _moved(201, 7.0), tmp / "moved.csv")  # 03-09 … 03-11: confirmed later
    t0, t1 = frame.index[0], frame.index[-1] + pd.Timedelta("15s")
    rc, text = diag(g, "unit", "build", "line", "--from", fmt(t0), "--to", fmt(t1),
                    "--loops-from", str(tags), "--far", "0.01")  # fmt: skip
    assert rc == 0, text
    unit = Unit.load("line", tmp / "rb")
    runs = {
        (fault, seed): unit.reset().evaluate(line7.simulate(2.0, seed, fault))
        for fault in ("manual_moved", "flow_bias")
        for seed in SEEDS
    }
    return text, unit, runs, g, tmp, frame


# ---------------------------------------------------------------- the build
def test_the_hand_valve_is_an_input_never_a_test_and_its_span_is_written(line):
    text, unit, _, _, _, frame = line
    assert "HAND_VALVE: manual (an operator's setting): an input, never tested; learned " in text
    assert "learned 40–47 % (no margin: it reads without noise)" in text, text
    tested = [unit.models[t].output for t in unit.tests]
    assert "HAND_VALVE[k]" not in tested and "HAND_VALVE" not in tested, tested
    assert not any(t.startswith("HAND_VALVE") for t in unit.tests)
    # still a candidate input: the tank level's test reads it
    assert any(i.startswith("HAND_VALVE") for t in unit.tests for i in unit.models[t].inputs)
    span = unit.file.manual["HAND_VALVE"]
    hv = frame["HAND_VALVE"]
    assert (span.min, span.max, span.margin) == (hv.min(), hv.max(), 0.0)
    assert "HAND_VALVE" not in unit.cmodel.tags  # never a tag at fault


# ---------------------------------------------------------------- the valve moved
@pytest.mark.parametrize("seed", SEEDS)
def test_the_valve_moved_is_check_function_naming_it_never_a_fault(line, seed):
    _, _, runs, *_ = line
    d = runs[("manual_moved", seed)]
    st = d.status.to_numpy()[ONSET:]
    assert (st == NE107.CHECK_FUNCTION).mean() > 0.9, pd.Series(st).value_counts()
    why = d.why.iloc[ONSET:][st == NE107.CHECK_FUNCTION]
    assert why.map(lambda s: bool(SAID.match(s))).mean() > 0.9, why.value_counts().head()
    named = {f for f in d.faults.iloc[ONSET:] if f}
    top = {t for c in ("top1", "top2", "top3") for t in d.top_tags[c].iloc[ONSET:] if t}
    assert "HAND_VALVE" not in named | top, (named, top)


def test_tests_not_reading_the_valve_keep_judging(line):
    """Seed 102's valve sits at 48–51 % on its second day, outside what the unit learned: the
    tests reading it are unknown, the loop's own tests still judge, and a flow-meter bias
    there is still found."""
    _, unit, runs, *_ = line
    d = runs[("flow_bias", 102)]
    f = line7.simulate(2.0, 102, "flow_bias")
    out = (f["HAND_VALVE"].rolling(10).min() > 47).to_numpy().copy()  # out for 10 samples
    out[:ONSET] = False
    assert out.sum() > 0.5 * ONSET
    s = d.symptoms.to_numpy()[out]
    reads = np.array(
        [any(i.startswith("HAND_VALVE") for i in unit.models[t].inputs) for t in unit.tests]
    )
    assert reads.any() and np.isnan(s[:, reads]).all()
    assert np.isfinite(s[:, unit.tests.index("FEED_FLOW")]).all()
    assert (d.detected.to_numpy()[out] == 1).mean() > 0.3


def _in_pieces_as_whole(unit: Unit, f: pd.DataFrame, k: int):
    """``f`` replayed whole, then in pieces of ``k`` samples each from the state saved (through
    JSON) after the one before: the same frames. Returns the whole replay."""
    whole = unit.reset().evaluate(f)
    unit.reset()
    parts = []
    for a in range(0, len(f), k):
        state = json.loads(json.dumps(unit.to_state()))
        parts.append(unit.load_state(state).evaluate(f.iloc[a : a + k]))
    pd.testing.assert_frame_equal(whole.to_frame(), concat(parts).to_frame())
    return whole


def test_pieces_the_plant_and_a_restart_say_the_same(line):
    """The replay in pieces, through a saved state, and the plant cycle by cycle (the live
    loop; its message is what the OPC UA server publishes) give the same status and why."""
    _, unit, *_ = line
    f = line7.simulate(1.2, 103, "manual_moved", onset_days=1.0).iloc[ONSET - 300 :]
    whole = _in_pieces_as_whole(unit, f, 611)
    assert whole.why.map(lambda s: bool(SAID.match(s))).sum() > 100
    plant = Plant({"line": unit.reset()}, {})
    got_status, got_msg = [], []
    for k, (ts, row) in enumerate(f.iterrows()):
        if k == 400:
            state = json.loads(json.dumps(plant.to_state()))
            plant = Plant({"line": Unit.load(unit.file.path, unit.file.path.parent)}, {})
            plant.load_state(state)
        s = plant.cycle(ts, row.to_dict())[0]
        got_status.append(int(s.status))
        got_msg.append(s.message)
    assert got_status == whole.status.astype(int).tolist()
    checking = whole.status.to_numpy() == NE107.CHECK_FUNCTION
    pairs = zip(np.array(got_msg, object)[checking], whole.why[checking], strict=True)
    assert all(m == w or m.startswith(w + "; ") for m, w in pairs)


# ---------------------------------------------------------------- accept, rollback
def test_accept_widens_the_span_the_unit_answers_there_and_rollback_restores_it(line):
    _, _, _, g, tmp, frame = line
    unit_file = tmp / "rb" / "line.unit.toml"
    before = unit_file.read_bytes()
    day8 = frame.index[0] + 8 * DAY  # the second day at 78 % (the first settles)
    rc, text = diag(g, "unit", "accept", "line", "--from", fmt(day8), "--to", fmt(day8 + DAY),
                    "--json")  # fmt: skip
    assert rc == 0, text
    res = json.loads(text)
    assert any(w.startswith("hand valve HAND_VALVE: span 40 … 47") for w in res["warnings"])
    span = UnitFile.load(unit_file).manual["HAND_VALVE"]
    assert (span.min, span.max) == (40.0, 78.0)
    unit = Unit.load(unit_file, tmp / "rb")
    # the move's settle kept, over the widened span
    was = re.search(rb"(?m)^manual_settle_max_s = (.*)$", before)
    assert unit.ev["manual_settle_max_s"] == float(was.group(1)) > 0
    assert [lp.span for lp in unit.settle.loops if lp.hand] == [(40.0, 78.0)]
    for seed in (202, 203):  # unseen days at 78 %
        d = unit.reset().evaluate(_moved(seed, 10.0).iloc[ONSET:])
        assert (d.detected == 1).mean() < 0.05, seed
        assert not d.why.str.contains("HAND_VALVE").any(), seed
    rc, text = diag(g, "unit", "rollback", "line")
    assert rc == 0, text
    assert unit_file.read_bytes() == before
    assert UnitFile.load(unit_file).manual["HAND_VALVE"].max == 47.0


# ---------------------------------------------------------------- declarations
def test_a_declaration_the_build_cannot_use_names_the_tag_and_where(line, tmp_path):
    _, _, _, g, tmp, frame = line
    t0, t1 = fmt(frame.index[0]), fmt(frame.index[0] + 2 * DAY)
    base = ["unit", "build", "x", "--from", t0, "--to", t1]
    rc, text = diag(g, *base, "--manual", "NOPE")
    assert rc == 2 and "--manual NOPE: hand valve NOPE (manual) is not in the data" in text
    rc, text = diag(g, *base, "--manual", "FEED_FLOW", "--loop", line7.LOOP)
    assert rc == 2 and "hand valve FEED_FLOW (manual) is a tag of loop FEED_FLOW=" in text
    bad = _tags_csv(tmp_path, loop="feed")
    rc, text = diag(g, *base, "--loops-from", str(bad))
    assert rc == 2 and f"{bad}:7: HAND_VALVE is a hand valve (role manual) and in loop feed" in text
    assert not (tmp / "rb" / "x.unit.toml").exists()


def test_a_bad_manual_row_is_a_file_line_problem(line, tmp_path):
    _, unit, *_ = line
    text = unit.file.path.read_text()
    text = text.replace("HAND_VALVE = {", "HAND_VALVE = {lo = 1, ", 1)
    with pytest.raises(UnitError) as exc:
        UnitFile(text, tmp_path / "line.unit.toml")
    lines = text.splitlines()
    at = lines.index("[manual]")
    line_no = next(k for k in range(at, len(lines)) if lines[k].startswith("HAND_VALVE")) + 1
    assert f"line.unit.toml:{line_no}: [manual] HAND_VALVE: must be" in str(exc.value)


def test_a_unit_file_without_the_declaration_reads_as_before(line, tmp_path):
    _, unit, *_ = line
    import tomlkit

    doc = tomlkit.parse(unit.file.path.read_text())
    del doc["manual"]
    text = tomlkit.dumps(doc)
    path = unit.file.path.parent / "old.unit.toml"
    path.write_text(text.replace('name = "line"', 'name = "old"'))
    old = Unit.load(path, path.parent)
    assert old.manual is None and old.file.manual == {}
    assert "HAND_VALVE" in old.cmodel.tags
    assert [r.lo for r in old.outside.ranges if r.tag == "HAND_VALVE"] != [40.0]


# ---------------------------------------------------------------- a second plant
@pytest.fixture(scope="module")
def steam(tmp_path_factory):
    from diag_plugin.unitbuild.build import build_unit

    folder = tmp_path_factory.mktemp("heater")
    res = build_unit("heater", heater.simulate(5.0, 1), folder=folder, period="20s",
                     far=0.01, manual=["STEAM_V"])  # fmt: skip
    return res, Unit.load(res.path, folder)


def test_a_steam_valve_set_by_hand_is_check_function_when_moved(steam):
    res, unit = steam
    assert "STEAM_V" not in [ch.tag for ch in res.tests]
    assert res.skipped["STEAM_V"].startswith("manual (an operator's setting)")
    span = unit.file.manual["STEAM_V"]
    assert 0.2 < span.margin < 0.6  # 3 × its transmitter's noise (0.1 %)
    on = int(86400 / heater.PERIOD_S)
    for seed in SEEDS:
        d = unit.reset().evaluate(heater.simulate(2.0, seed, "valve_moved"))
        st = d.status.to_numpy()[on:]
        assert (st == NE107.CHECK_FUNCTION).mean() > 0.9, seed
        assert (st == NE107.FAILURE).mean() < 0.05, seed
        why = d.why.iloc[on:][st == NE107.CHECK_FUNCTION]
        said = r"^STEAM_V(\[k-\d+\])? = (69|70)(\.\d+)? outside what the unit learned \(29"
        assert why.str.match(said).mean() > 0.9, why.value_counts().head()
        assert "STEAM_V" not in {f for f in d.faults if f}
        d = unit.reset().evaluate(heater.simulate(2.0, seed, "steam_bias"))
        alarm = d.detected.to_numpy()[on:] == 1
        assert alarm.mean() > 0.5, seed
        top = d.top_tags["top1"].iloc[on:][alarm]
        assert top.value_counts().index[0] == "F_STEAM", seed


def test_the_plant_cycle_by_cycle_agrees_where_a_grid_left_what_it_learned(steam):
    """The heater's valve moved: the tests reading it and, while it is outside, the grids whose
    inputs left their learned cells are unknown — the plant's fast path (the live loop) as the
    replay, through the move."""
    res, unit = steam
    on = int(86400 / heater.PERIOD_S)
    f = heater.simulate(1.2, 104, "valve_moved", onset_days=1.0).iloc[on - 200 : on + 1000]
    whole = unit.reset().evaluate(f)
    assert (whole.status.iloc[210:] == NE107.CHECK_FUNCTION).mean() > 0.9
    plant = Plant({"heater": Unit.load(res.path, res.path.parent)}, {})
    got = [plant.cycle(ts, row.to_dict())[0] for ts, row in f.iterrows()]
    assert [int(s.status) for s in got] == whole.status.astype(int).tolist()
    sym = np.array([[s.symptoms[t] for t in unit.tests] for s in got])
    np.testing.assert_array_equal(np.isnan(sym), whole.symptoms.isna().to_numpy())


# ---------------------------------------------------------------- a move's settle
MOVE = re.compile(r"^HAND_VALVE (\d+) → (\d+) at (\S+): settling after a hand valve's move")
#: seed 101's valve: 49 → 43 % (into the learned 40–47 %) at this row, 43 → 41 % later
MOVED_AT = 6005


def _raised(st: np.ndarray) -> np.ndarray:
    return (st != NE107.NORMAL) & (st != NE107.CHECK_FUNCTION)


def _without_move_settle(unit: Unit) -> Unit:
    """The same unit without the hand valve's settle (main: only set-point steps)."""
    from diag_plugin.diagnose.settle import settle_guard

    plain = Unit.load(unit.file.path, unit.file.path.parent)
    plain.ev["manual_settle_max_s"] = 0.0
    plain.settle = settle_guard(plain)
    return plain


def test_the_build_says_how_long_a_hand_valves_move_may_settle(line):
    text, unit, *_ = line
    max_s = unit.ev["manual_settle_max_s"]
    assert max_s > unit.ev["settle_max_s"] > 0
    said = unit.file.build["manual_settle"]
    assert said.startswith(f"manual_settle_max_s = {max_s:.0f} s: 2 × the median settling time")
    assert "hand valve move(s) in the window" in said and said in text
    hand = [lp for lp in unit.settle.loops if lp.hand]
    assert [(lp.sp, lp.span) for lp in hand] == [("HAND_VALVE", (40.0, 47.0))]


def test_a_hand_valves_move_is_check_function_not_an_alarm(line):
    """Seed 101 (never used to build), no fault: the outlet flow's transient after each move
    of the valve within its span was FAILURE on main; now CHECK_FUNCTION naming the move, and
    the unit's share of raised samples back below main's before the valve was declared (3.4 %).
    Without the move's settle the transients are raised (over 4 % of the samples before the
    loop-held flow's balance, 1.6 % with it, 2026-12-03): the settle raises fewer."""
    _, unit, *_ = line
    x = line7.simulate(2.0, 101)
    d = unit.reset().evaluate(x)
    main = _without_move_settle(unit).evaluate(x)
    st, st0 = d.status.to_numpy(), main.status.to_numpy()
    assert _raised(st0[ONSET:]).mean() > _raised(st[ONSET:]).mean()  # the moves' transients
    assert _raised(st[ONSET:]).mean() < 0.034
    why = d.why.to_numpy(dtype=object)
    moving = np.array([bool(MOVE.match(w)) for w in why])
    first = MOVE.match(why[np.argmax(moving)])
    assert first.group(1, 2) == ("49", "43"), why[np.argmax(moving)]
    at = pd.Timestamp(first.group(3).replace("Z", "+00:00"))
    assert at == x.index[MOVED_AT]
    # only alarms became CHECK_FUNCTION; elsewhere nothing changed
    changed = st != st0
    assert changed.any() and moving[changed].all() and (st[changed] == NE107.CHECK_FUNCTION).all()
    assert _raised(st0[moving]).any()


def test_a_fault_right_after_a_move_is_failure_after_manual_settle_max_s(line):
    """A flow-meter bias 2 min after the valve's move: CHECK_FUNCTION at most
    manual_settle_max_s, then FAILURE (main: FAILURE throughout)."""
    _, unit, *_ = line
    onset = MOVED_AT + 8
    x = line7.simulate(2.0, 101, "flow_bias", onset_days=onset * line7.PERIOD_S / 86400)
    x = x.iloc[: onset + 600]
    st = unit.reset().evaluate(x).status.to_numpy()
    st0 = _without_move_settle(unit).evaluate(x).status.to_numpy()
    late = MOVED_AT + int(np.ceil(unit.ev["manual_settle_max_s"] / line7.PERIOD_S))
    assert (st0[onset + 20 :] == NE107.FAILURE).mean() > 0.9
    assert (st[late:] == NE107.FAILURE).mean() > 0.9
    hidden = st[onset:late]
    assert (hidden != NE107.FAILURE).all() and (hidden == NE107.CHECK_FUNCTION).mean() > 0.9


def test_a_move_outside_the_span_opens_no_settle(line):
    """The valve to 78 % (outside what the unit learned): the manual guard's
    CHECK_FUNCTION naming it, no settle."""
    _, _, runs, *_ = line
    for seed in SEEDS:
        d = runs[("manual_moved", seed)]
        assert not d.why.str.contains("settling after a hand valve's move").any(), seed


def test_a_moves_settle_replay_pieces_restart_and_plant_agree(line):
    """Through the move of seed 101: one replay, pieces through saved states, and the live
    loop's stacked path restarted mid-settle give the same statuses and messages."""
    _, unit, *_ = line
    x = line7.simulate(2.0, 101).iloc[MOVED_AT - 200 : MOVED_AT + 400]
    one = _in_pieces_as_whole(unit, x, 97)
    assert one.why.map(lambda s: bool(MOVE.match(s))).sum() > 50
    plant = Plant({"line": Unit.load(unit.file.path, unit.file.path.parent)}, {})
    for k, (ts, row) in enumerate(x.iterrows()):
        if k == 300:  # inside the settle
            state = json.loads(json.dumps(plant.to_state()))
            assert state["settle"]["line"]["g"][0] == 1
            plant = Plant({"line": Unit.load(unit.file.path, unit.file.path.parent)}, {})
            plant.load_state(state)
        s, ref = plant.cycle(ts, row.to_dict())[0], one.at(k)
        assert (s.status, s.faults, s.message) == (ref.status, ref.faults, ref.message), k


def without_key(unit: Unit, key: str, name: str) -> Unit:
    """``unit``'s file less the ``[evaluation]`` ``key`` (a file written before it), saved
    beside it as unit ``name``, loaded."""
    path = unit.file.path.parent / f"{name}.unit.toml"
    text = re.sub(rf"(?m)^{key} = .*\n", "", unit.file.path.read_text())
    path.write_text(text.replace(f'name = "{unit.file.name}"', f'name = "{name}"'))
    return Unit.load(path, path.parent)


def test_a_unit_file_without_manual_settle_max_s_settles_no_move(line):
    _, unit, *_ = line
    old = without_key(unit, "manual_settle_max_s", "nomove")
    assert old.ev["manual_settle_max_s"] == 0
    assert not any(lp.hand for lp in old.settle.loops)


def test_a_noisy_valve_steps_only_within_its_span():
    """A hand valve read with noise (the heater's ±0.1 %): held within its margin, a move
    beyond its band within the learned span is a step; one out of it is not."""
    from diag_plugin.diagnose.settle import SettleGuard, SettleLoop

    rng = np.random.default_rng(0)
    valve = SettleLoop("V", "V", -1, 0.0, 0.0, 0.6, True, 0.3, (29.7, 49.0))
    g = SettleGuard([valve], 50, 5, 20.0, 2)
    x = np.r_[np.full(100, 35.0), np.full(100, 42.0), np.full(100, 70.0)]
    x = x + rng.normal(0, 0.1, x.size)
    assert [(j, round(a), round(b), r) for j, a, b, r in g.steps(x[:, None])] == [(0, 35, 42, 100)]
