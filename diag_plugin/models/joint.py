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

**Operating points** (``diag unit accept``): a period accepted at a new operating point
becomes a point of its own (``[rules] points``: per point the group's mean ``at``, its
constant's ``shift`` from the ``"1"`` term and its ``spread``). A row counts towards the point
nearest it in the inputs (scaled to their spans); per point the same QR statistics, so ``n``,
mean and scatter; ``v`` and ``s`` come from the pooled *within-point* covariance
``W = Σ_k (G_k − n_k m_k m_kᵀ)`` (:func:`within_component`) and each sample is scored against
its nearest point's mean, divided by that point's spread of the score relative to the
quietest point's (``Prediction.spread``). Over two points far apart the *total* covariance's
first component is the line between them, each point at one end: the test alarmed at both.
The models of parts merge into the model of all rows fitted with the same points.

Unlike a parity test, the joint test extrapolates: a common rise beyond what the window showed
is what it exists to see, so an input outside its span is neither clipped nor unknown.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from diag_plugin.models.estimation import QRLeastSquares, as_xy, finite_rows, spans_and_lags
from diag_plugin.models.linear import LinearCodec, LinearRegressor
from diag_plugin.models.narmax import PARAMS
from diag_plugin.models.protocol import REASON_NAN, REASON_OK, Prediction
from diag_plugin.models.spec import ModelSpec

if TYPE_CHECKING:
    from diag_plugin.rulebase.document import RuleBase

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


def _gram(qr: QRLeastSquares, k: int) -> np.ndarray:
    """``RᵀR`` of a factor over ``k`` columns (padded where fewer rows than columns)."""
    R = qr.R
    if R.shape[0] < k:  # fewer rows than variables: pad (Gram unchanged)
        R = np.vstack([R, np.zeros((k - R.shape[0], k))])
    return R.T @ R


def within_component(
    grams: list[np.ndarray],
) -> tuple[list[np.ndarray], np.ndarray, np.ndarray, np.ndarray]:
    """Per operating point its mean, and the standard deviations and first principal direction
    (of the correlation matrix, its largest entry positive) of the variables' *within-point*
    covariance: the scatter of each point's rows about that point's own mean, pooled
    (``W = Σ_k (G_k − n_k m_k m_kᵀ)``, the within-group scatter of a one-way analysis of
    variance). ``grams``: per point ``[1, u]ᵀ [1, u]`` over its rows. With one point it is
    :func:`first_component`; the spread *between* the points' means never enters ``v``.
    Last, per point the variance of its rows' score ``Σ v_i (u_i − m_i) / s_i`` (NaN for a
    point with fewer than two rows)."""
    k = grams[0].shape[0] - 1
    means, scatters = [], []
    n = 0.0
    for g in grams:
        nk = g[0, 0]
        m = g[0, 1:] / nk if nk > 0 else np.full(k, np.nan)
        means.append(m)
        scatters.append(g[1:, 1:] - nk * np.outer(m, m) if nk > 0 else np.zeros((k, k)))
        n += nk
    # W / n as Σ G_k / n − Σ (n_k / n) m_k m_kᵀ: with one point the bits of first_component
    n = max(n, 1.0)
    cov = sum(g[1:, 1:] for g in grams) / n
    cov = cov - sum((g[0, 0] / n) * np.outer(m, m) for g, m in zip(grams, means, strict=True)
                    if g[0, 0] > 0)  # fmt: skip
    s = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    s = np.where(s > 0, s, 1.0)
    w, V = np.linalg.eigh(cov / np.outer(s, s))
    v = V[:, -1]
    if v[np.argmax(np.abs(v))] < 0:
        v = -v
    a = v / s
    var = np.array([a @ S @ a / (g[0, 0] - 1) if g[0, 0] > 1 else np.nan
                    for S, g in zip(scatters, grams, strict=True)])  # fmt: skip
    return means, s, v, var


class JointRegressor(LinearRegressor):
    """The joint test of a group (module doc): inputs are the group's other tags, the output
    its first; the coefficients come from the group's first principal component, not from
    least squares. Parameters as :class:`~diag_plugin.models.linear.LinearRegressor`, and

    points : sequence of sequences of float, optional
        The operating points the test learned (``diag unit accept``), each the group's values
        there (the inputs, then the output; engineering units). Each training row belongs to
        the point nearest it in the inputs (scaled to their spans), and each sample is
        scored against the mean of its nearest point's rows; the component is the pooled
        *within-point* one (:func:`within_component`), and a sample's
        :attr:`~diag_plugin.models.protocol.Prediction.spread` is its point's spread of the
        score relative to the quietest point's (a unit's thresholds then judge each point
        by its own fault-free variation). None: one point (the build window).
    """

    _params = (*PARAMS, "points")

    def __init__(
        self,
        input_spans: Sequence[tuple[float, float]] | None = None,
        output_span: tuple[float, float] | None = None,
        output_lags: Sequence[int] | None = None,
        points: Sequence[Sequence[float]] | None = None,
    ) -> None:
        self._keep(locals())

    def _init(self, X: np.ndarray, y: np.ndarray | None = None) -> None:
        super()._init(X, y)
        d = X.shape[1]
        P = np.asarray(self.points if self.points else np.zeros((0, d + 1)), dtype=np.float64)
        if P.ndim != 2 or (len(P) and P.shape[1] != d + 1):
            raise ValueError(f"each point has the {d} inputs and the output, got {P.shape}")
        self.points_ = P
        # per point its own statistics; one point is the model's own (``qr_``)
        self.qrs_: list[QRLeastSquares] | None = [
            QRLeastSquares(len(self.terms_)) for _ in range(len(P) if len(P) >= 2 else 0)
        ]
        self._shift: np.ndarray | None = None
        self._spread: np.ndarray | None = None

    def nearest(self, X: np.ndarray) -> np.ndarray:
        """Per row the index of the nearest point, in the inputs scaled to their spans."""
        if len(self.points_) < 2:
            return np.zeros(X.shape[0], np.int64)
        A = self._scaled(self.points_[:, :-1])
        d2 = ((self._scaled(X)[:, None, :] - A[None, :, :]) ** 2).sum(axis=2)
        return np.argmin(d2, axis=1)

    def partial_fit(self, X: Any, y: Any) -> JointRegressor:
        """Add a chunk of rows, each to its nearest point's statistics."""
        X, y = as_xy(X, y)
        if hasattr(self, "spans_") and self.qrs_ is None:
            raise ValueError("this model was read from its coefficients: fit a new one")
        super().partial_fit(X, y)
        ok = finite_rows(X, y)
        X, y = X[ok], y[ok]
        at = self.nearest(X)
        for k, qr in enumerate(self.qrs_):
            rows = at == k
            if rows.any():
                qr.update(self._phi(self._scaled(X[rows])), y[rows])
        self._shift = None
        return self

    def merge(self, other: JointRegressor) -> JointRegressor:
        """Add the rows ``other`` was trained on (same spans and points): per point its
        statistics add, so the merged model is the model of all rows."""
        if self._merge_empty(other):
            return self
        if not np.array_equal(self.points_, other.points_):
            raise ValueError("cannot merge joint models with different operating points")
        super().merge(other)
        for a, b in zip(self.qrs_, other.qrs_, strict=True):
            a.merge(b)
        self._shift = None
        return self

    def _solve(self) -> None:
        k = len(self.terms_) + 1
        grams = [_gram(q, k) for q in (self.qrs_ or [self.qr_])]
        means, s, v, var = within_component(grams)
        vy = v[-1] if abs(v[-1]) > 1e-9 else 1e-9
        b = -s[-1] * v[:-1] / (vy * s[:-1])
        anchors = (
            np.column_stack([self._scaled(self.points_[:, :-1]), self.points_[:, -1]])
            if len(self.points_)
            else None
        )
        consts = []
        for j, m in enumerate(means):
            if not np.isfinite(m).all():  # a point without rows (held out): its own values
                m = anchors[j] if anchors is not None else np.zeros_like(s)
            consts.append(m[-1] - b @ m[:-1])
        self._coef = np.concatenate([[consts[0]], b])
        self._shift = np.asarray(consts) - consts[0]
        low = np.nanmin(var) if np.isfinite(var).any() and np.nanmin(var) > 0 else np.nan
        self._spread = np.where(np.isfinite(var) & (low > 0), np.sqrt(var / low), 1.0)

    @property
    def coef_scaled_(self) -> np.ndarray:
        self._check_fitted()
        if self._coef is None:
            self._solve()
        return self._coef

    def _per_point(self, attr: str, default: float) -> np.ndarray:
        self._check_fitted()
        if getattr(self, attr) is None:
            if self.qrs_ is None:
                return np.full(max(1, len(self.points_)), default)
            self._solve()
        return getattr(self, attr)

    @property
    def shifts_(self) -> np.ndarray:
        """Per point its constant less the first point's (the file's ``"1"`` term)."""
        return self._per_point("_shift", 0.0)

    @property
    def spreads_(self) -> np.ndarray:
        """Per point the spread of its score relative to the quietest point's (≥ 1)."""
        return self._per_point("_spread", 1.0)

    def _set_per_point(self, attr: str, values: Sequence[float]) -> JointRegressor:
        values = np.asarray(values, dtype=np.float64)
        k = max(1, len(self.points_))
        if values.shape != (k,):
            raise ValueError(f"expected {k} values, one per point, got {values.shape}")
        setattr(self, attr, values)
        return self

    def set_spreads(self, spreads: Sequence[float]) -> JointRegressor:
        """Each point's relative spread, as a model file gives them."""
        return self._set_per_point("_spread", spreads)

    def set_shifts(self, shifts: Sequence[float]) -> JointRegressor:
        """Each point's constant less the first's, as a model file gives them."""
        return self._set_per_point("_shift", shifts)

    def set_coefficients(self, coef: Sequence[float]) -> JointRegressor:
        super().set_coefficients(coef)
        self.qrs_ = None
        if self._shift is None:
            self._shift = np.zeros(max(1, len(self.points_)))
        return self

    def _predict_rows(self, X: np.ndarray) -> np.ndarray:
        y = super()._predict_rows(X)
        if len(self.points_) < 2:
            return y
        return y + self.shifts_[self.nearest(X)]

    def to_state(self) -> dict[str, Any]:
        state = super().to_state()
        state["params"]["points"] = self.points_.tolist() if len(self.points_) else None
        state["qrs"] = None if self.qrs_ is None else [q.to_state() for q in self.qrs_]
        state["shifts"] = None if self.qrs_ is not None else self.shifts_.tolist()
        state["spreads"] = None if self.qrs_ is not None else self.spreads_.tolist()
        return state

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> JointRegressor:
        m = super().from_state(state)
        k = max(1, len(m.points_))
        if m.qr_ is not None:
            m.qrs_ = [QRLeastSquares.from_state(q, len(m.terms_)) for q in state.get("qrs") or []]
        else:
            m.qrs_ = None
            m._shift = np.asarray(state.get("shifts") or np.zeros(k), np.float64)
            m._spread = np.asarray(state.get("spreads") or np.ones(k), np.float64)
        return m

    def predict_detail(self, X: Any) -> Prediction:
        """``ŷ`` wherever every input has a value, extrapolated (no span clips it)."""
        self._check_fitted()
        X = self._check_X(X)
        ok = np.isfinite(X).all(axis=1)
        y = np.full(X.shape[0], np.nan)
        if ok.any():
            y[ok] = self._predict_rows(X[ok])
        reason = np.where(ok, REASON_OK, REASON_NAN).astype(np.int8)
        spread = None
        if len(self.points_) >= 2:
            spread = np.full(X.shape[0], np.nan)
            spread[ok] = self.spreads_[self.nearest(X[ok])]
        return Prediction(y, ok.astype(np.float64), reason, spread=spread)


class JointCodec(LinearCodec):
    """Estimator factory and term I/O of ``joint`` (the ``linear`` file form)."""

    method = "joint"
    estimator = JointRegressor
    header = HEADER
    only = 'a joint test has only the constant "1" and its group\'s other tags'

    def new_estimator(self, spec: ModelSpec) -> JointRegressor:
        """An untrained model with the spec's spans and its ``[rules] points``."""
        opts = dict(spec.options)
        points = opts.pop(POINTS, None)
        kw = spans_and_lags(replace(spec, options=opts), self.method)
        return self.estimator(**kw, points=[p["at"] for p in points] if points else None)

    def check_options(self, rb: RuleBase) -> None:
        """``points`` is the one key ``[rules]`` takes: per point ``at`` (the inputs' and
        the output's values there), ``shift`` (its constant less the ``"1"`` term) and
        ``spread`` (its score's spread relative to the quietest point's)."""
        for key, value in rb.options.items():
            line = rb.line_of("rules", key)
            if key != POINTS:
                rb.error(line, f"{self.method} takes no option {key!r} in [rules]")
                continue
            width = len(rb.inputs) + 1
            ok = isinstance(value, list) and len(value) >= 2
            for p in value if ok else []:
                at = p.get("at") if isinstance(p, dict) else None
                shift = p.get("shift", 0.0) if isinstance(p, dict) else None
                spread = p.get("spread", 1.0) if isinstance(p, dict) else None
                ok = ok and set(p) <= {"at", "shift", "spread"} and isinstance(at, list)
                ok = ok and len(at) == width and all(_finite(v) for v in [*at, shift, spread])
                ok = ok and spread > 0
            if not ok:
                rb.error(
                    line,
                    f"[rules] points must be two or more {{ at = [...], shift = ..., spread = "
                    f"... }}, each "
                    f"'at' the {width - 1} input(s)' and the output's values (finite numbers)",
                )


#: the ``[rules]`` key of a joint test's operating points
POINTS = "points"


def _finite(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def set_points(
    rb: RuleBase,
    points: np.ndarray,
    shifts: Sequence[float],
    spreads: Sequence[float] | None = None,
) -> None:
    """Write ``[rules] points`` of a joint test's file (``rb``): per point ``at`` (the
    group's values there: inputs, then output), ``shift`` and ``spread``."""
    import tomlkit

    arr = tomlkit.array()
    spreads = np.ones(len(points)) if spreads is None else np.asarray(spreads, float)
    for at, sh, sp in zip(np.asarray(points, float), np.asarray(shifts, float), spreads,
                          strict=True):  # fmt: skip
        t = tomlkit.inline_table()
        t["at"] = [float(f"{v:.12g}") for v in at]
        t["shift"] = float(f"{sh:.12g}")
        t["spread"] = float(f"{sp:.12g}")
        arr.append(t)
    arr.multiline(True)
    rules = rb.doc["rules"]
    if POINTS in rules:
        rules[POINTS] = arr
    else:
        items = {k: rules[k] for k in list(rules)}
        for k in list(rules):
            del rules[k]
        rules[POINTS] = arr
        for k, v in items.items():
            rules[k] = v
    rb._dirty_head = True


class PointLinearRegressor(JointRegressor):
    """A ``linear`` parity test with operating points (``diag unit accept``): the tag
    against a least-squares combination of its inputs, the slopes fitted *within* the
    points (the pooled within-point scatter ``W``: ``b = W_xx⁻¹ W_xy``) and a constant per
    point (its means: ``c_k = m_yk − b · m_xk``), each sample predicted with its nearest
    point's constant (in the inputs, scaled to their spans) and its residual divided by
    that point's spread relative to the quietest point's. One least-squares line over two
    points far apart is the line *between* them: on SKAB (a unit from valve1/0's first
    400 s, anomaly-free's first hour accepted) Temperature against Thermocouple took a
    slope of 3.5 from the two points and its residual's spread at the build point doubled.
    Outside an input's span the prediction has no support, as a linear test's."""

    def _solve(self) -> None:
        k = len(self.terms_) + 1
        grams = [_gram(q, k) for q in (self.qrs_ or [self.qr_])]
        d = k - 2
        W = np.zeros((d + 1, d + 1))
        means, scatters = [], []
        for g in grams:
            n = g[0, 0]
            m = g[0, 1:] / n if n > 0 else np.full(d + 1, np.nan)
            S = g[1:, 1:] - n * np.outer(m, m) if n > 0 else np.zeros((d + 1, d + 1))
            means.append(m)
            scatters.append(S)
            W += S
        b = np.linalg.lstsq(W[:d, :d], W[:d, d], rcond=None)[0]
        consts = []
        for j, m in enumerate(means):
            if not np.isfinite(m).all():  # a point without rows (held out): its own values
                at = self.points_[j]
                m = np.concatenate([self._scaled(at[None, :-1])[0], at[-1:]])
            consts.append(m[-1] - b @ m[:-1])
        self._coef = np.concatenate([[consts[0]], b])
        self._shift = np.asarray(consts) - consts[0]
        a = np.concatenate([-b, [1.0]])
        var = np.array([a @ S @ a / (g[0, 0] - 1) if g[0, 0] > 1 else np.nan
                        for S, g in zip(scatters, grams, strict=True)])  # fmt: skip
        low = np.nanmin(var) if np.isfinite(var).any() and np.nanmin(var) > 0 else np.nan
        self._spread = np.where(np.isfinite(var) & (low > 0), np.sqrt(var / low), 1.0)

    def predict_detail(self, X: Any) -> Prediction:
        """As a linear test's (no support outside an input's span), with each sample's
        point's constant and spread."""
        p = LinearRegressor.predict_detail(self, X)
        Xc = self._check_X(X)
        ok = np.isfinite(Xc).all(axis=1)
        spread = np.full(Xc.shape[0], np.nan)
        if ok.any():
            spread[ok] = self.spreads_[self.nearest(Xc[ok])]
        return Prediction(p.y, p.support, p.reason, p.level, spread)
