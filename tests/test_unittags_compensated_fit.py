"""The 3-axis credit of a loop sensor's bias, tested on its fit alone (issue 34 item 4;
``CombinedModel._compensated_rbc``' second credit, :func:`~diag_plugin.diagnose.unittags.
_plane_credit`; docs/how-to/unit-loops.md, "loop sensor").

A bias the loop cannot wholly take (its actuator at a limit) leaves the rest on the loop's
error: ``z`` is fitted on the sensor's beyond-the-valve direction ``ξ_b``, the loop test's axis
and the actuator's, and where the coefficients of ``ξ_b`` and of the loop's error stand 3
standard errors clear of zero with one sign the sensor is credited ``uᵀG⁻¹u`` over the three
(Alcala & Qin, 2009, the multidimensional reconstruction-based contribution). Here on synthetic
scaled residuals with a known covariance: a bias of known size along the three axes is credited
what those axes explain (all of ``T²`` without noise, a share of it growing as the bias's
square); a true move of the measurement (its loop error and the tests beyond with opposite
signs), a bias too small to tell from noise, or a sample without the loop test earns nothing.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from diag_plugin.diagnose.unittags import COMPENSATED_SE, CombinedModel

#: the tests: the actuator's (its model's residual), the loop's own, three beyond the valve
T, JA, JL = 5, 0, 1
#: the sensor's compensated direction: the actuator's entry and the tests beyond (the loop's
#: error held at zero by the loop)
XI = np.array([0.8, 0.0, 0.5, -0.7, 0.3])


def _cov(seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((T, T))
    s = a @ a.T + T * np.eye(T)
    d = np.sqrt(np.diag(s))
    return s / np.outer(d, d)


def _model():
    """The one loop's sensor (tag column 0), its actuator's test and its loop test; ``dims``
    above ``T`` so that only the 3-axis credit is taken (the 2-axis one needs every test)."""
    return SimpleNamespace(process=XI[:, None].copy(), compensated=np.array([[0, JA, JL]]),
                           dims=T + 1)  # fmt: skip


def _credit(z: np.ndarray, k: np.ndarray | None = None) -> np.ndarray:
    """The sensor's contribution after ``_compensated_rbc`` (0 on entry) for scaled residuals
    ``z`` (samples × the known tests ``k``)."""
    s = _cov()
    k = np.arange(T) if k is None else k
    m = np.linalg.inv(s[np.ix_(k, k)])
    mz = z @ m
    q = np.einsum("ij,ij->i", mz, z)
    rbc = np.zeros((len(z), 1))
    CombinedModel._compensated_rbc(_model(), rbc, mz, m, k, q)
    return rbc[:, 0]


def _axes() -> np.ndarray:
    beyond = XI.copy()
    beyond[JA] = 0.0
    a = np.zeros((T, 3))
    a[:, 0], a[JL, 1], a[JA, 2] = beyond, 1.0, 1.0
    return a


def _explained(z: np.ndarray) -> np.ndarray:
    """``uᵀG⁻¹u`` over the three axes (generalised least squares in ``S⁻¹``), computed here
    from the whitened residuals' projection."""
    L = np.linalg.cholesky(np.linalg.inv(_cov()))
    zw, aw = z @ L, L.T @ _axes()
    fit = np.linalg.lstsq(aw, zw.T, rcond=None)[0]
    return np.sum((aw @ fit) ** 2, axis=0), fit.T


@pytest.mark.parametrize("b", [6.0, -6.0, 12.0])
def test_a_bias_along_the_three_axes_is_credited_all_it_explains(b):
    """A bias ``b`` (either sign): the tests beyond moved by ``b ξ_b``, the loop's error by
    ``0.6 b`` (the rest the loop could not take, the reading off its set-point the bias's
    way), the actuator by what its limit left (``-1.5``, either sign): without noise the three
    axes explain all of ``T²``, and the sensor is credited it; the fit's coefficients are
    the bias's."""
    z = (b * _axes() @ np.array([1.0, 0.6, 0.0]) + _axes()[:, 2] * -1.5)[None, :]
    got = _credit(z)
    q = float(z[0] @ np.linalg.inv(_cov()) @ z[0])
    assert got[0] == pytest.approx(q, rel=1e-9)
    _, coef = _explained(z)
    assert coef[0] == pytest.approx([b, 0.6 * b, -1.5], abs=1e-9)


def test_a_bias_in_noise_is_credited_what_its_axes_explain_growing_as_its_square():
    """Fault-free noise ``N(0, S)`` plus a bias of size ``b``: every sample credited exactly
    ``uᵀG⁻¹u`` over the three axes; the mean credit grows as ``b²``."""
    rng = np.random.default_rng(11)
    noise = rng.multivariate_normal(np.zeros(T), _cov(), size=400)
    means = {}
    for b in (12.0, 24.0):
        z = noise + b * _axes() @ np.array([1.0, 0.6, 0.0])
        got = _credit(z)
        want, coef = _explained(z)
        said = got > 0
        assert said.mean() > 0.99  # told from noise on (nearly) every sample
        np.testing.assert_allclose(got[said], want[said], rtol=1e-9)
        assert np.median(coef[:, 0]) == pytest.approx(b, rel=0.1)
        assert np.median(coef[:, 1]) == pytest.approx(0.6 * b, rel=0.1)
        means[b] = got.mean()
    assert means[24.0] / means[12.0] == pytest.approx(4.0, rel=0.15)


@pytest.mark.parametrize("size", [6.0, 12.0])
def test_a_true_move_of_the_measurement_earns_no_credit(size):
    """The reading and the true value off the set-point together (a fouled cooler, a stuck
    valve): the loop's error up, the tests beyond moving as a true rise moves them (``−ξ_b``,
    opposite to a bias's), the actuator moved too: opposite signs, no credit at any size."""
    rng = np.random.default_rng(5)
    noise = 0.1 * rng.multivariate_normal(np.zeros(T), _cov(), size=50)
    for s in (1.0, -1.0):
        z = noise + s * size * _axes() @ np.array([-1.0, 0.6, 0.4])
        _, coef = _explained(z)
        assert (np.sign(coef[:, 0]) != np.sign(coef[:, 1])).all()
        assert (_credit(z) == 0).all()


def test_a_bias_inside_its_noise_or_without_the_loop_test_earns_no_credit():
    """A bias whose loop-error coefficient is under 3 standard errors earns nothing; nor does
    a large one on a sample whose loop test is unknown (only the actuator's and the tests
    beyond known: the three axes cannot be fitted)."""
    g = _axes().T @ np.linalg.inv(_cov()) @ _axes()
    se = np.sqrt(np.diag(np.linalg.inv(g)))
    small = (_axes() @ np.array([10 * se[0], 0.5 * COMPENSATED_SE * se[1], 0.0]))[None, :]
    assert _credit(small)[0] == 0
    k = np.array([JA, 2, 3, 4])
    z = (9.0 * _axes() @ np.array([1.0, 0.6, 0.0]))[None, k]
    assert _credit(z, k)[0] == 0
