"""Pieces sharing a load: the load a piece carries, not its sibling's measurements (issue 34,
item 4; docs/reference/units.md, "A piece's tests read its own tags").

The two chillers of :mod:`tests.twinplant`, BOTH declared (A as running throughout, its run
tag ``A_RUN`` = 1; B by day only), built on 10 days (seed 1) and judged on seeds never used
to build. A chiller cools half the building's load while both run and all of it alone; its
tests may not read B's power (a sibling's measurement), and with ``LOAD`` and ``B_RUN``
alone chiller A's capacity test could not tell how much it carried: A's leaving-water sensor
bias was found on 54-61 % of its samples. The build offers each piece the unit-wide load over
the pieces running, ``share(LOAD,B_RUN)``, computed from the unit-wide tag and the other
pieces' run tags only.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from diag_plugin.diagnose.derived import DerivedInputs, stackable
from diag_plugin.diagnose.plant import Plant
from diag_plugin.diagnose.unit import Unit
from diag_plugin.regressors import InputSpec, SpecError, feature
from diag_plugin.status import NE107
from diag_plugin.unitbuild.build import build_unit
from diag_plugin.unitbuild.loops import Loop, parse_running
from tests import twinplant
from tests.test_unit_running import same_in_pieces

LOOPS = [Loop("A_T", "A_SP", "A_CAP"), Loop("B_T", "B_SP", "B_CAP")]
PIECES = ["A:A_RUN=1:A_T,A_CAP,A_KW", "B:B_RUN:B_T,B_CAP,B_KW"]
DAY = 1440


def _twins(days: float, seed: int, fault: str | None = None) -> pd.DataFrame:
    f = twinplant.simulate(days, seed, fault, onset_days=1.0)
    f.insert(0, "A_RUN", 1.0)
    return f


@pytest.fixture(scope="module")
def both(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("twins_both")
    eq = [parse_running(p) for p in PIECES]
    res = build_unit("chw", _twins(10, 1), folder=tmp, period="1min", far=0.01, loops=LOOPS,
                     disturbances=["LOAD"], equipment=eq)  # fmt: skip
    return res, Unit.load(res.path, tmp)


def _minutes(n: int) -> pd.DatetimeIndex:
    return pd.date_range("2026-06-01", periods=n, freq="1min", tz="UTC")


def test_share_is_the_load_over_the_pieces_running():
    f = pd.DataFrame({"LOAD": [800.0, 800, 900, 900], "B_RUN": [0.0, 1, 1, np.nan],
                      "C_RUN": [0.0, 0, 1, 1]},
                     index=_minutes(4))  # fmt: skip
    s = InputSpec.parse("share(LOAD,B_RUN,C_RUN)[k-1]")
    assert (s.fn, s.tags, s.lag, str(s)) == ("share", ("LOAD", "B_RUN", "C_RUN"), 1,
                                             "share(LOAD,B_RUN,C_RUN)[k-1]")  # fmt: skip
    got = feature(f, s)
    assert np.allclose(got[:3], [800, 400, 300]) and np.isnan(got[3])
    with pytest.raises(SpecError, match=r"share\(\) takes at least 2 tags, got 1"):
        InputSpec.parse("share(LOAD)[k]")


def test_each_piece_is_offered_the_load_it_carries_never_the_sibling_s_tags(both):
    res, unit = both
    own = {"A": {"A_T", "A_CAP", "A_KW"}, "B": {"B_T", "B_CAP", "B_KW"}}
    for test, model in unit.models.items():
        piece = "A" if model.output.startswith("A_") else "B"
        other = "B" if piece == "A" else "A"
        read = {t for s in model.inputs for t in InputSpec.parse(s).tags}
        assert not read & own[other], (test, model.inputs)
    # A's capacity reads the load it carries (main: A_CAP = f(A_KW, LOAD), blind to B's start)
    assert any(s.startswith("share(LOAD,B_RUN)") for s in unit.models["A_CAP"].inputs), (
        unit.models["A_CAP"].inputs)  # fmt: skip
    for piece, runs in (("A", "B_RUN"), ("B", "A_RUN")):
        said = [n for n in res.notes if n.startswith(f"{piece}: its tests may read share(")]
        assert len(said) == 1 and f"share(LOAD,{runs})" in said[0], res.notes


@pytest.mark.parametrize("seed", [12, 13])
def test_a_s_bias_is_found_and_named_on_a_with_both_declared(both, seed):
    """Tuned on seeds 7 and 8 (main 54.5 / 54.6 %, here 99.2 / 99.4 %), checked on 9 and 11."""
    _, unit = both
    f = _twins(2, seed, "a_bias")
    d = unit.reset().evaluate(f)
    after = np.arange(len(f)) >= DAY
    fail = d.status.to_numpy()[after] == NE107.FAILURE
    assert fail.mean() > 0.9, fail.mean()
    first = pd.Series(d.top["top1"].to_numpy()[after][fail]).astype(str)
    assert first.str.startswith("A_").mean() > 0.95, first.value_counts()


@pytest.mark.parametrize("seed", [12, 13])
def test_the_morning_hour_a_carries_alone_raises_no_more_than_on_main(both, seed):
    """Fault-free, A carries the whole morning load alone (06:30-07:30, before B has started
    and settled): its T² (1,000-47,000) was in the build's held-out T² on nine of ten days,
    but the combined threshold's tail fit sat below them all (3,952; main 31,717): fault-free
    FAILURE 2.99 / 2.78 % on seeds 12 / 13 (main 0.00 / 1.60 %, now 0.00 / 1.67 %), and B's
    bias named on B's tags first 89 / 90 % (main 96 / 97 %, now 100 / 97 %).
    :func:`~diag_plugin.learn.budget.calibrate_side` keeps an extrapolated threshold above
    the episodes the window shows more of than the budget allows."""
    _, unit = both
    assert unit.file.combined.high > 20_000, unit.file.combined.high
    f = _twins(2, seed)
    d = unit.reset().evaluate(f)
    after = np.arange(len(f)) >= DAY
    assert (d.status.to_numpy()[after] == NE107.FAILURE).mean() < 0.02
    f = _twins(2, seed, "b_bias")
    d = unit.reset().evaluate(f)
    judged = after & (f["B_RUN"].to_numpy() > 0)
    fail = d.status.to_numpy()[judged] == NE107.FAILURE
    first = pd.Series(d.top["top1"].to_numpy()[judged][fail]).astype(str)
    assert fail.mean() > 0.9 and first.str.startswith("B_").mean() > 0.95, first.value_counts()


def test_the_live_plant_and_pieces_read_the_share_as_the_replay(both):
    """The same statuses over B's start whole, in pieces from a saved state and live."""
    _, unit = both
    f = _twins(2, 9, "a_bias").iloc[DAY + 6 * 60 : DAY + 8 * 60]
    whole = same_in_pieces(unit, f, 57)
    plant = Plant({"chw": unit.reset()}, {})
    got = [plant.cycle(ts, row.to_dict())[0] for ts, row in f.iterrows()]
    assert [int(s.status) for s in got] == whole.status.astype(int).tolist()


def test_the_fast_path_computes_share_as_the_replay():
    """A unit file's ``share()`` input on the plant's stacked path (a unit without pieces):
    :class:`~diag_plugin.diagnose.derived.DerivedInputs` gives the numbers of
    :func:`~diag_plugin.regressors.feature`."""
    spec = InputSpec.parse("share(LOAD,B_RUN,C_RUN)[k]")
    assert stackable(spec)
    d = DerivedInputs()
    cols = {"LOAD": 0, "B_RUN": 1, "C_RUN": 2}
    assert d.add(spec, spec.tags) == 0
    d.freeze(cols)
    rows = np.array([[800.0, 0, 0], [800, 1, 0], [900, 1, 1], [900, np.nan, 1]])
    f = pd.DataFrame(rows, columns=list(cols),
                     index=_minutes(4))  # fmt: skip
    got = []
    for ts, row in zip(f.index, rows, strict=True):
        hist = np.concatenate([row, [np.nan]])[None, :]
        d.update(hist, ts)
        got.append(hist[0, 3])
    np.testing.assert_array_equal(got, feature(f, spec))
