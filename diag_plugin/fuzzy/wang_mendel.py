"""Wang–Mendel fuzzy models: classic (max weight) and modified, averaged (default).

Kościelny, Syfert & Bartyś, Sect. 4.1–4.2. Every training sample generates the
rule whose premises are the max-membership sets of its inputs (eq. 3, eq. 4).

* ``method="wm-avg"`` (modified method, eq. 5): rules with equal premises get
  the *average* conclusion. By default (``conclusion="mean"``) we average the
  measured outputs themselves (the limit of eq. 5 for an arbitrarily fine
  output partition), so the output partition only labels the rules;
  ``conclusion="sets"`` is eq. 5 as printed: each sample's conclusion is the
  centre of its output's max-membership set (eq. 3 applied to ``y``), and the
  cell averages those centres. Per cell we keep count, sum and sum of
  squares, which makes training incremental (``partial_fit``), mergeable
  (``merge``) and exactly reproducible (integer accumulators, see
  :mod:`diag_plugin.fuzzy._kernels`).
* ``method="wm"`` (classic, eq. 2 and step 4): the conflicting rule with the
  largest weight ``w = μ_out(y)·Π μ_k(x_k)`` wins; its conclusion is the centre
  of the output set. Ties keep the earlier sample, also across ``merge``.

Inference is the weighted average of the fired rules' conclusions (centroid
of singleton conclusions), using only rules that exist.

**Coarser levels behind the fine grid** (``levels``). A thin grid leaves many
cells without a rule. Level ``l`` groups ``2^l`` neighbouring fine sets of
each input into one coarse set (inputs stop halving at 2 sets); a sample's
coarse cell is its fine cell ``// 2^l``, so the coarse rules are the group-by
of the fine cells' exact integer accumulators (count, sum, sum of squares):
eq. 5 on bigger cells, exactly what training each coarser grid on the same
samples would give, under any chunking and merge. They are derived from the
fine rules, never stored. The firing weight the fine rules do not carry passes
to the next coarser level (see :func:`._kernels.infer_levels`): where the fine
rules carry it all, the answer is the fine grid's; where the fine cell has no
rule, coarser cells answer, and :meth:`WangMendelRegressor.predict_detail`
says at which level. Coarse levels answer only inside the range of the
training data (per input, the first to the last fine set holding data); beyond
it the fine grid alone answers. A sample no level's rules reach is
*unsupported*: NaN, with a reason code. ``levels=0`` is the paper's fine grid
alone.

**No level bridges a gap in one input** (:meth:`WangMendelRegressor.input_gaps`, issue 34
item 5). Inside that range an input's marginal occupancy (the fine sets holding data, summed
over the other inputs) may have a run of empty sets: a set-point held at a few values (a
pasteuriser's production rates and its cleaning flow), a plant run in two regimes. The coarse
cells straddle it and fill it by interpolating between values the plant was never seen
between; the answer there is not support. A run of ``g`` empty sets is such a gap where the
data, had it kept the density of the thinner of its two edge sets (``m`` samples) across the
run, would have put more samples in it than the input's typical occupied set holds (the median
over its occupied sets, ``M``): ``g·m > M``. A continuous input's sparse tail (edge sets of a
few samples against a core of thousands) is bridged as before; a value held for hours on both
sides of an empty run is not. Only the inputs in :attr:`WangMendelRegressor.unbridged` are
judged so (none by default: the levels answer as before); a unit that runs in regimes (two
or more learned combinations of its discrete states) marks the inputs an operator chooses
(set-points, hand valves, states), where a gap is where the plant changes regime (the
pasteuriser's production rates and its cleaning flow), and leaves a measured input's
bridged (a fault may move it into a gap, and the bridged answer is what detects it). A
sample whose own fine set of a marked input is in such a gap is answered by the fine grid
alone (its rules carry at most the neighbouring set's membership, so under
``LEVEL_SUPPORT``); an answer of a coarse level there is withdrawn: NaN, reason
*gap* (:data:`~diag_plugin.models.protocol.REASON_GAP`).

**Past the span, along the data's slope** (:attr:`WangMendelRegressor.trend_`, the
least-squares plane through the fine rules, derived like the levels and never stored). An
input past its span is clipped to it as before (reason *outside*), and the answer then moves
by the trend's slope times the distance past the span's end, for up to
:data:`~._numpy_kernels.REACH` of the span (then it holds). Inside the spans the answer is
unchanged, bit for bit.

The rule storage is sparse (sorted cell keys), so models with many inputs
never allocate the ``Π n_k`` grid; a dense look-up table is built only for
inference on small grids.
"""

from __future__ import annotations

import contextlib
import contextvars
import functools
import sys
from collections.abc import Iterator, Sequence
from types import ModuleType
from typing import NamedTuple

import numpy as np

from diag_plugin.fuzzy import _numpy_kernels as N
from diag_plugin.fuzzy.partition import UniformPartition
from diag_plugin.models.estimation import observed_span
from diag_plugin.models.params import ParamsMixin
from diag_plugin.models.protocol import (  # noqa: F401 - re-exported for callers
    REASON_GAP,
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
    """What inference reads of a fitted model: the input partitions as arrays and, per level
    (0 = the fine grid), the fine sets per coarse set, the keys' radix and the rules sorted by
    key (see :meth:`WangMendelRegressor.inference_grid`)."""

    lo: np.ndarray
    step: np.ndarray
    nsets: np.ndarray
    plateau: np.ndarray
    inner: np.ndarray  # (d, 2): first and last fine set of each input holding training data
    trend: np.ndarray  # (d + 1,): the model's linear trend b0, b1 … bd (:attr:`trend_`)
    blocks: np.ndarray  # (levels, d)
    radix: np.ndarray  # (levels, d)
    keys: list[np.ndarray]
    conclusions: list[np.ndarray]
    data: list[np.ndarray]  # per node: its own cell holds training data
    spreads: list[np.ndarray]  # per node: its outputs' spread relative to the model's


class LevelRules(NamedTuple):
    """The rules of one level: keys (ascending), conclusions, training samples and their
    standard deviation per cell."""

    keys: np.ndarray
    conclusions: np.ndarray
    count: np.ndarray
    sd: np.ndarray


def occupancy_gaps(counts: np.ndarray) -> np.ndarray:
    """The gaps of one input no level bridges (module doc), from its samples per fine set
    ``counts``: rows ``(a, b)`` of occupied sets with ``g = b - a - 1 > 0`` empty ones between
    them where ``g · min(counts[a], counts[b])`` exceeds the median count of the occupied
    sets. A set-point held at a few values leaves gaps between them; a continuous input's
    sparse tail (a few samples per set at the edge) none."""
    counts = np.asarray(counts, float)
    occ = np.flatnonzero(counts > 0)
    if occ.size < 2:
        return np.empty((0, 2), np.int64)
    a, b = occ[:-1], occ[1:]
    empty = b - a - 1
    wide = empty * np.minimum(counts[a], counts[b]) > np.median(counts[occ])
    return np.column_stack([a[wide], b[wide]]).astype(np.int64)


def rows_in_gap(
    X: np.ndarray, lo: np.ndarray, step: np.ndarray, nsets: np.ndarray, gaps: Sequence[np.ndarray]
) -> np.ndarray:
    """Rows of ``X`` whose own fine set of some input ``k`` (max membership, the value
    clipped to the span, as the kernels take it; NaN: none) lies strictly between the two
    occupied sets of one of ``gaps[k]`` (:func:`occupancy_gaps`)."""
    out = np.zeros(X.shape[0], bool)
    for k, g in enumerate(gaps):
        if not g.size:
            continue
        x = X[:, k]
        hi = lo[k] + step[k] * (nsets[k] - 1)
        i = np.minimum(np.floor((np.clip(x, lo[k], hi) - lo[k]) / step[k] + 0.5), nsets[k] - 1)
        at = np.searchsorted(g[:, 0], i, side="left") - 1  # the last gap opening below i
        ok = (at >= 0) & ~np.isnan(x)
        out[ok] |= i[ok] < g[at[ok], 1]
    return out


def withdraw(det: Prediction, rows: np.ndarray) -> None:
    """Withdraw the answers of ``rows`` of ``det`` in place: an input in a gap no level
    bridges (NaN, support 0, level -1, reason :data:`REASON_GAP`)."""
    if not rows.size:
        return
    det.y[rows] = np.nan
    det.support[rows] = 0.0
    det.reason[rows] = REASON_GAP
    if det.level is not None:
        det.level[rows] = -1
    if det.spread is not None:
        det.spread[rows] = np.nan


def level_blocks(nsets: Sequence[int], levels: int | None = None) -> np.ndarray:
    """Fine sets per coarse set, per level and input: level ``l`` halves every input ``l``
    times, an input stopping once it has 2 sets (``ceil(n / b) = 2``); there are as many levels
    as halvings of the input with most sets, at most ``levels`` beyond the fine one."""
    n = np.asarray(nsets, np.int64)
    stops = np.zeros(n.size, np.int64)
    for k, nk in enumerate(n):
        while -(-nk // (1 << stops[k])) > 2:
            stops[k] += 1
    deepest = int(stops.max()) if stops.size else 0
    if levels is not None:
        deepest = min(deepest, int(levels))
    lv = np.arange(deepest + 1)[:, None]
    return (1 << np.minimum(lv, stops[None, :])).astype(np.int64)


def _radix(nsets: np.ndarray) -> np.ndarray:
    radix = np.ones(nsets.size, dtype=np.int64)
    total = 1
    for k in range(nsets.size - 1, -1, -1):
        radix[k] = total
        total *= int(nsets[k])
    return radix


def pack(grids: Sequence[InferenceGrid], dense: bool) -> tuple:
    """The arrays :func:`._kernels.infer_levels` reads for several models (row ``i`` of the
    result describes ``grids[i]``); ``dense``: levels up to :data:`DENSE_LIMIT` cells get a
    look-up table (one model's inference), else every level is searched (a stack of many)."""
    m = len(grids)
    d_max = max((g.lo.size for g in grids), default=1)
    l_max = max((g.blocks.shape[0] for g in grids), default=1)
    n_inputs = np.array([g.lo.size for g in grids], np.int64)
    lo = np.zeros((m, d_max))
    step = np.ones((m, d_max))
    plateau = np.zeros((m, d_max))
    nsets = np.full((m, d_max), 2, np.int64)
    inner = np.zeros((m, d_max, 2), np.int64)
    trend = np.zeros((m, d_max + 1))
    blocks = np.ones((m, l_max, d_max), np.int64)
    radix = np.zeros((m, l_max, d_max), np.int64)
    n_levels = np.array([g.blocks.shape[0] for g in grids], np.int64)
    seg = np.zeros((m, l_max, 2), np.int64)
    dense_at = np.full((m, l_max), -1, np.int64)
    keys, values, spreads, data, tables = [], [], [], [], []
    at = 0
    dense_len = 0
    for i, g in enumerate(grids):
        d = g.lo.size
        lo[i, :d], step[i, :d], nsets[i, :d], plateau[i, :d] = g.lo, g.step, g.nsets, g.plateau
        inner[i, :d] = g.inner
        trend[i, : d + 1] = g.trend
        L = g.blocks.shape[0]
        blocks[i, :L, :d], radix[i, :L, :d] = g.blocks, g.radix
        for lv in range(L):
            k = g.keys[lv]
            seg[i, lv] = at, at + k.size
            keys.append(k)
            values.append(g.conclusions[lv])
            spreads.append(g.spreads[lv])
            data.append(g.data[lv])
            cells = int(np.prod(-(-g.nsets // g.blocks[lv])))
            if dense and cells <= DENSE_LIMIT:
                t = np.full(cells, -1, np.int64)
                t[k] = np.arange(at, at + k.size)
                dense_at[i, lv] = dense_len
                dense_len += cells
                tables.append(t)
            at += k.size
    cat_k = np.concatenate(keys) if keys else np.empty(0, np.int64)
    cat_v = np.concatenate(values) if values else np.empty(0)
    cat_s = np.concatenate(spreads) if spreads else np.empty(0)
    cat_f = np.concatenate(data) if data else np.empty(0, np.bool_)
    cat_d = np.concatenate(tables) if tables else np.empty(0, np.int64)
    return (n_inputs, lo, step, plateau, nsets, inner, trend, blocks, radix, n_levels, seg,
            dense_at, cat_k, cat_v, cat_s, cat_f, cat_d, LEVEL_SUPPORT)  # fmt: skip


def kernels(rows: int | None = None) -> ModuleType:
    """The loops that run a call on ``rows`` rows: numpy (:mod:`._numpy_kernels`: one model's
    inference, the dense accumulation) for fewer than :data:`NUMPY_ROWS` while numba is not
    loaded, else (and for a loop numpy lacks, ``rows`` None) the compiled ones
    (:mod:`._kernels`). Both give the same bits."""
    if rows is not None and rows < NUMPY_ROWS and "numba" not in sys.modules:
        return N
    from diag_plugin.fuzzy import _kernels

    return _kernels


def _fields(det: Prediction) -> tuple[np.ndarray, ...]:
    return det.y, det.support, det.reason, det.level, det.spread


def run_kernel(
    packed: tuple, which: np.ndarray, X: np.ndarray, prior: Prediction | None = None,
    first: int = 0,
) -> Prediction:  # fmt: skip
    """Prediction, support, reason and level per row of ``X`` by the packed models.

    ``first`` > 0 (one model, compiled loops): the levels from ``first`` on only, continuing
    ``prior``, the answer of the finer levels for the same rows, none of them reaching
    ``LEVEL_SUPPORT`` (see :func:`._kernels.infer_levels`); ``prior``'s arrays are written
    in place and returned."""
    n = X.shape[0]
    if first:
        assert prior is not None and not which.size
        out, sup, reason, level, spread = _fields(prior)
        loops = kernels(None)
    else:
        out = np.empty(n)
        sup = np.empty(n)
        reason = np.empty(n, np.int8)
        level = np.empty(n, np.int8)
        spread = np.empty(n)
        loops = kernels(None if which.size else n)  # numpy: one model's inference
    fields = (out, sup, reason, level, spread)
    for s in range(0, n, CHUNK_ROWS):
        e = s + CHUNK_ROWS
        if n <= CHUNK_ROWS:  # one call on the arrays themselves (no slices to make)
            rows, Xs, args = which, X, fields
        else:
            rows = which[s:e] if which.size else which
            Xs, args = X[s:e], tuple(f[s:e] for f in fields)
        if first:
            loops.infer_levels(rows, Xs, *packed, *args, first)
        else:
            loops.infer_levels(rows, Xs, *packed, *args)
    return Prediction(out, sup, reason, level, spread)


#: the exact training state (see :meth:`WangMendelRegressor.to_state`)
STATE_ARRAYS = ("keys_", "count_", "qsum_", "qsq_", "best_w_", "best_set_")
PARAMS = (
    "input_spans",
    "output_span",
    "n_sets",
    "output_sets",
    "shape",
    "method",
    "levels",
    "conclusion",
)
#: what a wm-avg cell averages: the measured outputs, or the centres of their output sets
CONCLUSIONS = ("mean", "sets")
#: grids up to this many cells train and infer through dense arrays
DENSE_LIMIT = 1 << 20
#: rows per compiled pass; bounds the memory of fit/predict
CHUNK_ROWS = 1 << 20
#: a call on fewer rows runs in numpy while numba is not loaded (:func:`kernels`): numba's
#: import and compiled-code load cost ≈ 0.6 s CPU, numpy's inference ≈ 0.25 µs a row more
#: than numba's (3 inputs, bench_train and benchmarks/bench_kernels.py)
NUMPY_ROWS = 1 << 21
#: no cell may hold more samples than this (integer sum of squares stays exact)
MAX_CELL_COUNT = 1 << 29
#: a level answers a sample where its rules carry at least this share of the firing weight
#: (the unit's default ``min_support``); else the next coarser level is asked
LEVEL_SUPPORT = 0.9
#: ridge on the linear trend's slopes (:attr:`WangMendelRegressor.trend_`), a share of each
#: input's weighted sum of squares about its mean over the fine rules
TREND_RIDGE = 1e-3
#: weight of the smoothness prior of a coarse level's node fit, relative to the data per node
SMOOTHING = 0.1
#: samples' worth of the model's typical spread a cell's own spread is pooled with
SPREAD_PRIOR = 5.0
#: a coarse level's node fit is solved with dense arrays where its normal equations and solve
#: cost at most this many multiply-adds (:func:`dense_node_fit`), else with scipy.sparse
DENSE_FLOPS = 1 << 27
#: ... and its dense design matrix (fine rules × nodes) holds at most this many entries
DENSE_CELLS = 1 << 22
#: coarse levels whose fit would weigh more (fine rules × 2^inputs) stay silent
FIT_LIMIT = 1 << 20
#: a prediction of more rows than this asks every level of all of them once more than half
#: of them need a coarse level (instead of copying the rows asked)
LAZY_ROWS = 1 << 16
#: from this many rows a call asks its rows' coarser levels all in one kernel call (packing
#: every level once, on the model's first such call): a replay's 7-day pieces, not a live
#: loop's single rows
ALL_LEVELS_ROWS = 1 << 10


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
    levels : int, optional
        Coarser levels behind the fine grid (see the module doc); by default as many as
        halving allows (31 sets: 16, 8, 4, 2); 0 = the fine grid alone.
    conclusion : {"mean", "sets"}
        What ``wm-avg`` averages per cell (eq. 5): the measured outputs (default) or, as
        the paper prints it, the centres of their max-membership output sets.
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
        levels: int | None = None,
        conclusion: str = "mean",
    ) -> None:
        self._keep(locals())

    # ------------------------------------------------------------------ set-up
    def _init_partitions(self, X: np.ndarray, y: np.ndarray) -> None:
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {self.method!r}")
        if self.conclusion not in CONCLUSIONS:
            raise ValueError(f"conclusion must be one of {CONCLUSIONS}, got {self.conclusion!r}")
        if self.levels is not None and (isinstance(self.levels, bool) or int(self.levels) < 0):
            raise ValueError(f"levels must be a non-negative integer, got {self.levels!r}")
        d = X.shape[1]
        sets = [self.n_sets] * d if np.isscalar(self.n_sets) else list(self.n_sets)
        if len(sets) != d:
            raise ValueError(f"n_sets has {len(sets)} entries for {d} inputs")
        spans = self.input_spans
        if spans is None:
            spans = [observed_span(X[:, k]) for k in range(d)]
        if len(spans) != d:
            raise ValueError(f"input_spans has {len(spans)} entries for {d} inputs")
        ospan = self.output_span if self.output_span is not None else observed_span(y)
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
        self.level_blocks_ = level_blocks([p.n for p in self.partitions_], self.levels)
        self.keys_ = np.empty(0, np.int64)
        self.count_ = np.empty(0, np.int64)
        self.qsum_ = np.empty(0, np.int64)
        self.qsq_ = np.empty(0, np.int64)
        self.best_w_ = np.empty(0, np.float64)
        self.best_set_ = np.empty(0, np.int64)
        self.n_samples_seen_ = 0
        self.n_skipped_ = 0
        self._touch()

    def _touch(self) -> None:
        """Forget what is derived from the rules (conclusions, levels, look-up tables)."""
        self._conclusions = None
        self._packed = None
        self._nodes: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._levels: dict[int, LevelRules] = {}
        self._spreads: dict[int, np.ndarray] = {}
        self._packs: dict[int, tuple] = {}
        self._fine: tuple | None = None
        self._trend: np.ndarray | None = None
        self._grid_base: tuple | None = None
        self._spread_ref: float | None = None
        self._fine_fit: tuple | None = None
        self._gaps: list[np.ndarray] | None = None

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
        return self.output_partition_.span / N.QUANT

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
        if self.conclusion == "sets" and self.method == "wm-avg":
            y = self._set_centres(y)
        for start in range(0, X.shape[0], CHUNK_ROWS):
            part = self._accumulate(X[start : start + CHUNK_ROWS], y[start : start + CHUNK_ROWS])
            self._merge_state(*part)
        return self

    def _set_centres(self, y: np.ndarray) -> np.ndarray:
        """Each output replaced by the centre of its max-membership output set (Kościelny
        et al., eq. 3 on ``y``): the ``A^{n+1}`` that eq. 5 averages as printed."""
        op = self.output_partition_
        out = op.centers[op.nearest(np.where(np.isfinite(y), y, op.lo))]
        return np.where(np.isfinite(y), out, y)

    def _accumulate(self, X: np.ndarray, y: np.ndarray):
        lo, step, nsets, _, core = self._arrays()
        op = self.output_partition_
        n = X.shape[0]
        if self.method == "wm":
            keys = np.empty(n, np.int64)
            w = np.empty(n, np.float64)
            yset = np.empty(n, np.int64)
            kernels().classic_weights(
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
            skipped = kernels(n).accumulate_dense(
                X, y, lo, step, nsets, self.radix_, op.lo, self._yquant, count, qsum, qsq
            )
            keys = np.flatnonzero(count).astype(np.int64)
            return keys, count[keys], qsum[keys], qsq[keys], None, None, int(skipped)
        keys = np.empty(n, np.int64)
        qy = np.empty(n, np.int64)
        kernels().keys_and_quanta(X, y, lo, step, nsets, self.radix_, op.lo, self._yquant, keys, qy)
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
        if not self.keys_.size:  # a first chunk (keys sorted, unique): its state as it is
            self._first_state(keys, count, qsum, qsq, best_w, best_set)
            return
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
        self._touch()

    def _first_state(self, keys, count, qsum, qsq, best_w, best_set) -> None:
        """:meth:`_merge_state` into an empty state: the union is ``keys`` and every sum is
        the chunk's own (copies of them, the same numbers), without the union's sort."""
        if count.size and count.max() > MAX_CELL_COUNT:
            raise OverflowError(
                f"a rule cell holds more than {MAX_CELL_COUNT} samples; "
                "split the training range or use more sets"
            )
        self.keys_ = np.array(keys, np.int64)
        self.count_ = np.array(count, np.int64)
        if self.method == "wm":
            # every weight beats the empty state's -1
            self.best_w_ = np.array(best_w, np.float64)
            self.best_set_ = np.array(best_set, np.int64)
        else:
            self.qsum_, self.qsq_ = np.array(qsum, np.int64), np.array(qsq, np.int64)
        self._touch()

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
            or self.conclusion != other.conclusion
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
        return self

    def without(self, other: WangMendelRegressor) -> WangMendelRegressor:
        """A copy of this model with the training state of ``other`` taken out: the model
        trained on everything but ``other``'s samples (the inverse of :meth:`merge`; exact for
        the averaged method's integer accumulators). Raises ``ValueError`` when ``other`` holds
        samples this model never had (a cell would fall below zero: ``other``'s data were not
        part of this model's training), and for the classic method (a maximum cannot be
        taken back)."""
        self._check_fitted()
        if self.method != "wm-avg":
            raise ValueError("only the averaged method's training can be taken apart")
        out = WangMendelRegressor.from_state(self.to_state())
        if not hasattr(other, "partitions_") or not other.keys_.size:
            return out
        if (
            other.partitions_ != self.partitions_
            or other.output_partition_ != self.output_partition_
        ):
            raise ValueError("cannot take apart models with different partitions")
        at = np.searchsorted(out.keys_, other.keys_)
        at = np.minimum(at, max(out.keys_.size - 1, 0))
        found = out.keys_.size > 0
        found = found & (out.keys_[at] == other.keys_) if out.keys_.size else np.zeros(0, bool)
        short = (~found).sum() + int(
            np.sum(np.maximum(other.count_[found] - out.count_[at[found]], 0))
        )
        if short:
            raise ValueError(f"{short} of the samples taken out were never in this model")
        count, qsum, qsq = out.count_.copy(), out.qsum_.copy(), out.qsq_.copy()
        np.subtract.at(count, at, other.count_)
        np.subtract.at(qsum, at, other.qsum_)
        np.subtract.at(qsq, at, other.qsq_)
        keep = count > 0
        out.keys_, out.count_ = out.keys_[keep], count[keep]
        out.qsum_, out.qsq_ = qsum[keep], qsq[keep]
        if out.best_w_.size == keep.size:  # rules set from a file carry them; a fit does not
            out.best_w_, out.best_set_ = out.best_w_[keep], out.best_set_[keep]
        out.n_samples_seen_ -= int(other.count_.sum())
        out._touch()
        return out

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
        self._touch()
        # explicit conclusions are used as written, not re-derived from the sums
        self._conclusions = conc
        return self

    # ------------------------------------------------------------------ levels
    @property
    def n_levels_(self) -> int:
        """Levels of the rule grid, the fine one included."""
        return int(self.level_blocks_.shape[0])

    def level_rules(self, level: int) -> LevelRules:
        """The rules of ``level`` (0 = the fine grid as trained or edited). A coarse rule is
        the group-by of the fine rules in its cell: count and output sums added as the exact
        integers they are (eq. 5 on the bigger cell); the classic method averages its fine
        conclusions weighted by their samples. Fine rules without samples (``n = 0``, written
        by hand) answer at the fine level only."""
        self._check_fitted()
        if not 0 <= level < self.n_levels_:
            raise ValueError(f"level must be 0…{self.n_levels_ - 1}, got {level}")
        cache = self.__dict__.setdefault("_levels", {})  # the node fit and spreads read it
        if level not in cache:
            cache[level] = self._derive_level(level)
        return cache[level]

    def _derive_level(self, level: int) -> LevelRules:
        if level == 0:
            return LevelRules(self.keys_, self.conclusions_, self.count_, self.sd_)
        if self.method != "wm" and "numba" in sys.modules:  # the same sums, compiled
            from diag_plugin.fuzzy import _kernels

            return LevelRules(*_kernels.coarse_rules(
                self.keys_, self.count_, self.qsum_, self.qsq_, self.radix_,
                self.level_blocks_[level], _radix(self.level_nsets(level)),
                self.output_partition_.lo, self._yquant))  # fmt: skip
        has = self.count_ > 0
        keys = self._coarse_keys(self.keys_[has], level)
        if self.method != "wm":
            # the integer accumulators summed per coarse cell: over the keys sorted, one
            # reduceat per accumulator (integer sums: the same numbers as np.add.at's in any
            # order, without its per-element loop)
            order = np.argsort(keys, kind="stable")
            sk = keys[order]
            new = np.ones(sk.size, bool)
            new[1:] = sk[1:] != sk[:-1]
            first = np.flatnonzero(new)
            ukeys = sk[first]
            count = np.add.reduceat(self.count_[has][order], first) if sk.size else sk.copy()
            qsum = np.add.reduceat(self.qsum_[has][order], first) if sk.size else sk.copy()
            qsq = np.add.reduceat(self.qsq_[has][order], first) if sk.size else sk.copy()
            mean = qsum / count
            conc = self.output_partition_.lo + mean * self._yquant
            sd = np.sqrt(np.maximum(qsq / count - mean * mean, 0.0)) * self._yquant
            return LevelRules(ukeys, conc, count, sd)
        ukeys, inv = np.unique(keys, return_inverse=True)
        inv = inv.reshape(-1)
        count = np.zeros(ukeys.size, np.int64)
        np.add.at(count, inv, self.count_[has])
        if self.method == "wm":
            acc = np.zeros(ukeys.size)
            np.add.at(acc, inv, self.count_[has] * self.conclusions_[has])
            return LevelRules(ukeys, acc / count, count, np.full(ukeys.size, np.nan))
        qsum = np.zeros(ukeys.size, np.int64)
        qsq = np.zeros(ukeys.size, np.int64)
        np.add.at(qsum, inv, self.qsum_[has])
        np.add.at(qsq, inv, self.qsq_[has])
        mean = qsum / count
        conc = self.output_partition_.lo + mean * self._yquant
        sd = np.sqrt(np.maximum(qsq / count - mean * mean, 0.0)) * self._yquant
        return LevelRules(ukeys, conc, count, sd)

    def _coarse_keys(self, keys: np.ndarray, level: int) -> np.ndarray:
        """Keys at ``level`` of the fine cells ``keys`` (each fine set index ``// b``)."""
        blocks = self.level_blocks_[level]
        radix = _radix(self.level_nsets(level))
        out = np.zeros(keys.size, np.int64)
        rem = keys.copy()
        for k in range(self.n_features_in_):
            idx, rem = np.divmod(rem, self.radix_[k])
            out += (idx // blocks[k]) * radix[k]
        return out

    def level_nsets(self, level: int) -> np.ndarray:
        """Sets of every input at ``level``."""
        n = np.array([p.n for p in self.partitions_], np.int64)
        return -(-n // self.level_blocks_[level])

    def level_cells(self, level: int, keys: np.ndarray | None = None) -> np.ndarray:
        """Set index of every input at ``level`` for each of its rules (rows × inputs)."""
        keys = self.level_rules(level).keys if keys is None else np.asarray(keys, np.int64)
        radix = _radix(self.level_nsets(level))
        out = np.empty((keys.size, self.n_features_in_), np.int64)
        rem = keys.copy()
        for k in range(self.n_features_in_):
            out[:, k], rem = np.divmod(rem, radix[k])
        return out

    def level_centers(self, level: int) -> list[np.ndarray]:
        """Centre of every set of each input at ``level``: the mean of the fine centres it
        groups (the coarse partition is uniform with ``b`` times the spacing)."""
        out = []
        for p, b in zip(self.partitions_, self.level_blocks_[level], strict=True):
            n = -(-p.n // int(b))
            out.append(p.lo + p.step * (0.5 * (b - 1) + b * np.arange(n)))
        return out

    # --------------------------------------------------------------- inference
    def predict_fine(self, X, rough: bool = False) -> tuple[Prediction, np.ndarray] | None:
        """The fine level's answer of every row of ``X`` through its dense table, and the rows
        :meth:`predict_detail` asks the coarser levels again (``again``: the fine rules carry
        less than ``LEVEL_SUPPORT`` of the weight inside the data's range); elsewhere the
        answer is :meth:`predict_detail`'s. None where the fine grid is too big for a dense
        table or numba is not loaded (:meth:`predict_detail` then searches every level).
        ``rough``: without the linear trend and the rules' spreads (not derived): the same
        answers but on rows past an input's span (reason 3, which move along the trend), no
        spread — a bound's pass, never :meth:`predict_detail`'s."""
        self._check_fitted()
        X = _as_2d(X)
        if X.shape[1] != self.n_features_in_:
            raise ValueError(f"model has {self.n_features_in_} inputs, X has {X.shape[1]}")
        n = X.shape[0]
        loops = kernels(n)
        fine = self._rough_table() if rough else self._fine_table()
        if fine is None or not hasattr(loops, "infer_fine"):
            return None
        det = Prediction(np.empty(n), np.empty(n), np.empty(n, np.int8), np.empty(n, np.int8),
                         np.empty(n))  # fmt: skip
        again = np.empty(n, np.bool_)
        if n <= CHUNK_ROWS:  # one call on the arrays themselves (a replay's 7-day piece)
            loops.infer_fine(X, *fine, *_fields(det), again)
            return det, again
        for s in range(0, n, CHUNK_ROWS):
            e = s + CHUNK_ROWS
            loops.infer_fine(X[s:e], *fine, *(f[s:e] for f in _fields(det)), again[s:e])
        return det, again

    def predict_detail(self, X, fine: tuple[Prediction, np.ndarray] | None = None) -> Prediction:
        """Prediction with support, a reason code and the answering level for each sample.
        ``fine``: :meth:`predict_fine`'s answer for the same ``X`` where the caller has it
        (its arrays are completed in place)."""
        self._check_fitted()
        X = _as_2d(X)
        n = X.shape[0]
        got = self.predict_fine(X) if fine is None else fine
        if got is None:
            # a fine grid too big for a dense table, or numpy's loops (no numba loaded: one
            # model's inference, :func:`kernels`): every level searched, the same bits
            if X.shape[1] != self.n_features_in_:
                raise ValueError(f"model has {self.n_features_in_} inputs, X has {X.shape[1]}")
            return self._no_bridge(X, self._predict_levels(X))
        # the fine level of every row through its dense table; only the rows it leaves short
        # of LEVEL_SUPPORT inside the data's range are asked again, level by level
        det, again = got
        rows = np.flatnonzero(again)
        packs = self.__dict__.setdefault("_packs", {})
        none = np.empty(0, np.int64)
        last = self.n_levels_ - 1
        depth = 0
        while rows.size:
            done = depth  # the levels up to it answered these rows short of LEVEL_SUPPORT
            depth += 1
            if (
                (rows.size > n // 2 and n > LAZY_ROWS)
                or last in packs
                or _SPARSE.get()
                or n >= ALL_LEVELS_ROWS
            ):
                # most of many rows asked again, or every level's rules packed already (by
                # an earlier call), or a model scored once (scoring_node_fit): every level of
                # them at once (the same answers: each row stops at the same level; the finer
                # levels are not evaluated again for it)
                depth = last
            if depth not in packs:
                packs[depth] = pack([self.inference_grid(depth)], dense=True)
            prior = Prediction(*(f[rows] for f in _fields(det)))
            sub = run_kernel(packs[depth], none, X[rows], prior, first=done + 1)
            for full, part in zip(_fields(det), _fields(sub), strict=True):
                full[rows] = part
            if depth == last:
                break
            rows = rows[(sub.support < LEVEL_SUPPORT) & (sub.reason != 1)]
        return self._no_bridge(X, det)

    def _rough_table(self) -> tuple | None:
        """:meth:`_fine_table` with a zero trend and zero spreads (:meth:`predict_fine`'s
        ``rough``): the fine rules' conclusions as they are, nothing else derived; None where
        :meth:`_fine_table` has none for the same reasons (a grid past :data:`DENSE_LIMIT`, an
        input of one set, a conclusion that is not finite)."""
        if self.n_cells_ > DENSE_LIMIT:
            return None
        lo, step, nsets, plateau, _ = self._arrays()
        values = np.asarray(self.conclusions_, float)
        if (np.asarray(nsets) < 2).any() or not np.isfinite(values).all():
            return None
        inner = self._inner(nsets)
        n = values.size
        rules = np.zeros((n + 1, 4))  # the last row: no rule; spreads 0, each known
        rules[:n, 0] = values
        rules[:n, 1] = 1.0
        rules[:n, 3] = 1.0
        table = np.full(self.n_cells_, n, np.int64)
        table[self.keys_] = np.arange(n)
        return (lo, step, plateau, nsets, inner, np.zeros(lo.size + 1), self.radix_.copy(), table,
                rules, LEVEL_SUPPORT, self.n_levels_ > 1)  # fmt: skip

    def _fine_table(self) -> tuple | None:
        """What :func:`._kernels.infer_fine` reads: the input partitions, the range holding
        training data, the fine level's radix, its dense table of rule rows and the rows
        (:func:`._kernels._fire_table`), the support that suffices and whether coarser levels
        exist; None where the fine grid has more than :data:`DENSE_LIMIT` cells, an input a
        single set, or a rule a conclusion or spread that is infinite (or a NaN conclusion):
        the table's corners of weight 0 are summed, the same bits only for finite ones."""
        if "_fine" not in self.__dict__ or self._fine is None:
            self._fine = self._make_fine_table()
        return self._fine or None

    def _make_fine_table(self) -> tuple:
        """:meth:`_fine_table`, built (``()`` where there is none)."""
        if self.n_cells_ > DENSE_LIMIT:
            return ()
        g = self.inference_grid(0)
        values = np.asarray(g.conclusions[0], float)
        spreads = np.asarray(g.spreads[0], float)
        if (
            (np.asarray(g.nsets) < 2).any()
            or not np.isfinite(values).all()
            or np.isinf(spreads).any()
        ):
            return ()
        n = values.size
        known = ~np.isnan(spreads)
        rules = np.zeros((n + 1, 4))  # the last row: no rule
        rules[:n, 0] = values
        rules[:n, 1] = 1.0
        rules[:n, 2] = np.where(known, spreads, 0.0)
        rules[:n, 3] = known
        table = np.full(self.n_cells_, n, np.int64)
        table[g.keys[0]] = np.arange(n)
        return (g.lo, g.step, g.plateau, g.nsets, np.ascontiguousarray(g.inner),
                np.ascontiguousarray(g.trend), g.radix[0].copy(), table, rules,
                LEVEL_SUPPORT, self.n_levels_ > 1)  # fmt: skip

    def _predict_levels(self, X: np.ndarray) -> Prediction:
        """:meth:`predict_detail` by :func:`._kernels.infer_levels` alone (searched rules)."""
        if self._packed is not None:
            return run_kernel(self._packed, np.empty(0, np.int64), X)
        # a coarse level is fitted only when a sample reaches it: the levels down to
        # ``depth`` answer every sample that one of them answers with LEVEL_SUPPORT (the
        # kernel stops there, as with every level); the others are asked again one level
        # deeper — exactly the answers of all levels, without fitting those nobody asks
        packs = self.__dict__.setdefault("_packs", {})
        none = np.empty(0, np.int64)
        last = self.n_levels_ - 1
        depth = 0
        rows = np.empty(0, np.int64)
        while True:
            if depth not in packs:
                packs[depth] = pack([self.inference_grid(depth)], dense=True)
            if depth == last:
                self._packed = packs[depth]
            if depth == 0 or rows.size == X.shape[0]:
                det = run_kernel(packs[depth], none, X)
                rows = np.arange(X.shape[0])
            else:
                sub = run_kernel(packs[depth], none, X[rows])
                for full, part in zip(_fields(det), _fields(sub), strict=True):
                    full[rows] = part
            if depth == last:
                return det
            if depth == 0:  # the kernel asks no coarse level outside the data's range
                rows = rows[self._inside(X)]
            ask = (det.support[rows] < LEVEL_SUPPORT) & (det.reason[rows] != 1)
            rows = rows[ask]
            if not rows.size:
                return det
            depth += 1
            if rows.size > X.shape[0] // 2 and X.shape[0] > LAZY_ROWS:
                # most of many rows asked again: one pass of every level over all of them
                # (no copy of the rows asked; memory in proportion to the rows as before)
                depth, rows = last, np.arange(X.shape[0])

    def _inside(self, X: np.ndarray) -> np.ndarray:
        """Rows whose fine set of every input may lie between the first and last set holding
        training data (:func:`._kernels.infer_levels`' ``inside``; a row within rounding of
        that range counts as inside, so no row the kernel takes inside is left out)."""
        lo, step, nsets, _, _ = self._arrays()
        ok = np.ones(X.shape[0], bool)
        rem = self.keys_[self.count_ > 0]
        if not rem.size:
            return ok
        for k in range(self.n_features_in_):
            idx, rem = np.divmod(rem, self.radix_[k])
            x = np.clip(X[:, k], lo[k], lo[k] + step[k] * (nsets[k] - 1))
            t = (x - lo[k]) / step[k] + 0.5
            hi_i = np.minimum(np.floor(t + 1e-9), nsets[k] - 1)
            lo_i = np.minimum(np.floor(t - 1e-9), nsets[k] - 1)
            ok &= ~((hi_i < idx.min()) | (lo_i > idx.max())) | np.isnan(X[:, k])
        return ok

    def set_counts(self) -> list[np.ndarray]:
        """Per input the training samples in each of its fine sets (the marginal occupancy
        of the rule cells, summed over the other inputs)."""
        cells = self.cell_indices()
        n = self.count_.astype(float)
        return [
            np.bincount(cells[:, k], weights=n, minlength=p.n)
            for k, p in enumerate(self.partitions_)
        ]

    def input_gaps(self) -> list[np.ndarray]:
        """Per input the gaps no level bridges (module doc): rows ``(a, b)``, the occupied
        fine sets on either side of a run of ``b - a - 1`` empty ones (:func:`occupancy_gaps`);
        derived from the rules' counts, never stored."""
        if self.__dict__.get("_gaps") is None:
            self._gaps = [occupancy_gaps(c) for c in self.set_counts()]
        return self._gaps

    def unbridged_gaps(self) -> list[np.ndarray]:
        """:meth:`input_gaps` of the inputs in :attr:`unbridged` (positions; none by default:
        every level answers as the paper's levels do), the others' left empty. A unit sets it
        to the inputs an operator chooses — set-points, hand valves, discrete states
        (:func:`~diag_plugin.diagnose.unittags.unbridge`): there a gap is an operating point
        never run; a measured input in a gap may be a fault's own move (a meter's bias), where
        the bridged answer is what detects it."""
        keep = set(getattr(self, "unbridged", ()))
        if not keep:  # every model's every prediction asks: nothing derived for none marked
            return [np.empty((0, 2), np.int64) for _ in self.partitions_]
        return [g if k in keep else g[:0] for k, g in enumerate(self.input_gaps())]

    def in_gap(self, X) -> np.ndarray:
        """Rows of ``X`` whose own fine set of some input lies in one of
        :meth:`unbridged_gaps` (:func:`rows_in_gap`)."""
        X = _as_2d(X)
        if not self.keys_.size:
            return np.zeros(X.shape[0], bool)
        lo, step, nsets, _, _ = self._arrays()
        return rows_in_gap(X, lo, step, nsets, self.unbridged_gaps())

    def _no_bridge(self, X: np.ndarray, det: Prediction) -> Prediction:
        """``det`` with every coarse level's answer in a gap of an input withdrawn (module
        doc): NaN, support 0, level -1, reason :data:`REASON_GAP`; in place."""
        if det.level is None or not any(g.size for g in self.unbridged_gaps()):
            return det
        rows = np.flatnonzero(det.level > 0)
        if rows.size:
            withdraw(det, rows[self.in_gap(X[rows])])
        return det

    def predict(self, X) -> np.ndarray:
        """Model output; NaN where no trained rule covers the sample."""
        return self.predict_detail(X).y

    def extrapolate(self, X, pred: np.ndarray | None = None) -> np.ndarray:
        """A value for every sample: the prediction where the model has one, else the
        conclusion of the nearest trained rule (set centres in units of set spacing).
        ``pred``: this model's prediction of ``X`` where the caller has it already (not
        computed again).

        Used only to *score* samples the model does not cover (so an error figure
        counts every sample); the model itself still reports them as unsupported.
        """
        X = _as_2d(X)
        y = self.predict(X) if pred is None else np.array(pred, float)
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
        """Share of samples of ``X`` answered by trained rules (at any level)."""
        return self.predict_detail(X).coverage

    def inference_grid(self, depth: int | None = None) -> InferenceGrid:
        """Partitions and rules of every level (down to level ``depth``) as flat arrays, for
        evaluators that run many models at once (:class:`diag_plugin.fuzzy.stack.
        WangMendelStack`); keys ascending."""
        self._check_fitted()
        levels = self.n_levels_ if depth is None else min(depth + 1, self.n_levels_)
        lo, step, nsets, plateau, inner, all_radix = self._base_grid()
        lo, step, nsets, plateau, inner = (a.copy() for a in (lo, step, nsets, plateau, inner))
        radix = all_radix[:levels].copy()
        nodes = [self.level_nodes(lv) for lv in range(levels)]
        spread = self.__dict__.setdefault("_spreads", {})
        for lv, (k, _, _) in enumerate(nodes):
            if lv not in spread:
                spread[lv] = self._node_spread(lv, k)
        spreads = [spread[lv] for lv in range(levels)]
        return InferenceGrid(
            lo,
            step,
            nsets,
            plateau,
            inner,
            self.trend_.copy(),
            self.level_blocks_[:levels].copy(),
            radix,
            [k for k, _, _ in nodes],
            [v for _, v, _ in nodes],
            [f for _, _, f in nodes],
            spreads,
        )

    def _inner(self, nsets: np.ndarray) -> np.ndarray:
        """The first and last fine set of every input holding training data (inputs × 2)."""
        inner = np.column_stack([np.zeros(nsets.size, np.int64), nsets - 1])
        rem = self.keys_[self.count_ > 0]
        for k in range(self.n_features_in_ if rem.size else 0):
            idx, rem = np.divmod(rem, self.radix_[k])
            inner[k] = idx.min(), idx.max()
        return inner

    def _base_grid(self) -> tuple:
        """What every depth of :meth:`inference_grid` shares (partitions, the data's range,
        each level's radix), derived once per trained state: predict_detail asks one depth
        after another."""
        if self.__dict__.get("_grid_base") is None:
            lo, step, nsets, plateau, _ = self._arrays()
            inner = self._inner(nsets)
            all_radix = np.stack([_radix(self.level_nsets(lv)) for lv in range(self.n_levels_)])
            self._grid_base = (lo, step, nsets, plateau, inner, all_radix)
        return self._grid_base

    @property
    def trend_(self) -> np.ndarray:
        """The model's linear trend ``[b0, b1 … bd]`` (output = ``b0 + Σ b_k x_k``): the
        least-squares plane through the fine rules' conclusions at their set centres, each
        weighted by its training samples (every rule alike where none has a count), with a
        ridge of :data:`TREND_RIDGE` of each input's own spread on the slopes (an input the
        rules do not vary gets slope 0). Derived from the rules like the levels, never stored,
        so an expert's edit carries into it.

        Inference reads it where an input is past its span: the answer moves along the
        trend (see :func:`._kernels.infer_levels`), so a slow excursion of the plant beyond
        the training's range is followed along the data's own relation instead of held at
        the grid's edge."""
        if getattr(self, "_trend", None) is None:
            self._trend = _linear_trend(self)
        return self._trend

    @property
    def spread_(self) -> float:
        """The model's typical spread: the pooled standard deviation of the training outputs
        within the fine cells, ``sqrt(Σ n sd² / Σ n)`` (NaN for the classic method)."""
        if self.__dict__.get("_spread_ref") is None:  # once per trained state
            n = self.count_.astype(float)
            if self.method == "wm" or not n.sum():
                self._spread_ref = float("nan")
            else:
                self._spread_ref = float(np.sqrt(np.sum(n * self.sd_**2) / n.sum()))
        return self._spread_ref

    def _node_spread(self, level: int, nodes: np.ndarray) -> np.ndarray:
        """Per node of ``level``: the spread of its cell's training outputs relative to the
        model's (:attr:`spread_`), pooled towards 1 by :data:`SPREAD_PRIOR` samples (a cell of
        one sample has no spread of its own); NaN for nodes without data (and for the classic
        method, whose rules keep no spread)."""
        ref = self.spread_
        rules = self.level_rules(level)
        out = np.full(nodes.size, np.nan)
        if not ref > 0:
            return out
        i = np.minimum(np.searchsorted(rules.keys, nodes), max(rules.keys.size - 1, 0))
        ok = rules.keys.size > 0
        ok = ok & (rules.keys[i] == nodes) if rules.keys.size else np.zeros(nodes.size, bool)
        n = rules.count[i].astype(float)
        rel2 = (n * (rules.sd[i] / ref) ** 2 + SPREAD_PRIOR) / (n + SPREAD_PRIOR)
        out[ok] = np.sqrt(rel2[ok])
        return out

    def level_nodes(self, level: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What inference reads of ``level``: the node keys (ascending), the value at each node
        and whether the node's own cell holds training data.

        Level 0: the fine rules as they are (every one counts as data). A coarser level: the
        node values are the least-squares fit of the coarse grid's multilinear interpolation
        to the fine rules (each fine conclusion at its set centres, weighted by its samples
        ``n``), with a weak smoothness prior (second differences along each input, weight
        :data:`SMOOTHING` of the data per node). The plain cell mean (eq. 5 on the bigger
        cell, :meth:`level_rules`) sits at the centroid of the cell's data, not at its centre,
        and interpolated as if it were at the centre it errs by up to half the cell's change
        of output; the fit puts each node where the interpolation needs it (on a 3-input heat
        exchanger the held-out error where only coarse levels answer fell from 3.7 to 1.3 of
        an output with spread 3.0). Nodes next to the data get values too (the fit extends the
        trend one cell), but a coarse level answers only where the sample's own cell holds
        data. Where fine rules × 2^inputs exceed :data:`FIT_LIMIT` (many inputs, hundreds of
        thousands of rules) the coarse levels stay silent: the model is the fine grid alone
        (their cells' means, centroids off-centre, were tried and answered worse, 2.5 % of
        span in-sample with 9 inputs)."""
        self._check_fitted()
        if level == 0:
            return self.keys_, np.asarray(self.conclusions_, float), np.ones(self.keys_.size, bool)
        if level not in self._nodes:
            self._nodes[level] = _fit_nodes(self, level)
        return self._nodes[level]

    def _check_fitted(self) -> None:
        if not hasattr(self, "partitions_"):
            raise RuntimeError("this model is not trained yet: call fit or load a rule base")

    @property
    def n_rules_(self) -> int:
        return int(self.keys_.size)


def _fit_nodes(m: WangMendelRegressor, level: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Node keys, values and data flags of a coarse level (see :meth:`level_nodes`)."""
    cells = m.level_rules(level)
    n_rules = int(np.count_nonzero(m.count_ > 0))
    if not n_rules:
        return cells.keys, cells.conclusions, np.ones(cells.keys.size, bool)
    d = m.n_features_in_
    if n_rules << d > FIT_LIMIT:  # too big to fit: the level stays silent
        return np.empty(0, np.int64), np.empty(0), np.empty(0, bool)
    _, n, sw, fine, y_fine, plateau = _fine_rules(m)
    blocks = m.level_blocks_[level]
    nsets = m.level_nsets(level)
    radix = _radix(nsets)
    # each fine rule at its set centres, in the coarse partition: lower node and weight
    loops = _design_loops(nsets)
    if loops is not None:  # the same arithmetic compiled: the same r, col, w and nodes
        nodes, r, col, w = loops.coarse_corners(
            fine, blocks.astype(np.int64), nsets, plateau, radix, int(np.prod(nsets))
        )
    else:
        nodes, r, col, w = _corners(m, fine, blocks, nsets, radix)
    # nodes and keys both ascending and unique: membership by one search (np.isin's answer)
    at = np.minimum(np.searchsorted(cells.keys, nodes), max(cells.keys.size - 1, 0))
    data = cells.keys[at] == nodes if cells.keys.size else np.zeros(nodes.size, bool)
    if dense_node_fit(n.size, nodes.size):  # dense numpy, no sparse overhead (nor import)
        return nodes, _fit_dense(nodes, r, col, w, sw, n, y_fine, d, radix, nsets), data
    import scipy.sparse as sp

    A = sp.csr_matrix((w * sw[r], (r, col)), shape=(n.size, nodes.size))
    y = y_fine
    # smoothness: second differences along each input where both neighbours are nodes
    idx = np.column_stack([(nodes // radix[k]) % nsets[k] for k in range(d)])
    pr, pc, pv = [], [], []
    row = 0
    for k in range(d):
        below = np.searchsorted(nodes, nodes - radix[k])
        above = np.searchsorted(nodes, nodes + radix[k])
        below = np.minimum(below, nodes.size - 1)
        above = np.minimum(above, nodes.size - 1)
        inside = (idx[:, k] > 0) & (idx[:, k] < nsets[k] - 1)
        ok = inside & (nodes[below] == nodes - radix[k]) & (nodes[above] == nodes + radix[k])
        mid = np.flatnonzero(ok)
        rr = np.arange(row, row + mid.size)
        pr += [rr, rr, rr]
        pc += [below[mid], mid, above[mid]]
        pv += [np.ones(mid.size), np.full(mid.size, -2.0), np.ones(mid.size)]
        row += mid.size
    per_node = n.sum() / nodes.size
    P = sp.csr_matrix(
        (np.concatenate(pv), (np.concatenate(pr), np.concatenate(pc))), shape=(row, nodes.size)
    )
    ridge = 1e-6 * per_node
    M = A.T @ A + SMOOTHING * per_node * (P.T @ P) + ridge * sp.identity(nodes.size)
    rhs = A.T @ (sw * y) + ridge * float(np.average(y, weights=n))
    if _ITERATIVE.get():
        values = np.atleast_1d(_solve_spd(M.tocsr(), rhs))
    else:
        from scipy.sparse.linalg import spsolve

        values = np.atleast_1d(spsolve(M.tocsc(), rhs))
    return nodes, values, data


def dense_node_fit(n_rules: int, nodes: int) -> bool:
    """Whether a coarse level of ``nodes`` nodes fitted to ``n_rules`` fine rules is solved
    with dense arrays (:func:`_fit_dense`) rather than scipy.sparse: where the normal
    equations ``A.T @ A`` (``n_rules · nodes²`` multiply-adds) and their solve (``nodes³``)
    stay within :data:`DENSE_FLOPS` and the design ``A`` within :data:`DENSE_CELLS` entries.

    Measured (issue 37; CPU time of one warm fit, BLAS at one thread, the 2-core machine
    under load), dense against sparse: 0.1 against 1-1.7 ms for the example valve models of
    one and two inputs (21 rules × 11 nodes, 175 × 52) and the TEP unit's models (1-12
    rules); 2.4-3.9 against 3-6 ms for the valve unit's three-input models' level 3
    (7,774-8,161 rules × 48 nodes, 2·10^7 multiply-adds); 0.8-3.7 against 1-4 ms for the
    chemical plant unit's three-input levels of 208-349 nodes (458-714 rules); 5.7-7
    against 3.3-5.3 ms for ``benchmarks/bench_train.py``'s model's level 1 (1,365 rules ×
    248 nodes, 10^8); 26-34 against 7-10 ms for the valve unit's level 2 (≈ 8,000 × 320,
    8·10^8) and 0.46-0.77 s against 20-26 ms for its level 1 (≈ 8,000 × 1,330, 1.6·10^10).
    The first sparse fit of a process also imports scipy.sparse and scipy.sparse.linalg
    (0.19-0.21 s on a quiet machine): a fresh process fitting the bench model's four
    coarse levels spent 0.03 s CPU dense, 0.23 s sparse. So the bound lets the dense path
    cost up to about twice the sparse one warm (a few ms a level) and keeps the import out
    of processes that fit only levels of that size, as a trained model of a few inputs and
    some thousand rules has; the old bound (rules × nodes ≤ 2^17) sent that model's level 1
    to scipy.sparse."""
    return n_rules * nodes <= DENSE_CELLS and (n_rules + nodes) * nodes * nodes <= DENSE_FLOPS


@functools.cache
def _blas_controller():
    """threadpoolctl's handle on the BLAS numpy loaded, made once per process (None without
    threadpoolctl)."""
    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:  # pragma: no cover - threadpoolctl is a dependency
        return None
    return ThreadpoolController()


def _one_blas_thread() -> contextlib.AbstractContextManager:
    """BLAS held to one thread for a dense node fit: with a thread per core on a loaded
    2-core machine a 1,365 × 81 ``A.T @ A`` and its solve took 0.2 s instead of 2 ms (the
    threads spin, CPU time too), and the threads' share of the products can change the
    values' last bits; one thread gives the same bits on any machine."""
    c = _blas_controller()
    return contextlib.nullcontext() if c is None else c.limit(limits=1, user_api="blas")


#: whether the node fit solves by conjugate gradients (:func:`iterative_node_fit`)
_ITERATIVE: contextvars.ContextVar[bool] = contextvars.ContextVar(
    "wm_iterative_node_fit", default=False
)


@contextlib.contextmanager
def iterative_node_fit() -> Iterator[None]:
    """Within it, coarse levels' node fits solve by conjugate gradients (:func:`_solve_spd`:
    the direct solve's values to about 1e-10 relative, seconds instead of minutes for models
    of five inputs). ``diag explain`` screens dozens of candidate models this way; a model
    trained, built into a unit or replayed keeps the direct solve's exact bits (the switch
    is the calling context's: another thread's fits are not touched)."""
    token = _ITERATIVE.set(True)
    try:
        yield
    finally:
        _ITERATIVE.reset(token)


#: whether the node fit sums its normal equations over each rule's corners
#: (:func:`scoring_node_fit`)
_SPARSE: contextvars.ContextVar[bool] = contextvars.ContextVar("wm_sparse_normal", default=False)


@contextlib.contextmanager
def scoring_node_fit() -> Iterator[None]:
    """Within it, models are fitted to be scored once (``diag unit build``'s choice of
    inputs, :mod:`diag_plugin.unitbuild.build`): a coarse level's node fit forms its normal
    equations from each fine rule's own corners (:func:`._kernels.normal_equations`, at most
    ``4^d`` products a rule where the dense ``A.T @ A`` multiplies every rule by every node
    pair: the same sums in another order, equal to rounding, not to the bit), and a
    prediction's rows asked again after the fine level are answered by every coarse level at
    once (the same answers; levels no row reaches are fitted too, which costs less than a
    pass per level for the few rows a held-out block asks again). Models trained, built into
    a unit or replayed keep the dense products' exact bits (the switch is the calling
    context's, like :func:`iterative_node_fit`)."""
    token = _SPARSE.set(True)
    try:
        yield
    finally:
        _SPARSE.reset(token)


#: relative residual ``|M x - b| / |b|`` the node fit's conjugate gradients stop at
SOLVE_RTOL = 1e-12
#: iterations after which the node fit falls back to the direct solve (the audit's 5-input
#: levels converged in 50-1,500; the direct solve of such a level costs minutes, 20,000
#: iterations of 10^4 nodes some 20 s)
CG_MAXITER = 20_000


def _solve_spd(M, rhs: np.ndarray) -> np.ndarray:
    """``M x = rhs`` for the node fit's symmetric positive definite normal equations:
    conjugate gradients preconditioned by ``M``'s diagonal, to :data:`SOLVE_RTOL`; a direct
    sparse LU where they do not converge.

    A coarse level's nodes couple with every node of the cells around them (3^d of them with
    d inputs); a direct factorisation of such a matrix fills in towards dense as d grows (with
    5 inputs and 7,358 nodes: 4.6 s CPU per level, where conjugate gradients take 0.2 s and
    agree to 4e-8 of the output's unit) — what made ``diag explain`` take minutes once a
    candidate made a model of five inputs (issue 37)."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import cg, spsolve

    d = M.diagonal()  # M is CSR: a row-wise product per iteration (CSC scatters)
    if np.all(d > 0) and np.any(rhs):
        x, info = cg(M, rhs, rtol=SOLVE_RTOL, atol=0.0, M=sp.diags(1.0 / d), maxiter=CG_MAXITER)
        if info == 0 and np.all(np.isfinite(x)):
            return x
    return spsolve(M.tocsc(), rhs)


def _linear_trend(m: WangMendelRegressor) -> np.ndarray:
    """:attr:`WangMendelRegressor.trend_`: weighted least squares of the fine conclusions on
    their set centres, slopes with a ridge of :data:`TREND_RIDGE` of each input's weighted sum
    of squares (in set spacings, so the solve is well scaled)."""
    d = m.n_features_in_
    out = np.zeros(d + 1)
    conc = np.asarray(m.conclusions_, float)
    ok = np.isfinite(conc)
    w = np.where(ok & (m.count_ > 0), m.count_, 0).astype(float)
    if not w.sum():
        w = ok.astype(float)
    total = w.sum()
    if not total:
        return out
    lo, step, _, _, _ = m._arrays()
    z = m.cell_indices().astype(float)  # set centres in set spacings from lo
    y = np.where(ok, conc, 0.0)
    mz = (w @ z) / total
    my = float(w @ y) / total
    zc = z - mz
    G = (zc * w[:, None]).T @ zc
    G[np.diag_indices(d)] += TREND_RIDGE * np.diag(G) + 1e-12 * total
    s = np.linalg.solve(G, zc.T @ (w * (y - my)))
    out[1:] = s / step
    out[0] = my - float(s @ (mz + lo / step))
    return out


#: coarse grids of at most this many cells have their node fit's design made by the
#: compiled loop (it marks the nodes met in a table of every cell)
DESIGN_CELLS = 1 << 22


def _design_loops(nsets: np.ndarray) -> ModuleType | None:
    """The compiled loops for a coarse level's design (:func:`._kernels.coarse_corners`,
    :func:`._kernels.smooth_gram`) where numba is loaded (the build loads it before its pools
    fork) and the level's grid is small enough, else None (:func:`_corners`, numpy's loops:
    the same bits)."""
    if "numba" not in sys.modules or nsets.min() < 2 or np.prod(nsets) > DESIGN_CELLS:
        return None
    from diag_plugin.fuzzy import _kernels  # numba is loaded: the compiled loops, whatever
    # :func:`kernels` would give a call of few rows

    return _kernels


def _corners(m: WangMendelRegressor, fine: np.ndarray, blocks, nsets, radix):
    """:func:`._kernels.coarse_corners` in numpy: the nodes met (ascending) and, for each
    corner with a positive weight of each fine rule's coarse cell, the rule, the node's index
    and the weight (corner by corner)."""
    d = m.n_features_in_
    lower = np.empty_like(fine)
    upper_w = np.empty(fine.shape)
    for k, p in enumerate(m.partitions_):
        b = int(blocks[k])
        t = np.clip((fine[:, k] - 0.5 * (b - 1)) / b, 0.0, nsets[k] - 1.0)
        j = np.minimum(np.floor(t).astype(np.int64), nsets[k] - 2)
        pl = p.plateau if p.shape == "trapezoidal" else 0.0
        lower[:, k] = j
        upper_w[:, k] = np.clip((t - j - 0.5 * pl) / (1.0 - pl), 0.0, 1.0)
    rows, cols, vals = [], [], []
    lower_w = 1.0 - upper_w
    for c in range(1 << d):
        up = np.array([(c >> k) & 1 for k in range(d)], bool)
        w = corner_weight(upper_w, lower_w, up)
        ok = w > 0
        rows.append(np.flatnonzero(ok))
        cols.append((lower[ok] + up) @ radix)
        vals.append(w[ok])
    r, c, w = np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)
    nodes, col = np.unique(c, return_inverse=True)
    return nodes, r, col.reshape(-1), w


def corner_weight(upper_w: np.ndarray, lower_w: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Each row's multilinear weight of one corner of its coarse cell: the product over the
    inputs of ``upper_w`` where the corner is the upper node (``up``), else ``lower_w``,
    multiplied in the inputs' order — ``np.prod(np.where(up, upper_w, lower_w), axis=1)``
    to the bit, without building the selected array."""
    w = upper_w[:, 0] if up[0] else lower_w[:, 0]
    for k in range(1, up.size):
        w = w * (upper_w[:, k] if up[k] else lower_w[:, k])
    return w


def _fine_rules(m: WangMendelRegressor) -> tuple:
    """What every coarse level's node fit reads of the fine rules holding samples, derived
    once per trained state: the mask, their counts ``n`` and ``sqrt(n)``, their set indices,
    their conclusions, and each input's plateau."""
    got = m.__dict__.get("_fine_fit")
    if got is None:
        has = m.count_ > 0
        n = m.count_[has].astype(float)
        plateau = np.array([p.plateau if p.shape == "trapezoidal" else 0.0
                            for p in m.partitions_])  # fmt: skip
        got = (has, n, np.sqrt(n), m.cell_indices(m.keys_[has]),
               np.asarray(m.conclusions_, float)[has], plateau)  # fmt: skip
        m._fine_fit = got
    return got


def _fit_dense(nodes, r, col, w, sw, n, y, d, radix, nsets) -> np.ndarray:
    """:func:`_fit_nodes`' least squares with dense arrays (a level of few nodes): ``n``,
    ``sw`` and ``y`` are the fine rules' counts, their square roots and conclusions."""
    k = nodes.size
    per_node = n.sum() / k
    ridge = 1e-6 * per_node
    loops = _design_loops(nsets)
    PtP = (
        loops.smooth_gram(nodes, radix, nsets)
        if loops is not None
        else _smooth_gram(nodes, d, radix, nsets)
    )
    with _one_blas_thread():
        if loops is not None and _SPARSE.get():  # scoring: the products over each corner
            AtA, Aty = loops.normal_equations(r, col, w, sw, y, n.size, k)
        else:
            # each (fine rule, node) pair at most once: the sums of np.add.at, without its loop
            A = np.bincount(r * k + col, w * sw[r], minlength=n.size * k).reshape(n.size, k)
            AtA, Aty = A.T @ A, A.T @ (sw * y)
        M = AtA + SMOOTHING * per_node * PtP
        M.flat[:: k + 1] += ridge  # + ridge·I: the same sums, off the diagonal + 0 left out
        # np.average(y, weights=n) as it computes it: Σ y·n / Σ n
        rhs = Aty + ridge * float(np.multiply(y, n).sum() / n.sum())
        return np.linalg.solve(M, rhs)


def _smooth_gram(nodes: np.ndarray, d: int, radix, nsets) -> np.ndarray:
    """:func:`._kernels.smooth_gram` in numpy: ``P.T @ P`` of the second differences, summed
    pair by pair (``np.bincount`` over each difference's nine node pairs: small integers, so
    the dense product's exact values, without its ``d·k³`` multiplications of mostly zeros)."""
    k = nodes.size
    idx = np.column_stack([(nodes // radix[j]) % nsets[j] for j in range(d)])
    below_all, mid_all, above_all = [], [], []
    for j in range(d):
        below = np.searchsorted(nodes, nodes - radix[j]).clip(0, k - 1)
        above = np.searchsorted(nodes, nodes + radix[j]).clip(0, k - 1)
        inside = (idx[:, j] > 0) & (idx[:, j] < nsets[j] - 1)
        ok = inside & (nodes[below] == nodes - radix[j]) & (nodes[above] == nodes + radix[j])
        mid = np.flatnonzero(ok)
        below_all.append(below[mid])
        mid_all.append(mid)
        above_all.append(above[mid])
    # one row per second difference: 1, -2, 1 at the node below, the node, the node above
    at = np.stack([np.concatenate(below_all), np.concatenate(mid_all), np.concatenate(above_all)])
    v = np.array([1.0, -2.0, 1.0])
    pairs = (at[:, None, :] * k + at[None, :, :]).ravel()
    weights = np.repeat(np.outer(v, v).ravel(), at.shape[1])
    return np.bincount(pairs, weights, minlength=k * k).reshape(k, k)


def _copy_state(m: WangMendelRegressor) -> dict:
    state = dict(m.__dict__)
    for k, v in state.items():
        if isinstance(v, np.ndarray):
            state[k] = v.copy()
    state["partitions_"] = list(m.partitions_)
    return state
