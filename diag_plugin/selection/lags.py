"""Dead times from the data: the horizon screened and a cheap correlation screen of lags."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

#: dead times screened by default: this much time (and at least MIN_LAGS samples)
LAG_HORIZON_S = 600.0
MIN_LAGS = 10
#: a longer lag is suggested only when it scores better by more than this share
TOLERANCE = 0.01


def lag_screen(target: np.ndarray, x: np.ndarray, max_lag: int) -> np.ndarray:
    """|correlation| of ``target[k]`` with ``x[k-L]`` for ``L = 0 … max_lag`` (NaN-tolerant,
    via FFT): a cheap screen of dead times before any model is retrained."""
    from scipy.signal import correlate

    n = min(target.size, x.size)
    t, v = target[:n], x[:n]
    both = np.isfinite(t) & np.isfinite(v)
    if both.sum() < 10:
        return np.zeros(max_lag + 1)
    t0 = np.where(np.isfinite(t), t - np.nanmean(t[both]), 0.0)
    v0 = np.where(np.isfinite(v), v - np.nanmean(v[both]), 0.0)
    norm = math.sqrt(float(t0 @ t0) * float(v0 @ v0))
    if norm == 0:
        return np.zeros(max_lag + 1)
    full = correlate(t0, v0, mode="full", method="fft")
    lags = full[n - 1 : n + max_lag]
    out = np.zeros(max_lag + 1)
    out[: lags.size] = np.abs(lags) / norm
    return out


def default_max_lag(index: pd.DatetimeIndex) -> int:
    """Dead-time horizon from the data: 10 minutes of samples (at least 10), at most a
    tenth of the rows (transport delays of minutes are common in plants)."""
    if len(index) < 2:
        return 0
    period = (index[1] - index[0]) / pd.Timedelta(seconds=1)
    want = max(MIN_LAGS, math.ceil(LAG_HORIZON_S / period)) if period > 0 else MIN_LAGS
    return int(max(0, min(want, len(index) // 10)))
