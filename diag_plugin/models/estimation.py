"""Pieces the regression methods share (Takagi–Sugeno, NARMAX): input checks, nominal spans and
reason codes, a chunked QR least-squares accumulator, and free-run (output-error) simulation.

Least squares is never solved through an explicit inverse (Laukonen et al., remark after
eq. 24): rows are folded chunk by chunk into the triangular factor ``R`` of a QR decomposition
(``RᵀR = AᵀA`` without ever forming ``AᵀA``), and the small triangular system is solved with
``lstsq``, which also copes with rank deficiency (an input that never moved).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from diag_plugin.models.params import ParamsMixin
from diag_plugin.models.protocol import (
    REASON_NAN,
    REASON_OK,
    REASON_OUTSIDE,
    Capabilities,
    Prediction,
    mean_stand_in,
)

log = logging.getLogger(__name__)

#: rows processed at once (bounds the memory of fitting and prediction)
CHUNK_ROWS = 1 << 16


def as_2d(X: Any) -> np.ndarray:
    """``X`` as a float64 samples × inputs array."""
    X = np.asarray(X, dtype=np.float64)
    if X.ndim == 1:
        X = X[:, None]
    if X.ndim != 2:
        raise ValueError(f"X must be 2-D (samples × inputs), got shape {X.shape}")
    return X


def as_xy(X: Any, y: Any) -> tuple[np.ndarray, np.ndarray]:
    """``X`` (2-D) and ``y`` (1-D) checked for matching rows."""
    X = as_2d(X)
    y = np.asarray(y, dtype=np.float64).ravel()
    if X.shape[0] != y.shape[0]:
        raise ValueError(f"X has {X.shape[0]} rows but y has {y.shape[0]}")
    return X, y


def observed_span(v: np.ndarray) -> tuple[float, float]:
    """The range of the finite values of ``v`` (widened a hair if constant)."""
    v = v[np.isfinite(v)]
    if v.size == 0:
        raise ValueError("cannot infer a span from data that is all NaN")
    lo, hi = float(v.min()), float(v.max())
    if hi <= lo:
        hi = lo + max(abs(lo), 1.0) * 1e-3
    return lo, hi


def resolve_spans(spans: Sequence[Sequence[float]] | None, X: np.ndarray) -> np.ndarray:
    """Nominal spans as a ``d × 2`` array: the given ones, else the range seen in ``X``."""
    d = X.shape[1]
    if spans is None:
        return np.array([observed_span(X[:, k]) for k in range(d)], dtype=np.float64)
    out = np.asarray(spans, dtype=np.float64).reshape(-1, 2)
    if out.shape[0] != d:
        raise ValueError(f"input_spans has {out.shape[0]} entries for {d} inputs")
    if not np.all(out[:, 1] > out[:, 0]):
        raise ValueError(f"every span needs lo < hi, got {out.tolist()}")
    return out


def finite_rows(X: np.ndarray, y: np.ndarray | None = None) -> np.ndarray:
    """Mask of the rows whose inputs (and output) are all finite."""
    ok = np.isfinite(X).all(axis=1)
    if y is not None:
        ok &= np.isfinite(y)
    return ok


def detail(
    X: np.ndarray, spans: np.ndarray, predict_rows: Callable[[np.ndarray], np.ndarray]
) -> Prediction:
    """Prediction with reason codes: NaN inputs give NaN (``REASON_NAN``); inputs outside their
    nominal span are clipped to it and flagged ``REASON_OUTSIDE``; every rule of these
    methods exists, so support is 1 wherever there is a prediction."""
    n = X.shape[0]
    y = np.full(n, np.nan)
    reason = np.full(n, REASON_OK, dtype=np.int8)
    nan = ~np.isfinite(X).all(axis=1)
    reason[nan] = REASON_NAN
    ok = np.flatnonzero(~nan)
    for s in range(0, ok.size, CHUNK_ROWS):
        rows = ok[s : s + CHUNK_ROWS]
        x = X[rows]
        clipped = np.clip(x, spans[:, 0], spans[:, 1])
        outside = (clipped != x).any(axis=1)
        reason[rows[outside]] = REASON_OUTSIDE
        y[rows] = predict_rows(clipped)
    return Prediction(y, np.isfinite(y).astype(np.float64), reason)


class QRLeastSquares:
    """Least squares ``min ‖A c − b‖²`` accumulated over row chunks by updating the triangular
    factor of a QR decomposition of ``[A | b]`` (stable: no normal equations, no inverse).

    The factor ``R`` of ``[A | b]`` holds everything: its top-left block is ``R_A``, its last
    column ``Q_Aᵀ b`` and its corner ``±‖residual‖``. Two accumulators over different rows
    combine into the one of all rows (``merge``), so the solution does not depend on the
    chunking (up to rounding).
    """

    def __init__(self, n_cols: int) -> None:
        self.R = np.zeros((0, n_cols + 1))
        self.n = 0

    def update(self, A: np.ndarray, b: np.ndarray) -> QRLeastSquares:
        """Fold rows ``A``, ``b`` in (weighted least squares: scale both rows by √weight)."""
        if A.shape[0] == 0:
            return self
        M = np.vstack([self.R, np.column_stack([A, b])])
        self.R = _triangle(M)
        self.n += int(A.shape[0])
        return self

    def merge(self, other: QRLeastSquares) -> QRLeastSquares:
        """Add the rows ``other`` has seen."""
        n = self.n + other.n
        self.update(other.R[:, :-1], other.R[:, -1])
        self.n = n
        return self

    @property
    def rss(self) -> float:
        """Residual sum of squares of the solution."""
        p = self.R.shape[1] - 1
        return float(self.R[p, p] ** 2) if self.R.shape[0] > p else 0.0

    def solve(self) -> np.ndarray:
        """The least-squares solution (minimum norm where the rows do not determine it)."""
        return solve_triangle(self.R)

    def to_state(self) -> dict[str, Any]:
        return {"R": self.R.tolist(), "n": self.n}

    @classmethod
    def from_state(cls, state: dict[str, Any], n_cols: int) -> QRLeastSquares:
        q = cls(n_cols)
        q.R = np.asarray(state["R"], dtype=np.float64).reshape(-1, n_cols + 1)
        q.n = int(state["n"])
        return q


#: rows per block of the first QR stage at least (tall-skinny QR: a block fits the cache,
#: which makes it many times faster than one QR of all rows)
QR_BLOCK = 256


def _triangle(M: np.ndarray) -> np.ndarray:
    """The triangular factor ``R`` of a QR decomposition of ``M`` (at most ``cols`` rows)."""
    return triangles(M[None])[0]


def triangles(M: np.ndarray) -> np.ndarray:
    """The triangular factors ``R`` of QR decompositions of a stack of matrices
    (``batch × rows × cols`` → ``batch × min(rows, cols) × cols``).

    Tall matrices go in two stages (tall-skinny QR): the ``R`` of each block of rows, then
    the ``R`` of those stacked; zero rows padding the last block change nothing."""
    batch, rows, cols = M.shape
    size = max(QR_BLOCK, 4 * cols)
    if rows > 2 * size:
        blocks = -(-rows // size)
        padded = np.zeros((batch, blocks * size, cols))
        padded[:, :rows] = M
        M = np.linalg.qr(padded.reshape(batch * blocks, size, cols), mode="r")
        M = M.reshape(batch, blocks * cols, cols)
    return np.linalg.qr(M, mode="r")


#: singular values of ``R_A`` below this share of its largest count as zero in
#: :func:`solve_triangle`: a column the rows do not determine (an input constant over them,
#: so a copy of the constant) leaves rounding of about ``eps·√rows`` there, not an exact 0,
#: and ``lstsq``'s default cut-off (``eps·columns``) kept it — a short window's fold where a
#: pump ran throughout got coefficients of ±4·10¹³ on its run tag and the constant
#: (issue 34: thresholds of 10¹⁴ % of span)
RANK_RCOND = 1e-10


def solve_triangle(R: np.ndarray) -> np.ndarray:
    """The least-squares solution held by the ``R`` of ``[A | b]`` (see
    :class:`QRLeastSquares`); minimum norm where the rows do not determine it (singular
    values under :data:`RANK_RCOND` of the largest taken as zero)."""
    p = R.shape[1] - 1
    k = min(p, R.shape[0])
    if k == 0:
        return np.zeros(p)
    return np.linalg.lstsq(R[:k, :p], R[:k, p], rcond=RANK_RCOND)[0]


def output_lags_of(output_spec: str, input_specs: Sequence[str]) -> list[int]:
    """Per input: how many samples it lags the output by if it *is* the output's tag (a plain
    ``TAG[k-d]`` of the output ``TAG[k]``), else 0. These inputs are fed back in free run."""
    from diag_plugin.regressors import InputSpec

    out = InputSpec.parse(output_spec)
    lags = []
    for s in input_specs:
        spec = InputSpec.parse(s)
        same = not out.fn and not spec.fn and spec.tags == out.tags and spec.lag > out.lag
        lags.append(spec.lag - out.lag if same else 0)
    return lags


def spans_and_lags(spec: Any, method: str) -> dict[str, Any]:
    """Keyword arguments of an untrained model of a method that takes no options (linear,
    narmax2): the inputs' and output's spans and :func:`output_lags_of`; a ValueError naming
    the options when ``spec`` (a ``ModelSpec``) has some."""
    if spec.options:
        raise ValueError(f"{method} takes no options, got {', '.join(spec.options)}")
    return {
        "input_spans": [v.span for v in spec.inputs],
        "output_span": spec.output.span,
        "output_lags": output_lags_of(spec.output.spec, [v.spec for v in spec.inputs]),
    }


class FreeRunCapabilities:
    """``capabilities`` of a method that can simulate its output from its own past outputs:
    on the class, what the method can do; on a model, ``free_run`` only if some input is a lag
    of the output (``output_lags``)."""

    def __init__(self, base: Capabilities) -> None:
        self.base = base

    def __get__(self, obj: Any, owner: type | None = None) -> Capabilities:
        if obj is None:
            return self.base
        lags = getattr(obj, "output_lags", None) or []
        return replace(self.base, free_run=self.base.free_run and any(d > 0 for d in lags))


def free_run(
    X: np.ndarray,
    output_lags: Sequence[int],
    spans: np.ndarray,
    predict_rows: Callable[[np.ndarray], np.ndarray],
) -> np.ndarray:
    """Output-error simulation: rows of ``X`` are consecutive samples; each input that is the
    output lagged by ``d`` (``output_lags[j] = d > 0``) is replaced by the model's own output
    ``d`` rows earlier (Laukonen et al., eqs. 7–11: the regression vectors carry the
    *estimates* ŷ(k−1), ŷ(k−2), …). Before the first ``d`` rows, and after a sample without
    an estimate (a missing input), the measured value starts the recursion again."""
    lags = np.asarray(output_lags, dtype=np.int64)
    cols = np.flatnonzero(lags > 0)
    X = as_2d(X)
    if cols.size == 0:
        return detail(X, spans, predict_rows).y
    n = X.shape[0]
    yhat = np.full(n, np.nan)
    lo, hi = spans[:, 0], spans[:, 1]
    x = np.empty((1, X.shape[1]))
    for k in range(n):
        x[0] = X[k]
        for j in cols:
            i = k - lags[j]
            if i >= 0 and np.isfinite(yhat[i]):
                x[0, j] = yhat[i]
        if np.isfinite(x).all():
            yhat[k] = predict_rows(np.clip(x, lo, hi))[0]
    return yhat


class SpanEstimator(ParamsMixin):
    """What the estimators fitted on nominal input spans share (``narmax2``, ``track``): an
    empty model from explicit spans, the spans in the state, the mean output standing in where
    an input is missing, and the fitted check. Subclasses set ``spans_``, ``output_span_`` and
    ``output_mean_`` and define ``_init``, ``partial_fit`` and ``predict``."""

    input_spans: Sequence[tuple[float, float]] | None

    def fit(self, X: Any, y: Any) -> Any:
        """A new model of all rows of ``X`` and ``y`` (rows with a NaN are skipped): the spans
        forgotten, then :meth:`partial_fit` on everything."""
        self.__dict__.pop("spans_", None)
        return self.partial_fit(X, y)

    def _set_spans(self, X: np.ndarray, y: np.ndarray | None) -> None:
        """``spans_`` (given, else the range of ``X``) and ``output_span_`` (given, else the
        range of ``y``, else unknown)."""
        self.spans_ = resolve_spans(self.input_spans, X)
        if getattr(self, "output_span", None) is not None:
            self.output_span_ = tuple(float(v) for v in self.output_span)
        elif y is not None and np.isfinite(y).any():
            self.output_span_ = observed_span(y)
        else:
            self.output_span_ = (float("nan"), float("nan"))

    def _merge_empty(self, other: Any) -> bool:
        """True when ``merge`` has nothing left to add: ``other`` untrained, or this model
        untrained and now a copy of ``other``."""
        if not hasattr(other, "spans_"):
            return True
        if not hasattr(self, "spans_"):
            self.__dict__.update(type(other).from_state(other.to_state()).__dict__)
            return True
        return False

    def init(self, n_features: int) -> Any:
        """An empty model for ``n_features`` inputs; needs explicit spans."""
        if self.input_spans is None:
            raise ValueError("init needs input_spans")
        self._init(np.zeros((0, n_features)))
        return self

    def _span_params(self) -> dict[str, Any]:
        """The constructor parameters with the spans as learned (for ``to_state``)."""
        self._check_fitted()
        params = self.get_params()
        params["input_spans"] = self.spans_.tolist()
        params["output_span"] = list(self.output_span_)
        return params

    def extrapolate(self, X: Any, pred: np.ndarray | None = None) -> np.ndarray:
        """The prediction (``pred``, where the caller has it: not computed again); the mean
        training output where an input is missing."""
        return mean_stand_in(self.predict(X) if pred is None else pred, self.output_mean_)

    def _check_fitted(self) -> None:
        if not hasattr(self, "spans_"):
            raise RuntimeError("this model is not trained yet: call fit or load a model file")
