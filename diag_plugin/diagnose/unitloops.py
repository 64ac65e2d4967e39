"""Loops and alarms an operator can live with (issue 34, items 4, 6, 7).

**Alarm settings in time** (ISA-18.2, alarm rationalisation: on-delay, off-delay and deadband
are set per alarm in seconds and in the signal's units, never in samples). A unit file may give
``on_delay_s`` and ``off_delay_s`` in its ``[evaluation]``: :func:`resolved_evaluation` turns
them into sample counts at the models' period (``ceil(seconds / period)``, at least 1), so the
same file means the same alarm behaviour at 1 s and at 3 min. ``deadband`` (a share of the
threshold): a symptom, once on, clears only when the residual falls below ``(1 − deadband)``
times the threshold it crossed (:class:`Deadband`), so a residual hovering at its threshold
does not chatter.

**The spread of a loop's error** (valve stiction). A sticking valve makes its loop cycle: the
control error oscillates around zero, its level (mean) stays where it was. A test with
``statistic = "spread"`` judges the running standard deviation of its residual instead
(:class:`RunningSpread`: exponentially weighted mean and variance,

    ``m_k = m_{k−1} + a (r_k − m_{k−1})``,  ``v_k = (1 − a) (v_{k−1} + a (r_k − m_{k−1})²)``

(West, 1979, the weighted incremental variance), ``a = 1 − exp(−T / W)`` for period ``T`` and
window ``W = spread_window_s``), learned and thresholded like any test's residual; ``diag unit
build`` writes one beside each loop's level test and names the loop's actuator for it.

**The named tag held through an episode** (:class:`EpisodeHold`): each tag's share of the
alarm is averaged over the samples of the current alarm episode, and the tags are ranked by
that mean, so the tags named do not flicker from sample to sample within one alarm (as the
isolated faults are held, :mod:`~diag_plugin.diagnose.isolation`).
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np
import pandas as pd


def resolved_evaluation(ev: dict[str, Any], period: str) -> dict[str, Any]:
    """``ev`` with ``on_delay``/``off_delay`` in samples from ``on_delay_s``/``off_delay_s``
    (when set) at ``period``: ``ceil(seconds / period)``, at least 1 sample."""
    out = dict(ev)
    s = pd.Timedelta(period).total_seconds()
    for key in ("on_delay", "off_delay"):
        sec = float(ev.get(f"{key}_s", 0.0) or 0.0)
        if sec > 0 and s > 0:
            out[key] = max(1, math.ceil(sec / s - 1e-9))
    return out


def spread_alpha(window_s: float, period: str) -> float:
    """The weight ``a = 1 − exp(−T / W)`` of a running spread over ``window_s`` seconds at
    ``period`` (``W`` at least 5 samples)."""
    s = pd.Timedelta(period).total_seconds()
    w = max(float(window_s), 5.0 * s)
    return 1.0 - math.exp(-s / w)


@numba.njit(cache=True)
def _spread_kernel(x, a, mean, var, seen):  # pragma: no cover - numba
    n, m = x.shape
    out = np.full((n, m), np.nan)
    for j in range(m):
        mu = mean[j]
        v = var[j]
        k = seen[j]
        for i in range(n):
            r = x[i, j]
            if np.isnan(r):
                continue
            if k == 0:
                mu = r
                v = 0.0
            else:
                d = r - mu
                mu += a * d
                v = (1.0 - a) * (v + a * d * d)
            k += 1
            out[i, j] = math.sqrt(v)
        mean[j] = mu
        var[j] = v
        seen[j] = k
    return out


class RunningSpread:
    """Running standard deviation per column (see module doc), state carried across pieces;
    NaN samples are skipped (unknown in, unknown out)."""

    def __init__(self, alpha: float, columns: int) -> None:
        self.alpha = float(alpha)
        self.mean = np.zeros(columns)
        self.var = np.zeros(columns)
        self.seen = np.zeros(columns, np.int64)

    def transform(self, x: np.ndarray) -> np.ndarray:
        a = np.ascontiguousarray(np.asarray(x, float).reshape(len(x), -1))
        return _spread_kernel(a, self.alpha, self.mean, self.var, self.seen)

    def to_state(self) -> dict[str, Any]:
        return {"mean": self.mean.tolist(), "var": self.var.tolist(), "seen": self.seen.tolist()}

    def load_state(self, state: dict[str, Any]) -> None:
        self.mean = np.asarray(state["mean"], float)
        self.var = np.asarray(state["var"], float)
        self.seen = np.asarray(state["seen"], np.int64)


@numba.njit(cache=True)
def _deadband_kernel(r, lo, hi, keep, state):  # pragma: no cover - numba
    n, m = r.shape
    out = np.full((n, m), np.nan)
    for j in range(m):
        s = state[j]
        for i in range(n):
            x = r[i, j]
            if np.isnan(x) or np.isnan(hi[j]):
                continue
            if x > hi[j] or (s > 0 and x > keep * hi[j]):
                s = 1.0
            elif x < lo[j] or (s < 0 and x < keep * lo[j]):
                s = -1.0
            else:
                s = 0.0
            out[i, j] = s
        state[j] = s
    return out


class Deadband:
    """Raw symptoms −1/0/+1 (NaN unknown) with a deadband: on past a threshold, off only
    back inside ``(1 − deadband)`` × it (see module doc); state carried across pieces."""

    def __init__(self, deadband: float, columns: int) -> None:
        self.keep = 1.0 - float(deadband)
        self.state = np.zeros(columns)

    def transform(self, r: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        a = np.ascontiguousarray(np.asarray(r, float))
        return _deadband_kernel(a, np.asarray(lo, float), np.asarray(hi, float), self.keep,
                                self.state)  # fmt: skip


class EpisodeHold:
    """Each tag's share averaged over the current alarm episode (see module doc)."""

    def __init__(self, tags: int) -> None:
        self.total = np.zeros(tags)
        self.count = 0

    def transform(self, share: np.ndarray, active: np.ndarray) -> np.ndarray:
        """Per sample the mean share since its episode began (NaN outside alarms)."""
        act = np.asarray(active, bool)
        n = act.size
        if n == 0:
            return np.full(share.shape, np.nan)
        s = np.where(act[:, None], np.nan_to_num(share, nan=0.0), 0.0)
        cs, cc = np.cumsum(s, axis=0), np.cumsum(act.astype(float))
        prev = np.r_[self.count > 0, act[:-1]]
        start = act & ~prev
        last = np.maximum.accumulate(np.where(start, np.arange(n), -1))
        before = np.clip(last - 1, 0, None)
        base_s = np.where((last > 0)[:, None], cs[before], 0.0)
        base_c = np.where(last > 0, cc[before], 0.0)
        carry = last < 0  # the episode the previous piece left open
        total = cs - base_s + np.where(carry[:, None], self.total, 0.0)
        count = cc - base_c + np.where(carry, self.count, 0)
        with np.errstate(invalid="ignore", divide="ignore"):
            out = np.where(act[:, None], total / np.maximum(count, 1)[:, None], np.nan)
        if act[-1]:
            self.total, self.count = total[-1].copy(), int(count[-1])
        else:
            self.total, self.count = np.zeros(share.shape[1]), 0
        return out

    def to_state(self) -> dict[str, Any]:
        return {"total": self.total.tolist(), "count": self.count}

    def load_state(self, state: dict[str, Any]) -> None:
        self.total = np.asarray(state["total"], float)
        self.count = int(state["count"])
