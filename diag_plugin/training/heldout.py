"""Whether the held-out block judges a model over its inputs' operating range or at one
point of it. On a short window the last 20 % held out can be one constant valve opening
(the i34-qa2 pass: 614 rows at 1 s, 124 held-out samples all at ZC201 = 91.64 %): the
held-out RMSE, and the shape and set counts chosen on it, then say how the model does at
that one point, not over the steps the window visits."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: an input whose held-out values cover less than this share of the range the whole
#: window visits is named (a single operating point covers none of it)
NARROW = 0.05

#: inputs whose values say nothing of an operating point (time of day, drift, direction)
_SKIP = ("dir(", "hour(", "days(")


def narrow_ranges(
    specs: Sequence[str],
    lo: np.ndarray,
    hi: np.ndarray,
    held_lo: np.ndarray,
    held_hi: np.ndarray,
) -> list[dict]:
    """The inputs (``specs``) whose held-out range ``held_lo`` … ``held_hi`` covers under
    :data:`NARROW` of the range ``lo`` … ``hi`` the whole window visits, each as ``input``,
    ``heldout`` [lo, hi], ``window`` [lo, hi] and ``share`` (0 for a single point)."""
    out = []
    for j, spec in enumerate(specs):
        a, b, c, d = (float(v[j]) for v in (lo, hi, held_lo, held_hi))
        if spec.startswith(_SKIP) or not np.isfinite([a, b, c, d]).all() or b <= a:
            continue
        share = (d - c) / (b - a)
        if share < NARROW:
            out.append({"input": spec, "heldout": [c, d], "window": [a, b], "share": share})
    return out


def narrow_inputs(specs: Sequence[str], X: np.ndarray | None, held: np.ndarray) -> list[dict]:
    """:func:`narrow_ranges` of the inputs' values ``X`` (samples × inputs) with the
    held-out rows marked by ``held``; empty without values or without held-out rows."""
    if X is None or not len(X) or not held.any():
        return []
    lo, hi = _range(X)
    held_lo, held_hi = _range(X[held])
    return narrow_ranges(specs, lo, hi, held_lo, held_hi)


def _range(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per column, the least and the greatest finite value (NaN where none)."""
    ok = np.isfinite(X)
    lo = np.where(ok.any(axis=0), np.nanmin(np.where(ok, X, np.inf), axis=0), np.nan)
    hi = np.where(ok.any(axis=0), np.nanmax(np.where(ok, X, -np.inf), axis=0), np.nan)
    return lo, hi


def narrow_note(n: dict) -> str:
    """One warning line for an entry of :func:`narrow_ranges`."""
    c, d = n["heldout"]
    a, b = n["window"]
    where = f"{c:.4g}" if d <= c else f"{c:.4g} … {d:.4g}, {n['share']:.0%} of"
    return (
        f"⚠ the held-out samples see {n['input']} at one operating point ({where} the "
        f"{a:.4g} … {b:.4g} the window visits): "
        "the held-out error judges the model there only, not over the operating points the "
        "data visit (a longer window, or one ending in a stretch that moves it, judges more)"
    )
