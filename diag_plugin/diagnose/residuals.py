"""Residual generation and post-processing (issue 9, "Residuals and symptoms").

* :func:`residual_pct` — residual in % of the nominal span, seed 001 eq. (6); re-exported
  from :mod:`diag_plugin.metrics`.
* :class:`LowPass` — causal 4th-order Butterworth low-pass with carried state (seed 000,
  Sec. IV: cut-off π/100 rad/sample).
* :class:`MaxScaler` — division by the signal's maximum over a reference window (seed 000).
* :class:`Latch` — once over its threshold a residual stays "nonzero" until :meth:`Latch.reset`
  (seed 000: "a binary signal of one is given ... for the remainder of the test").

Arrays are ``(n_samples,)`` or ``(n_samples, n_residuals)``; a :class:`pandas.DataFrame` or
:class:`pandas.Series` comes back with the same index and columns. A residual that is NaN is
*unknown* (model unsupported, input NaN, stale or bad quality) and stays NaN downstream.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numba
import numpy as np
import pandas as pd

from diag_plugin.diagnose.butterworth import butter_sos, sosfilt_zi
from diag_plugin.metrics import residual_pct
from diag_plugin.models.protocol import Prediction

__all__ = ["Latch", "LowPass", "MaxScaler", "residual_pct"]

ArrayLike = np.ndarray | pd.DataFrame | pd.Series


def _as_2d(x: Any, copy: bool = True) -> tuple[np.ndarray, Callable[[np.ndarray], Any]]:
    """Return ``x`` as a float ``(n, m)`` array and a function that wraps a result back;
    ``copy=False`` for callers that only read it (a float array is then not copied)."""
    if isinstance(x, pd.DataFrame):
        idx, cols = x.index, x.columns
        return x.to_numpy(dtype=float, copy=copy), lambda a: pd.DataFrame(
            a, index=idx, columns=cols
        )
    if isinstance(x, pd.Series):
        idx, name = x.index, x.name
        return x.to_numpy(dtype=float, copy=copy).reshape(-1, 1), lambda a: pd.Series(
            a[:, 0], index=idx, name=name
        )
    a = np.array(x, dtype=float, copy=copy or None)
    if a.ndim == 1:
        return a.reshape(-1, 1), lambda b: b[:, 0]
    if a.ndim != 2:
        raise ValueError(f"expected 1-D or 2-D residuals, got shape {a.shape}")
    return a, lambda b: b


def _per_column(value: Any, columns: Any, m: int, what: str) -> np.ndarray:
    """Broadcast a scalar, sequence, dict or Series to one float per column."""
    if isinstance(value, dict | pd.Series):
        if columns is None:
            raise ValueError(f"{what} given by name needs DataFrame input")
        missing = [c for c in columns if c not in value]
        if missing:
            raise KeyError(f"{what} missing for columns {missing}")
        return np.array([float(value[c]) for c in columns])
    arr = np.broadcast_to(np.asarray(value, dtype=float), (m,)).copy()
    return arr


@numba.njit(cache=True, nogil=True)
def _lowpass_kernel(x, sos, zi, gap, max_gap, steady, zi_step, out):  # pragma: no cover
    """``x`` (samples × columns) filtered into ``out`` (its shape; ``x`` itself to filter in
    place: each value is read before it is written) by the second-order sections ``sos``
    from the state ``zi`` (columns × sections × 2), skipping non-finite samples (NaN out,
    state held), the state back at rest after more than ``max_gap`` of them — or, for a
    column marked ``steady``, at the steady state of the sample that ends the gap
    (``zi_step`` × that sample: ``sosfilt_zi``, the state after a step held forever);
    ``zi`` and ``gap`` advanced. Row by row, so the samples are read in memory order; each
    column's recursion is its own."""
    n, m = x.shape
    ns = sos.shape[0]
    for i in range(n):
        for j in range(m):
            x_cur = x[i, j]
            if not np.isfinite(x_cur):
                out[i, j] = np.nan
                gap[j] += 1
                continue
            if gap[j] > max_gap:
                level = x_cur if steady[j] else 0.0
                for s in range(ns):
                    zi[j, s, 0] = zi_step[s, 0] * level
                    zi[j, s, 1] = zi_step[s, 1] * level
            gap[j] = 0
            for s in range(ns):
                x_new = sos[s, 0] * x_cur + zi[j, s, 0]
                zi[j, s, 0] = sos[s, 1] * x_cur - sos[s, 4] * x_new + zi[j, s, 1]
                zi[j, s, 1] = sos[s, 2] * x_cur - sos[s, 5] * x_new
                x_cur = x_new
            out[i, j] = x_cur
    return out


class LowPass:
    """Causal Butterworth low-pass of residuals with carried state (seed 000, Sec. IV).

    Seed 000 filters every residual with "a fourth-order Butterworth low-pass filter with a
    cutoff frequency of π/100" (rad/sample). scipy normalises frequencies to the Nyquist
    frequency (1.0 = π rad/sample), so the default ``wn=0.01`` *is* π/100 rad/sample; the filter
    is ``scipy.signal.butter(order, wn, output="sos")`` (:func:`~diag_plugin.diagnose.butterworth.
    butter_sos`, the same bits) run as ``sosfilt`` runs it. The state ``zi`` of
    every residual column is carried between calls, so one pass, any chunking and one sample per
    cycle give the same values. The filter starts from rest (zero state).

    NaN handling: a NaN input sample gives a NaN output and leaves that column's state
    untouched (the filter holds, it is not fed the NaN). After a gap of more than ``max_gap``
    consecutive NaN samples (default 100 = 1/wn, about the filter's memory) the state is reset
    to rest at the next finite sample, so a stale pre-gap value does not leak into new data.
    The gap counter is carried across chunks too.

    ``steady``: per column whether it restarts after such a gap at the steady state of its
    first sample instead of at rest — for a column whose normal value is far from zero, as a
    running spread (a valve-stiction test's statistic, always positive) is: from rest it
    would ramp up from zero, a deviation below its normal level as large as the level itself
    (on a 5 s boiler unit after a 1.5 h outage the combined T² read 304 against a limit of 111,
    a false alarm of 9 minutes; docs/reference/units.md). Default: none.
    """

    def __init__(
        self,
        wn: float = 0.01,
        order: int = 4,
        max_gap: int = 100,
        steady: np.ndarray | list[bool] | None = None,
    ) -> None:
        if not 0.0 < wn < 1.0:
            raise ValueError("wn must be in (0, 1) (1.0 = Nyquist = π rad/sample)")
        self.wn = float(wn)
        self.order = int(order)
        self.max_gap = int(max_gap)
        self.steady = None if steady is None else np.asarray(steady, bool).copy()
        # scipy.signal.butter(order, wn, output="sos") and sosfilt_zi, the same bits, without
        # importing scipy.signal (~0.8 CPU s of each diag diagnose, issue 34)
        self.sos_ = butter_sos(self.order, self.wn)
        #: the state after a unit step held forever (a steady column's restart, × its sample)
        self.zi_step_ = np.ascontiguousarray(sosfilt_zi(self.sos_))
        self.zi_: np.ndarray | None = None  # (m, n_sections, 2)
        self.gap_: np.ndarray | None = None  # (m,) consecutive NaNs at the end of the last call

    def reset(self) -> LowPass:
        """Forget the carried state (the filter restarts from rest)."""
        self.zi_ = None
        self.gap_ = None
        return self

    def _init_state(self, m: int) -> None:
        if self.zi_ is None:
            self.zi_ = np.zeros((m, self.sos_.shape[0], 2))
            self.gap_ = np.zeros(m, dtype=np.int64)
        elif self.zi_.shape[0] != m:
            raise ValueError(f"filter state has {self.zi_.shape[0]} columns, input has {m}")

    def transform(self, r: ArrayLike, *, overwrite: bool = False) -> ArrayLike:
        """Filter residuals (seed 000 Sec. IV), continuing from the carried state.
        ``overwrite=True`` with a C-ordered float array ``r`` the caller owns: filtered in
        place, no second array of the residuals' size (``r`` is returned)."""
        a, wrap = _as_2d(r, copy=False)  # read only unless overwrite
        n, m = a.shape
        self._init_state(m)
        assert self.zi_ is not None and self.gap_ is not None
        if not n:
            return wrap(np.full_like(a, np.nan))
        # one compiled pass per column over the finite samples (the recursion of scipy's
        # sosfilt, direct form II transposed, the same operations in the same order)
        x = np.ascontiguousarray(a)
        inplace = overwrite and x is a and isinstance(r, np.ndarray) and x.ndim == r.ndim
        out = x if inplace else np.empty_like(x)
        if self.steady is None:
            steady = np.zeros(m, np.bool_)
        elif len(self.steady) != m:
            raise ValueError(f"steady has {len(self.steady)} columns, input has {m}")
        else:
            steady = self.steady
        return wrap(
            _lowpass_kernel(
                x, self.sos_, self.zi_, self.gap_, self.max_gap, steady, self.zi_step_, out
            )
        )

    def to_state(self) -> dict[str, Any]:
        """Parameters and carried state as plain JSON-able values."""
        return {
            "wn": self.wn,
            "order": self.order,
            "max_gap": self.max_gap,
            "steady": None if self.steady is None else self.steady.tolist(),
            "zi": None if self.zi_ is None else self.zi_.tolist(),
            "gap": None if self.gap_ is None else self.gap_.tolist(),
        }

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> LowPass:
        """Rebuild a filter from :meth:`to_state` output."""
        f = cls(
            wn=state["wn"],
            order=state["order"],
            max_gap=state["max_gap"],
            steady=state.get("steady"),  # states saved before it restart every column at rest
        )
        if state.get("zi") is not None:
            f.zi_ = np.asarray(state["zi"], dtype=float)
            f.gap_ = np.asarray(state["gap"], dtype=np.int64)
        return f


class MaxScaler:
    """Divide residuals by the signal's maximum over a reference window (seed 000, Sec. IV).

    Seed 000 scales the filtered residual "by dividing by the maximum value of the signal over
    the entire IM240 cycle". :meth:`fit` takes the measured signal(s) over a fault-free
    reference window and stores ``max_ = nanmax(|y|)`` per column; :meth:`transform` returns
    ``r / max_``. A column whose maximum is 0 or NaN is rejected.
    """

    def __init__(self) -> None:
        self.max_: np.ndarray | None = None

    def fit(self, y: ArrayLike) -> MaxScaler:
        """Learn the per-column maximum of ``|y|`` over the reference window."""
        a, _ = _as_2d(y)
        with np.errstate(all="ignore"):
            mx = np.nanmax(np.abs(a), axis=0) if a.shape[0] else np.full(a.shape[1], np.nan)
        if not np.all(np.isfinite(mx) & (mx > 0)):
            raise ValueError(f"signal maximum must be finite and > 0, got {mx.tolist()}")
        self.max_ = mx
        return self

    def transform(self, r: ArrayLike) -> ArrayLike:
        """Scaled residual ``r / max_`` (seed 000 Figs. 8–12's vertical axes)."""
        if self.max_ is None:
            raise RuntimeError("MaxScaler is not fitted")
        a, wrap = _as_2d(r)
        return wrap(a / self.max_)

    def to_state(self) -> dict[str, Any]:
        """Learned maxima as plain JSON."""
        return {"max": None if self.max_ is None else self.max_.tolist()}

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> MaxScaler:
        """Rebuild from :meth:`to_state` output."""
        s = cls()
        if state.get("max") is not None:
            s.max_ = np.asarray(state["max"], dtype=float)
        return s


class Latch:
    """Latch a residual once ``|r|`` exceeds its threshold, until :meth:`reset` (seed 000).

    Seed 000 Sec. IV: "if the threshold is exceeded, then a binary signal of one is given for
    that particular residual for the remainder of the test" (thresholds as Table III, ±value).
    Output per sample and column: 1.0 once latched, 0.0 before, and NaN (*unknown*) for a NaN
    residual while not yet latched. A latched residual stays 1.0 even through NaN samples.
    The latched flags are carried across calls.
    """

    def __init__(self, thresholds: Any) -> None:
        self.thresholds = thresholds
        self.latched_: np.ndarray | None = None

    def reset(self) -> Latch:
        """Clear all latches."""
        self.latched_ = None
        return self

    def transform(self, r: ArrayLike) -> ArrayLike:
        """Latched 0/1 (NaN unknown) per sample, continuing from the carried latches."""
        a, wrap = _as_2d(r)
        n, m = a.shape
        cols = r.columns if isinstance(r, pd.DataFrame) else None
        k = _per_column(self.thresholds, cols, m, "threshold")
        if self.latched_ is None:
            self.latched_ = np.zeros(m, dtype=bool)
        with np.errstate(invalid="ignore"):
            over = np.abs(a) > k
        latched = np.maximum.accumulate(np.vstack([self.latched_[None, :], over]), axis=0)[1:]
        out = latched.astype(float)
        out[~latched & np.isnan(a)] = np.nan
        if n:
            self.latched_ = latched[-1].copy()
        return wrap(out)

    def to_state(self) -> dict[str, Any]:
        """Latched flags as plain JSON."""
        return {"latched": None if self.latched_ is None else self.latched_.tolist()}

    @classmethod
    def from_state(cls, state: dict[str, Any], thresholds: Any) -> Latch:
        """Rebuild from :meth:`to_state` output and the thresholds."""
        lt = cls(thresholds)
        if state.get("latched") is not None:
            lt.latched_ = np.asarray(state["latched"], dtype=bool)
        return lt


def supported(pred: Prediction, min_support: float | np.ndarray) -> np.ndarray:
    """The model output where trained rules carry at least ``min_support`` of the firing
    weight, NaN elsewhere.

    At the edge of the trained region a Wang–Mendel prediction leans on the neighbouring
    rules (the weights of missing rules are dropped and the rest renormalised); its residual
    says more about the model than about the plant, so the test is *unknown* there, never a
    symptom. Methods without rule support (TS, NARMAX) report support 1 wherever they predict.
    """
    return np.where(pred.support >= min_support, pred.y, np.nan)
