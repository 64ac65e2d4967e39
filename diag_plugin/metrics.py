"""Residuals and error figures in % of the output's nominal span — the one place they are
computed (Kościelny et al., eq. 6), for training, compare, explain and the report."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: below this coverage every error figure is shown with a warning
COVERAGE_WARN = 0.95
#: error figures name the share answered at rule level k ``coverage_level_k``
LEVEL_KEY = "coverage_level_"


def levels_note(fig: dict) -> str:
    """Where the answers came from, when coarser levels gave some: ``level 0 92.1 %, level 1
    6.0 %, …`` and what a coarser level is (a user saw the fine grid answer 8 % of the samples
    with no word of who answered the rest, issue 37); empty when the fine grid answered
    everything or the method has no levels."""
    by = {
        int(k.removeprefix(LEVEL_KEY)): v
        for k, v in fig.items()
        if k.startswith(LEVEL_KEY) and v is not None
    }
    if not by or set(by) == {0}:
        return ""
    parts = [f"level {k} {100 * v:.1f} %" for k, v in sorted(by.items())]
    coarse = sorted(k for k in by if k > 0)
    merged = ", ".join(f"{2**k}" for k in coarse)
    return (
        "answered at " + ", ".join(parts) + " (0 = the fine rule grid; where its cell has no "
        f"rule a coarser level answers: level {', '.join(map(str, coarse))} = cells of up to "
        f"{merged} neighbouring sets of each input, fitted to the fine rules; "
        "docs/reference/models.md)"
    )


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
    #: samples answered per rule level (0 = the fine grid), for models with levels
    n_level: dict[int, int] = field(default_factory=dict)

    def update(
        self,
        r: np.ndarray,
        r_fallback: np.ndarray | float | None = None,
        level: np.ndarray | None = None,
    ) -> ErrorStats:
        """Add residuals (% of span); ``r_fallback`` are those of the stand-in prediction;
        ``level`` the rule level that answered each sample (``Prediction.level``)."""
        r = np.asarray(r, float)
        own = np.isfinite(r)
        if level is not None:
            lv = np.asarray(level)[own].astype(np.int64)
            for k, c in enumerate(np.bincount(lv[lv >= 0]) if lv.size else []):
                if c:
                    self.n_level[k] = self.n_level.get(k, 0) + int(c)
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
        for k, c in other.n_level.items():
            self.n_level[k] = self.n_level.get(k, 0) + c
        return self

    def result(self) -> dict[str, float | int]:
        """RMSE, MAE, bias and max |error| in % of span (stand-in where no prediction),
        coverage (and its split by rule level, ``coverage_level_k``, when levels were given),
        the RMSE on covered samples alone and the sample count."""
        n = max(self.n, 1)
        nan = float("nan")
        by_level = (
            {f"{LEVEL_KEY}{k}": self.n_level[k] / self.n_total for k in sorted(self.n_level)}
            if self.n_level and self.n_total
            else {}
        )
        return {
            "rmse_pct": float(np.sqrt(self.s2 / n)) if self.n else nan,
            "mae_pct": self.sabs / n if self.n else nan,
            "bias_pct": self.s1 / n if self.n else nan,
            "max_abs_pct": self.maxabs if self.n else nan,
            "coverage": self.n_cov / self.n_total if self.n_total else nan,
            "rmse_covered_pct": float(np.sqrt(self.s2_cov / self.n_cov)) if self.n_cov else nan,
            "samples": self.n_total,
            **by_level,
        }


def error_figures(
    residual: np.ndarray,
    fallback: np.ndarray | float | None = None,
    level: np.ndarray | None = None,
) -> dict:
    """The figures of :meth:`ErrorStats.result` for one array of residuals."""
    return ErrorStats().update(residual, fallback, level).result()
