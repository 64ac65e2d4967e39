"""Values from pandas/numpy made fit for JSON output — one rule for every ``--json``."""

from __future__ import annotations

import math
from collections.abc import Mapping


def finite_float(v) -> float | None:
    """``v`` as a finite float, else None (missing, text, NaN or infinite)."""
    if v is None:
        return None
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def to_jsonable(v):
    """Timestamps as ISO text, numpy scalars as Python numbers, NaN/NaT/inf as None,
    mappings and sequences converted element by element."""
    if v is None or isinstance(v, bool | str):
        return v
    if isinstance(v, Mapping):
        return {str(k): to_jsonable(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [to_jsonable(x) for x in v]
    if hasattr(v, "isoformat"):
        return None if str(v) == "NaT" else v.isoformat()
    if hasattr(v, "item") and not hasattr(v, "__len__"):
        return to_jsonable(v.item())
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v
