"""Wang–Mendel fuzzy models: classic (max weight) and modified, averaged (default).

Kościelny, Syfert & Bartyś, Sect. 4.1–4.2. Every training sample generates the
rule whose premises are the max-membership sets of its inputs (eq. 3, eq. 4).

* ``method="wm-avg"`` (modified method, eq. 5): rules with equal premises get
  the *average* conclusion. We average the measured outputs themselves (the
  limit of eq. 5 for an arbitrarily fine output partition), so the output
  partition only labels the rules; per cell we keep count, sum and sum of
  squares, which makes training incremental (``partial_fit``), mergeable
  (``merge``) and exactly reproducible (integer accumulators, see
  :mod:`diag_plugin.fuzzy._kernels`).
* ``method="wm"`` (classic, eq. 2 and step 4): the conflicting rule with the
  largest weight ``w = μ_out(y)·Π μ_k(x_k)`` wins; its conclusion is the centre
  of the output set. Ties keep the earlier sample, also across ``merge``.

Inference is the weighted average of the fired rules' conclusions (centroid
of singleton conclusions), using only rules that exist. A sample whose fired
rules were all never trained is *unsupported*: its prediction is NaN, and
:meth:`WangMendelRegressor.predict_detail` says why.

The rule storage is sparse (sorted cell keys), so models with many inputs
never allocate the ``Π n_k`` grid; a dense look-up table is built only for
inference on small grids.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from diag_plugin.fuzzy import _kernels as K
from diag_plugin.fuzzy.partition import UniformPartition
from diag_plugin.models.params import ParamsMixin
from diag_plugin.models.protocol import (  # noqa: F401 - re-exported for callers
    REASON_NAN,
    REASON_OK,
    REASON_OUTSIDE,
    REASON_UNSUPPORTED,
    REASONS,
    Capabilities,
    Prediction,
)

METHODS = ("wm-avg", "wm")


class InferenceGrid(NamedTuple):
    """What inference reads of a fitted model: the input partitions as arrays and the rules
    sorted by key (see :meth:`WangMendelRegressor.inference_grid`)."""

    lo: np.ndarray
    step: np.ndarray
    nsets: np.ndarray
    plateau: np.ndarray
    radix: np.ndarray
    keys: np.ndarray
    conclusions: np.ndarray


#: the exact training state (see :meth:`WangMendelRegressor.to_state`)
STATE_ARRAYS = ("keys_", "count_", "qsum_", "qsq_", "best_w_", "best_set_")
PARAMS = ("input_spans", "output_span", "n_sets", "output_sets", "shape", "method")
#: grids up to this many cells train and infer through dense arrays
DENSE_LIMIT = 1 << 20
#: rows per compiled pass; bounds the memory of fit/predict
CHUNK_ROWS = 1 << 20
#: no cell may hold more samples than this (integer sum of squares stays exact)
MAX_CELL_COUNT = 1 << 29


def _as_2d(X) -> np.ndarray:
    X = np.asarray(X, dtype=np.float64)
    if X.ndim == 1:
        X = X[:, None]
    if X.ndim != 2:
        raise ValueError(f"X must be 2-D (samples × inputs), got shape {X.shape}")
    return np.ascontiguousarray(X)


class WangMendelRegressor(ParamsMixin):
    """Wang–Mendel fuzzy model of one output from ``d`` inputs.

    Parameters
    ----------
    input_spans : sequence of (lo, hi), optional
        Nominal span of each input; by default the range seen in the first
        ``fit``/``partial_fit`` call.
    output_span : (lo, hi), optional
        Nominal span of the output (residuals are in % of it, eq. 6).
    n_sets : int or sequence of int
        Sets per input (31 in the paper); a sequence gives one per input.
    output_sets : int
        Sets of the output partition (classic method's conclusions, labels).
    shape : {"trapezoidal", "triangular"}
    method : {"wm-avg", "wm"}
    """

    _params = PARAMS

    capabilities = Capabilities(incremental=True, mergeable=True, rule_regions=True)

    def __init__(
        self,
        input_spans: Sequence[tuple[float, float]] | None = None,
        output_span: tuple[float, float] | None = None,
        n_sets: int | Sequence[int] = 31,
        output_sets: int = 31,
        shape: str = "trapezoidal",
        method: str = "wm-avg",
    ) -> None:
        self.input_spans = input_spans
        self.output_span = output_span
        self.n_sets = n_sets
        self.output_sets = output_sets
        self.shape = shape
        self.method = method

    # ------------------------------------------------------------------ set-up
    def _init_partitions(self, X: np.ndarray, y: np.ndarray) -> None:
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {self.method!r}")
        d = X.shape[1]
        sets = [self.n_sets] * d if np.isscalar(self.n_sets) else list(self.n_sets)
        if len(sets) != d:
            raise ValueError(f"n_sets has {len(sets)} entries for {d} inputs")
        spans = self.input_spans
        if spans is None:
            spans = [_observed_span(X[:, k]) for k in range(d)]
        if len(spans) != d:
            raise ValueError(f"input_spans has {len(spans)} entries for {d} inputs")
        ospan = self.output_span if self.output_span is not None else _observed_span(y)
        self.partitions_ = [
            UniformPartition(float(lo), float(hi), int(n), self.shape)
            for (lo, hi), n in zip(spans, sets, strict=True)
        ]
        self.output_partition_ = UniformPartition(
            float(ospan[0]), float(ospan[1]), int(self.output_sets), self.shape
        )
        radix = np.ones(d, dtype=np.int64)
        total = 1
        for k in range(d - 1, -1, -1):
            radix[k] = total
            total *= self.partitions_[k].n
            if total >= 2**62:
                raise ValueError("rule grid too large: the product of set counts exceeds 2^62")
        self.radix_ = radix
        self.n_cells_ = total
        self.n_features_in_ = d
        self.keys_ = np.empty(0, np.int64)
        self.count_ = np.empty(0, np.int64)
        self.qsum_ = np.empty(0, np.int64)
        self.qsq_ = np.empty(0, np.int64)
        self.best_w_ = np.empty(0, np.float64)
        self.best_set_ = np.empty(0, np.int64)
        self.n_samples_seen_ = 0
        self.n_skipped_ = 0
        self._lut = None

    def _arrays(self):
        P = self.partitions_
        lo = np.array([p.lo for p in P])
        step = np.array([p.step for p in P])
        nsets = np.array([p.n for p in P], dtype=np.int64)
        plateau = np.array([p.plateau if p.shape == "trapezoidal" else 0.0 for p in P])
        core = np.array([p.core_halfwidth for p in P])
        return lo, step, nsets, plateau, core

    @property
    def _yquant(self) -> float:
        return self.output_partition_.span / K.QUANT

    # ---------------------------------------------------------------- training
    def fit(self, X, y) -> WangMendelRegressor:
        """Train from scratch on ``X`` (samples × inputs) and ``y``."""
        self.__dict__.pop("partitions_", None)  # partial_fit then starts afresh
        return self.partial_fit(X, y)

    def partial_fit(self, X, y) -> WangMendelRegressor:
        """Add a chunk of samples; equal to one ``fit`` on all chunks together."""
        X = _as_2d(X)
        y = np.ascontiguousarray(np.asarray(y, dtype=np.float64).ravel())
        if X.shape[0] != y.shape[0]:
            raise ValueError(f"X has {X.shape[0]} rows but y has {y.shape[0]}")
        if not hasattr(self, "partitions_"):
            self._init_partitions(X, y)
        elif X.shape[1] != self.n_features_in_:
            raise ValueError(f"model has {self.n_features_in_} inputs, X has {X.shape[1]}")
        for start in range(0, X.shape[0], CHUNK_ROWS):
            part = self._accumulate(X[start : start + CHUNK_ROWS], y[start : start + CHUNK_ROWS])
            self._merge_state(*part)
        self._lut = None
        return self

    def _accumulate(self, X: np.ndarray, y: np.ndarray):
        lo, step, nsets, _, core = self._arrays()
        op = self.output_partition_
        n = X.shape[0]
        if self.method == "wm":
            keys = np.empty(n, np.int64)
            w = np.empty(n, np.float64)
            yset = np.empty(n, np.int64)
            K.classic_weights(
                X,
                y,
                lo,
                step,
                core,
                nsets,
                self.radix_,
                op.lo,
                op.step,
                op.core_halfwidth,
                op.n,
                keys,
                w,
                yset,
            )
            ok = keys >= 0
            skipped = int(n - ok.sum())
            keys, w, yset = keys[ok], w[ok], yset[ok]
            # first occurrence of the maximal weight per cell (stable ordering)
            order = np.lexsort((np.arange(keys.size), -w, keys))
            keys, w, yset = keys[order], w[order], yset[order]
            first = np.r_[True, keys[1:] != keys[:-1]] if keys.size else np.zeros(0, bool)
            ukeys = keys[first]
            count = np.diff(np.r_[np.flatnonzero(first), keys.size]).astype(np.int64)
            empty = np.zeros(ukeys.size, np.int64)
            return ukeys, count, empty, empty, w[first], yset[first], skipped
        if self.n_cells_ <= DENSE_LIMIT:
            count = np.zeros(self.n_cells_, np.int64)
            qsum = np.zeros(self.n_cells_, np.int64)
            qsq = np.zeros(self.n_cells_, np.int64)
            skipped = K.accumulate_dense(
                X, y, lo, step, nsets, self.radix_, op.lo, self._yquant, count, qsum, qsq
            )
            keys = np.flatnonzero(count).astype(np.int64)
            return keys, count[keys], qsum[keys], qsq[keys], None, None, int(skipped)
        keys = np.empty(n, np.int64)
        qy = np.empty(n, np.int64)
        K.keys_and_quanta(X, y, lo, step, nsets, self.radix_, op.lo, self._yquant, keys, qy)
        ok = keys >= 0
        skipped = int(n - ok.sum())
        ukeys, inv = np.unique(keys[ok], return_inverse=True)
        q = qy[ok]
        count = np.bincount(inv, minlength=ukeys.size).astype(np.int64)
        qsum = np.zeros(ukeys.size, np.int64)
        qsq = np.zeros(ukeys.size, np.int64)
        np.add.at(qsum, inv, q)
        np.add.at(qsq, inv, q * q)
        return ukeys, count, qsum, qsq, None, None, skipped

    def _merge_state(self, keys, count, qsum, qsq, best_w, best_set, skipped) -> None:
        self.n_skipped_ += skipped
        self.n_samples_seen_ += int(count.sum())
        allk = np.union1d(self.keys_, keys)
        a = np.searchsorted(allk, self.keys_)
        b = np.searchsorted(allk, keys)
        new_count = np.zeros(allk.size, np.int64)
        new_count[a] += self.count_
        new_count[b] += count
        if new_count.size and new_count.max() > MAX_CELL_COUNT:
            raise OverflowError(
                f"a rule cell holds more than {MAX_CELL_COUNT} samples; "
                "split the training range or use more sets"
            )
        if self.method == "wm":
            w = np.full(allk.size, -1.0)
            s = np.zeros(allk.size, np.int64)
            w[a], s[a] = self.best_w_, self.best_set_
            take = best_w > w[b]  # strict: the earlier sample wins ties
            w[b[take]], s[b[take]] = best_w[take], best_set[take]
            self.best_w_, self.best_set_ = w, s
        else:
            new_sum = np.zeros(allk.size, np.int64)
            new_sq = np.zeros(allk.size, np.int64)
            new_sum[a] += self.qsum_
            new_sum[b] += qsum
            new_sq[a] += self.qsq_
            new_sq[b] += qsq
            self.qsum_, self.qsq_ = new_sum, new_sq
        self.keys_, self.count_ = allk, new_count
        self._conclusions = None

    def merge(self, other: WangMendelRegressor) -> WangMendelRegressor:
        """Add the training state of ``other`` (trained on later data) in place.

        Both models must have the same partitions and method. For the averaged
        method the result is exactly the model trained on both data sets.
        """
        if not hasattr(other, "partitions_"):
            return self
        if not hasattr(self, "partitions_"):
            self.__dict__.update(_copy_state(other))
            return self
        if (
            self.partitions_ != other.partitions_
            or self.output_partition_ != other.output_partition_
            or self.method != other.method
        ):
            raise ValueError("cannot merge models with different partitions or methods")
        self._merge_state(
            other.keys_,
            other.count_,
            other.qsum_,
            other.qsq_,
            other.best_w_,
            other.best_set_,
            other.n_skipped_,
        )
        self._lut = None
        return self

    def to_state(self) -> dict:
        """Parameters and exact training state as plain numbers and integer arrays (no pickle):
        ``from_state(m.to_state())`` predicts and merges exactly like ``m``."""
        self._check_fitted()
        params = self.get_params()
        params["input_spans"] = [[p.lo, p.hi] for p in self.partitions_]
        params["output_span"] = [self.output_partition_.lo, self.output_partition_.hi]
        params["n_sets"] = [p.n for p in self.partitions_]
        return {
            "params": params,
            **{k: getattr(self, k).copy() for k in STATE_ARRAYS},
            "n_samples_seen": int(self.n_samples_seen_),
            "n_skipped": int(self.n_skipped_),
        }

    @classmethod
    def from_state(cls, state: dict) -> WangMendelRegressor:
        """The model a :meth:`to_state` describes."""
        m = cls(**state["params"])
        m.init(len(state["params"]["n_sets"]))
        for k in STATE_ARRAYS:
            setattr(m, k, np.asarray(state[k], dtype=getattr(m, k).dtype))
        m.n_samples_seen_ = int(state["n_samples_seen"])
        m.n_skipped_ = int(state["n_skipped"])
        return m

    def init(self, n_features: int) -> WangMendelRegressor:
        """An empty trained state (no rules) for ``n_features`` inputs; needs explicit spans."""
        if self.input_spans is None or self.output_span is None:
            raise ValueError("init needs input_spans and output_span")
        self._init_partitions(np.zeros((1, n_features)), np.zeros(1))
        return self

    # ----------------------------------------------------------- rule access
    @property
    def conclusions_(self) -> np.ndarray:
        """Conclusion of each rule (engineering units), aligned with ``keys_``."""
        if getattr(self, "_conclusions", None) is None:
            if self.method == "wm":
                op = self.output_partition_
                self._conclusions = op.lo + op.step * self.best_set_
            else:
                mean_q = self.qsum_ / np.maximum(self.count_, 1)
                self._conclusions = self.output_partition_.lo + mean_q * self._yquant
        return self._conclusions

    @property
    def output_mean_(self) -> float:
        """Mean training output (rules weighted by their samples): the stand-in prediction
        where no rule covers a sample when errors are scored."""
        n = self.count_.sum() if hasattr(self, "count_") else 0
        return float(self.conclusions_ @ self.count_ / n) if n else float("nan")

    @property
    def sd_(self) -> np.ndarray:
        """Standard deviation of the training outputs in each rule cell."""
        n = np.maximum(self.count_, 1).astype(float)
        if self.method == "wm":
            return np.full(self.keys_.size, np.nan)
        mean = self.qsum_ / n
        var = np.maximum(self.qsq_ / n - mean * mean, 0.0)
        return np.sqrt(var) * self._yquant

    def cell_indices(self, keys: np.ndarray | None = None) -> np.ndarray:
        """Set index of every input for each rule key (rows × inputs)."""
        keys = self.keys_ if keys is None else np.asarray(keys, np.int64)
        out = np.empty((keys.size, self.n_features_in_), np.int64)
        rem = keys.copy()
        for k in range(self.n_features_in_):
            out[:, k], rem = np.divmod(rem, self.radix_[k])
        return out

    def regions(self, X) -> np.ndarray:
        """Rule cell of each sample: the max-membership set of every input (eq. 3), as keys."""
        self._check_fitted()
        X = _as_2d(X)
        cells = np.column_stack([p.nearest(X[:, k]) for k, p in enumerate(self.partitions_)])
        return self.cell_keys(cells) if len(cells) else np.empty(0, np.int64)

    def cell_keys(self, indices: np.ndarray) -> np.ndarray:
        """Rule keys of set-index rows (inverse of :meth:`cell_indices`)."""
        return np.asarray(indices, np.int64).reshape(-1, self.n_features_in_) @ self.radix_

    def set_rules(self, keys, conclusions, counts=None, sds=None) -> WangMendelRegressor:
        """Replace the rule base by explicit rules (e.g. read from an edited file).

        The per-cell statistics are rebuilt from count, conclusion and sd so
        that ``partial_fit`` can continue from a loaded model.
        """
        keys = np.asarray(keys, np.int64)
        order = np.argsort(keys, kind="stable")
        keys = keys[order]
        if keys.size and np.any(keys[1:] == keys[:-1]):
            raise ValueError("duplicate rule premises")
        conc = np.asarray(conclusions, float)[order]
        n = np.ones(keys.size, np.int64) if counts is None else np.asarray(counts, np.int64)[order]
        sd = np.zeros(keys.size) if sds is None else np.nan_to_num(np.asarray(sds, float)[order])
        op = self.output_partition_
        mean_q = (conc - op.lo) / self._yquant
        sd_q = sd / self._yquant
        self.keys_, self.count_ = keys, n
        self.qsum_ = np.rint(mean_q * n).astype(np.int64)
        self.qsq_ = np.rint(n * (sd_q**2 + mean_q**2)).astype(np.int64)
        self.best_w_ = np.ones(keys.size)
        self.best_set_ = op.nearest(conc)
        # explicit conclusions are used as written, not re-derived from the sums
        self._conclusions = conc
        self._lut = None
        return self

    # --------------------------------------------------------------- inference
    def _lookup(self):
        if self._lut is None:
            if self.n_cells_ <= DENSE_LIMIT:
                lut = np.full(self.n_cells_, np.nan)
                lut[self.keys_] = self.conclusions_
            else:
                lut = np.empty(0)
            self._lut = lut
        return self._lut

    def predict_detail(self, X) -> Prediction:
        """Prediction with support and a reason code for each sample."""
        self._check_fitted()
        X = _as_2d(X)
        if X.shape[1] != self.n_features_in_:
            raise ValueError(f"model has {self.n_features_in_} inputs, X has {X.shape[1]}")
        lo, step, nsets, plateau, _ = self._arrays()
        out = np.empty(X.shape[0])
        sup = np.empty(X.shape[0])
        reason = np.empty(X.shape[0], np.int8)
        lut = self._lookup()
        conc = np.ascontiguousarray(self.conclusions_, dtype=np.float64)
        for s in range(0, X.shape[0], CHUNK_ROWS):
            e = s + CHUNK_ROWS
            K.infer(
                X[s:e],
                lo,
                step,
                plateau,
                nsets,
                self.radix_,
                self.keys_,
                conc,
                lut,
                out[s:e],
                sup[s:e],
                reason[s:e],
            )
        return Prediction(out, sup, reason)

    def predict(self, X) -> np.ndarray:
        """Model output; NaN where no trained rule covers the sample."""
        return self.predict_detail(X).y

    def extrapolate(self, X) -> np.ndarray:
        """A value for every sample: the prediction where the model has one, else the
        conclusion of the nearest trained rule (set centres in units of set spacing).

        Used only to *score* samples the model does not cover (so an error figure
        counts every sample); the model itself still reports them as unsupported.
        """
        X = _as_2d(X)
        y = self.predict(X)
        miss = np.flatnonzero(~np.isfinite(y) & np.isfinite(X).all(axis=1))
        if miss.size and self.keys_.size:
            from scipy.spatial import cKDTree

            steps = np.array([p.step for p in self.partitions_])
            lo = np.array([p.lo for p in self.partitions_])
            cells = self.cell_indices().astype(float)
            tree = cKDTree(cells)
            _, j = tree.query((X[miss] - lo) / steps)
            y[miss] = self.conclusions_[j]
        return y

    def coverage(self, X) -> float:
        """Share of samples of ``X`` covered by trained rules."""
        return self.predict_detail(X).coverage

    def inference_grid(self) -> InferenceGrid:
        """Partitions and rules as flat arrays, for evaluators that run many models at once
        (:class:`diag_plugin.fuzzy.stack.WangMendelStack`); ``keys`` ascending."""
        self._check_fitted()
        lo, step, nsets, plateau, _ = self._arrays()
        order = np.argsort(self.keys_, kind="stable")
        return InferenceGrid(
            lo,
            step,
            nsets,
            plateau,
            self.radix_.copy(),
            np.asarray(self.keys_, np.int64)[order],
            np.asarray(self.conclusions_, np.float64)[order],
        )

    def _check_fitted(self) -> None:
        if not hasattr(self, "partitions_"):
            raise RuntimeError("this model is not trained yet: call fit or load a rule base")

    @property
    def n_rules_(self) -> int:
        return int(self.keys_.size)


def _observed_span(v: np.ndarray) -> tuple[float, float]:
    v = v[np.isfinite(v)]
    if v.size == 0:
        raise ValueError("cannot infer a span from data that is all NaN")
    lo, hi = float(v.min()), float(v.max())
    if hi <= lo:
        hi = lo + max(abs(lo), 1.0) * 1e-3
    return lo, hi


def _copy_state(m: WangMendelRegressor) -> dict:
    state = dict(m.__dict__)
    for k, v in state.items():
        if isinstance(v, np.ndarray):
            state[k] = v.copy()
    state["partitions_"] = list(m.partitions_)
    return state
