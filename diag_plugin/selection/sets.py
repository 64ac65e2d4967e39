"""Set counts from the data: the most sets per input the data fill."""

from __future__ import annotations

import sys
from collections.abc import Sequence

import numpy as np

#: training samples per rule cell a grid should keep (set counts chosen from the data)
MIN_PER_CELL = 20
#: set counts chosen from the data stay within these
SETS_RANGE = (3, 31)
#: grids of at most this many cells count their occupied cells in a dense table
OCCUPANCY_CELLS = 1 << 22


def sets_for_data(cols: Sequence[np.ndarray], spans: Sequence[tuple[float, float]]) -> int:
    """The most sets per input (within :data:`SETS_RANGE`; 31 is the paper's count) for which
    the rule cells the data occupy hold :data:`MIN_PER_CELL` samples on average — the
    operating range counts, not the nominal span."""
    X = np.column_stack(cols) if cols else np.empty((0, 0))
    X = X[np.isfinite(X).all(axis=1)] if X.size else X
    n = len(X)
    lo = np.array([s[0] for s in spans])
    width = np.array([s[1] - s[0] for s in spans])
    if n:
        pos = (X - lo) / width  # each sample's place in the span, computed once
        if "numba" in sys.modules and SETS_RANGE[1] ** X.shape[1] <= OCCUPANCY_CELLS:
            if np.isfinite(pos).all():  # the compiled search: the same counts, one loop each
                from diag_plugin.fuzzy import _kernels

                return int(_kernels.sets_filled(pos, SETS_RANGE[1], SETS_RANGE[0], MIN_PER_CELL))
    for sets in range(SETS_RANGE[1], SETS_RANGE[0] - 1, -1):
        if n == 0:
            break
        idx = np.clip(np.floor(pos * (sets - 1) + 0.5), 0, sets - 1).astype(np.int64)
        if n >= MIN_PER_CELL * _occupied(idx, sets):
            return sets
    return SETS_RANGE[0] if n else SETS_RANGE[1]


#: an input visits discrete operating levels (a stepped valve command) when at least this
#: share of its samples sit at levels, each narrower than half a set of the finest grid and
#: holding at least :data:`LEVEL_MIN_SHARE` of the samples
LEVEL_SHARE = 0.95
LEVEL_MIN_SHARE = 0.01


def operating_levels(col: np.ndarray, span: tuple[float, float]) -> np.ndarray | None:
    """The operating levels (each level's median, ascending) an input's values ``col``
    dwell at, when they dwell at levels (:data:`LEVEL_SHARE`); None for an input that moves
    over its range (sorted values with no gap wider than half a set of the finest grid,
    :data:`SETS_RANGE`) or with too few values to tell."""
    x = np.sort(col[np.isfinite(col)])
    tol = (span[1] - span[0]) / (2 * (SETS_RANGE[1] - 1))
    if x.size < MIN_PER_CELL or not tol > 0:
        return None
    groups = np.split(x, np.flatnonzero(np.diff(x) > tol) + 1)
    least = max(2, LEVEL_MIN_SHARE * x.size)
    levels = [g for g in groups if g[-1] - g[0] <= tol and g.size >= least]
    if sum(g.size for g in levels) < LEVEL_SHARE * x.size:
        return None
    return np.array([float(np.median(g)) for g in levels])


def sets_for_levels(levels: np.ndarray, span: tuple[float, float], most: int) -> int:
    """The fewest sets (from :data:`SETS_RANGE`'s least, at most ``most``) whose evenly
    spaced centres over ``span`` put each of ``levels`` in a set of its own — more sets
    train no more rules; ``most`` where none up to it does."""
    pos = (np.asarray(levels, float) - span[0]) / (span[1] - span[0])
    for sets in range(SETS_RANGE[0], most):
        idx = np.clip(np.floor(pos * (sets - 1) + 0.5), 0, sets - 1)
        if np.unique(idx).size == idx.size:
            return sets
    return most


def _occupied(idx: np.ndarray, sets: int) -> int:
    """Distinct rows of ``idx`` (set indices 0 … sets-1 per column): a count of a dense
    occupancy table where the grid is small (no sort), else of the unique keys."""
    key = idx @ (sets ** np.arange(idx.shape[1], dtype=np.int64))
    cells = sets ** idx.shape[1]
    if cells <= OCCUPANCY_CELLS:
        seen = np.zeros(cells, bool)
        seen[key] = True
        return int(np.count_nonzero(seen))
    return int(np.unique(key).size)


def sets_for_cells(n_train: int, cells: int, current: int) -> int:
    """Sets for a new input so that each occupied rule cell keeps about
    :data:`MIN_PER_CELL` training samples (``cells``: rules the model has now)."""
    fit = n_train // max(MIN_PER_CELL * max(cells, 1), 1)
    return int(min(max(fit, 2), current))


def set_index(
    col: np.ndarray, x: np.ndarray, sets: int, tail: float, least: int = 1, clip: bool = True
) -> np.ndarray:
    """Set index (0 … sets-1) of every row of ``col``, the nearest of ``sets`` evenly spaced
    centres over the ``tail`` … 1-``tail`` quantiles of the finite training values ``x``;
    -1 where ``col`` is missing, and everywhere when ``x`` has fewer than ``least`` values.
    Rows beyond the outer centres fall in the outer sets; with ``clip=False`` those more than
    half a set beyond them are -1 too (off the training values' support).
    """
    out = np.full(col.size, -1, np.int64)
    if x.size < least:
        return out
    lo, hi = (float(q) for q in np.quantile(x, [tail, 1.0 - tail]))
    ok = np.isfinite(col)
    if hi <= lo:
        out[ok] = 0
        return out
    t = np.floor((col[ok] - lo) / (hi - lo) * (sets - 1) + 0.5)
    off = (t < 0) | (t > sets - 1)
    out[ok] = np.where(off & (not clip), -1, np.clip(t, 0, sets - 1)).astype(np.int64)
    return out
