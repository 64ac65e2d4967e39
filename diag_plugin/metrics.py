"""Residuals and error figures in % of the output's nominal span — the one place they are
computed (Kościelny et al., eq. 6), for training, compare, explain and the report."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def residual_pct(y: np.ndarray, yhat: np.ndarray, span: float) -> np.ndarray:
    """Residual in % of the nominal span: ``(y − ŷ) / (y_max − y_min) · 100`` (eq. 6)."""
    return (np.asarray(y, float) - np.asarray(yhat, float)) / span * 100.0


@dataclass
class ErrorStats:
    """Streaming statistics of residuals in % of span (eq. 6), mergeable across chunks.

    NaN residuals (samples the model did not predict) count against
    ``coverage`` and are left out of the error figures.
    """

    n: int = 0
    n_total: int = 0
    s1: float = 0.0
    s2: float = 0.0
    sabs: float = 0.0
    maxabs: float = 0.0

    def update(self, r: np.ndarray) -> ErrorStats:
        """Add residuals (% of span)."""
        r = np.asarray(r, float)
        self.n_total += r.size
        r = r[np.isfinite(r)]
        self.n += r.size
        self.s1 += float(r.sum())
        self.s2 += float(r @ r)
        self.sabs += float(np.abs(r).sum())
        if r.size:
            self.maxabs = max(self.maxabs, float(np.abs(r).max()))
        return self

    def merge(self, other: ErrorStats) -> ErrorStats:
        self.n += other.n
        self.n_total += other.n_total
        self.s1 += other.s1
        self.s2 += other.s2
        self.sabs += other.sabs
        self.maxabs = max(self.maxabs, other.maxabs)
        return self

    def result(self) -> dict[str, float | int]:
        """RMSE, MAE, bias and max |error| in % of span, coverage and the sample count."""
        n = max(self.n, 1)
        nan = float("nan")
        return {
            "rmse_pct": float(np.sqrt(self.s2 / n)) if self.n else nan,
            "mae_pct": self.sabs / n if self.n else nan,
            "bias_pct": self.s1 / n if self.n else nan,
            "max_abs_pct": self.maxabs if self.n else nan,
            "coverage": self.n / self.n_total if self.n_total else nan,
            "samples": self.n_total,
        }


def error_figures(residual: np.ndarray) -> dict[str, float | int]:
    """The figures of :meth:`ErrorStats.result` for one array of residuals."""
    return ErrorStats().update(residual).result()
