"""The isolated faults and the ranking's first tag never two different confident answers
(issue 34, item 4).

Acceptance pass on a pumping station (docs/explanation/acceptance-pumps.md, "A meter bias
named right, isolated wrong"): a bias of the discharge flow meter moved the three tests that
read it (its own, ``InletFlow = f(DischFlow[k-7])``, ``sumpLvl = f(DischFlow[k-7])``), but
only the level's, whose band is the narrowest, fired. The derived matrix's exact column for
that pattern is the level's (its one test), so ``faults`` said ``sumpLvl`` on 90.6 % of the
alarm samples while the ranking named ``DischFlow`` on 97.7 %. The sump here is written for
this test with the station's structure: a discharge meter OUT, the inlet IN and the level LVL
following the discharge 7 minutes later (a float valve), IN measured coarsely.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from diag_plugin.diagnose.matrix import DiagnosticMatrix
from diag_plugin.diagnose.plant import Plant
from diag_plugin.diagnose.unit import Unit
from diag_plugin.diagnose.unitfile import UnitFile
from diag_plugin.examples.coupled import DAY, START, build
from diag_plugin.learn.thresholds import learn_thresholds

SUMP_TAGS = {"OUT": (0, 100), "IN": (0, 100), "LVL": (0, 100)}
#: the station's models: the meter from the inlet, the inlet and the level from the meter
SUMP_TESTS = {
    "rOUT": ("OUT[k]", ["IN[k]"]),
    "rIN": ("IN[k]", ["OUT[k-7]"]),
    "rLVL": ("LVL[k]", ["OUT[k-7]"]),
}


def sump(n: int, seed: int, bias: float = 0.0, onset: int = 0) -> pd.DataFrame:
    """``n`` minutes: a demand with a daily cycle and a wander; the meter OUT reads it (+
    ``bias`` from ``onset``); the inlet and the level follow it 7 minutes later."""
    rng = np.random.default_rng([seed, 344])
    t = np.arange(n)
    walk = np.cumsum(rng.normal(0, 0.05, n))
    walk -= np.convolve(walk, np.ones(241) / 241, mode="same")  # no drift out of the range
    q = 50 + 15 * np.sin(2 * np.pi * t / DAY) + 3 * walk
    late = np.r_[np.full(7, q[0]), q[:-7]]
    out = q + 0.3 * rng.standard_normal(n) + bias * (t >= onset)
    inlet = late + 5.0 * rng.standard_normal(n)
    level = 150 - 2.0 * late + 0.1 * rng.standard_normal(n)
    idx = pd.date_range(START, periods=n, freq="60s", name="ts")
    return pd.DataFrame({"OUT": out, "IN": inlet, "LVL": level}, idx)


@pytest.fixture(scope="module")
def unit(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sump")
    window = sump(14 * DAY, 1)
    path = build(folder, window, {"combined": True, "isolation": "tags"},
                 tests=SUMP_TESTS, tags=SUMP_TAGS)  # fmt: skip
    uf = UnitFile.load(path)
    uf.set_learned(learn_thresholds(Unit.load(path), [window], far=0.01))
    uf.save()
    return Unit.load(path)


def test_a_meter_bias_only_the_level_sees_is_isolated_as_the_meter_too(unit):
    """The meter biased by 2.5 % of span: only the level's test fires, the ranking names
    OUT. Fails on main, where ``faults`` is ``LVL`` alone on those samples."""
    m = unit.matrix
    assert m.entries[:, m.faults.index("OUT")].tolist() == ["1", "1", "1"]  # every test
    assert m.entries[:, m.faults.index("LVL")].tolist() == ["0", "0", "1"]  # its own
    d = unit.reset().evaluate(sump(3 * DAY, 7, bias=2.5, onset=DAY))
    alarm = d.detected.to_numpy()[DAY:] == 1
    assert alarm.sum() > 100, alarm.sum()
    s = d.symptoms.iloc[DAY:][alarm]
    only_level = (s["rLVL"] != 0) & (s["rOUT"] == 0) & (s["rIN"] == 0)
    assert only_level.mean() > 0.4  # the pattern of the finding
    top1 = d.top_tags["top1"].iloc[DAY:][alarm]
    faults = d.faults.iloc[DAY:][alarm]
    assert (top1 == "OUT").mean() > 0.9, top1.value_counts()
    # the operator is never sent to one tag by the isolation and another by the ranking
    both = [t in f.split("|") for f, t in zip(faults, top1, strict=True) if t]
    assert np.mean(both) > 0.99, faults.value_counts()
    assert (faults[only_level] == "LVL|OUT").all(), faults[only_level].value_counts()


def test_the_live_path_gives_the_same_faults(unit):
    f = sump(DAY // 2, 8, bias=2.5, onset=60)
    one = unit.reset().evaluate(f)
    plant = Plant({"p": unit.reset()})
    seen = set()
    for i, (ts, row) in enumerate(f.iloc[:400].iterrows()):
        st = plant.cycle(ts, row)[0]
        want = one.at(i)
        assert (st.status, st.faults) == (want.status, want.faults)
        seen.add("|".join(st.faults))
    assert "LVL|OUT" in seen, seen


def test_a_first_tag_the_symptoms_contradict_is_not_added():
    """The ranking's first tag is added only where its column allows every symptom on."""
    from diag_plugin.diagnose.unittags import with_ranked

    m = DiagnosticMatrix(["r1", "r2", "r3"], ["A", "B", "C"],
                         [["1", "1", "0"], ["0", "1", "0"], ["1", "1", "+"]])  # fmt: skip
    faults = np.array(["A", "A", "A", "C", "", "unit", "A|B"], object)
    first = np.array(["B", "C", "A", "B", "B", "B", "B"], object)
    s = np.array([[1, 0, 1], [1, 0, 1], [1, 0, 1], [0, 0, -1], [0, 0, 0], [1, 0, 0], [1, 0, 1]])
    got = with_ranked(m, faults, first, s.astype(float)).tolist()
    # B's column holds r1 and r3; C's lacks r1; A is there already; B's allows any sign of
    # r3 (C's "+" does not allow −1, but C is the exact one there); nothing to add to "",
    # "unit" or a fault already named
    assert got == ["A|B", "A", "A", "C|B", "", "unit", "A|B"]
