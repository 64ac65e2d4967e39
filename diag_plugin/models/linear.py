"""A linear model of the inputs (method ``linear``) and its model-file codec.

``ŷ = β₀ + Σ β_i x_i``: the first-order part of Laukonen et al., eq. 12 (the ``narmax2``
polynomial without its squares and products), fitted by the same batch least squares over
inputs scaled to their spans (:class:`~diag_plugin.models.narmax.Narmax2Regressor`: a QR
factor, so ``partial_fit`` on consecutive chunks and ``merge`` of models trained on parts give
the model of all rows). ``diag unit build`` tests with it where a window is too short for a
rule grid: a residual of one tag against a linear combination of others is a PCA-like
parity relation (a residual subspace of one row), which a few hundred samples determine
(``1 + d`` parameters against a grid's ``sets^d``). The file is the ``narmax2`` form with the
constant and one term per input::

    [rules]
    list = [
        { term = "1", coef = 12.5 },
        { term = "FI101[k]", coef = 0.42 },
    ]

After ``diag unit accept`` a test with inputs also has ``[rules] points`` (as a joint test's:
per point ``at``, ``shift``, ``spread``): the slopes fitted within the points, each sample
predicted with its nearest point's constant
(:class:`~diag_plugin.models.joint.PointLinearRegressor`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from diag_plugin.models.narmax import Narmax2Regressor, NarmaxCodec
from diag_plugin.models.protocol import REASON_OUTSIDE, Prediction

HEADER = """\
# Model file (diag-plugin), method linear: y = b0 + sum of b_i * input_i (the first-order
# part of Laukonen et al., eq. 12). Edit by hand, then run `diag rules check FILE`.
# One term per line: term = "1" (constant) or "SPEC" (an input of [[inputs]]); coef in
# engineering units (output unit per input unit). A term left out counts as 0.
"""


def linear_terms(d: int) -> list[tuple[int, ...]]:
    """The constant and one term per input, as input-index tuples."""
    return [(), *((i,) for i in range(d))]


class LinearRegressor(Narmax2Regressor):
    """``ŷ = β₀ + Σ β_i x_i`` by batch least squares (see module doc); parameters as
    :class:`~diag_plugin.models.narmax.Narmax2Regressor`.

    Where an input is outside its span the prediction (at the span's edge) has no support:
    a line learned from a few hundred samples says nothing about a range it never saw, so
    a unit's test is unknown there and names the input (not a symptom)."""

    def predict_detail(self, X: Any) -> Prediction:
        p = super().predict_detail(X)
        support = np.where(p.reason == REASON_OUTSIDE, 0.0, p.support)
        return Prediction(p.y, support, p.reason, p.level, p.spread)

    @staticmethod
    def _term_list(d: int) -> list[tuple[int, ...]]:
        return linear_terms(d)

    @staticmethod
    def _phi(Z: np.ndarray) -> np.ndarray:
        return np.hstack([np.ones((Z.shape[0], 1)), Z])

    def _basis(self) -> np.ndarray:
        """``M`` with ``φ(z) = M φ(x)`` for ``z = (x − centre) / half`` (first order)."""
        d = self._centre.size
        M = np.zeros((d + 1, d + 1))
        M[0, 0] = 1.0
        M[1:, 0] = -self._centre / self._half
        M[1:, 1:] = np.diag(1.0 / self._half)
        return M


class LinearCodec(NarmaxCodec):
    """Estimator factory and term I/O of ``linear`` (the ``narmax2`` file form, first order)."""

    method = "linear"
    estimator = LinearRegressor
    header = HEADER
    only = 'a linear model has only the constant "1" and its inputs'

    def allows(self, term: tuple[int, ...]) -> bool:
        """The constant and the inputs, no products."""
        return len(term) <= 1

    # operating points (``diag unit accept``, ``[rules] points``): a parity test per point,
    # :class:`~diag_plugin.models.joint.PointLinearRegressor`; a file without is as before
    def new_estimator(self, spec: Any) -> Any:
        """An untrained model; with ``[rules] points``, one per operating point."""
        from dataclasses import replace

        from diag_plugin.models.estimation import spans_and_lags
        from diag_plugin.models.joint import POINTS, PointLinearRegressor

        points = spec.options.get(POINTS) if spec.options else None
        if not points:
            return super().new_estimator(spec)
        opts = {k: v for k, v in spec.options.items() if k != POINTS}
        kw = spans_and_lags(replace(spec, options=opts), self.method)
        return PointLinearRegressor(**kw, points=[p["at"] for p in points])

    def to_model(self, rb: Any) -> Any:
        """The model the file describes (with points: each point's shift and spread)."""
        from diag_plugin.models.joint import POINTS

        m = super().to_model(rb)
        points = rb.options.get(POINTS)
        if points:
            m.set_shifts([float(p.get("shift", 0.0)) for p in points])
            m.set_spreads([float(p.get("spread", 1.0)) for p in points])
        return m

    def apply_training(self, rb: Any, model: Any) -> list:
        """The terms and, for a model with points, ``[rules] points``."""
        from diag_plugin.models.joint import set_points

        out = super().apply_training(rb, model)
        if len(getattr(model, "points_", ())) >= 2:
            set_points(rb, model.points_, model.shifts_, model.spreads_)
        return out

    def check_options(self, rb: Any) -> None:
        """``points`` (as a joint test's) is the one key ``[rules]`` takes."""
        from diag_plugin.models.joint import POINTS, JointCodec

        if POINTS in rb.options:
            return JointCodec.check_options(self, rb)  # type: ignore[arg-type]
        return super().check_options(rb)
