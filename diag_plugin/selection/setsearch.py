"""Sets per input chosen from the data, on held-out samples (issue 37).

One count for every input (:func:`~diag_plugin.selection.sets.sets_for_data`) gives an input
that hardly matters as many sets as the one that matters most: with four inputs the grid of
31⁴ cells is so thin that the fine rules answer a small share of the held-out samples and
the coarser levels answer the rest. :func:`choose_sets` searches each input's count on a
ladder (:data:`LADDER`) by coordinate descent: from the data-filled count for every input,
each round tries one step down for each input, trains the model on the
rows before the time-ordered cut and scores it on the held-out samples (every ``stride``-th
of them, so the search stays quick; the training rows are all used, so no cell is thinner
than it will be), and takes the move that cuts the held-out error most. It stops when no
move cuts it by :data:`GAIN` or more. Among moves that change the error by less than
:data:`GAIN`, one that lets the fine grid answer more samples is taken.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from dataclasses import replace as dc_replace

import numpy as np

from diag_plugin.rulebase.document import RuleBase
from diag_plugin.selection.scoring import HeldOutScorer

#: the set counts tried (31 is the paper's)
LADDER = (3, 5, 7, 11, 15, 21, 31)
#: a move must cut the held-out error by this share
GAIN = 0.01
#: held-out samples scored during the search (every n/HELD_SCORED-th)
HELD_SCORED = 20_000
#: rounds of the search at most
ROUNDS = 8


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
    allow a search (too few samples either side of the cut)."""
    y_held = y.copy()
    after = np.flatnonzero(np.isfinite(y[cut:])) + cut
    if after.size < 20 or cut < 20:
        return None
    stride = max(1, after.size // HELD_SCORED)
    keep = np.zeros(y.size, bool)
    keep[after[::stride]] = True
    y_held[cut:] = np.where(keep[cut:], y[cut:], np.nan)
    scorer = HeldOutScorer(rb, cols, y_held, cut)
    cache: dict[tuple[int, ...], tuple[float, float]] = {}

    def score(sets: tuple[int, ...]) -> tuple[float, float]:
        if sets not in cache:
            vs = [dc_replace(v, sets=s) for v, s in zip(rb.inputs, sets, strict=True)]
            rmse, _, _, fine = scorer.score(vs, cols)
            cache[sets] = (rmse if math.isfinite(rmse) else math.inf, fine)
        return cache[sets]

    first = tuple(_snap(start) for _ in rb.inputs)
    cur = first
    for _ in range(ROUNDS):
        err, fine = score(cur)
        moves = []
        for k, s in enumerate(cur):
            i = LADDER.index(s)
            if i > 0:  # down only: finer grids cost most to fit, and thin grids are the ill
                moves.append(cur[:k] + (LADDER[i - 1],) + cur[k + 1 :])
        scored = [(score(m), m) for m in moves]
        better = [(e, m) for (e, _), m in scored if e < err * (1 - GAIN)]
        if better:
            cur = min(better)[1]
            continue
        # no clear gain: a move that keeps the error and lets the fine grid answer more
        wider = [
            (-f, e, m) for (e, f), m in scored if e <= err * (1 + GAIN / 2) and f > fine + 0.05
        ]
        if not wider:
            break
        cur = min(wider)[2]
    (e0, f0), (e1, f1) = score(first), score(cur)
    return SetChoice(list(cur), e1, f1, list(first), e0, f0)
