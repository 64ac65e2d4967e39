"""CHECK_FUNCTION during a data outage names what is missing (issue 34, the boiler's acceptance
pass, docs/explanation/acceptance-boiler.md): the whole feed gone reads otherwise than one
transmitter lost, several missing are named or counted, each with the time the gap began —
the same in the replay (one piece or several), the plant's cycle by cycle and after a
restart from a saved state.

The unit is the coupled process's (six tags, five tests; diag_plugin/examples/coupled.py),
trained and its thresholds learned on 3 fault-free days of seed 1, replayed on a day of
seed 2 with tags blanked for 90 min from 10:00."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from diag_plugin.diagnose.plant import Plant
from diag_plugin.diagnose.unit import Unit
from diag_plugin.diagnose.unitfile import UnitFile
from diag_plugin.examples.coupled import DAY, build, process
from diag_plugin.learn.thresholds import learn_thresholds
from diag_plugin.status import NE107

GAP = slice(600, 690)  # 10:00 to 11:30 at 60 s


@pytest.fixture(scope="module")
def unit_path(tmp_path_factory):
    folder = tmp_path_factory.mktemp("outage")
    window = process(3 * DAY, 1)
    path = build(folder, window, {})
    got = learn_thresholds(Unit.load(path), [window], far=0.05)
    uf = UnitFile.load(path)
    uf.set_learned(got)
    uf.save()
    return path


def _outage(tags: list[str]) -> pd.DataFrame:
    frame = process(DAY, 2)
    frame.iloc[GAP, [frame.columns.get_loc(t) for t in tags]] = np.nan
    return frame


def _checking_whys(unit: Unit, frame: pd.DataFrame) -> pd.Series:
    d = unit.reset().evaluate(frame)
    gap = d.status.iloc[GAP]
    assert (gap == NE107.CHECK_FUNCTION).any()  # the outage outlasts the symptoms' hold
    return d.why.iloc[GAP][gap == NE107.CHECK_FUNCTION]


@pytest.mark.parametrize(
    "tags, said",
    [
        (list("ABCDEF"), "no values from any of the 6 tags since {t} (source outage?)"),
        (["D"], "D without a value since {t}"),  # no test reading D is first in order
        (["E", "B"], "B, E without a value since {t}"),  # the unit's order, not the test's
        (["C", "D", "E", "F"], "4 of 6 tags without a value since {t} (C, D, E, …)"),
    ],
    ids=["all", "one", "two", "four"],
)
def test_the_why_names_every_tag_without_a_value_and_since_when(unit_path, tags, said):
    frame = _outage(tags)
    whys = _checking_whys(Unit.load(unit_path), frame)
    start = frame.index[GAP.start].isoformat()
    assert set(whys) == {said.format(t=start)}


def test_a_replay_in_pieces_and_the_plant_cycle_by_cycle_say_the_same(unit_path):
    frame = _outage(["C", "D", "E"])
    frame.iloc[650:700, frame.columns.get_loc("A")] = np.nan  # a fourth tag goes later
    whole = Unit.load(unit_path).reset().evaluate(frame)
    assert whole.why.str.startswith("4 of 6 tags without a value since ").any()
    # the gap's start carried from piece to piece, and through a saved state
    u = Unit.load(unit_path).reset()
    parts = [u.evaluate(frame.iloc[:620]).why, u.evaluate(frame.iloc[620:660]).why]
    u2 = Unit.load(unit_path).reset().load_state(u.to_state())
    parts.append(u2.evaluate(frame.iloc[660:]).why)
    pd.testing.assert_series_equal(pd.concat(parts), whole.why)
    # the plant, one row a cycle (its fast path skips a unit with all inputs good), restarted
    # from its saved state inside the outage
    plant = Plant({"p": Unit.load(unit_path)}, {})
    got = []
    for k, (ts, row) in enumerate(frame.iterrows()):
        if k == 640:
            state = plant.to_state()
            plant = Plant({"p": Unit.load(unit_path)}, {}).load_state(state)
        got.extend(s.message for s in plant.cycle(ts, row.to_dict()))
    assert got == whole.why.tolist()


@pytest.mark.parametrize("total", [1, 2, 5, 12])
def test_sentences_stay_short_whatever_the_count(total):
    from diag_plugin.diagnose.operating import SHORT, gone_sentence  # not on main

    names = [f"TAG_{i:02d}" for i in range(total)]
    for k in range(1, total + 1):
        s = gone_sentence(names[:k], total, "2026-03-07T03:10:00+00:00")
        every = k == total and total > 1  # the whole feed: a count, no names
        assert s.count("TAG_") == (0 if every else min(k, SHORT))
        assert s.startswith(f"{k} of {total} tags") == (k > SHORT and not every)
        assert len(s) <= 100
