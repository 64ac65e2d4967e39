"""A joint test of a collinear group of tags (method ``joint``) and its model-file codec.

Tags that move together (two accelerometers on one pump) test each other: ``A = b₀ + b₁ B``
is a parity relation, the *residual* direction of the group, and a rise of both together —
along the group's own direction of variation — leaves it quiet. PCA sees that rise in its
T² (the *principal* direction). The joint test is that T² for the group: the score of the
group's standardised deviations on their first principal component (Jackson and Mudholkar's
PCA decomposition; MacGregor and Kourti, T² of the retained component),

``t = Σ_i v_i (x_i − m_i) / s_i``, with ``v`` the first eigenvector of the group's correlation
matrix, ``m`` and ``s`` the training means and standard deviations.

It is written as a linear model of one tag of the group (the output: the build chooses the
tag with the largest |loading| ``v_y`` on the component, :func:`~diag_plugin.unitbuild.short.
joint_groups`, so the division below never comes near zero) on the others::

    y − ŷ = (s_y / v_y) · t,   ŷ = m_y − (s_y / v_y) Σ_{i≠y} v_i (x_i − m_i) / s_i

so the unit's machinery runs it unchanged — a residual per sample, thresholds learned to the
test's share of the unit's budget, the tags named by contribution — and its file is the
``linear`` form (a constant and one coefficient per tag). The training statistics are the same
QR factor as the ``linear`` method's (:class:`~diag_plugin.models.estimation.QRLeastSquares` of
``[1, x, y]``): its ``RᵀR`` is the group's Gram matrix, so means and covariance follow exactly
and ``partial_fit``/``merge`` over parts give the model of all rows (``diag unit accept``).

Unlike a parity test, the joint test extrapolates: a common rise beyond what the window showed
is what it exists to see, so an input outside its span is neither clipped nor unknown.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from diag_plugin.models.linear import LinearCodec, LinearRegressor
from diag_plugin.models.protocol import REASON_NAN, REASON_OK, Prediction

HEADER = """\
# Model file (diag-plugin), method joint: the score of a collinear group of tags on its first
# principal component (T² of the group's standardised deviations), written as
# y = b0 + sum of b_i * input_i so that y - ŷ is that score. Edit by hand, then run
# `diag rules check FILE`. One term per line: term = "1" or "SPEC"; coef in engineering units.
"""


def first_component(gram: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Means, standard deviations and the first principal direction (of the correlation
    matrix, its largest entry positive) of the variables whose Gram matrix with a leading
    constant column is ``gram`` (``[1, u]ᵀ [1, u]`` over ``n = gram[0, 0]`` rows)."""
    n = gram[0, 0]
    m = gram[0, 1:] / n
    cov = gram[1:, 1:] / n - np.outer(m, m)
    s = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    s = np.where(s > 0, s, 1.0)
    corr = cov / np.outer(s, s)
    w, V = np.linalg.eigh(corr)
    v = V[:, -1]
    if v[np.argmax(np.abs(v))] < 0:
        v = -v
    return m, s, v


class JointRegressor(LinearRegressor):
    """The joint test of a group (module doc): inputs are the group's other tags, the output
    its first; the coefficients come from the group's first principal component, not from
    least squares. Parameters as :class:`~diag_plugin.models.linear.LinearRegressor`."""

    @property
    def coef_scaled_(self) -> np.ndarray:
        self._check_fitted()
        if self._coef is None:
            R = self.qr_.R
            k = R.shape[1]
            if R.shape[0] < k:  # fewer rows than variables: pad (Gram unchanged)
                R = np.vstack([R, np.zeros((k - R.shape[0], k))])
            gram = R.T @ R  # over [1, z, y], z the inputs scaled to their spans
            m, s, v = first_component(gram)
            vy = v[-1] if abs(v[-1]) > 1e-9 else 1e-9
            b = -s[-1] * v[:-1] / (vy * s[:-1])
            self._coef = np.concatenate([[m[-1] - b @ m[:-1]], b])
        return self._coef

    def predict_detail(self, X: Any) -> Prediction:
        """``ŷ`` wherever every input has a value, extrapolated (no span clips it)."""
        self._check_fitted()
        X = self._check_X(X)
        ok = np.isfinite(X).all(axis=1)
        y = np.full(X.shape[0], np.nan)
        if ok.any():
            y[ok] = self._predict_rows(X[ok])
        reason = np.where(ok, REASON_OK, REASON_NAN).astype(np.int8)
        return Prediction(y, ok.astype(np.float64), reason)


class JointCodec(LinearCodec):
    """Estimator factory and term I/O of ``joint`` (the ``linear`` file form)."""

    method = "joint"
    estimator = JointRegressor
    header = HEADER
    only = 'a joint test has only the constant "1" and its group\'s other tags'
