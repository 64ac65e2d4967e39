"""A quick screen of candidate inputs before any model is retrained (issue 37).

Retraining the model for every candidate, every lag and every set count is what made
``diag explain`` take minutes on months of data with four inputs. The screen asks a cheaper
question first: how much of what the current model *misses* — its out-of-fold residual on
the training rows — does a candidate explain, judged on the held-out block?

* The model is trained on all but one of :data:`FOLDS` interleaved groups of time blocks of
  the training rows and predicts the group left out (for Wang–Mendel a group-by over rule
  cells: the out-of-fold residual is what the model cannot learn from its inputs, not its
  in-sample residual, which a fine grid shrinks towards zero).
* Every row gets a set index of each model input (uniform sets over the range the training
  data use, 0.1–99.9 % quantiles; as many as keep
  :data:`~diag_plugin.selection.sets.MIN_PER_CELL` training samples per cell of two inputs)
  — computed once; a candidate adds its own set index to the cell key.
* A candidate's correction is the mean out-of-fold residual of its cells — alone, and
  paired with each model input — (one pass of integer-keyed accumulators: ``bincount``),
  shrunk towards zero by :data:`PRIOR` samples; its screening error is the best held-out
  RMSE (% of span) of the model's held-out prediction plus such a correction.

The screen only orders candidates; the best are then retrained and scored exactly as
training would score them (:class:`~diag_plugin.selection.scoring.HeldOutScorer`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace as dc_replace

import numpy as np

from diag_plugin.rulebase.document import RuleBase
from diag_plugin.selection.sets import MIN_PER_CELL, SETS_RANGE, set_index

#: groups of interleaved time blocks the out-of-fold residual is computed over
FOLDS = 2
#: time blocks the training rows are cut into (alternating between the groups)
BLOCKS = 10
#: samples' worth of "no correction" each cell's mean residual is pooled with
PRIOR = 5.0
#: cells at most this many are accumulated densely (bincount), else through unique keys
DENSE_CELLS = 1 << 22


class Screen:
    """Screening error of candidate inputs of ``rb``'s model (see the module doc).

    ``cols``: the model's input columns over every row; ``y``: the output; ``cut``: first
    held-out row; ``va``: the held-out rows scored; ``base_va``: the model's prediction on
    them (its stand-in where it has none), as the held-out scorer computed it."""

    def __init__(
        self,
        rb: RuleBase,
        cols: Sequence[np.ndarray],
        y: np.ndarray,
        cut: int,
        va: np.ndarray,
        base_va: np.ndarray,
    ):
        self.y = y
        self.cut = cut
        self.va = va
        self.base_va = base_va
        self.span = rb.output.span[1] - rb.output.span[0]
        self.resid = _oof_residual(rb, cols, y, cut)
        self.train = np.isfinite(self.resid)
        #: first row of the last of the BLOCKS time blocks (the edge of the training part)
        self.edge = -(-(BLOCKS - 1) * cut // BLOCKS)
        self.n_train = int(self.train.sum())
        self.cols = list(cols)
        # sets per input of a pair's cells: MIN_PER_CELL training samples per cell
        fill = max(self.n_train / MIN_PER_CELL, 1.0)
        self.pair_sets = int(min(max(math.floor(math.sqrt(fill) + 1e-9), 2), SETS_RANGE[1]))
        self.pair_idx = [self.index(c, self.pair_sets) for c in cols]

    def index(self, col: np.ndarray, sets: int) -> np.ndarray:
        """Set index (0 … sets-1) of every row of ``col`` over the range its training rows
        use; -1 where missing."""
        x = col[: self.cut][self.train]
        return set_index(col, x[np.isfinite(x)], sets, 0.001)

    def rmse(self, col: np.ndarray, sets: int | None = None) -> float:
        """Screening error (held-out RMSE, % of span) with ``col`` added to the model's
        inputs (or put in place of one); ``sets``: the candidate's set count.

        The correction is looked up in cells of the candidate alone and of the candidate
        paired with each of the model's inputs (at the resolution two inputs' cells fill:
        an effect that acts with an input — a valve's travel against its command — needs
        both finely); the best of these is the candidate's screening error."""
        s_c = max(2, int(min(sets or self.pair_sets, self.pair_sets)))
        own = self.index(col, s_c)
        best = self._score([own], [s_c])
        # the input a candidate would replace is paired too: what the candidate explains of
        # the residual beside it is what replacing it can gain (a dead time: the residual
        # of f(x[k]) is a function of x[k] and x[k-L])
        for k in range(len(self.cols)):
            best = min(best, self._score([self.pair_idx[k], own], [self.pair_sets, s_c]))
        return best

    def unjudged(self, col: np.ndarray, sets: int | None = None) -> float:
        """Share of the held-out rows (``col`` measured) the screen cannot judge ``col`` on:
        its value lies within the range of the training rows but in a cell of ``col`` alone
        (``sets`` as :meth:`rmse` takes them) that fewer than :data:`PRIOR` training rows
        visit before the last of the :data:`BLOCKS` time blocks.

        The correction there rests on the last block's rows alone, or on none. The fold
        layout ends at the cut: the last block's out-of-fold residual is what a model
        without it makes of the inputs it reaches (extrapolating, where the inputs wander
        somewhere new just before the cut), while the model judged on the held-out block
        was trained on it — issue 37: a manual valve moved half an hour before the cut, its
        correction +29.6 % of span where the held-out residual averages −11.3 %. A value
        beyond the training range (a drift's ``days()``) is an extrapolation the retrained
        model answers with its nearest rule too: not counted."""
        s_c = max(2, int(min(sets or self.pair_sets, self.pair_sets)))
        own = self.index(col, s_c)
        kv = own[self.va]
        seen = kv >= 0
        before = np.flatnonzero(self.train[: self.edge] & (own[: self.edge] >= 0))
        if not seen.any() or not before.size:
            return 0.0
        cnt = np.bincount(own[before], minlength=s_c)
        x = col[: self.cut][self.train & (own[: self.cut] >= 0)]
        v = col[self.va]
        thin = seen & (v >= x.min()) & (v <= x.max()) & (cnt[np.maximum(kv, 0)] < PRIOR)
        return float(thin.sum() / seen.sum())

    def _score(self, parts: Sequence[np.ndarray], sets: Sequence[int]) -> float:
        key = np.zeros(self.y.size, np.int64)
        bad = np.zeros(self.y.size, bool)
        radix = 1
        for ix, n in zip(parts, sets, strict=True):
            key += ix * radix
            bad |= ix < 0
            radix *= n
        key[bad] = -1
        tr = np.flatnonzero(self.train & (key[: self.cut] >= 0))
        kt, rt = key[tr], self.resid[tr]
        kv = key[self.va]
        if radix <= DENSE_CELLS:
            cnt = np.bincount(kt, minlength=radix)
            sm = np.bincount(kt, rt, minlength=radix)
            corr = sm / (cnt + PRIOR)
            fix = np.where(kv >= 0, corr[np.maximum(kv, 0)], 0.0)
        else:
            uk, inv = np.unique(kt, return_inverse=True)
            corr = np.bincount(inv, rt) / (np.bincount(inv) + PRIOR)
            pos = np.minimum(np.searchsorted(uk, kv), max(uk.size - 1, 0))
            hit = (kv >= 0) & (uk[pos] == kv) if uk.size else np.zeros(kv.size, bool)
            fix = np.where(hit, corr[pos] if uk.size else 0.0, 0.0)
        r = (self.y[self.va] - self.base_va - fix) / self.span * 100.0
        return float(np.sqrt(np.mean(r * r))) if r.size else math.nan


def _oof_residual(rb: RuleBase, cols: Sequence[np.ndarray], y: np.ndarray, cut: int) -> np.ndarray:
    """Out-of-fold residual of the model on the training rows (NaN elsewhere): each of
    :data:`FOLDS` interleaved groups of :data:`BLOCKS` time blocks predicted by the model
    trained on the other groups (its nearest rule standing in where it has none)."""
    out = np.full(cut, np.nan)
    if not len(cols) or cut < 10:
        return out
    X = np.column_stack([c[:cut] for c in cols])
    rows = np.flatnonzero(np.isfinite(X).all(axis=1) & np.isfinite(y[:cut]))
    if rows.size < 10 * FOLDS:
        return out
    group = (rows * BLOCKS // cut) % FOLDS
    spec = dc_replace(rb.spec, inputs=list(rb.inputs))
    for g in range(FOLDS):
        tr, te = rows[group != g], rows[group == g]
        if tr.size < 10 or te.size == 0:
            continue
        m = rb.codec.new_estimator(spec).fit(X[tr], y[tr])
        out[te] = y[te] - m.extrapolate(X[te])
    return out
