"""Sets per input chosen from the data, on held-out samples (issue 37).

One count for every input (:func:`~diag_plugin.selection.sets.sets_for_data`) gives an input
that hardly matters as many sets as the one that matters most: with four inputs the grid of
31⁴ cells is so thin that the fine rules answer a small share of the held-out samples and
the coarser levels answer the rest. :func:`choose_sets` searches each input's count on a
ladder (:data:`LADDER`) by coordinate descent: from the data-filled count for every input,
each round tries one step down and one up for each input, trains the fine grid alone on the
rows before the time-ordered cut (accumulators only: no coarse level to fit, and all training
rows, so no cell is thinner than it will be) and scores it on the held-out samples (every
``stride``-th of them, its nearest rule standing in where it has none), and takes the move that
cuts that error most; it stops when no move cuts it by :data:`GAIN`. The choice is then scored
as training scores it (coarser levels behind the fine grid) beside the start, and kept only
when it is no worse and the error falls or the fine grid answers more. The search runs only
where the start's fine grid answers less than :data:`FINE_TARGET` of the held-out samples.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from dataclasses import dataclass
from dataclasses import replace as dc_replace

import numpy as np

from diag_plugin.fuzzy.partition import SHAPES
from diag_plugin.rulebase.document import RuleBase
from diag_plugin.selection.scoring import HeldOutScorer

#: the set counts tried (31 is the paper's)
LADDER = (3, 5, 7, 11, 15, 21, 31, 41)
#: a move must cut the held-out error by this share
GAIN = 0.01
#: held-out samples scored during the search (every n/HELD_SCORED-th)
HELD_SCORED = 20_000
#: rounds of the search at most
ROUNDS = 12
#: the search runs only where the fine grid answers less than this share of held-out samples
FINE_TARGET = 0.8
#: how the note of a shape choice begins (:meth:`ShapeChoice.note`)
SHAPE_NOTE = "set shape chosen on held-out data"


@dataclass(frozen=True)
class SetChoice:
    """Chosen sets per input with the held-out error (% of span) and the share the fine grid
    answered, before (``start``) and after the search."""

    sets: list[int]
    rmse_pct: float
    fine: float
    start: list[int]
    start_rmse_pct: float
    start_fine: float

    def note(self, names: Sequence[str]) -> str:
        chosen = ", ".join(f"{n} {s}" for n, s in zip(names, self.sets, strict=True))
        return (
            f"sets per input chosen on held-out data: {chosen} (held-out error "
            f"{self.start_rmse_pct:.2f} → {self.rmse_pct:.2f} % of span, the fine grid "
            f"answering {self.start_fine:.0%} → {self.fine:.0%} of the samples; "
            f"{self.start[0]} sets each to start)"
        )


def _snap(n: int) -> int:
    return min(LADDER, key=lambda s: (abs(s - n), s))


def choose_sets(
    rb: RuleBase, cols: Sequence[np.ndarray], y: np.ndarray, cut: int, start: int
) -> SetChoice | None:
    """Sets per input of ``rb``'s inputs (see the module doc), or None where the data do not
    allow a search (too few samples either side of the cut) or the fine grid of ``start``
    sets each already answers :data:`FINE_TARGET` of the held-out samples."""
    after = np.flatnonzero(np.isfinite(y[cut:])) + cut
    if after.size < 20 or cut < 20 or not len(cols):
        return None
    stride = max(1, after.size // HELD_SCORED)
    y_held = y.copy()
    keep = np.zeros(y.size, bool)
    keep[after[::stride]] = True
    y_held[cut:] = np.where(keep[cut:], y[cut:], np.nan)
    scorer = HeldOutScorer(rb, cols, y_held, cut)
    first = tuple(_snap(start) for _ in rb.inputs)

    def full(sets: tuple[int, ...]) -> tuple[float, float]:
        vs = [dc_replace(v, sets=s) for v, s in zip(rb.inputs, sets, strict=True)]
        rmse, _, _, fine = scorer.score(vs, cols)
        return (rmse if math.isfinite(rmse) else math.inf), fine

    e0, f0 = full(first)
    if f0 >= FINE_TARGET:
        return None
    X = np.column_stack(cols)
    tr = np.flatnonzero(np.isfinite(X[:cut]).all(axis=1) & np.isfinite(y[:cut]))
    va = scorer.va[np.isfinite(X[scorer.va]).all(axis=1)]
    if tr.size < 20 or va.size < 10:
        return None
    cache: dict[tuple[int, ...], float] = {}

    def quick(sets: tuple[int, ...]) -> float:
        """Held-out RMSE of the fine grid alone (levels=0), its nearest rule standing in:
        accumulators only, no coarse level to fit."""
        if sets not in cache:
            vs = [dc_replace(v, sets=s) for v, s in zip(rb.inputs, sets, strict=True)]
            m = rb.codec.new_estimator(dc_replace(rb.spec, inputs=vs))
            if "levels" in getattr(m, "_params", ()):
                m.set_params(levels=0)
            m.fit(X[tr], y[tr])
            r = (y[va] - m.extrapolate(X[va])) / scorer.span * 100.0
            cache[sets] = float(np.sqrt(np.mean(r * r))) if np.isfinite(r).all() else math.inf
        return cache[sets]

    cur = first
    for _ in range(ROUNDS):
        err = quick(cur)
        moves = []
        for k, s in enumerate(cur):
            i = LADDER.index(s)
            for j in (i - 1, i + 1):
                if 0 <= j < len(LADDER):
                    moves.append(cur[:k] + (LADDER[j],) + cur[k + 1 :])
        best = min((quick(m), m) for m in moves)
        if not best[0] < err * (1 - GAIN):
            break
        cur = best[1]
    if cur == first:
        return None
    e1, f1 = full(cur)
    if not (e1 <= e0 * (1 + GAIN / 2) and (e1 < e0 or f1 > f0)):
        return None  # the full model (coarser levels behind the fine grid) is not better
    return SetChoice(list(cur), e1, f1, list(first), e0, f0)


@dataclass(frozen=True)
class ShapeChoice:
    """The set shape chosen on held-out data, with the held-out error (% of span) of each
    shape tried."""

    shape: str
    rmse_pct: dict[str, float]

    def note(self) -> str:
        tried = ", ".join(f"{s} {e:.2f}" for s, e in self.rmse_pct.items())
        return f"{SHAPE_NOTE}: {self.shape} (held-out error, % of span: {tried})"


def choose_shape(
    rb: RuleBase, cols: Sequence[np.ndarray], y: np.ndarray, cut: int
) -> ShapeChoice | None:
    """The shape of the sets (:data:`~diag_plugin.fuzzy.partition.SHAPES`) whose model, trained
    on the rows before the time-ordered ``cut``, errs least on the held-out rows after it
    (every sample scored, the nearest rule standing in where a model has no answer, as
    ``diag train`` scores); the paper's trapezoidal sets unless another shape cuts that error
    by :data:`GAIN`. None where the data do not allow a choice (fewer than 20 samples either
    side of the cut, or no input).

    Why it matters: with trapezoidal sets (Kościelny et al., Sect. 4.4) only one rule fires
    on the plateau around each set centre, so the defuzzified output (eq. 5 conclusions,
    centroid of the fired rules) is a staircase — flat over half of every cell — where
    triangular sets give the multilinear interpolation between rule centres. On a smooth
    surface measured with little noise the staircase costs up to a quarter of a cell's change
    of output; on a noisy or stepwise one the plateau may do no harm."""
    after = np.flatnonzero(np.isfinite(y[cut:]))
    if after.size < 20 or cut < 20 or not len(cols):
        return None
    if "shape" not in getattr(rb.codec.estimator, "_params", ()):
        return None  # a method without fuzzy sets (the codec's estimator class says)
    errors: dict[str, float] = {}
    for shape in SHAPES:
        probe = copy.copy(rb)  # the same file with other sets: only the spec is read
        probe.shape = shape
        scorer = HeldOutScorer(probe, cols, y, cut)
        if scorer.base_model is None or not math.isfinite(scorer.base_rmse):
            return None
        errors[shape] = scorer.base_rmse
    best = min(errors, key=errors.get)
    paper = "trapezoidal"
    shape = best if errors[best] < errors[paper] * (1 - GAIN) else paper
    return ShapeChoice(shape, errors)
