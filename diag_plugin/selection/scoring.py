"""Held-out scoring of model variants: a time-ordered held-out block
(:class:`HeldOutScorer`, what ``diag explain`` ranks with) and time-blocked cross-validation
over a window's blocks (:class:`BlockScorer`, what ``diag unit build`` chooses inputs with)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace as dc_replace

import numpy as np
import pandas as pd

from diag_plugin.metrics import residual_pct
from diag_plugin.rulebase.document import RuleBase
from diag_plugin.training.chunked import split_time

#: measured samples a held-out block needs to judge a candidate
MIN_HELD = 10


class FrozenRuleBase:
    """What scoring reads of a rule base — its spec, codec, output and inputs — read once.

    :class:`~diag_plugin.rulebase.document.RuleBase` derives each of them from its TOML
    document on every access; a scorer fits thousands of variants of one model, so it reads
    them once. ``inputs`` replaces the inputs (a variant of the same model)."""

    def __init__(self, rb, inputs: Sequence | None = None):
        base = rb if isinstance(rb, FrozenRuleBase) else None
        self.codec = base.codec if base else rb.codec
        self.output = base.output if base else rb.output
        spec = base.spec if base else rb.spec
        self.inputs = list(spec.inputs) if inputs is None else list(inputs)
        self.spec = spec if inputs is None else dc_replace(spec, inputs=list(inputs))


class HeldOutScorer:
    """Trains a variant of the model on the rows before the cut and scores every variant on
    the *same* held-out samples: all rows after the cut with a measured output.

    Where a variant has no rule its nearest trained rule stands in (``extrapolate``) —
    exactly how ``diag train`` and ``diag compare`` score a model — so predicting fewer
    samples never makes a variant look better, and the error a candidate promises is the
    error training then reports. Each variant's own coverage is reported
    beside its error.
    """

    def __init__(
        self,
        rb: RuleBase | FrozenRuleBase,
        cols: Sequence[np.ndarray],
        y: np.ndarray,
        cut: int,
        fitted: tuple | None = None,
    ):
        self.rb = rb if isinstance(rb, FrozenRuleBase) else FrozenRuleBase(rb)
        rb = self.rb
        self.y = y
        self.cut = cut
        self.span = rb.output.span[1] - rb.output.span[0]
        tr_y = np.isfinite(y[:cut])
        self._tr_y = tr_y  # every variant's training rows have a measured output
        self.mean = float(y[:cut][tr_y].mean()) if tr_y.any() else math.nan
        self.va = np.flatnonzero(np.isfinite(y[cut:])) + cut
        self.last_fine = 0.0
        #: the last variant :meth:`score` fitted (see :attr:`fitted`)
        self.last_fit: tuple | None = None
        if fitted is None:
            pred, self.base_model, self.base_rows = self._fit_predict(list(rb.inputs), cols)
            self.base_fine = self.last_fine
            #: the model's held-out prediction, its stand-in where it has none
            self.base_pred = self._stand_in(pred, self.base_model, cols)
        else:  # this variant as score() fitted it on the same rows: the same model
            pred, self.base_model, self.base_rows, self.base_fine, self.base_pred = fitted
        self.base_cov = float(np.isfinite(pred).mean()) if pred.size else 0.0
        self.base_rmse = self._rmse(self.base_pred)
        self.base_rules = rb.codec.size(self.base_model) if self.base_model is not None else 0

    def _fit(self, variables, X: np.ndarray):
        """A variant fitted on the training rows (None where too few) and its training rows."""
        tr = np.isfinite(X[: self.cut]).all(axis=1) & self._tr_y
        n_train = int(tr.sum())
        if n_train < 10 or self.va.size < 10:
            return None, n_train
        spec = dc_replace(self.rb.spec, inputs=list(variables))
        m = self.rb.codec.new_estimator(spec).fit(X[: self.cut][tr], self.y[: self.cut][tr])
        return m, n_train

    def _fit_predict(self, variables, cols, X: np.ndarray | None = None, prefit=None):
        if not len(cols):  # no input yet: the training mean stands in everywhere
            return np.full(self.va.size, np.nan), None, int(np.isfinite(self.y[: self.cut]).sum())
        X = np.column_stack(cols) if X is None else X
        m, n_train, fine = (*self._fit(variables, X), None) if prefit is None else prefit
        if m is None:
            return np.full(self.va.size, np.nan), None, n_train
        det = m.predict_detail(X[self.va]) if fine is None else m.predict_detail(X[self.va], fine)
        self.last_fine = (
            float(np.mean(det.level == 0)) if det.level is not None else det.coverage
        )  # the share the fine grid answered: levels behind it hide a thin grid otherwise
        return det.y, m, n_train

    def bound(self, variables, cols, X: np.ndarray | None = None) -> tuple[float, tuple | None]:
        """A lower bound of a variant's held-out sum of squared errors (% of span, the sum
        :meth:`score`'s RMSE is the root mean of), from its fine rule level alone: the
        squared errors of the held-out samples the fine level answers for good (none that
        :meth:`~diag_plugin.fuzzy.wang_mendel.WangMendelRegressor.predict_detail` asks a
        coarser level again, none without an answer); 0 where the model has no fine pass.
        With it the fit, for :meth:`score` of the same variant (``prefit``) to finish
        instead of fitting again."""
        if not len(cols):
            return 0.0, None
        X = np.column_stack(cols) if X is None else X
        m, n_train = self._fit(variables, X)
        fine = m.predict_fine(X[self.va], rough=True) if hasattr(m, "predict_fine") else None
        if fine is None:
            return 0.0, (m, n_train, None)
        det, again = fine
        # past an input's span (reason 3) the answer moves along the trend the rough pass
        # leaves out: those samples are left out of the bound too
        final = ~again & np.isfinite(det.y) & (det.reason != 3)
        r = residual_pct(self.y[self.va][final], det.y[final], self.span)
        return float(r @ r), (m, n_train, None)

    def _stand_in(self, pred: np.ndarray, model, cols, X: np.ndarray | None = None) -> np.ndarray:
        """``pred`` with the model's stand-in (its ``extrapolate``: the nearest rule) where it
        has no prediction, and the training mean where an input is missing (``X``: the
        columns stacked, where the caller has them)."""
        out = pred.copy()
        miss = ~np.isfinite(out)
        if model is not None and miss.any():
            X = (np.column_stack(cols) if X is None else X)[self.va[miss]]
            out[miss] = model.extrapolate(X, pred=out[miss])  # predicted already: no answer
        return np.where(np.isfinite(out), out, self.mean)

    def _rmse(self, pred: np.ndarray) -> float:
        if not pred.size or not np.isfinite(pred).all():
            return math.nan
        r = residual_pct(self.y[self.va], pred, self.span)
        return float(np.sqrt(np.mean(r * r)))

    def score(
        self, variables, cols, X: np.ndarray | None = None, prefit: tuple | None = None
    ) -> tuple[float, float, float, float]:
        """Held-out RMSE in % of span on the common samples, own coverage, training samples
        per rule, and the share its fine rule grid answered, of a variant (``X``: ``cols``
        stacked, where the caller has them; ``prefit``: :meth:`bound`'s fit of it)."""
        self.last_fine = 0.0
        self.last_fit = None
        pred, m, n_train = self._fit_predict(variables, cols, X, prefit)
        if m is None:
            return math.nan, 0.0, 0.0, 0.0
        own = np.isfinite(pred)
        per_cell = n_train / max(self.rb.codec.size(m), 1)
        full = self._stand_in(pred, m, cols, X)
        self.last_fit = (pred, m, n_train, self.last_fine, full)
        rmse = self._rmse(full)
        return rmse, float(own.mean()), per_cell, self.last_fine

    def per_rule(self, variables, cols) -> tuple[float, tuple | None]:
        """Training samples per rule of a variant from its fit alone — no coarse level fitted,
        nothing predicted: whether the data can fill its grid at a small share of
        :meth:`score`'s cost (the same figure :meth:`score` reports; 0 where nothing fits) —
        and the fit, for :meth:`score` of the same variant (``prefit``) to finish instead of
        fitting again."""
        if not len(cols):
            return 0.0, None
        m, n_train = self._fit(variables, np.column_stack(cols))
        if m is None:
            return 0.0, None
        return n_train / max(self.rb.codec.size(m), 1), (m, n_train, None)

    def residual(self, cols) -> np.ndarray:
        """The current model's in-sample residual on the training rows (NaN where none)."""
        out = np.full(self.cut, np.nan)
        if self.base_model is not None:
            X = np.column_stack(cols)[: self.cut]
            out = self.y[: self.cut] - self.base_model.predict(X)
        return out


class BlockScorer:
    """:class:`HeldOutScorer` over time blocks: each block of
    the window is held out in turn, a variant is trained on the other blocks and scored on
    it, and the squared errors of all blocks are pooled (time-blocked cross-validation).

    A relation that holds only in part of the window — a correlation that the operators'
    set-point choices of one period made, which another period's choices break — scores
    badly on the blocks it does not hold in; a single held-out tail would judge it on one
    period only. The blocks are ``diag unit learn``'s (:func:`~diag_plugin.learn.thresholds.
    block_of`: a window of several runs is cut between runs), so inputs are chosen on the
    error the thresholds are then learned from. A Wang–Mendel fit is a group-by over rule
    cells, independent of row order, so each fold is the window's rows reordered (training
    rows first) and cut there."""

    def __init__(
        self,
        rb: RuleBase | FrozenRuleBase,
        cols: Sequence[np.ndarray],
        y: np.ndarray,
        block: np.ndarray,
        fitted: Sequence[tuple] | None = None,
    ):
        """``fitted``: the blocks' fits of this very variant from another scorer's
        :meth:`score` on the same ``y`` and blocks (:meth:`fitted`), used instead of
        fitting it again."""
        rb = rb if isinstance(rb, FrozenRuleBase) else FrozenRuleBase(rb)
        self.rb = rb
        self.y = y
        self.folds = []
        good = np.isfinite(y)
        for b in np.unique(block):
            held = block == b
            if np.count_nonzero(held & good) < MIN_HELD:
                continue  # a block the tag is (nearly) missing from judges nothing
            order = np.r_[np.flatnonzero(~held), np.flatnonzero(held)]
            self.folds.append((order, int(np.count_nonzero(~held))))
        if fitted is not None and len(fitted) != len(self.folds):
            raise ValueError("fitted: one fit per block is needed")
        self.parts = [
            HeldOutScorer(rb, [c[o] for c in cols], y[o], cut, None if fitted is None else f)
            for (o, cut), f in zip(self.folds, fitted or [None] * len(self.folds), strict=True)
        ]
        self.base_rmse = self._pool([p.base_rmse for p in self.parts])
        self.mean = float(y[good].mean()) if good.any() else math.nan
        # the current model on every row, for the screen of the next input
        self.model = None
        if len(cols):
            X = np.column_stack(cols)
            ok = np.isfinite(X).all(axis=1) & good
            if ok.sum() >= 10:
                self.model = rb.codec.new_estimator(rb.spec).fit(X[ok], y[ok])

    def _pool(self, rmse: Sequence[float]) -> float:
        """RMSE over every held-out sample from the blocks' RMSEs (NaN if any is NaN)."""
        n = np.array([p.va.size for p in self.parts], float)
        r = np.asarray(rmse, float)
        if not n.sum() or not np.isfinite(r[n > 0]).all():
            return math.nan
        return float(np.sqrt(np.sum(n[n > 0] * r[n > 0] ** 2) / n.sum()))

    def bound(self, variables, cols) -> tuple[float, list | None]:
        """A lower bound of :meth:`score`'s pooled RMSE of a variant from each block's fine
        rule level alone (:meth:`HeldOutScorer.bound`), and the blocks' fits for
        :meth:`score` to finish (``prefit``): a variant whose bound exceeds an error already
        reached cannot do better, and its coarse levels need not be fitted."""
        if not len(cols):
            return 0.0, None
        X = np.column_stack(cols)
        sse, fits = 0.0, []
        for p, (o, _) in zip(self.parts, self.folds, strict=True):
            Xo = X[o]
            s, fit = p.bound(variables, list(Xo.T), Xo)
            sse += s
            fits.append(fit)
        n = sum(p.va.size for p in self.parts)
        return (math.sqrt(sse / n) if n else 0.0), fits

    def score(self, variables, cols, prefit: list | None = None) -> tuple[float, float]:
        """Pooled held-out RMSE (% of span) and own coverage of a variant (``prefit``: the
        blocks' fits from :meth:`bound`)."""
        # the columns stacked once; each block's rows taken from the stack (the same values)
        X = np.column_stack(cols) if len(cols) else np.empty((self.y.size, 0))
        got = []
        pre = prefit or [None] * len(self.parts)
        for p, (o, _), f in zip(self.parts, self.folds, pre, strict=True):
            Xo = X[o]
            got.append(p.score(variables, list(Xo.T), Xo if len(cols) else None, f))
        n = np.array([p.va.size for p in self.parts], float)
        cov = float(np.sum(n * np.array([g[1] for g in got])) / max(n.sum(), 1.0))
        return self._pool([g[0] for g in got]), cov

    def fitted(self) -> list[tuple] | None:
        """The blocks' fits of the variant :meth:`score` scored last (None if a block fitted
        none): a :class:`BlockScorer` of that variant over the same ``y`` and blocks takes
        them as its ``fitted`` instead of fitting the same models again."""
        fits = [p.last_fit for p in self.parts]
        return None if any(f is None for f in fits) else fits

    def residual(self, cols) -> np.ndarray:
        """The current model's in-sample residual on every row (NaN where none)."""
        if self.model is None:
            return self.y - self.mean
        return self.y - self.model.predict(np.column_stack(cols))


def cut_row(index: pd.DatetimeIndex, holdout: float) -> int:
    """First row of the held-out block: the product's one time-based cut."""
    if len(index) == 0:
        return 0
    step = index[1] - index[0] if len(index) > 1 else pd.Timedelta(0)
    t = split_time(index[0], index[-1] + step, holdout, step if len(index) > 1 else None)
    return int(index.searchsorted(t))
