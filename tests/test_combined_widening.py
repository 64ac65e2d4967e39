"""The combined T² takes each test at its predictive spread (issue 34, short windows).

A test whose residual wanders slower than the build window holds a handful of independent
values there; its centre and scale are then known to Student's t with ``n − 1`` degrees of
freedom, not exactly, and the combined test widens its scale by the ratio of t's quantile to
the normal's (:func:`~diag_plugin.learn.thresholds.predictive_widening`). A test the window
knows well (hundreds of values) is left as it was.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from diag_plugin.diagnose.unittags import CombinedModel
from diag_plugin.learn.thresholds import (
    PREDICTIVE_TAIL,
    _centre_scale,
    _combined_params,
    predictive_widening,
)
from diag_plugin.models.series import effective_samples


def test_the_widening_is_students_quantile_over_the_normals():
    n = np.array([1.0, 4.0, 10.0, 40.0, 400.0, 1e5])
    w = predictive_widening(n)
    q = stats.norm.isf(PREDICTIVE_TAIL)
    assert w[1] == pytest.approx(stats.t.isf(PREDICTIVE_TAIL, 3.0) / q)
    assert w[2] == pytest.approx(stats.t.isf(PREDICTIVE_TAIL, 9.0) / q)
    assert np.all(np.diff(w) < 0)  # fewer values, wider
    assert w[0] == pytest.approx(stats.t.isf(PREDICTIVE_TAIL, 1.0) / q)  # ν at least 1
    assert 3.0 < w[1] < 3.6 and w[4] < 1.01 and w[5] == pytest.approx(1.0, abs=1e-4)


def _window(n: int = 400, seed: int = 5) -> np.ndarray:
    """A fast test (white residual) and a slow one (a residual that wanders over the window:
    AR(1) with a time constant of ~200 samples)."""
    rng = np.random.default_rng(seed)
    fast = rng.normal(size=n)
    slow = np.zeros(n)
    for i in range(1, n):
        slow[i] = 0.995 * slow[i - 1] + rng.normal()
    return np.c_[fast, slow]


def test_a_slow_test_is_widened_and_a_fast_one_left_as_it_was():
    x = _window()
    c, s, S, lam = _combined_params(x)
    c0, s0 = _centre_scale(x)
    z = (x - c0) / s0
    n_fast, n_slow = effective_samples(z[:, 0]), effective_samples(z[:, 1])
    assert n_slow < 10 < 200 < n_fast
    np.testing.assert_allclose(c, c0)
    np.testing.assert_allclose(s / s0, predictive_widening(np.array([n_fast, n_slow])))
    assert s[0] / s0[0] < 1.01 and s[1] / s0[1] > 1.3
    # the covariance stays that of the window's scaled residuals (shrunk as before)
    cov = np.cov(z.T)
    np.testing.assert_allclose(np.diag(S), np.diag(cov))


def test_a_wander_of_the_slow_test_weighs_less_in_t2_a_bias_of_the_fast_one_as_much():
    x = _window()
    c, s, S, _ = _combined_params(x)
    c0, s0 = _centre_scale(x)
    model = CombinedModel([], c, s, S, np.zeros((2, 0)), None)
    plain = CombinedModel([], c0, s0, S, np.zeros((2, 0)), None)
    wander = c0 + np.array([[0.0, 6.0]]) * s0  # the slow test 6 of its window's scales off
    bias = c0 + np.array([[6.0, 0.0]]) * s0  # the fast test 6 of its scales off
    t2_w, t2_w0 = model.evaluate(wander)[0][0], plain.evaluate(wander)[0][0]
    t2_b, t2_b0 = model.evaluate(bias)[0][0], plain.evaluate(bias)[0][0]
    w = predictive_widening(np.array([effective_samples((x[:, 1] - c0[1]) / s0[1])]))[0]
    assert t2_w == pytest.approx(t2_w0 / w**2, rel=1e-9)
    assert t2_w < 0.6 * t2_w0
    assert t2_b == pytest.approx(t2_b0, rel=0.02)


def test_at_two_operating_points_the_independent_values_add_up():
    """After ``diag unit accept`` each window is an operating point: a test's independent
    values are counted within each window and summed, not over the two joined (a slow wander
    over the accepted hour would count the build window's values as a handful, and widen a
    test the build window knew well: SKAB's valve1/1 fault went from 76 % to 0 % detected)."""
    rng = np.random.default_rng(7)
    a = _window(400, seed=1)  # the build window
    slow = np.cumsum(rng.normal(size=3600)) * 0.05  # an hour that wanders at the other point
    b = np.c_[slow + 10.0, rng.normal(size=3600) + 5.0]
    x = np.r_[a, b]
    point = np.r_[np.zeros(400, int), np.ones(3600, int)]
    c, s, S, _ = _combined_params(x, point)
    z = np.empty_like(x)
    scales = np.empty((2, 2))
    for p, rows in enumerate((slice(0, 400), slice(400, None))):
        cp, sp = _centre_scale(x[rows])
        z[rows] = (x[rows] - cp) / sp
        scales[p] = sp
    per = [sum(effective_samples(z[point == p, j]) for p in (0, 1)) for j in (0, 1)]
    joined = [effective_samples(z[:, j]) for j in (0, 1)]
    assert joined[0] < 0.5 * per[0]  # the joined series would count far fewer
    np.testing.assert_allclose(s / scales, np.tile(predictive_widening(np.array(per)), (2, 1)))


def test_a_test_that_fits_a_computed_tag_exactly_is_taken_at_a_converters_resolution():
    """A valve command computed from its split-range output and shut most of the window
    leaves its test float rounding for residuals (the AHU pass: robust scale 2e-77 %, the
    scaled residual's variance 8e+150, ``T²`` of 1e-199 with negative values, the test
    carrying all of it, docs/explanation/acceptance-ahu.md). Its scale is at least one 16-bit
    count of the span (``RESOLUTION_PCT``): its scaled residuals vanish below that, the
    covariance stays of the order of one, and ``T²`` is the other test's alone, non-negative
    (its own threshold still judges the exact test)."""
    from diag_plugin.learn.thresholds import RESOLUTION_PCT

    rng = np.random.default_rng(3)
    n = 2000
    exact = np.where(rng.random(n) < 0.7, 0.0, rng.normal(0, 1e-76, n))  # rounding
    x = np.c_[rng.normal(size=n), exact]
    c, s, S, _ = _combined_params(x)
    assert s[1] >= RESOLUTION_PCT
    assert np.all(np.isfinite(S)) and np.abs(S).max() < 10, S
    model = CombinedModel([], c, s, S, np.zeros((2, 0)), None)
    t2, _ = model.evaluate(x[:300], None, shares=False)
    alone = ((x[:300, 0] - c[0]) / s[0]) ** 2 / S[0, 0]
    assert np.all(t2 >= 0)
    np.testing.assert_allclose(t2, alone, rtol=1e-6)
