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


#: dead times screened by a direct product of lagged columns at most (more: per-pair FFTs)
DIRECT_LAGS = 64


class LagScreen:
    """:func:`lag_screen` of one target against many candidate columns in one pass.

    The candidates are centred once (``columns``: name → values over the same rows); each
    call lags the target (``L = 0 … max_lag``) into a matrix and multiplies it with every
    candidate column at once, instead of a correlation per candidate. Each candidate's
    correlation is :func:`lag_screen`'s (the means over the rows both have, the missing rows
    as zeros; sums instead of its FFT, so equal to rounding). A candidate missing on some
    row the target has, or a horizon over :data:`DIRECT_LAGS`, is screened by
    :func:`lag_screen` itself."""

    def __init__(self, columns: dict[str, np.ndarray], max_lag: int):
        self.names = list(columns)
        self.pos = {c: i for i, c in enumerate(self.names)}
        self.max_lag = int(max_lag)
        self.raw = columns
        V = np.column_stack([columns[c] for c in self.names]) if self.names else np.empty((0, 0))
        self.have = np.isfinite(V)
        g = np.array(
            [float(np.mean(V[h, i])) if h.any() else 0.0 for i, h in enumerate(self.have.T)]
        )
        self.V0 = np.where(self.have, V - g, 0.0)  # centred on the column's own mean
        self.S1 = self.V0.sum(axis=0)
        self.S2 = np.einsum("ij,ij->j", self.V0, self.V0)
        self.cnt = self.have.sum(axis=0).astype(float)
        self.all_have = self.have.all(axis=0)

    def screen(self, target: np.ndarray, names: list[str]) -> dict[str, np.ndarray]:
        """``{name: |correlation| of target[k] with name[k-L] for L = 0 … max_lag}``."""
        L = self.max_lag
        ft = np.isfinite(target)
        out: dict[str, np.ndarray] = {}
        n = target.size
        idx = np.array([self.pos[c] for c in names], np.int64)
        direct = np.zeros(idx.size, bool)
        if L <= DIRECT_LAGS and n == self.V0.shape[0] and ft.sum() >= 10 and idx.size:
            # a candidate with a value on every row the target has: the rows both have are
            # the target's, so one centring of the target serves every such candidate
            direct = self.all_have[idx] | self.have[ft][:, idx].all(axis=0)
        if direct.any():
            sel = idx[direct]
            nt = float(ft.sum())
            t0 = np.where(ft, target - float(np.mean(target[ft])), 0.0)
            lagged = np.zeros((L + 1, n))
            for g in range(min(L, n - 1) + 1):
                lagged[g, : n - g] = t0[g:]  # row g: target[k] beside x[k-g]
            V0 = self.V0[:, sel]
            delta = (ft @ V0) / nt  # candidate's mean on the target's rows less its own
            prod = lagged @ V0
            if not self.all_have[sel].all():
                prod -= delta * (lagged @ self.have[:, sel])
            else:
                prod -= np.outer(lagged.sum(axis=1), delta)
            vv = self.S2[sel] - 2.0 * delta * self.S1[sel] + delta * delta * self.cnt[sel]
            norm = np.sqrt(float(t0 @ t0) * vv)
            with np.errstate(invalid="ignore", divide="ignore"):
                corr = np.where(norm > 0, np.abs(prod) / np.where(norm > 0, norm, 1.0), 0.0)
            for j, c in enumerate(np.asarray(names, object)[direct]):
                out[c] = corr[:, j]
        for c, d in zip(names, direct, strict=True):
            if not d:
                out[c] = lag_screen(target, self.raw[c], L)
        return out
