"""Takagi–Sugeno fuzzy model identified by Fuzzy c-Means, and its model-file codec (``ts-fcm``).

Laukonen et al., Sect. II (after Sin and deFigueiredo):

* Rules (eq. 13): ``If H^j Then ŷ^j = c_0^j + c_1^j x_1 + … + c_n^j x_n``, ``j = 1 … N``.
* Premises by Fuzzy c-Means (eqs. 15–22): ``N`` cluster centres ``v_j`` minimising eq. 15,
  started from seeded random centres within the data's range (eq. 18), memberships (eq. 19)
  and centres (eq. 20) updated until no centre moves more than ``ε`` (eqs. 21–22).
* Consequents by weighted least squares per rule (eqs. 23–25), solved by QR over row chunks,
  never through the inverse of eq. 24.
* Inference: memberships of eq. 26 and the weighted average of the rule outputs (eq. 14).

Distances are measured with every input scaled to ``[0, 1]`` over its nominal span, so an
input in kPa does not outweigh one in %, and ``ε = 0.01`` means 1 % of span. Membership
exponent: the seed prints ``(‖x−v_j‖²/‖x−v_k‖²)^(m−1)`` in eqs. 17, 19 and 26; Bezdek's
necessary condition is ``^(1/(m−1))``. The two agree at the seed's ``m = 2``; we use Bezdek's.
Weights of the least squares: eq. 23 weights each squared error by ``μ_ij``, eq. 24 (its
stated solution) by ``μ_ij²`` (``D_j²``) — the seed contradicts itself. ``weight_power`` picks
the exponent: 2 (eq. 24, the default) or 1 (eq. 23); docs/explanation/engine.md compares the two.

Fitting is chunked over rows (memory stays flat in the number of rows) and vectorised. The
clustering needs all rows at every iteration, so the method is *not* incremental: ``fit`` only.

The file lists one rule per line in engineering units, inputs in ``[[inputs]]`` order::

    [rules]
    n_clusters = 10
    m = 2.0
    eps = 0.01
    max_iter = 300
    random_state = 0
    list = [
        { centre = [45.2, 1030.0], slope = [0.1203, -0.0034], const = 12.5, n = 5231 },
    ]
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numba as nb
import numpy as np

from diag_plugin.models.codec import RuleCodec
from diag_plugin.models.estimation import (
    CHUNK_ROWS,
    FreeRunCapabilities,
    as_2d,
    as_xy,
    detail,
    finite_rows,
    free_run,
    observed_span,
    output_lags_of,
    resolve_spans,
    solve_triangle,
    triangles,
)
from diag_plugin.models.fedrow import fed_row
from diag_plugin.models.params import ParamsMixin
from diag_plugin.models.protocol import (
    REASON_NAN,
    REASON_UNSUPPORTED,
    Capabilities,
    Prediction,
    mean_stand_in,
)
from diag_plugin.models.spec import ModelSpec

if TYPE_CHECKING:
    from diag_plugin.rulebase.document import RuleBase

log = logging.getLogger(__name__)

PARAMS = (
    "n_clusters",
    "m",
    "eps",
    "max_iter",
    "random_state",
    "weight_power",
    "input_spans",
    "output_span",
    "output_lags",
)
#: squared distance below which a sample sits on a centre (eq. 17's special case)
TINY = 1e-300


# ---------------------------------------------------------------- Fuzzy c-Means
def memberships(Z: np.ndarray, V: np.ndarray, m: float) -> np.ndarray:
    """Grade of membership of each row of ``Z`` in each cluster of centres ``V``
    (Laukonen et al., eqs. 17, 19 and 26; Bezdek's exponent ``1/(m−1)``). Rows sum to one; a
    row on a centre belongs to it alone."""
    d2 = (
        np.einsum("ij,ij->i", Z, Z)[:, None]
        - 2.0 * (Z @ V.T)
        + np.einsum("ij,ij->i", V, V)[None, :]
    )
    np.maximum(d2, TINY, out=d2)
    # ratios to the nearest centre keep the powers in range
    w = np.divide(d2.min(axis=1, keepdims=True), d2, out=d2)
    if m != 2.0:
        np.power(w, 1.0 / (m - 1.0), out=w)
    w /= w.sum(axis=1, keepdims=True)
    return w


#: row blocks of one Fuzzy c-Means pass, summed in a fixed order (same result on any
#: number of threads)
BLOCKS = 16


@nb.njit(cache=True, nogil=True)
def _ratios(d2, dmin, m):  # pragma: no cover - compiled
    """Eqs. 19 and 26 for one row, in place: each squared distance ``d2[j]`` becomes
    ``(dmin / d2[j])^(1/(m−1))`` (ratios to the nearest centre keep the powers in range);
    returns their sum, which divides them into the memberships."""
    expo = 1.0 / (m - 1.0)
    tot = 0.0
    for j in range(d2.size):
        w = dmin / d2[j]
        if m != 2.0:
            w = w**expo
        d2[j] = w
        tot += w
    return tot


@nb.njit(cache=True, nogil=True, parallel=True)
def _fcm_pass(X, lo, width, V, m, num, den):  # pragma: no cover - compiled
    """One pass of eqs. 19–20 over the rows of ``X`` (scaled by ``lo``, ``width``): per block of
    rows, ``Σ μ^m z`` into ``num[block]`` and ``Σ μ^m`` into ``den[block]``."""
    n, d = X.shape
    N = V.shape[0]
    nb_blocks = num.shape[0]
    size = (n + nb_blocks - 1) // nb_blocks
    for b in nb.prange(nb_blocks):
        z = np.empty(d)
        d2 = np.empty(N)
        for i in range(b * size, min(n, (b + 1) * size)):
            for k in range(d):
                z[k] = (X[i, k] - lo[k]) / width[k]
            dmin = np.inf
            for j in range(N):
                acc = 0.0
                for k in range(d):
                    t = z[k] - V[j, k]
                    acc += t * t
                acc = max(acc, 1e-300)
                d2[j] = acc
                dmin = min(dmin, acc)
            tot = _ratios(d2, dmin, m)
            for j in range(N):
                u = d2[j] / tot
                um = u * u if m == 2.0 else u**m
                den[b, j] += um
                for k in range(d):
                    num[b, j, k] += um * z[k]


@nb.njit(cache=True, nogil=True)
def _free_run_kernel(X, cols, lags, lo, hi, width, V, vv, coef, intercept, m):  # pragma: no cover
    """:func:`~diag_plugin.models.estimation.free_run` of the Takagi–Sugeno model compiled:
    row by row, each lag column ``cols[c]`` gets the estimate ``lags[c]`` rows earlier (the
    measured value before it exists or after a row without one), the row is clipped to its
    span, scaled (``lo``, ``width``) for the memberships of eq. 26 against the scaled centres
    ``V`` (``vv``: their squared norms) and its output is eq. 14 over the rules of eq. 13 in
    engineering units — the arithmetic of :func:`memberships` and ``_predict_rows``."""
    n, d = X.shape
    N = V.shape[0]
    yhat = np.full(n, np.nan)
    x = np.empty(d)
    z = np.empty(d)
    w = np.empty(N)
    for k in range(n):
        if not fed_row(X, k, cols, lags, yhat, x):
            continue
        zz = 0.0
        for j in range(d):
            x[j] = min(max(x[j], lo[j]), hi[j])
            z[j] = (x[j] - lo[j]) / width[j]
            zz += z[j] * z[j]
        dmin = np.inf
        for r in range(N):
            zv = 0.0
            for j in range(d):
                zv += z[j] * V[r, j]
            d2 = max(zz - 2.0 * zv + vv[r], TINY)
            w[r] = d2
            dmin = min(dmin, d2)
        tot = _ratios(w, dmin, m)
        y = 0.0
        for r in range(N):
            rule = intercept[r]
            for j in range(d):
                rule += x[j] * coef[r, j]
            y += w[r] / tot * rule
        yhat[k] = y
    return yhat


def initial_centres(lo: np.ndarray, hi: np.ndarray, n: int, rng: np.random.Generator):
    """``n`` random centres within the data's range per input (Laukonen et al., eq. 18)."""
    return lo + rng.random((n, lo.size)) * (hi - lo)


def fuzzy_c_means(
    X: np.ndarray,
    n_clusters: int,
    m: float = 2.0,
    eps: float = 0.01,
    max_iter: int = 300,
    random_state: int | None = 0,
    *,
    chunk: int = CHUNK_ROWS,
    scale: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, int]:
    """Cluster centres of the rows of ``X`` by Fuzzy c-Means (Laukonen et al., eqs. 15–22).

    ``scale = (lo, width)`` clusters ``(X − lo) / width`` (the centres are returned in that
    scale); rows are processed ``chunk`` at a time, so memory does not grow with the rows.
    Stops when no centre moves more than ``eps`` (eqs. 21–22) or after ``max_iter``
    iterations; returns the centres and the iterations run.
    """
    if m <= 1.0:
        raise ValueError(f"fuzziness m must be > 1, got {m}")
    n, d = X.shape
    if n < n_clusters:
        raise ValueError(f"{n_clusters} clusters need at least as many samples, got {n}")
    lo0, width = scale if scale is not None else (np.zeros(d), np.ones(d))
    lo, hi = np.full(d, np.inf), np.full(d, -np.inf)
    for s in range(0, n, chunk):
        Z = (X[s : s + chunk] - lo0) / width
        lo, hi = np.minimum(lo, Z.min(axis=0)), np.maximum(hi, Z.max(axis=0))
    V = initial_centres(lo, hi, n_clusters, np.random.default_rng(random_state))
    it = 0
    X = np.ascontiguousarray(X, dtype=np.float64)
    lo0 = np.ascontiguousarray(lo0, dtype=np.float64)
    width = np.ascontiguousarray(width, dtype=np.float64)
    for _ in range(max_iter):
        it += 1
        num = np.zeros((BLOCKS, n_clusters, d))
        den = np.zeros((BLOCKS, n_clusters))
        _fcm_pass(X, lo0, width, V, float(m), num, den)  # eq. 19, and the sums of eq. 20
        num, den = num.sum(axis=0), den.sum(axis=0)
        new = np.where(den[:, None] > 0, num / np.maximum(den, TINY)[:, None], V)  # eq. 20
        shift = float(np.sqrt(((new - V) ** 2).sum(axis=1)).max())
        V = new
        if shift <= eps:  # eq. 22
            break
    else:
        log.info("fuzzy c-means: no convergence to eps=%g in %d iterations", eps, max_iter)
    return V, it


# -------------------------------------------------------------- the estimator
class TakagiSugenoRegressor(ParamsMixin):
    """Takagi–Sugeno fuzzy model with Fuzzy c-Means premises (Laukonen et al., Sect. II).

    Parameters
    ----------
    n_clusters : int
        Clusters = rules ``N`` (the seed: 10).
    m : float
        Fuzziness factor (> 1; the seed: 2).
    eps : float
        Tolerance on the centres' moves, in units of the inputs' spans (the seed: 0.01).
    max_iter : int
        Iterations of Fuzzy c-Means at most.
    random_state : int or None
        Seed of the initial centres (eq. 18).
    weight_power : float
        Exponent ``p`` of the memberships weighting each rule's least squares,
        ``J_j = Σ_i μ_ij^p (c_jᵀ x̂_i − y_i)²``: 2 as eq. 24 solves it (``D_j²``, the
        default), 1 as eq. 23 writes the cost.
    input_spans, output_span : optional
        Nominal spans (by default the range seen in ``fit``); inputs outside are clipped and
        flagged.
    output_lags : sequence of int, optional
        Per input, ``d > 0`` if it is the output lagged by ``d`` samples (fed back by
        :meth:`simulate`).
    """

    _params = PARAMS

    capabilities = FreeRunCapabilities(
        Capabilities(incremental=False, mergeable=False, rule_regions=False, free_run=True)
    )

    def __init__(
        self,
        n_clusters: int = 10,
        m: float = 2.0,
        eps: float = 0.01,
        max_iter: int = 300,
        random_state: int | None = 0,
        weight_power: float = 2.0,
        input_spans: Sequence[tuple[float, float]] | None = None,
        output_span: tuple[float, float] | None = None,
        output_lags: Sequence[int] | None = None,
    ) -> None:
        self._keep(locals())

    # ---------------------------------------------------------------- training
    def fit(self, X: Any, y: Any) -> TakagiSugenoRegressor:
        """Premises by Fuzzy c-Means, then the consequents by weighted least squares
        (rows with a missing value are skipped)."""
        X, y = as_xy(X, y)
        d = X.shape[1]
        if self.output_lags is not None and len(self.output_lags) != d:
            raise ValueError(f"output_lags has {len(self.output_lags)} entries for {d} inputs")
        if not float(self.weight_power) > 0:
            raise ValueError(
                f"weight_power must be > 0 (eq. 23: 1, eq. 24: 2), got {self.weight_power}"
            )
        ok = finite_rows(X, y)
        if not ok.all():
            log.debug("ts-fcm: %d rows with a missing value skipped", int((~ok).sum()))
            X, y = X[ok], y[ok]
        self.spans_ = resolve_spans(self.input_spans, X)
        self.output_span_ = (
            tuple(float(v) for v in self.output_span)
            if self.output_span is not None
            else observed_span(y)
        )
        self.n_features_in_ = d
        lo, width = self._scale
        V, self.n_iter_ = fuzzy_c_means(
            X,
            int(self.n_clusters),
            float(self.m),
            float(self.eps),
            int(self.max_iter),
            self.random_state,
            scale=(lo, width),
        )
        V = V[np.lexsort(V.T[::-1])]  # rules in a stable, readable order
        self.centers_ = lo + V * width
        self._fit_consequents(X, y, V)
        self.n_samples_seen_ = int(y.size)
        self.output_mean_ = float(y.mean())
        return self

    def _fit_consequents(self, X: np.ndarray, y: np.ndarray, V: np.ndarray) -> None:
        """Per rule, weighted least squares of eqs. 23–25 (weights ``μ_ij^p``, ``p =
        weight_power``: ``D_j²`` of eq. 24 for 2, eq. 23's ``μ_ij`` for 1): the rows
        ``μ_ij^(p/2) [1, x_i | y_i]`` of all rules folded, chunk by chunk, into one triangular
        QR factor per rule (a stacked QR), in the scaled inputs; then converted to engineering
        units."""
        N, d = V.shape
        lo, width = self._scale
        R = np.zeros((N, 0, d + 2))
        weight = np.zeros(N)
        rows = max(CHUNK_ROWS // N, 1024)  # the stacked rows of all rules stay one chunk
        half = float(self.weight_power) / 2.0
        for s in range(0, X.shape[0], rows):
            Z = (X[s : s + rows] - lo) / width
            U = memberships(Z, V, float(self.m))
            weight += U.sum(axis=0)
            W = U if half == 1.0 else U**half  # row factors: squared, the weights μ^p
            Ab = np.column_stack([np.ones(Z.shape[0]), Z, y[s : s + rows]])
            R = triangles(np.concatenate([R, W.T[:, :, None] * Ab[None]], axis=1))
        c = np.array([solve_triangle(R[j]) for j in range(N)])  # N × (1 + d), scaled inputs
        self.coef_ = c[:, 1:] / width
        self.intercept_ = c[:, 0] - self.coef_ @ lo
        self.weight_ = weight

    def partial_fit(self, X: Any, y: Any) -> TakagiSugenoRegressor:
        """Fit on the first call; the clustering needs all rows at once, so a trained model
        cannot take more (``capabilities.incremental`` is False)."""
        if hasattr(self, "centers_"):
            raise NotImplementedError(
                "ts-fcm is not incremental: Fuzzy c-Means needs all rows; fit once on all data"
            )
        return self.fit(X, y)

    def merge(self, other: TakagiSugenoRegressor) -> TakagiSugenoRegressor:
        """Not available: clusterings of parts do not combine into the clustering of all."""
        raise NotImplementedError("ts-fcm models cannot be merged (capabilities.mergeable)")

    def set_rules(
        self,
        centres: np.ndarray,
        slopes: np.ndarray,
        consts: np.ndarray,
        weights: np.ndarray | None = None,
    ) -> TakagiSugenoRegressor:
        """Use explicit rules in engineering units (a model file); needs ``input_spans``."""
        centres = np.asarray(centres, dtype=np.float64)
        d = len(self.input_spans) if self.input_spans is not None else centres.shape[-1]
        self.spans_ = resolve_spans(self.input_spans, np.zeros((1, d)))
        self.output_span_ = (
            tuple(float(v) for v in self.output_span)
            if self.output_span is not None
            else (math.nan, math.nan)
        )
        self.n_features_in_ = d
        self.centers_ = centres.reshape(-1, d)
        self.coef_ = np.asarray(slopes, dtype=np.float64).reshape(-1, d)
        self.intercept_ = np.asarray(consts, dtype=np.float64).ravel()
        N = self.centers_.shape[0]
        self.weight_ = np.ones(N) if weights is None else np.asarray(weights, float).ravel()
        self.n_iter_ = 0
        self.n_samples_seen_ = int(round(float(self.weight_.sum()))) if weights is not None else 0
        self.output_mean_ = self._rules_mean()
        return self

    def _rules_mean(self) -> float:
        """Each rule's output at its centre, averaged by the rules' training weight: the
        stand-in mean of a model read from its rules."""
        if self.centers_.shape[0] == 0 or self.weight_.sum() <= 0:
            return math.nan
        at_centre = np.einsum("jk,jk->j", self.coef_, self.centers_) + self.intercept_
        return float(at_centre @ self.weight_ / self.weight_.sum())

    # ------------------------------------------------------------------ state
    def to_state(self) -> dict[str, Any]:
        """Parameters and learned rules as plain JSON values (no pickle)."""
        self._check_fitted()
        params = self.get_params()
        params["input_spans"] = self.spans_.tolist()
        params["output_span"] = list(self.output_span_)
        params["output_lags"] = None if self.output_lags is None else list(self.output_lags)
        return {
            "params": params,
            "centers": self.centers_.tolist(),
            "coef": self.coef_.tolist(),
            "intercept": self.intercept_.tolist(),
            "weight": self.weight_.tolist(),
            "n_iter": int(self.n_iter_),
            "n_samples_seen": int(self.n_samples_seen_),
            "output_mean": float(self.output_mean_),
        }

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> TakagiSugenoRegressor:
        """The model a :meth:`to_state` describes."""
        m = cls(**state["params"])
        m.set_rules(state["centers"], state["coef"], state["intercept"], state["weight"])
        m.n_iter_ = int(state["n_iter"])
        m.n_samples_seen_ = int(state["n_samples_seen"])
        m.output_mean_ = float(state["output_mean"])
        return m

    # --------------------------------------------------------------- inference
    @property
    def _scale(self) -> tuple[np.ndarray, np.ndarray]:
        return self.spans_[:, 0], self.spans_[:, 1] - self.spans_[:, 0]

    def _predict_rows(self, X: np.ndarray) -> np.ndarray:
        """Eq. 14 with the memberships of eq. 26 (they sum to one)."""
        lo, width = self._scale
        U = memberships((X - lo) / width, (self.centers_ - lo) / width, float(self.m))
        rules = X @ self.coef_.T + self.intercept_  # ŷ^j of eq. 13
        return np.einsum("ij,ij->i", U, rules)

    def predict_detail(self, X: Any) -> Prediction:
        """Prediction (one step ahead: inputs as measured) with a reason code per sample."""
        self._check_fitted()
        X = self._check_X(X)
        if self.centers_.shape[0] == 0:  # a file without rules
            reason = np.where(np.isfinite(X).all(axis=1), REASON_UNSUPPORTED, REASON_NAN)
            return Prediction(np.full(len(X), np.nan), np.zeros(len(X)), reason.astype(np.int8))
        return detail(X, self.spans_, self._predict_rows)

    def predict(self, X: Any) -> np.ndarray:
        """Model output (eq. 14); NaN where an input is missing."""
        return self.predict_detail(X).y

    def extrapolate(self, X: Any, pred: np.ndarray | None = None) -> np.ndarray:
        """The prediction (``pred``, where the caller has it: not computed again); the mean
        training output where there is none."""
        return mean_stand_in(self.predict(X) if pred is None else pred, self.output_mean_)

    def simulate(self, X: Any) -> np.ndarray:
        """Free-run (output-error) output over consecutive rows: inputs that are lags of the
        output get the model's own earlier outputs, as the seed's regression vectors
        (eqs. 7–11) carry the estimates ŷ(k−1), ŷ(k−2), …"""
        self._check_fitted()
        X = self._check_X(X)
        lags = np.asarray(self.output_lags or [0] * self.n_features_in_, dtype=np.int64)
        cols = np.flatnonzero(lags > 0)
        if cols.size == 0 or self.centers_.shape[0] == 0:
            return free_run(X, lags, self.spans_, self._predict_rows)
        lo, width = self._scale
        V = (self.centers_ - lo) / width
        return _free_run_kernel(
            np.ascontiguousarray(X, dtype=np.float64),
            cols,
            lags[cols],
            np.ascontiguousarray(lo),
            np.ascontiguousarray(self.spans_[:, 1]),
            np.ascontiguousarray(width),
            np.ascontiguousarray(V),
            np.einsum("ij,ij->i", V, V),
            np.ascontiguousarray(self.coef_, dtype=np.float64),
            np.ascontiguousarray(self.intercept_, dtype=np.float64),
            float(self.m),
        )

    @property
    def n_rules_(self) -> int:
        return int(self.centers_.shape[0])

    def _check_X(self, X: Any) -> np.ndarray:
        X = as_2d(X)
        if X.shape[1] != self.n_features_in_:
            raise ValueError(f"model has {self.n_features_in_} inputs, X has {X.shape[1]}")
        return X

    def _check_fitted(self) -> None:
        if not hasattr(self, "centers_"):
            raise RuntimeError("this model is not trained yet: call fit or load a model file")


# ------------------------------------------------------------------ the file codec
HEADER = """\
# Model file (diag-plugin), method ts-fcm: a Takagi-Sugeno fuzzy model whose rules come from
# Fuzzy c-Means clusters (Laukonen et al., eqs. 13-26). Edit by hand, then `diag rules check`.
# [rules] n_clusters, m (fuzziness), eps (tolerance, share of span), max_iter, random_state
# and weight_power (memberships^p weight each rule's least squares: 2 = eq. 24, 1 = eq. 23)
# set the training. One rule per line, values per input in [[inputs]] order:
# centre = cluster centre, slope and const = the rule's output const + slope . x (output
# unit), n = training weight of the rule (sum of memberships). Comments stay with a rule.
"""
OPTIONS: dict[str, Any] = {
    "n_clusters": 10,
    "m": 2.0,
    "eps": 0.01,
    "max_iter": 300,
    "random_state": 0,
    "weight_power": 2.0,
}
RULE_KEYS = {"centre", "slope", "const", "n"}


@dataclass
class TSRule:
    """One line of a Takagi–Sugeno model file."""

    centre: list[float]
    slope: list[float]
    const: float
    n: int = 0
    line: int = 0
    comments: list[str] = field(default_factory=list)
    trailing: str = ""


class TakagiSugenoCodec(RuleCodec):
    """Estimator factory and rule I/O of ``ts-fcm`` (c-means memberships and linear
    conclusions: no FCL form)."""

    method = "ts-fcm"
    estimator = TakagiSugenoRegressor
    header = HEADER

    def default_options(self) -> dict[str, Any]:
        """The training options a new file gets in its ``[rules]`` table (the seed's values)."""
        return dict(OPTIONS)

    def new_estimator(self, spec: ModelSpec) -> TakagiSugenoRegressor:
        """An untrained model with the file's options and spans."""
        unknown = set(spec.options) - set(OPTIONS)
        if unknown:
            raise ValueError(f"ts-fcm: unknown option(s) {', '.join(sorted(unknown))}")
        opts = {**OPTIONS, **spec.options}
        return TakagiSugenoRegressor(
            **opts,
            input_spans=[v.span for v in spec.inputs],
            output_span=spec.output.span,
            output_lags=output_lags_of(spec.output.spec, [v.spec for v in spec.inputs]),
        )

    def to_model(self, rb: RuleBase) -> TakagiSugenoRegressor:
        """The model the file describes; expert edits are used as written."""
        d = len(rb.inputs)
        rules = rb.rules
        return self.new_estimator(rb.spec).set_rules(
            np.array([r.centre for r in rules], float).reshape(-1, d),
            np.array([r.slope for r in rules], float).reshape(-1, d),
            np.array([r.const for r in rules], float),
            np.array([r.n for r in rules], float),
        )

    def apply_training(self, rb: RuleBase, model: TakagiSugenoRegressor) -> list[TSRule]:
        """The trained rules. Retraining re-clusters, so old rules have no successors: their
        comments are kept above the first rule rather than lost."""
        old_comments = [c for r in rb.rules for c in r.comments]
        old_comments += [r.trailing for r in rb.rules if r.trailing]
        out = [
            TSRule([float(v) for v in c], [float(v) for v in s], float(b), int(round(w)))
            for c, s, b, w in zip(
                model.centers_, model.coef_, model.intercept_, model.weight_, strict=True
            )
        ]
        if out:
            out[0].comments = old_comments
        return out

    def size(self, model: TakagiSugenoRegressor) -> int:
        """Rules of a trained model."""
        return model.n_rules_

    # ------------------------------------------------------------- file I/O
    def read_rules(
        self, rb: RuleBase, items: list, positions: Sequence[tuple[int, list[str], str]]
    ) -> list[TSRule]:
        """Options and rules from ``[rules]``; each problem goes to ``rb.error(line, …)``."""
        _check_options(rb)
        d = len(rb.inputs)
        out: list[TSRule] = []
        shape = "centre = [...], slope = [...], const = ..."
        for e in self.entries(rb, items, positions, "rule", RULE_KEYS, shape):
            item, line, where = e.item, e.line, e.where
            vecs = {}
            for key in ("centre", "slope"):
                v = item.get(key)
                if not isinstance(v, list) or not all(_is_num(x) for x in v):
                    rb.error(line, f"{where}: {key} must be a list of {d} numbers, got {v!r}")
                elif len(v) != d:
                    rb.error(line, f"{where}: {key} has {len(v)} values for {d} inputs")
                elif not all(math.isfinite(x) for x in v):
                    rb.error(line, f"{where}: {key} must be finite, got {v!r}")
                else:
                    vecs[key] = [float(x) for x in v]
            const = item.get("const")
            if not _is_num(const) or not math.isfinite(const):
                rb.error(line, f"{where}: const must be a finite number, got {const!r}")
            n = item.get("n", 0)
            if isinstance(n, bool) or not isinstance(n, int) or n < 0:
                rb.error(line, f"{where}: n must be a non-negative integer, got {n!r}")
            if len(rb.problems) > e.problems:
                continue
            out.append(
                TSRule(vecs["centre"], vecs["slope"], float(const), n, line, e.comments, e.trailing)
            )
        return out

    def rule_table(self, rb: RuleBase) -> tuple[list[str], list[list[str]]]:
        """Columns and rows for ``diag rules show``: per rule its centre, its output
        ``const + slope·x`` and its training weight."""
        specs = [v.spec for v in rb.inputs]
        cols = ["rule", *(f"centre {s}" for s in specs), "const"]
        cols += [f"slope {s}" for s in specs] + ["n"]
        rows = [
            [str(i + 1), *(f"{c:.5g}" for c in r.centre), f"{r.const:.5g}"]
            + [f"{c:.5g}" for c in r.slope]
            + [str(r.n)]
            for i, r in enumerate(rb.rules)
        ]
        return cols, rows

    def format_rules(self, rb: RuleBase) -> str:
        """The ``list = [...]`` text, one rule per line, comments kept."""

        def text(r: TSRule) -> str:
            centre = ", ".join(_num(v, 8) for v in r.centre)
            slope = ", ".join(_num(v, 10) for v in r.slope)
            return (
                f"{{ centre = [{centre}], slope = [{slope}], "
                f"const = {_num(r.const, 10)}, n = {r.n} }},"
            )

        return self.format_list(rb.rules, text)


def _check_options(rb: RuleBase) -> None:
    """The training options in ``[rules]``: known names, sensible values."""
    checks = {
        "n_clusters": (
            lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 1,
            "an integer ≥ 1",
        ),
        "m": (lambda v: _is_num(v) and v > 1, "a number > 1"),
        "eps": (lambda v: _is_num(v) and v > 0, "a number > 0"),
        "max_iter": (
            lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 1,
            "an integer ≥ 1",
        ),
        "random_state": (
            lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 0,
            "a non-negative integer",
        ),
        "weight_power": (lambda v: _is_num(v) and v > 0, "a number > 0 (eq. 23: 1, eq. 24: 2)"),
    }
    for key, value in rb.options.items():
        line = rb.line_of("rules", key)
        if key not in checks:
            rb.error(line, f"unknown ts-fcm option {key!r} (known: {', '.join(checks)})")
        elif not checks[key][0](value):
            rb.error(line, f"{key} must be {checks[key][1]}, got {value!r}")


def _is_num(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _num(v: float, digits: int) -> str:
    """A float as TOML with ``digits`` significant digits."""
    text = f"{v:.{digits}g}"
    return text if any(c in text for c in ".en") else text + ".0"
