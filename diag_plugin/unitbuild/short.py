"""How ``diag unit build`` fits the window it is given: a few hundred samples, or a day at 1 s.

:func:`plan_for` reads the window's length and chooses, saying why (issue 34, item 3):

* **A short window** (fewer than :data:`SHORT_ROWS` grid points, at least
  :data:`MIN_ROWS`; e.g. SKAB's protocol, the first 400 samples of a run at 1 s): at most
  :data:`SHORT_MAX_INPUTS` inputs per test, chosen with a linear model (a few hundred samples
  determine ``1 + d`` coefficients, not a grid of ``sets^d`` rules); then per test a rule grid
  of at most :data:`SHORT_MAX_SETS` sets per input only where the data fill its cells with
  :data:`SHORT_PER_CELL` samples each *and* it beats the linear test's held-out error by more
  than the build's ``MIN_GAIN``; elsewhere the test is linear (:mod:`diag_plugin.models.linear`):
  the tag against a least-squares combination of its inputs, a PCA-like parity relation.
* **A long window on a fast grid** (more than :data:`SELECT_ROWS` grid points, e.g. a day at
  1 s): the inputs and dead times are chosen on a grid :func:`coarse_factor` times coarser
  (means over consecutive samples), the dead times scaled back; the models are then trained,
  and the thresholds learned, at the data's own rate, and the unit runs at that rate.
* Otherwise the build as before (``wm-avg`` on the sets the data fill).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from diag_plugin.regressors import InputSpec
from diag_plugin.selection.sets import SETS_RANGE

#: fewest grid points a unit is built from (the thresholds need a few hundred settled residuals)
MIN_ROWS = 200
#: below this many grid points the window is short (see module doc)
SHORT_ROWS = 1000
#: inputs per test at most in a short window
SHORT_MAX_INPUTS = 2
#: sets per input at most in a short window's rule grid
SHORT_MAX_SETS = 5
#: training samples per occupied rule cell a short window's grid must hold
SHORT_PER_CELL = 40
#: above this many grid points inputs are chosen on a coarser grid
SELECT_ROWS = 20_000
#: the linear method a short window's tests fall back to
LINEAR = "linear"


@dataclass
class Plan:
    """What the build does with this window, and why (printed and kept in ``[build]``)."""

    rows: int
    period: str
    short: bool = False
    max_inputs: int = 3
    select_method: str = "wm-avg"
    max_sets: int | None = None
    factor: int = 1
    reasons: list[str] = field(default_factory=list)

    @property
    def select_period(self) -> str:
        """The grid inputs are chosen on."""
        return _fmt(pd.Timedelta(self.period) * self.factor)

    def as_dict(self) -> dict:
        return {
            "rows": self.rows,
            "short": self.short,
            "max_inputs": self.max_inputs,
            "select_method": self.select_method,
            "max_sets": self.max_sets,
            "select_period": self.select_period,
            "reasons": list(self.reasons),
        }


def _fmt(td: pd.Timedelta) -> str:
    s = td.total_seconds()
    if s >= 60 and s % 60 == 0:
        return f"{int(s // 60)}min"
    return f"{s:g}s"


def coarse_factor(rows: int) -> int:
    """Consecutive samples averaged into one for the choice of inputs: the window shrunk to
    at most :data:`SELECT_ROWS` grid points."""
    return max(1, math.ceil(rows / SELECT_ROWS))


def plan_for(rows: int, period: str, max_inputs: int) -> Plan:
    """The build's plan for a window of ``rows`` grid points of ``period`` (module doc)."""
    p = Plan(rows, period, max_inputs=max_inputs)
    if rows < SHORT_ROWS:
        p.short = True
        p.max_inputs = min(max_inputs, SHORT_MAX_INPUTS)
        p.select_method = LINEAR
        p.max_sets = SHORT_MAX_SETS
        p.reasons.append(
            f"short window ({rows} samples of {period}, under {SHORT_ROWS}): at most "
            f"{p.max_inputs} inputs per test, chosen with a linear model; a rule grid (at most "
            f"{SHORT_MAX_SETS} sets per input) only where its cells hold {SHORT_PER_CELL} "
            "samples each and it beats the linear test on held-out error, else a linear "
            "(PCA-like) test"
        )
    elif rows > SELECT_ROWS:
        p.factor = coarse_factor(rows)
        p.reasons.append(
            f"long window ({rows} samples of {period}): inputs and dead times chosen on a "
            f"{p.select_period} grid (means of {p.factor} samples), models trained and "
            f"thresholds learned at {period}"
        )
    return p


def coarse_frame(frame: pd.DataFrame, factor: int) -> pd.DataFrame:
    """Means of ``factor`` consecutive rows (NaN-tolerant), indexed by each group's first
    timestamp: the grid the inputs are chosen on."""
    if factor <= 1:
        return frame
    g = np.arange(len(frame)) // factor
    out = frame.groupby(g).mean()
    out.index = frame.index[::factor][: len(out)]
    return out


def scale_lag(spec: str, factor: int) -> str:
    """An input spec chosen on the coarse grid with its dead time on the data's grid."""
    if factor <= 1:
        return spec
    s = InputSpec.parse(spec)
    return str(InputSpec(s.fn, s.tags, s.lag * factor, s.param))


def grid_cells(cols: Sequence[np.ndarray], spans: Sequence[tuple[float, float]], sets: int):
    """Rows with every input known, and the rule cells they occupy at ``sets`` per input."""
    X = np.column_stack(cols)
    X = X[np.isfinite(X).all(axis=1)]
    lo = np.array([s[0] for s in spans])
    width = np.array([s[1] - s[0] for s in spans])
    idx = np.clip(np.floor((X - lo) / width * (sets - 1) + 0.5), 0, sets - 1).astype(np.int64)
    return len(X), int(np.unique(idx @ (sets ** np.arange(idx.shape[1], dtype=np.int64))).size)


def short_sets(cols: Sequence[np.ndarray], spans: Sequence[tuple[float, float]]) -> int | None:
    """The most sets per input (at most :data:`SHORT_MAX_SETS`) whose occupied cells hold
    :data:`SHORT_PER_CELL` samples each; None where even the coarsest grid is too thin."""
    for sets in range(SHORT_MAX_SETS, SETS_RANGE[0] - 1, -1):
        n, cells = grid_cells(cols, spans, sets)
        if n >= SHORT_PER_CELL * cells:
            return sets
    return None


#: a linear test's inputs are trusted this share of their observed range beyond it
MARGIN = 0.25


def widened(span: tuple[float, float]) -> tuple[float, float]:
    """A linear test's input span from a short window's observed range, :data:`MARGIN` of
    it wider on each side: where an input leaves it the test is unknown (the unit
    CHECK_FUNCTION, naming the input; ``diag unit accept`` learns the new range)."""
    lo, hi = span
    w = (hi - lo) * MARGIN
    return (lo - w, hi + w)
