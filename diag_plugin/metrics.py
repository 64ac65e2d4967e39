"""Residuals and error figures in % of the output's nominal span — the one place they are
computed (Kościelny et al., eq. 6), for training, compare, explain and the report."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: below this coverage every error figure is shown with a warning
COVERAGE_WARN = 0.95


def coverage_note(fig: dict) -> str:
    """A warning to print beside an error figure when the model covers too few samples."""
    cov = fig.get("coverage")
    if cov is None or not np.isfinite(cov) or cov >= COVERAGE_WARN:
        return ""
    return (
        f"⚠ the model predicts only {cov:.0%} of the samples; the others are scored with its "
        f"nearest rule ({fig.get('rmse_covered_pct', float('nan')):.2f} % on the covered ones)"
    )


def residual_pct(y: np.ndarray, yhat: np.ndarray, span: float) -> np.ndarray:
    """Residual in % of the nominal span: ``(y − ŷ) / (y_max − y_min) · 100`` (eq. 6)."""
    return (np.asarray(y, float) - np.asarray(yhat, float)) / span * 100.0


@dataclass
class ErrorStats:
    """Streaming statistics of residuals in % of span (eq. 6), mergeable across chunks.

    The headline figures count every sample: where the model gave no prediction
    (no rule), the residual of its stand-in prediction (the model's
    ``extrapolate``: for Wang–Mendel the nearest trained rule) is used, so a
    model cannot look better by predicting fewer samples. ``coverage`` is the
    share the model predicted itself, and ``rmse_covered_pct`` the error on
    those samples alone.
    """

    n: int = 0
    n_total: int = 0
    s1: float = 0.0
    s2: float = 0.0
    sabs: float = 0.0
    maxabs: float = 0.0
    n_cov: int = 0
    s2_cov: float = 0.0

    def update(self, r: np.ndarray, r_fallback: np.ndarray | float | None = None) -> ErrorStats:
        """Add residuals (% of span); ``r_fallback`` are those of the stand-in prediction."""
        r = np.asarray(r, float)
        own = np.isfinite(r)
        self.n_cov += int(own.sum())
        self.s2_cov += float(r[own] @ r[own])
        if r_fallback is not None:
            r = np.where(own, r, np.broadcast_to(np.asarray(r_fallback, float), r.shape))
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
        self.n_cov += other.n_cov
        self.s2_cov += other.s2_cov
        return self

    def result(self) -> dict[str, float | int]:
        """RMSE, MAE, bias and max |error| in % of span (stand-in where no prediction),
        coverage, the RMSE on covered samples alone and the sample count."""
        n = max(self.n, 1)
        nan = float("nan")
        return {
            "rmse_pct": float(np.sqrt(self.s2 / n)) if self.n else nan,
            "mae_pct": self.sabs / n if self.n else nan,
            "bias_pct": self.s1 / n if self.n else nan,
            "max_abs_pct": self.maxabs if self.n else nan,
            "coverage": self.n_cov / self.n_total if self.n_total else nan,
            "rmse_covered_pct": float(np.sqrt(self.s2_cov / self.n_cov)) if self.n_cov else nan,
            "samples": self.n_total,
        }


def error_figures(
    residual: np.ndarray, fallback: np.ndarray | float | None = None
) -> dict[str, float | int]:
    """The figures of :meth:`ErrorStats.result` for one array of residuals."""
    return ErrorStats().update(residual, fallback).result()
