"""A reading beyond every answer its test's model can give, gone there on its own (issue 34,
items 1 and 5; :mod:`diag_plugin.diagnose.beyond`).

A small plant built once: a feed analyser ``AI1`` that wanders slowly (nothing sets it), the
reactor's heat ``TI1`` that follows it through a 30-min lag, and a steam flow ``FI1`` that
follows an operator's temperature set-point ``TIC1.SP`` (not held at it: another quantity).
The build models the analyser from the heat it causes.
A step of the feed's composition past anything learned leaves the analyser's own test's range
at once and the heat's some minutes later: on main the analyser's test is unknown from then on
(CHECK_FUNCTION, "TI1 outside what the unit learned", the step read as an operating point);
here it keeps the least residual any answer of its model would leave, alarms and names the
analyser. An operator's set-point moved past anything learned carries the flow out after it:
that stays CHECK_FUNCTION, naming the set-point (item 5)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from diag_plugin.diagnose.beyond import answer_range, bound_residual, own_excursion
from diag_plugin.diagnose.unit import Unit
from diag_plugin.status import NE107

PERIOD = "1min"


def _ou(rng, n: int, sd: float, tau: float) -> np.ndarray:
    a = np.exp(-1.0 / tau)
    e = rng.normal(0.0, sd * np.sqrt(1 - a * a), n)
    x = np.empty(n)
    x[0] = rng.normal(0.0, sd)
    for k in range(1, n):
        x[k] = a * x[k - 1] + e[k]
    return x


def _lag(x: np.ndarray, tau: float) -> np.ndarray:
    y = np.empty_like(x)
    y[0] = x[0]
    a = 1.0 / tau
    for k in range(1, x.size):
        y[k] = y[k - 1] + a * (x[k] - y[k - 1])
    return y


def simulate(days: float, seed: int, *, feed_step: float = 0.0, sp_step: float = 0.0,
             onset: int | None = None) -> pd.DataFrame:  # fmt: skip
    """The plant at 1 min; from ``onset`` (default: a third in) the feed's composition up by
    ``feed_step`` and the operator's set-point by ``sp_step``."""
    rng = np.random.default_rng([seed, 77])
    n = int(days * 1440)
    k0 = n // 3 if onset is None else onset
    feed = 2.0 + _ou(rng, n, 0.04, 360.0)
    feed[k0:] += feed_step
    sp = 60.0 + np.round(_ou(rng, n, 2.0, 600.0))
    sp[k0:] += sp_step
    heat = 50.0 + 40.0 * (_lag(feed, 30.0) - 2.0)
    flow = 1.0 + 0.05 * _lag(sp - 60.0, 5.0)
    idx = pd.date_range("2026-03-01", periods=n, freq=PERIOD, tz="UTC")
    return pd.DataFrame(
        {
            "AI1": feed + rng.normal(0, 0.004, n),
            "TI1": heat + rng.normal(0, 0.1, n),
            "FI1": flow + rng.normal(0, 0.05, n),
            "TIC1.SP": sp,
        },
        index=idx,
    )


@pytest.fixture(scope="module")
def unit(tmp_path_factory):
    from diag_plugin.unitbuild.build import build_unit

    folder = tmp_path_factory.mktemp("beyond")
    res = build_unit("feed", simulate(6.0, 1), folder=folder, period=PERIOD, far=0.01)
    return Unit.load(res.path, folder)


def _reads(unit: Unit, test: str) -> set[str]:
    return {i.split("[")[0] for i in unit.models[test].inputs}


def test_the_analysers_step_past_what_was_learned_alarms_and_names_it(unit):
    assert _reads(unit, "AI1") == {"TI1"}, unit.models["AI1"].inputs  # the build's own choice
    for seed in (11, 12, 13):
        x = simulate(2.0, seed, feed_step=0.4, onset=1440)
        d = unit.reset().evaluate(x)
        after = slice(1440 + 120, None)  # the heat past what was learned too by then
        rng = answer_range(unit.models["AI1"].model, unit.models["AI1"].out_range)
        assert (x["AI1"].to_numpy()[after] > rng[1]).all()
        r = d.residuals["AI1"].to_numpy()[after]
        # main: unknown on most of these samples (its input TI1 outside what it learned)
        assert np.isfinite(r).mean() > 0.99, seed
        status = d.status.to_numpy()[after]
        seen = np.unique(status, return_counts=True)
        assert (status == NE107.FAILURE).mean() > 0.75, (seed, seen)
        top = d.top["top1"].to_numpy()[after]
        assert (top == "AI1").mean() > 0.9, (seed, pd.Series(top).value_counts())


def test_an_operators_move_past_what_was_learned_stays_check_function(unit):
    assert "TIC1.SP" in _reads(unit, "FI1")
    assert unit.file.test("FI1").set_point is None  # not a loop's: modelled, not tracked
    x = simulate(2.0, 21, sp_step=12.0, onset=1440)
    d = unit.reset().evaluate(x)
    after = slice(1440 + 60, None)  # the flow past what was learned too by then
    assert np.isnan(d.residuals["FI1"].to_numpy()[after]).all()
    assert (d.status.to_numpy()[after] == NE107.CHECK_FUNCTION).all()
    assert d.why.iloc[after].str.startswith("TIC1.SP").all()


def test_the_excursion_is_its_own_only_if_its_test_knew_it_there():
    out = np.array([0, 1, 1, 1, 0, 1, 1, 1], bool)
    known = np.array([1, 1, 0, 0, 1, 0, 1, 0], bool)
    own, end = own_excursion(out, known, False)
    assert own.tolist() == [0, 1, 1, 1, 0, 0, 1, 1] and end
    own, end = own_excursion(out[:3], np.zeros(3, bool), True)  # carried from a piece before
    assert own.tolist() == [0, 0, 0] and not end
    own, _ = own_excursion(np.ones(2, bool), np.zeros(2, bool), True)
    assert own.tolist() == [1, 1]


def test_the_bound_is_the_distance_past_the_answers_range_in_percent_of_span():
    r = np.array([5.0, np.nan, np.nan, np.nan])
    y = np.array([12.5, 13.0, 11.0, 8.0])
    got, end = bound_residual(r, y, (9.0, 12.0, 1.0), 4.0, False)
    assert got[0] == 5.0 and got[1] == pytest.approx(25.0)  # (13 − 12) · 100 / 4
    assert np.isnan(got[2])  # inside the range: unknown as before
    assert np.isnan(got[3]) and not end  # beyond, but its test never knew it there
