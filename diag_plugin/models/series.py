"""How many independent values a series holds — the one estimate every stage uses: the
thresholds and their false-alarm budget (``diagnose/``, ``learn/``), the short-window checks of
a unit build (``unitbuild/``) and the consequence check of ``explain`` (``selection/``).

Below both chains of the layer order (README, "Layer order"), so the run-time and the
workbench share it rather than each writing its own.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["autocorrelation", "effective_samples"]


def effective_samples(x: Any) -> float:
    """About how many independent values a series holds: ``n / τ`` with ``τ`` the
    integrated autocorrelation time ``1 + 2 Σ ρ_k``, summed up to the first lag where the
    sample autocorrelation ``ρ_k`` is no longer positive (Sokal's window, truncated where the
    estimate turns to noise). A filtered residual is strongly correlated: a quantile learned
    over few independent values is their maximum, and fault-free data outside the window cross
    it. NaNs are left out (the series is taken as contiguous); fewer than 3 finite values
    give their count."""
    a = np.asarray(x, dtype=float).ravel()
    a = a[np.isfinite(a)]
    n = a.size
    if n < 3:
        return float(n)
    a = a - a.mean()
    if not np.any(a):
        return float(n)
    rho, k = autocorrelation(a)
    tau = max(1.0, 1.0 + 2.0 * float(rho[1:k].sum()))
    return n / tau


def autocorrelation(a: np.ndarray) -> tuple[np.ndarray, int]:
    """The sample autocorrelation ``ρ_k`` (k = 0 … n−1) of a centred series ``a`` with some
    non-zero value, and Sokal's window: the first lag where ``ρ_k`` is no longer positive
    (``n`` where it stays positive); :func:`effective_samples` sums ``ρ`` below it."""
    from scipy import signal

    n = a.size
    ac = signal.correlate(a, a, mode="full", method="fft")[n - 1 :]
    rho = ac / ac[0]
    stop = np.flatnonzero(rho[1:] <= 0.0)
    return rho, int(stop[0]) + 1 if stop.size else n
