"""Whether a tag's values are a few discrete levels: a pump's run feedback (0/1), a filter's
state (filtering 0, backwash 1, filter-to-waste 2). The one rule ``diag unit build`` (a
discrete state: never tested, a candidate input) and ``diag tags`` (a state held for hours is
no frozen sensor) share.
"""

from __future__ import annotations

import numpy as np

#: the roles of a declared discrete state in a tags CSV (a row without a loop): a recipe's
#: phase or step, a mode of more levels than :func:`discrete_levels` finds (``diag unit
#: build --state``, ``diag tags --tags``)
STATE_ROLES = ("state", "phase", "step")
#: the role of a run condition in a tags CSV (a two-valued state the unit or a piece runs by)
RUNNING_ROLE = "running"

#: a tag whose few commonest values hold this share of its good values is a discrete state:
#: the rest are points a switch fell within and a grid averaged (docs/reference/historian.md,
#: "Aligned windows")
DISCRETE_SHARE = 0.99
#: the most levels a discrete state takes (a filter's 0/1/2). Not 4: SKAB's quantized
#: pressure (steps of 0.33, four values on a tuning run's 400 samples) would be one
MAX_LEVELS = 3
#: the fewest samples on which each level of a state is read exactly: the one commonest
#: value and a few others each seen once are an analog tag that mostly reads one value (a
#: standby's current, 0 on 396 of 400 samples and 32.3-34.8 A on 4), not a state
MIN_REPEATS = 2
#: the most levels a mode a unit or a piece runs in takes (``--running MODE=1``: idle 0,
#: production 1, CIP 2-4) and a declared state is listed by: a recipe's phases, an HTST
#: pasteuriser's five modes (docs/explanation/acceptance-pasteuriser.md); more is an analog tag
MAX_MODE_LEVELS = 20


def discrete_levels(v: np.ndarray, most: int = MAX_LEVELS) -> tuple[float, ...] | None:
    """The levels of a discrete state, sorted, else None: its two commonest values holding
    :data:`DISCRETE_SHARE` of its finite values, or its three commonest (up to ``most``,
    :data:`MAX_LEVELS`; a run condition's mode :data:`MAX_MODE_LEVELS`) holding that share,
    each beyond the second held on two values running (a mode, not where a grid averaged a
    switch). A filter washed once in 400 samples — 0 on 97.5 %,
    backwash 1 and filter-to-waste 2 on the rest — is one; an analog tag (hundreds of
    values), a quantized one of four values or more, a third value never held, a level read
    on one sample only (:data:`MIN_REPEATS`: a standby that ran 4 samples at 32.3-34.8 A,
    0 on the rest), or a constant (one value) are not."""
    x = np.asarray(v, float)
    x = x[np.isfinite(x)]
    vals, counts = np.unique(x, return_counts=True)
    if len(vals) < 2:
        return None
    order = np.argsort(-counts, kind="stable")
    need = DISCRETE_SHARE * len(x)
    held = None
    for k in range(2, min(most, len(vals)) + 1):
        top = order[:k]
        if counts[top[-1]] < MIN_REPEATS:
            return None  # a value seen once is no level: an analog reading (a standby's amps)
        if k > 2:
            if held is None:
                held = set(np.unique(x[1:][x[1:] == x[:-1]]).tolist())
            if float(vals[top[-1]]) not in held:
                return None
        if counts[top].sum() >= need:
            return tuple(sorted(float(vals[i]) for i in top))
    return None


def levels_text(v: np.ndarray, levels: tuple[float, ...]) -> str:
    """The values a discrete state held, as ``0, 1 or 2``: its ``levels`` and any other value
    of ``v`` held on two values running (a filter's third mode, filter-to-waste, 0.6 % of a
    window, beside its two commonest); a value on single points is where a grid averaged a
    switch (0.5) and is left out."""
    x = np.asarray(v, float)
    x = x[np.isfinite(x)]
    held = set(levels)
    if len(x) > 1:
        held |= {float(y) for y in x[1:][x[1:] == x[:-1]]}
    vals = [f"{y:g}" for y in sorted(held)]
    return ", ".join(vals[:-1]) + f" or {vals[-1]}"
