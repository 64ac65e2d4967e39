"""A tested tag the window saw at few independent values: its own test unknown where the tag
leaves what the unit learned, the tag named (issue 34, items 3 and 5;
docs/how-to/unit-loops.md, "The line imported off the grid", the 5 min bullet).

The 7-tag line (:mod:`tests.line7`) exported as 5-min means, its hand valve not declared: the
window (6 days of seed 1) holds ``HAND_VALVE`` at 40–47 %, about 3 independent values of it;
seed 101's operator sets it to 49 %. The build tests it (``HAND_VALVE = f(OUT_FLOW,
TANK_LEVEL)``, a rule grid whose answers never leave 40–47) and now writes its span in
``[narrow]``; where it is outside, its own test is unknown, as the tests reading it are.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import tomlkit

from diag_plugin.diagnose.plant import Plant
from diag_plugin.diagnose.unit import Unit
from diag_plugin.status import NE107
from diag_plugin.unitbuild.build import build_unit, narrow_outputs
from diag_plugin.unitbuild.loops import parse_loop
from tests import line7


def _5min(frame: pd.DataFrame) -> pd.DataFrame:
    """The run as a plant's 5-min export: means stamped at the period's end."""
    return frame.resample("5min", label="right", closed="right").mean()


@pytest.fixture(scope="module")
def line5(tmp_path_factory):
    """The line's unit built on 5-min means (the loop declared, the hand valve not) and its
    fault-free seed 101 (2 days)."""
    folder = tmp_path_factory.mktemp("narrow5")
    res = build_unit("u", _5min(line7.simulate(6.0, 1)), folder=folder, period="300s",
                     loops=[parse_loop(line7.LOOP)], far=0.01, force=True)  # fmt: skip
    return Unit.load(res.path, folder), _5min(line7.simulate(2.0, 101))


def test_the_build_writes_the_hand_valve_s_span_as_narrow(line5):
    """``[narrow]`` holds the hand valve at the window's 40–47 %; the tags moving faster than
    the window (the flows, the level: 7.2 and more independent values) are not in it."""
    unit, _ = line5
    doc = tomlkit.parse(unit.file.path.read_text())
    narrow = dict(doc["narrow"])
    assert set(narrow) == {"HAND_VALVE"}
    assert (narrow["HAND_VALVE"]["min"], narrow["HAND_VALVE"]["max"]) == (40.0, 47.0)


def test_the_fault_free_run_is_not_raised_for_the_new_position(line5):
    """Seed 101 puts the valve at 49 %: main raised FAILURE on 63.95 % of the 5-min fault-free
    run (the valve's own test answering the position as a fault, ``HAND_VALVE`` held first on
    56 % of the alarms); with its test unknown there, 30.5 % (the out-flow's test, which reads
    no valve, raises the rest). 45 %: 14 points over the measured share, 19 under main's.
    Where the valve is outside, its own test is unknown and the unit names it."""
    unit, free = line5
    d = unit.reset().evaluate(free)
    assert (d.detected == 1).mean() < 0.45
    j = unit.tests.index("HAND_VALVE")
    out = (free["HAND_VALVE"] > 47.0).to_numpy()
    assert out.mean() > 0.3  # the run does leave the span
    assert np.isnan(d.residuals.to_numpy()[out, j]).all()
    check = d.status.to_numpy(int) == int(NE107.CHECK_FUNCTION)
    said = d.why.fillna("").astype(str).to_numpy()[check & out]
    assert said.size and np.mean([s.startswith("HAND_VALVE") for s in said]) > 0.5
    assert any("HAND_VALVE = 49 outside what the unit learned (40 … 47)" in s for s in said)


def test_the_live_loop_s_fast_path_agrees(line5):
    """The plant's fast path (``diag run``) blanks the same test: one cycle at a time across
    the valve's move, the same status and message as one by one."""
    unit, free = line5
    path, rb = unit.file.path, unit.file.path.parent
    fast = Plant.load([path], rb)
    slow = Plant(Plant.load([path], rb).units, batched=False)
    assert fast.fast == ["u"] and slow.slow == ["u"]
    moved = int(np.argmax((free["HAND_VALVE"] > 47.0).to_numpy()))
    rows = free.iloc[max(0, moved - 40) : moved + 40]
    for k, (ts, row) in enumerate(rows.iterrows()):
        a, b = fast.cycle(ts, row.to_dict())[0], slow.cycle(ts, row.to_dict())[0]
        assert (a.status, a.message) == (b.status, b.message), k


def test_a_fast_tag_and_a_linear_test_are_not_narrow():
    """:func:`narrow_outputs` names a rule grid's tag of few independent values only: the same
    slow tag tested by a line, and a fast tag on a grid, are not named."""
    from diag_plugin.unitbuild.build import TestChoice

    idx = pd.date_range("2026-03-02", periods=2000, freq="5min")
    rng = np.random.default_rng(3)
    frame = pd.DataFrame(
        {"SLOW": np.repeat([40.0, 45.0, 42.0, 47.0], 500), "FAST": rng.normal(size=2000)},
        index=idx,
    )
    kept = [TestChoice("SLOW", "SLOW", 1.0), TestChoice("FAST", "FAST", 1.0)]
    assert [s.tag for s in narrow_outputs(frame, kept)] == ["SLOW"]
    kept[0].method = "linear"
    assert narrow_outputs(frame, kept) == []


def test_accept_widens_the_narrow_span(line5, tmp_path):
    """``diag unit accept``'s widening (:func:`~diag_plugin.unitbuild.accept.widen_manual`) of
    the fault-free run: ``[narrow]`` then holds 49 %, and the valve's test answers there."""
    import shutil

    from diag_plugin.unitbuild.accept import widen_manual

    unit, free = line5
    folder = shutil.copytree(unit.file.path.parent, tmp_path / "u")
    path = folder / unit.file.path.name
    said = widen_manual(path, free)
    assert any(s.startswith("narrow tag HAND_VALVE: span 40 … 47") for s in said), said
    wider = Unit.load(path, folder)
    assert wider.file.narrow["HAND_VALVE"].max == 49.0
    j = wider.tests.index("HAND_VALVE")
    r = wider.reset().evaluate(free).residuals.to_numpy()[:, j]
    assert np.isfinite(r[(free["HAND_VALVE"] > 47.0).to_numpy()]).mean() > 0.5


def test_the_cli_says_the_narrow_tag_whatever_the_count_of_notes(tmp_path):
    """``diag unit build`` prints the narrow tested tag as a warning of its own, not as one of
    the four notes it shows (the line's 5-min build has 11 notes; as a plain note it was the
    second shown here, and cut to "… more notes" on a build with four notes ahead of it)."""
    from tests.offgrid import write_csv
    from tests.test_any_plant_tour import diag

    g = ["--db", f"sqlite:///{tmp_path / 'h.db'}", "--rulebases", str(tmp_path / "rb")]
    train = _5min(line7.simulate(6.0, 1))
    write_csv(train, tmp_path / "train.csv")
    rc, text = diag(g, "import", str(tmp_path / "train.csv"))
    assert rc == 0, text
    end = (train.index[-1] + pd.Timedelta(minutes=5)).strftime("%Y-%m-%dT%H:%M:%SZ")
    rc, built = diag(g, "unit", "build", "line", "--from", train.index[0].strftime(
        "%Y-%m-%dT%H:%M:%SZ"), "--to", end, "--loop", line7.LOOP, "--far", "0.01")  # fmt: skip
    assert rc == 0, built
    warned = [ln for ln in built.splitlines() if ln.startswith("  ⚠ 1 tested tag(s) seen at")]
    assert len(warned) == 1 and "HAND_VALVE 40 … 47" in warned[0], built
