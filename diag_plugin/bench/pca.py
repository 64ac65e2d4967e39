"""PCA fault detection with Hotelling's T² and the Q (squared prediction error) statistic.

The established multivariate detector a plant engineer would pick instead of model-based
residuals, so every detection figure of the product is shown beside it (DESIGN.md). Fitted on
a fault-free window of the plant's tags:

* the tags are standardised (mean and standard deviation of the window); with ``lags`` each
  tag's previous samples join them (dynamic PCA, Ku, Storer & Georgakis, 1995);
* the principal components keep ``n_components`` of them, or as many as explain that share of
  the variance when it is a float below 1 (default 0.9);
* ``T² = Σ t_a² / λ_a`` over the kept components (the scores' Mahalanobis distance) and
  ``Q = ‖x − x̂‖²`` of the residual subspace;
* control limits at a false-alarm probability ``alpha`` per sample: ``T²`` by the F
  distribution, ``a (n−1)(n+1) / (n (n−a)) · F(a, n−a)`` (Tracy, Young & Mason, 1992), ``Q`` by
  Jackson & Mudholkar (1979) from the discarded eigenvalues. Limits at another rate, or held to
  an alarm budget per hour (:mod:`diag_plugin.learn.budget`), are set with
  :meth:`PCADetector.set_limits`.

scikit-learn style: ``PCADetector(...).fit(frame)``, ``score(frame)`` (a frame of ``T2`` and
``Q``), ``decide(frame)`` (1.0 alarm, 0.0 none, NaN where a tag is missing), ``limits(alpha)``,
``contributions(frame)`` (each tag's part of the two statistics, to rank tags).
numpy and scipy only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pandas as pd
from scipy import stats

from diag_plugin.models.params import ParamsMixin

__all__ = ["PCADetector"]


class PCADetector(ParamsMixin):
    """PCA with T² and Q statistics and their control limits (see module doc).

    Parameters
    ----------
    n_components : int or float
        Components kept: a count, or the share of variance to explain (0 < share < 1).
    alpha : float
        False-alarm probability per sample of each statistic's limit set by :meth:`fit`.
    lags : int
        Previous samples of each tag added as variables (dynamic PCA).
    columns : sequence of str, optional
        The tags used (default: every numeric column of the frame given to :meth:`fit`).
    """

    _params = ("n_components", "alpha", "lags", "columns")

    def __init__(
        self,
        n_components: int | float = 0.9,
        alpha: float = 0.01,
        lags: int = 0,
        columns: Sequence[str] | None = None,
    ) -> None:
        self._keep(locals())

    # ------------------------------------------------------------ design
    def _matrix(self, frame: pd.DataFrame) -> np.ndarray:
        """Rows × variables: the tags and their ``lags`` previous samples (NaN where unknown)."""
        cols = self.columns_ if hasattr(self, "columns_") else self._pick(frame)
        missing = [c for c in cols if c not in frame]
        if missing:
            raise KeyError(f"PCA detector: tag(s) {', '.join(missing)} not in the data")
        base = frame[list(cols)].to_numpy(float)
        parts = [base]
        for k in range(1, self.lags + 1):
            shifted = np.full_like(base, np.nan)
            shifted[k:] = base[:-k]
            parts.append(shifted)
        return np.hstack(parts)

    def _pick(self, frame: pd.DataFrame) -> list[str]:
        if self.columns is not None:
            return list(self.columns)
        return [c for c in frame.columns if np.issubdtype(frame[c].dtype, np.number)]

    # ------------------------------------------------------------ fitting
    def fit(self, frame: pd.DataFrame) -> PCADetector:
        """Learn the standardisation, components and limits from a fault-free window."""
        if not 0.0 < self.alpha < 1.0:
            raise ValueError(f"alpha must be in (0, 1), got {self.alpha}")
        self.columns_ = self._pick(frame)
        X = self._matrix(frame)
        X = X[np.isfinite(X).all(axis=1)]
        n, m = X.shape
        if n <= m + 1:
            raise ValueError(f"PCA detector: {n} complete rows for {m} variables; need more")
        self.mean_ = X.mean(axis=0)
        sd = X.std(axis=0, ddof=1)
        self.scale_ = np.where(sd > 0, sd, 1.0)
        Z = (X - self.mean_) / self.scale_
        _, s, vt = np.linalg.svd(Z, full_matrices=False)
        eig = s**2 / (n - 1)
        self.explained_variance_ = eig
        if isinstance(self.n_components, float) and 0 < self.n_components < 1:
            share = np.cumsum(eig) / eig.sum()
            a = int(np.searchsorted(share, self.n_components) + 1)
        else:
            a = int(self.n_components)
        if not 1 <= a <= m:
            raise ValueError(f"n_components must give 1…{m} components, got {self.n_components}")
        a = min(a, m - 1) if m > 1 else a  # keep a residual subspace for Q
        self.n_components_ = a
        self.components_ = vt[:a]
        self.n_samples_ = n
        self.t2_limit_, self.q_limit_ = self.limits(self.alpha)
        return self

    def limits(self, alpha: float) -> tuple[float, float]:
        """Control limits of T² and Q at false-alarm probability ``alpha`` per sample."""
        n, a = self.n_samples_, self.n_components_
        t2 = a * (n - 1) * (n + 1) / (n * (n - a)) * stats.f.ppf(1 - alpha, a, n - a)
        rest = self.explained_variance_[a:]
        th1, th2, th3 = (float(np.sum(rest**i)) for i in (1, 2, 3))
        if th1 <= 0 or th2 <= 0:
            return float(t2), 0.0
        h0 = 1 - 2 * th1 * th3 / (3 * th2**2)
        c = stats.norm.ppf(1 - alpha)
        q = th1 * (c * math.sqrt(2 * th2 * h0**2) / th1 + 1 + th2 * h0 * (h0 - 1) / th1**2) ** (
            1 / h0
        )
        return float(t2), float(q)

    def set_limits(self, t2: float, q: float) -> PCADetector:
        """Use these control limits (e.g. held to an alarm budget) instead of ``alpha``'s."""
        self.t2_limit_, self.q_limit_ = float(t2), float(q)
        return self

    # ------------------------------------------------------------ scoring
    def score(self, frame: pd.DataFrame) -> pd.DataFrame:
        """``T2`` and ``Q`` per row of ``frame`` (NaN where a tag or a lag is missing)."""
        X = self._matrix(frame)
        Z = (X - self.mean_) / self.scale_
        ok = np.isfinite(Z).all(axis=1)
        t2 = np.full(len(Z), np.nan)
        q = np.full(len(Z), np.nan)
        if ok.any():
            T = Z[ok] @ self.components_.T
            t2[ok] = np.sum(T**2 / self.explained_variance_[: self.n_components_], axis=1)
            E = Z[ok] - T @ self.components_
            q[ok] = np.sum(E**2, axis=1)
        return pd.DataFrame({"T2": t2, "Q": q}, index=frame.index)

    def contributions(self, frame: pd.DataFrame) -> pd.DataFrame:
        """Per row and tag, the tag's part of ``T²/T²_lim + Q/Q_lim``: the T² part by the
        complete decomposition ``z_j (P Λ⁻¹ Pᵀ z)_j`` (it sums to T²), the Q part by ``e_j²``
        (Qin, 2003, *J. Chemometrics* 17:480), a tag's lagged copies summed into it."""
        Z = (self._matrix(frame) - self.mean_) / self.scale_
        P = self.components_
        T = Z @ P.T
        c_t2 = Z * ((T / self.explained_variance_[: self.n_components_]) @ P)
        E = Z - T @ P
        c = c_t2 / self.t2_limit_ + E**2 / self.q_limit_
        m = len(self.columns_)
        per_tag = c.reshape(len(c), self.lags + 1, m).sum(axis=1)
        return pd.DataFrame(per_tag, index=frame.index, columns=self.columns_)

    def decide(self, frame: pd.DataFrame) -> pd.Series:
        """1.0 where T² or Q is beyond its limit, 0.0 where neither, NaN where unknown."""
        s = self.score(frame)
        over = (s["T2"] > self.t2_limit_) | (s["Q"] > self.q_limit_)
        return over.astype(float).where(s.notna().all(axis=1), np.nan)
