"""Conversions between the stored time (int64 µs since epoch, UTC) and pandas."""

from __future__ import annotations

import time

import numpy as np
import pandas as pd

US = 1_000_000


def now_us() -> int:
    """The current time as int µs since epoch UTC."""
    return int(time.time() * US)


def to_us(t) -> int:
    """A time (str, datetime, Timestamp, int µs) as int µs since epoch UTC; naive means UTC."""
    if isinstance(t, (int, np.integer)):
        return int(t)
    ts = pd.Timestamp(t)
    if ts.tzinfo is None:
        ts = ts.tz_localize("UTC")
    return int(ts.tz_convert("UTC").as_unit("us").asm8.view(np.int64))


def from_us(us: int | None) -> pd.Timestamp | None:
    if us is None:
        return None
    return pd.Timestamp(int(us), unit="us", tz="UTC")


def period_us(period) -> int:
    """A period ('10s', Timedelta, seconds as number) in µs."""
    if isinstance(period, (int, float, np.integer, np.floating)):
        us = int(round(float(period) * US))
    else:
        us = int(pd.Timedelta(period) // pd.Timedelta(1, "us"))
    if us <= 0:
        raise ValueError(f"period must be positive, got {period!r}")
    return us


def index_us(index) -> np.ndarray:
    """A DatetimeIndex / datetime-like array as int64 µs UTC (naive means UTC)."""
    idx = pd.DatetimeIndex(index)
    if idx.tz is None:
        idx = idx.tz_localize("UTC")
    return idx.tz_convert("UTC").as_unit("us").asi8.astype(np.int64, copy=False)


def us_index(us: np.ndarray, name: str = "ts") -> pd.DatetimeIndex:
    """int64 µs → tz-aware UTC DatetimeIndex."""
    arr = np.asarray(us, dtype=np.int64).view("datetime64[us]")
    return pd.DatetimeIndex(arr, name=name).tz_localize("UTC")
