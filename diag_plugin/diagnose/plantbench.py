"""Scoring a detector on a plant-wide simulator, and the PCA T² + Q baseline beside it.

The pieces a plant benchmark needs (issue 25), independent of what raised the alarms:

* :func:`detection_rate` — the share of samples at and after the onset that are in alarm;
* :func:`detection_delay` — the time from the onset to the first alarm at or after it;
* :func:`false_alarm_rate` — on a fault-free run, the share of samples in alarm and the alarm
  episodes (onsets) per hour;
* :class:`PCABaseline` — PCA T² + Q (:class:`~diag_plugin.diagnose.pca.PCADetector`, dynamic
  with ``lags`` previous samples), fitted on fault-free runs, its two limits set together so
  that the share of samples in alarm (T² *or* Q beyond its limit) is ``far`` on fault-free data
  *it was not fitted on*: each training run is scored by a PCA fitted on the other runs
  (leave-one-run-out), the same quantile of each statistic's out-of-sample distribution is
  used for both limits, found by bisection so the union's rate is ``far``;
* :meth:`PCABaseline.contributions` and :meth:`PCABaseline.rank_tags` — each tag's share of
  the combined index ``T²/T²_lim + Q/Q_lim``: the T² part by the complete decomposition
  ``z_j (P Λ⁻¹ Pᵀ z)_j`` and the Q part by ``e_j²`` (Qin, 2003, *J. Chemometrics* 17:480, eqs.
  on contribution plots; Alcala & Qin, 2011), lagged copies summed into their tag, averaged over
  the samples in alarm after the onset: the tags a plant engineer would look at first.

Alarm series are boolean (or 0/1 with NaN for unknown samples, which count neither way).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np
import pandas as pd

from diag_plugin.diagnose.pca import PCADetector

__all__ = [
    "PCABaseline",
    "detection_delay",
    "detection_rate",
    "false_alarm_rate",
    "in_top",
]

log = logging.getLogger(__name__)


def _flags(alarm: pd.Series) -> tuple[np.ndarray, np.ndarray]:
    """(in alarm, known) of an alarm series."""
    x = np.asarray(alarm, dtype=float)
    known = np.isfinite(x)
    return np.where(known, x, 0.0) > 0, known


def _after(alarm: pd.Series, onset: pd.Timestamp) -> pd.Series:
    if not isinstance(alarm, pd.Series) or not isinstance(alarm.index, pd.DatetimeIndex):
        raise TypeError("alarm must be a pandas Series indexed by timestamp")
    return alarm[alarm.index >= pd.Timestamp(onset)]


def detection_rate(alarm: pd.Series, onset: pd.Timestamp) -> float:
    """Share of the known samples at or after ``onset`` that are in alarm (NaN if none)."""
    on, known = _flags(_after(alarm, onset))
    return float(on[known].mean()) if known.any() else float("nan")


def detection_delay(alarm: pd.Series, onset: pd.Timestamp) -> float:
    """Seconds from ``onset`` to the first alarm at or after it (NaN if none)."""
    after = _after(alarm, onset)
    on, _ = _flags(after)
    hit = np.flatnonzero(on)
    if not hit.size:
        return float("nan")
    return float((after.index[hit[0]] - pd.Timestamp(onset)).total_seconds())


def false_alarm_rate(alarm: pd.Series, period_s: float) -> tuple[float, float]:
    """On a fault-free run: (share of known samples in alarm, alarm episodes per hour of known
    samples). An episode starts at a sample in alarm whose previous known sample was not (or
    at the first known sample, if in alarm)."""
    on, known = _flags(alarm)
    k = on[known]
    if not k.size:
        return float("nan"), float("nan")
    starts = int(k[0]) + int(np.count_nonzero(k[1:] & ~k[:-1]))
    hours = k.size * period_s / 3600.0
    return float(k.mean()), starts / hours


def in_top(ranked: Sequence[str], tags: Sequence[str], k: int = 3) -> bool:
    """Whether any of ``tags`` is among the first ``k`` of ``ranked``."""
    return any(t in list(ranked)[:k] for t in tags)


def _union_limits(t2: np.ndarray, q: np.ndarray, far: float) -> tuple[float, float, float]:
    """Limits at the same upper quantile ``1 − p`` of each statistic with the union's rate
    ``far``: bisection on ``p`` (the union's rate grows with it)."""
    ok = np.isfinite(t2) & np.isfinite(q)
    t2, q = t2[ok], q[ok]
    lo, hi = far / 2, far
    for _ in range(40):
        p = 0.5 * (lo + hi)
        a, b = np.quantile(t2, 1 - p), np.quantile(q, 1 - p)
        rate = float(np.mean((t2 > a) | (q > b)))
        lo, hi = (p, hi) if rate < far else (lo, p)
    p = 0.5 * (lo + hi)
    return float(np.quantile(t2, 1 - p)), float(np.quantile(q, 1 - p)), p


class PCABaseline:
    """PCA (or dynamic PCA) T² + Q with limits at a false-alarm rate from out-of-sample data.

    Parameters
    ----------
    far : float
        Share of fault-free samples in alarm the limits are set to (0 < far < 1).
    lags : int
        Previous samples of each tag added as variables (dynamic PCA; 0 = static PCA).
    n_components : int or float
        As :class:`PCADetector` (default: components to 90 % of the variance).
    columns : sequence of str, optional
        The tags used (default: every column of the first training run).
    """

    def __init__(
        self,
        far: float = 0.01,
        lags: int = 0,
        n_components: int | float = 0.9,
        columns: Sequence[str] | None = None,
    ) -> None:
        self.far = far
        self.lags = lags
        self.n_components = n_components
        self.columns = columns

    def _detector(self) -> PCADetector:
        return PCADetector(n_components=self.n_components, lags=self.lags, columns=self.columns_)

    def _joined(self, runs: Sequence[pd.DataFrame]) -> pd.DataFrame:
        """The runs one after another with ``lags`` empty rows between them, so no lagged
        row straddles two runs (the detector drops rows with a missing value)."""
        gap = pd.DataFrame(np.nan, index=range(self.lags), columns=self.columns_)
        parts = []
        for r in runs:
            parts += [r[self.columns_].reset_index(drop=True), gap]
        return pd.concat(parts[:-1], ignore_index=True)

    def fit(self, runs: Sequence[pd.DataFrame]) -> PCABaseline:
        """Fit on fault-free ``runs`` (at least two, scored each by a PCA without it)."""
        if not 0 < self.far < 1:
            raise ValueError(f"far must be in (0, 1), not {self.far}")
        if len(runs) < 2:
            raise ValueError("PCA baseline: give at least two fault-free runs (leave-one-out)")
        self.columns_ = list(self.columns) if self.columns is not None else list(runs[0].columns)
        t2s, qs = [], []
        for i, run in enumerate(runs):
            rest = self._joined([r for j, r in enumerate(runs) if j != i])
            s = self._detector().fit(rest).score(run)
            t2s.append(s["T2"].to_numpy())
            qs.append(s["Q"].to_numpy())
        t2_lim, q_lim, p = _union_limits(np.concatenate(t2s), np.concatenate(qs), self.far)
        self.detector_ = self._detector().fit(self._joined(runs)).set_limits(t2_lim, q_lim)
        self.quantile_ = 1 - p
        log.info(
            "PCA baseline: %d components of %d variables, limits T² %.3g, Q %.3g "
            "(quantile %.5f of out-of-sample statistics, far %g)",
            self.detector_.n_components_,
            len(self.detector_.mean_),
            t2_lim,
            q_lim,
            self.quantile_,
            self.far,
        )
        return self

    def alarms(self, frame: pd.DataFrame) -> pd.Series:
        """1.0 where T² or Q is beyond its limit, 0.0 where neither, NaN where unknown."""
        return self.detector_.decide(frame)

    def contributions(self, frame: pd.DataFrame) -> pd.DataFrame:
        """Per sample and tag, the tag's part of ``T²/T²_lim + Q/Q_lim`` (lags summed)."""
        d = self.detector_
        Z = (d._matrix(frame) - d.mean_) / d.scale_
        P = d.components_
        lam = d.explained_variance_[: d.n_components_]
        T = Z @ P.T
        c_t2 = Z * ((T / lam) @ P)  # complete decomposition: sums to T² per row
        E = Z - T @ P
        c = c_t2 / d.t2_limit_ + E**2 / d.q_limit_
        m = len(d.columns_)
        per_tag = c.reshape(len(c), self.lags + 1, m).sum(axis=1)
        return pd.DataFrame(per_tag, index=frame.index, columns=d.columns_)

    def rank_tags(
        self, frame: pd.DataFrame, onset: pd.Timestamp, alarm: pd.Series | None = None
    ) -> list[str]:
        """The tags by mean contribution over the samples in alarm at or after ``onset``
        (all samples after it when none is in alarm); highest first."""
        alarm = self.alarms(frame) if alarm is None else alarm
        after = frame.index >= pd.Timestamp(onset)
        on, _ = _flags(alarm)
        rows = after & on if (after & on).any() else after
        c = self.contributions(frame)[rows].mean(axis=0, skipna=True)
        return list(c.sort_values(ascending=False).index)
