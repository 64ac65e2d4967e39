"""A piece of equipment whose run tag is a mode of more than two values (issue 34, item 5).

Acceptance pass 8 (docs/explanation/acceptance-filters.md): a filter's state is 0 while it
filters, 1 in backwash, 2 filtering to waste. `--running 'F1:F1_STATE=0:F1_FLOW,…'` names
the value it runs at, yet main refused it, `run condition F1_STATE of F1 is not two-valued
over the window (3 value(s): 0, 1, 2); a piece that ran throughout: F1_STATE=VALUE`, the
fix it offered the one given. A run value at one end of the tag's values is taken (stopped
nearer the next value: every other mode); since acceptance pass 10 (a pasteuriser's
production, 1 of 0-4) one in the middle too (tests/test_unit_running_modes.py); none is
refused, saying to give one.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from diag_plugin.unitbuild.equipment import equipment_conditions
from diag_plugin.unitbuild.loops import parse_running
from historian.errors import UserError


def _filter(n: int = 3000) -> pd.DataFrame:
    state = np.zeros(n)
    for start in range(300, n - 50, 1000):  # backwash 12 samples, then filter-to-waste 10
        state[start : start + 12] = 1
        state[start + 12 : start + 22] = 2
    flow = np.where(state == 1, 0.0, 400.0)
    return pd.DataFrame({"F1_STATE": state, "F1_FLOW": flow})


def test_a_mode_tag_runs_at_the_value_given_and_is_stopped_in_every_other_mode():
    frame = _filter()
    (piece,), notes = equipment_conditions(frame, [parse_running("F1:F1_STATE=0:F1_FLOW")])
    assert (piece.rc.run, piece.rc.stop) == (0.0, 1.0)
    stopped = piece.stopped(frame["F1_STATE"].to_numpy())
    assert np.array_equal(stopped, frame["F1_STATE"].to_numpy() != 0)
    assert "runs while F1_STATE = 0" in notes[0]
    # the other end too: a tag whose highest value is the running one
    frame["F1_STATE"] = 2 - frame["F1_STATE"]
    (piece,), _ = equipment_conditions(frame, [parse_running("F1:F1_STATE=2:F1_FLOW")])
    assert (piece.rc.run, piece.rc.stop) == (2.0, 1.0)
    assert np.array_equal(piece.stopped(frame["F1_STATE"].to_numpy()), frame["F1_STATE"] != 2)


def test_a_mode_tag_without_a_value_is_refused_saying_to_give_one():
    with pytest.raises(UserError, match=r"takes 3 values .*\(0, 1 or 2\); give the one it runs at"):
        equipment_conditions(_filter(), [parse_running("F1:F1_STATE:F1_FLOW")])


def test_a_mode_tag_runs_at_a_middle_value_stopped_at_both_others():
    frame = _filter()
    (piece,), _ = equipment_conditions(frame, [parse_running("F1:F1_STATE=1:F1_FLOW")])
    assert (piece.rc.run, piece.rc.levels) == (1.0, (0.0, 1.0, 2.0))
    v = frame["F1_STATE"].to_numpy()
    assert np.array_equal(piece.stopped(v), v != 1)


def test_a_stopped_piece_is_said_at_the_value_its_run_tag_holds():
    """Its why named the stop value (``F1_STATE = 1``) also during filter-to-waste (2)."""
    from diag_plugin.diagnose.equipment import off_mask

    frame = _filter()
    (piece,), _ = equipment_conditions(frame, [parse_running("F1:F1_STATE=0:F1_FLOW")])
    v = frame["F1_STATE"].to_numpy()
    since = np.array([10**6])
    off, said, _, _ = off_mask(
        [piece], [np.array([0])], {"F1_STATE": v}, since, ["F1_FLOW"], len(v)
    )
    assert np.array_equal(off[:, 0], v != 0)
    texts = {text: at for at, text in said}
    assert set(texts) == {
        "F1 stopped (F1_STATE = 1): tests F1_FLOW off",
        "F1 stopped (F1_STATE = 2): tests F1_FLOW off",
    }
    assert np.array_equal(texts["F1 stopped (F1_STATE = 2): tests F1_FLOW off"], v == 2)
    assert np.array_equal(texts["F1 stopped (F1_STATE = 1): tests F1_FLOW off"], v == 1)
    # a run tag of many values while stopped (a historian's means across switches): one
    # reason at the stop value, not one a value
    rng = np.random.default_rng(3)
    analog = np.where(v != 0, 1.0 + rng.uniform(0.0, 0.4, len(v)), 0.0)
    _, said, _, _ = off_mask(
        [piece], [np.array([0])], {"F1_STATE": analog}, np.array([10**6]), ["F1_FLOW"], len(v)
    )
    assert [text for _, text in said] == [
        f"F1 stopped (F1_STATE = {piece.rc.stop:g}): tests F1_FLOW off"
    ]
