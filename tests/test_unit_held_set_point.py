"""A set-point held over the build window and moved later: an operating point the unit never
saw, said as CHECK_FUNCTION naming the set-point, not a FAILURE of the tags its other tests read
(issue 34, item 5).

Acceptance pass 11 (docs/explanation/acceptance-aeration2.md): an aeration basin's dissolved
oxygen held at 2.0 mg/l for 14 days, its set-point moved to 1.5 by the operator: the blower's
and the other zone's valve tests, which read the oxygen, were in alarm on 58-61 % of two
fault-free days and named the probe. The build had said of the held set-point "where one
leaves it the unit says so (CHECK_FUNCTION)"; now it does. The 7-tag line of
:mod:`tests.line7` (its feed loop's set-point ``FEED_TARGET`` held over the first stretch of a
run, then moved by the operators) is the plant here: written once from its physics, not tuned.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from diag_plugin.diagnose.unit import Unit
from diag_plugin.diagnose.unitfile import UnitFile
from diag_plugin.status import NE107
from diag_plugin.unitbuild.build import NARROW_SAID, UNWATCHED_SAID, build_unit
from diag_plugin.unitbuild.loops import Loop
from tests import line7


def _held_window(seed: int = 4):
    run = line7.simulate(0.5, seed=seed)
    sp = run["FEED_TARGET"].to_numpy()
    moves = np.flatnonzero(np.diff(sp) != 0) + 1
    window = run.iloc[: moves[0]]  # the set-point held over the whole window
    assert window["FEED_TARGET"].nunique() == 1 and len(window) >= 400
    return run, window, moves


@pytest.fixture(scope="module")
def declared(tmp_path_factory):
    folder = tmp_path_factory.mktemp("held")
    run, window, moves = _held_window()
    res = build_unit("held", window, folder=folder, period="15s", far=0.01, workers=1,
                     loops=[Loop("FEED_FLOW", "FEED_TARGET", "VALVE_A")])  # fmt: skip
    return run, window, moves, res, folder


def test_a_declared_loops_held_set_point_is_fixed_at_its_measurements_reach(declared):
    """The unit file's ``[fixed]`` row of the held set-point: its value, and as margin the
    farthest the loop's measurement went from it over the window; the build says so."""
    run, window, _, res, folder = declared
    held = float(window["FEED_TARGET"].iloc[0])
    reach = float(np.nanmax(np.abs(window["FEED_FLOW"].to_numpy(float) - held)))
    row = UnitFile.load(folder / "held.unit.toml").doc["fixed"]["FEED_TARGET"]
    assert row["min"] == row["max"] == held
    assert row["margin"] == pytest.approx(reach, rel=1e-9)
    said = f"FEED_TARGET did not move over the window ({held:.4g} ± {row['margin']:.4g})"
    assert any(said in n and "CHECK_FUNCTION naming it" in n for n in res.notes), res.notes


def test_a_move_beyond_the_reach_is_check_function_naming_the_set_point(declared):
    """Where the operators' next set-point is farther from the held one than the loop's
    measurement ever went, the unit is CHECK_FUNCTION naming ``FEED_TARGET``, its value and
    since when, and raises no FAILURE; where it is back within reach, it answers again."""
    run, window, moves, _, folder = declared
    row = UnitFile.load(folder / "held.unit.toml").doc["fixed"]["FEED_TARGET"]
    d = Unit.load("held", folder).evaluate(run)
    st = d.status.to_numpy()
    sp = run["FEED_TARGET"].to_numpy(float)
    far = np.abs(sp - row["min"]) > row["margin"]
    after = np.arange(len(run)) >= moves[0]
    assert far[after].mean() > 0.2  # the run moves it beyond the reach for a good while
    # the guard's on-delay and the loop's settle aside: 40 samples (10 min) after each move
    steady = np.ones(len(run), bool)
    for m in moves:
        steady[m : m + 40] = False
    moved = far & steady
    assert (st[moved] == NE107.CHECK_FUNCTION).all(), np.unique(st[moved], return_counts=True)
    assert d.why[moved].str.contains("FEED_TARGET = ").all()
    assert d.why[moved].str.contains("outside what the unit learned").all()
    assert not (st[after & far] == NE107.FAILURE).any()


def test_an_undeclared_held_set_point_is_said_not_guarded(tmp_path):
    """A set-point by its name (``FEED.SP``) held over the window with no loop declared: no
    ``[fixed]`` row (its measurement is unknown; a row at the build's test of a constant made
    a tank's units CHECK_FUNCTION where they answered right), and the build says that its
    moves are judged by the tests and how to have them guarded (declare the loop). On
    b58dc32 the narrow-inputs note promised CHECK_FUNCTION for it and nothing did it; on
    2b47779 its line there (given a span) still read under that promise: now it says it is
    not watched, and the promise is made with that exception."""
    run, window, _ = _held_window()
    window = window.rename(columns={"FEED_TARGET": "FEED.SP"})
    info = {"FEED.SP": {"lo": 0.0, "hi": 2 * float(window["FEED.SP"].iloc[0])}}
    res = build_unit("free", window, folder=tmp_path, period="15s", far=0.01, workers=1,
                     tag_info=info)  # fmt: skip
    doc = UnitFile.load(tmp_path / "free.unit.toml").doc
    assert "FEED.SP" not in doc.get("fixed", {})
    note = next((n for n in res.notes if "declared in no loop" in n), None)
    assert note is not None and "FEED.SP" in note and "--loop PV=SP:OUT" in note, res.notes
    narrow = next(n for n in res.notes if NARROW_SAID in n)
    line = re.search(r"FEED\.SP [^(]*\(([^)]*)\)", narrow)
    assert line is not None and "held at one value" in line[1], narrow
    assert line[1].endswith(f"; {UNWATCHED_SAID}"), narrow
    assert "CHECK_FUNCTION), but for one marked not watched" in narrow
