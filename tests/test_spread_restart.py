"""A spread test's filter after a data outage (issue 34 acceptance pass, H3).

A loop's spread test (valve stiction: the running MAD of its control error) is always
positive; its normal value is the loop's noise, never near zero. After a gap longer than the
low-pass filter's ``max_gap`` the filter restarted from rest, so the spread came back ramping
up from zero: a deviation below its normal level as large as the level itself, which the
combined T² (two-sided) read as a fault. On a 5 s boiler unit (three declared loops) a 1.5 h
outage gave T² = 304 and a 9-minute false alarm right after the data returned. Now a spread
test's filter restarts at the steady state of its first value after the gap; every other
test still restarts from rest (docs/reference/units.md).

The 7-tag line of :mod:`tests.line7` (its flow loop declared: a spread test), built on three
fault-free days; unseen fault-free seeds with a 2 h outage of every tag.
"""

from __future__ import annotations

import numpy as np
import pytest

from diag_plugin.diagnose.residuals import LowPass
from diag_plugin.diagnose.unit import Unit
from diag_plugin.unitbuild.build import build_unit
from diag_plugin.unitbuild.loops import parse_loop
from tests import line7

OUTAGE = 480  # samples of 15 s: 2 h
BEFORE = 720  # the 3 h before it


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    folder = tmp_path_factory.mktemp("spread_restart")
    train = line7.simulate(3.0, seed=1)
    res = build_unit("line", train, folder=folder, period="15s", far=0.01, workers=1,
                     loops=[parse_loop(line7.LOOP)])  # fmt: skip
    return res.path, folder


@pytest.fixture
def unit(built):
    return Unit.load(*built)


@pytest.mark.parametrize("seed", [201, 202, 203])
def test_a_spread_test_comes_back_from_an_outage_at_its_level_not_from_zero(unit, seed):
    spread = [t for t in unit.tests if t.endswith("_spread")]
    assert spread, "the declared loop gives a spread test"
    run = line7.simulate(1.0, seed=seed)
    a = len(run) // 2
    run.iloc[a : a + OUTAGE] = np.nan
    unit.reset()
    d = unit.evaluate(run)
    for name in spread:
        r = d.residuals[name].to_numpy()
        normal = float(np.nanmedian(r[a - BEFORE : a]))
        back = r[a + OUTAGE :]
        first = float(back[np.isfinite(back)][0])
        assert normal > 0
        # on main the first value after the outage was 0.1-0.3 % of the normal level
        assert first > 0.25 * normal, (name, first, normal)


def test_the_live_fast_path_restarts_a_spread_test_as_the_replay_does(built):
    """The live loop's stacked path (:class:`~diag_plugin.diagnose.plant.Plant`, one row a
    cycle) marks its spread tests as the unit does: the same statuses and residuals through
    the outage and after it."""
    from helpers import plant_statuses, same_status

    from diag_plugin.diagnose.plant import Plant

    path, folder = built
    run = line7.simulate(0.25, seed=202)
    a = len(run) // 2
    run.iloc[a - 200 : a - 200 + 150] = np.nan  # longer than the filter's max_gap (100)
    fast = Plant.load([path], folder)
    slow = Plant(Plant.load([path], folder).units, batched=False)
    assert fast.fast == ["line"] and slow.slow == ["line"]
    x, y = plant_statuses(fast, run)["line"], plant_statuses(slow, run)["line"]
    for i, (p, q) in enumerate(zip(x, y, strict=True)):
        same_status(p, q, i, exact=False)
    spread = [k for k in x[0].residuals if k.endswith("_spread")]
    back = [s.residuals[spread[0]] for s in x[a - 50 :] if np.isfinite(s.residuals[spread[0]])]
    assert back and back[0] > 0.25 * np.nanmedian([s.residuals[spread[0]] for s in x[: a - 200]])


def test_only_the_steady_columns_restart_at_their_value():
    """Column 0 restarts from rest as before (a residual off zero ramps through the filter,
    docs/reference/units.md: kept), column 1 (steady) at its first value after the gap; a
    gap within ``max_gap`` holds both states, as before."""
    x = np.full((300, 2), 3.0)
    x[100:120] = np.nan  # longer than max_gap = 10
    x[200:205] = np.nan  # shorter: the state is held
    f = LowPass(0.1, 4, max_gap=10, steady=[False, True])
    y = f.transform(x)
    ref = LowPass(0.1, 4, max_gap=10).transform(x[:, :1])
    np.testing.assert_array_equal(y[:, 0], ref[:, 0])
    assert y[120, 0] < 0.1  # from rest
    np.testing.assert_allclose(y[120:200, 1], 3.0, rtol=1e-9)  # at its level at once
    # the state survives to_state / from_state, the steady columns with it
    g = LowPass.from_state(f.to_state())
    z = np.full((40, 2), 3.0)
    z[:20] = np.nan
    np.testing.assert_allclose(g.transform(z)[20:, 1], 3.0, rtol=1e-9)
