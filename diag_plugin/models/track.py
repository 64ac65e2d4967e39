"""The control loop's own model (method ``track``) and its model-file codec.

A controller holds its measurement at its set-point, so the loop's model is the set-point
itself: ``ŷ = a · SP + b`` with the slope ``a = 1`` and ``b`` the loop's steady offset, the
mean of ``y − SP`` over training (zero for a controller with integral action). Its residual
(Kościelny et al., eq. 6) is the control error. Nothing is identified but ``b``, so the model
holds at every set-point an operator may enter — a polynomial fitted to the few set-points a
window holds bends away from the identity outside them, a rule grid has no rule there — and
the set-point is never clipped to a span.

The file lists the two terms, in engineering units, as ``narmax2`` files do::

    [rules]
    list = [
        { term = "1", coef = 0.02 },          # b, learned
        { term = "TIC103.SP[k]", coef = 1.0 },  # a, 1 unless an expert edits it
    ]

A term left out takes its default (``b = 0``, ``a = 1``); retraining writes both again, ``a = 1``
and ``b`` learned.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from diag_plugin.models.estimation import (
    SpanEstimator,
    as_2d,
    as_xy,
    finite_rows,
)
from diag_plugin.models.narmax import NarmaxCodec
from diag_plugin.models.protocol import REASON_NAN, REASON_OK, Capabilities, Prediction
from diag_plugin.models.spec import ModelSpec

if TYPE_CHECKING:
    from diag_plugin.rulebase.document import RuleBase

HEADER = """\
# Model file (diag-plugin), method track: a control loop holds its measurement at its
# set-point, y = a * SP + b (a = 1; b, the loop's steady offset, learned). The residual is the
# control error. Edit by hand, then run `diag rules check FILE`. Terms: "1" (b) and the one
# input (a); a term left out takes its default (b = 0, a = 1).
"""

#: the terms as input-index tuples: the constant (offset) and the set-point (slope)
TERMS: list[tuple[int, ...]] = [(), (0,)]


class TrackRegressor(SpanEstimator):
    """The measurement as its set-point plus the loop's steady offset (see module doc).

    Parameters
    ----------
    input_spans : sequence of one (lo, hi), optional
        Nominal span of the set-point (reported, never used to clip).
    output_span : (lo, hi), optional
        Nominal span of the measurement.
    slope : float
        ``a``: 1 for a loop that holds its measurement at the set-point.
    """

    _params = ("input_spans", "output_span", "slope")

    capabilities = Capabilities(incremental=True, mergeable=True)

    def __init__(
        self,
        input_spans: Sequence[tuple[float, float]] | None = None,
        output_span: tuple[float, float] | None = None,
        slope: float = 1.0,
    ) -> None:
        self._keep(locals())

    def _init(self, X: np.ndarray, y: np.ndarray | None = None) -> None:
        if X.shape[1] != 1:
            raise ValueError(f"a track model has one input, its set-point; got {X.shape[1]}")
        self._set_spans(X, y)
        self.n_features_in_ = 1
        self.terms_ = list(TERMS)
        self.n_samples_seen_ = 0
        self.y_sum_ = 0.0
        self.error_sum_ = 0.0  # Σ (y − a·SP)
        self._offset: float | None = None  # an explicit b (a model file)

    # ---------------------------------------------------------------- training
    def partial_fit(self, X: Any, y: Any) -> TrackRegressor:
        """Add a chunk of rows; consecutive chunks give the model of one ``fit`` on all."""
        X, y = as_xy(X, y)
        if not hasattr(self, "spans_"):
            self._init(X, y)
        elif X.shape[1] != 1:
            raise ValueError(f"a track model has one input, its set-point; got {X.shape[1]}")
        ok = finite_rows(X, y)
        self.n_samples_seen_ += int(ok.sum())
        self.y_sum_ += float(y[ok].sum())
        self.error_sum_ += float((y[ok] - self.slope * X[ok, 0]).sum())
        self._offset = None
        return self

    def merge(self, other: TrackRegressor) -> TrackRegressor:
        """Add the rows ``other`` was trained on: the model of both data sets."""
        if self._merge_empty(other):
            return self
        if self.slope != other.slope:
            raise ValueError("cannot merge track models with different slopes")
        self.n_samples_seen_ += other.n_samples_seen_
        self.y_sum_ += other.y_sum_
        self.error_sum_ += other.error_sum_
        return self

    # ------------------------------------------------------------- parameters
    @property
    def offset_(self) -> float:
        """``b``: the mean of ``y − a·SP`` over training (or the file's value)."""
        self._check_fitted()
        if self._offset is not None:
            return self._offset
        return self.error_sum_ / self.n_samples_seen_ if self.n_samples_seen_ else 0.0

    @property
    def coef_(self) -> np.ndarray:
        """Coefficients of :attr:`terms_` (``b``, ``a``) in engineering units."""
        return np.array([self.offset_, float(self.slope)])

    def set_coefficients(self, coef: Sequence[float]) -> TrackRegressor:
        """Use explicit ``(b, a)`` (a model file)."""
        b, a = (float(c) for c in coef)
        self.slope = a
        self._offset = b
        return self

    @property
    def output_mean_(self) -> float:
        """Mean training output (NaN for a model read from its coefficients)."""
        return self.y_sum_ / self.n_samples_seen_ if self.n_samples_seen_ else math.nan

    # ------------------------------------------------------------------ state
    def to_state(self) -> dict[str, Any]:
        """Parameters and training state as plain JSON values (no pickle)."""
        return {
            "params": self._span_params(),
            "n_samples_seen": int(self.n_samples_seen_),
            "y_sum": float(self.y_sum_),
            "error_sum": float(self.error_sum_),
            "offset": self._offset,
        }

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> TrackRegressor:
        """The model a :meth:`to_state` describes."""
        m = cls(**state["params"]).init(1)
        m.n_samples_seen_ = int(state["n_samples_seen"])
        m.y_sum_ = float(state["y_sum"])
        m.error_sum_ = float(state["error_sum"])
        m._offset = state.get("offset")
        return m

    # --------------------------------------------------------------- inference
    def predict_detail(self, X: Any) -> Prediction:
        """``a·SP + b`` per row; NaN (``REASON_NAN``) where the set-point is missing."""
        self._check_fitted()
        X = as_2d(X)
        if X.shape[1] != 1:
            raise ValueError(f"a track model has one input, its set-point; got {X.shape[1]}")
        y = self.slope * X[:, 0] + self.offset_
        ok = np.isfinite(y)
        reason = np.where(ok, REASON_OK, REASON_NAN).astype(np.int8)
        return Prediction(y, ok.astype(np.float64), reason)

    def predict(self, X: Any) -> np.ndarray:
        return self.predict_detail(X).y


class TrackCodec(NarmaxCodec):
    """Estimator factory and term I/O of ``track`` (the ``narmax2`` file form, two terms)."""

    method = "track"
    estimator = TrackRegressor
    header = HEADER
    only = 'a track model has only the constant "1" (its offset) and its input (slope 1)'

    def new_estimator(self, spec: ModelSpec) -> TrackRegressor:
        """An untrained model of the spec's one input (the set-point)."""
        if spec.options:
            raise ValueError(f"track takes no options, got {', '.join(spec.options)}")
        if len(spec.inputs) != 1:
            raise ValueError(
                f"a track model has one input, its set-point; the spec has {len(spec.inputs)}"
            )
        return TrackRegressor(
            input_spans=[v.span for v in spec.inputs], output_span=spec.output.span
        )

    def to_model(self, rb: RuleBase) -> TrackRegressor:
        """The model the file describes (a term left out: ``b = 0``, ``a = 1``)."""
        coef = {(): 0.0, (0,): 1.0}
        for r in rb.rules:
            coef[r.term] = r.coef
        return self.new_estimator(rb.spec).init(1).set_coefficients([coef[()], coef[(0,)]])

    def size(self, model: TrackRegressor) -> int:
        return len(TERMS)

    def allows(self, term: tuple[int, ...]) -> bool:
        """Only ``1`` and the input."""
        return term in TERMS
