"""Symptom evaluation per test (residual column) — issue 9, "Residuals and symptoms".

* :class:`FixedThresholds` — crisp two-sided thresholds (seed 000 Table III, ±value; seed 001
  Sec. 5: ``d_j = 0`` when ``|r_j| ≤ K``, 1 when ``|r_j| > K``), optionally separate low/high,
  giving −1/0/+1 (``signed=True``) or 0/1.
* :class:`LearnedThresholds` — thresholds from a fault-free window: ``quantile(|r|) · margin``,
  with the window they came from (seed 000: "computed empirically by analyzing the deviation of
  the residuals from zero during no fault operation").
* :class:`FuzzyThreeValued` — memberships of N, 0, P (trapezoidal, summing to 1): ours, the signed
  fuzzy counterpart of seed 001's two-valued big/small (B/S) residual evaluation.
* :class:`OnOffDelay` — on/off delays against chattering, state carried across chunks.

UNKNOWN: a NaN residual (model unsupported, input NaN, stale or bad quality) gives the symptom
:data:`UNKNOWN`, which is NaN in the float outputs: never a symptom, never a fault. Use
:func:`is_unknown` to test for it. Fuzzy memberships are all NaN for an unknown sample.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
import pandas as pd

from diag_plugin.diagnose.residuals import ArrayLike, _as_2d, _per_column
from diag_plugin.models.series import effective_samples

__all__ = [
    "UNKNOWN",
    "FixedThresholds",
    "FuzzyThreeValued",
    "LearnedThresholds",
    "OnOffDelay",
    "is_unknown",
    "three_valued",
]

UNKNOWN: float = float("nan")
"""Symptom value of a sample whose residual is unknown (NaN in every float output)."""


def is_unknown(s: ArrayLike) -> np.ndarray:
    """Boolean mask of :data:`UNKNOWN` symptom values."""
    return np.isnan(np.asarray(s, dtype=float))


def _columns(r: Any) -> Any:
    return r.columns if isinstance(r, pd.DataFrame) else None


class FixedThresholds:
    """Crisp two-sided thresholds (seed 000 Table III; seed 001 Sec. 5, threshold ``K``).

    ``high`` (scalar, sequence or ``{column: value}``) is the upper threshold; ``low`` defaults
    to ``-high``. A sample is +1 when ``r > high``, −1 when ``r < low``, 0 otherwise and
    :data:`UNKNOWN` (NaN) when ``r`` is NaN. With ``signed=False`` the output is 0/1 (``|d_j|``).
    """

    def __init__(self, high: Any, low: Any = None, signed: bool = True) -> None:
        self.high = high
        self.low = low
        self.signed = signed

    def _limits(self, cols: Any, m: int) -> tuple[np.ndarray, np.ndarray]:
        hi = _per_column(self.high, cols, m, "high threshold")
        lo = -hi if self.low is None else _per_column(self.low, cols, m, "low threshold")
        if np.any(lo > hi):
            raise ValueError("low threshold above high threshold")
        return lo, hi

    def transform(self, r: ArrayLike) -> ArrayLike:
        """Symptoms −1/0/+1 (or 0/1), NaN unknown (seed 001 Sec. 5, ``d_j``)."""
        a, wrap = _as_2d(r)
        lo, hi = self._limits(_columns(r), a.shape[1])
        with np.errstate(invalid="ignore"):
            s = (a > hi).astype(float) - (a < lo).astype(float)
        if not self.signed:
            s = np.abs(s)
        s[np.isnan(a)] = UNKNOWN
        return wrap(s)


class LearnedThresholds(FixedThresholds):
    """Thresholds learned from a fault-free window: ``quantile(|r|, q) · margin`` (seed 000).

    Seed 000 Sec. IV computes its Table III thresholds "empirically by analyzing the deviation of
    the residuals from zero during no fault operation"; here that is the ``quantile`` (default
    0.999) of ``|r|`` over the window times a ``margin`` (default 1.2), symmetric (±). NaN
    residuals in the window are ignored. After :meth:`fit`: ``thresholds_`` (Series per column),
    ``window_`` (first and last index label of the frame, for the unit file), ``n_samples_`` and
    ``n_independent_`` (:func:`effective_samples` per column: how many independent values the
    quantile was taken over).
    """

    def __init__(self, quantile: float = 0.999, margin: float = 1.2, signed: bool = True) -> None:
        if not 0.0 < quantile <= 1.0:
            raise ValueError("quantile must be in (0, 1]")
        if margin <= 0:
            raise ValueError("margin must be > 0")
        super().__init__(high=None, signed=signed)
        self.quantile = float(quantile)
        self.margin = float(margin)
        self.thresholds_: pd.Series | None = None
        self.window_: tuple[Any, Any] | None = None
        self.n_samples_: pd.Series | None = None
        self.n_independent_: pd.Series | None = None

    def fit(self, residuals: pd.DataFrame) -> LearnedThresholds:
        """Learn one threshold per column from fault-free residuals (seed 000 Table III)."""
        df = pd.DataFrame(residuals)
        a = df.to_numpy(dtype=float)
        n = np.isfinite(a).sum(axis=0)
        if np.any(n == 0):
            empty = [c for c, k in zip(df.columns, n, strict=True) if k == 0]
            raise ValueError(f"no finite residuals to learn from in columns {empty}")
        q = np.nanquantile(np.abs(a), self.quantile, axis=0) * self.margin
        self.thresholds_ = pd.Series(q, index=df.columns, name="threshold")
        self.n_samples_ = pd.Series(n, index=df.columns, name="n")
        self.n_independent_ = pd.Series(
            [effective_samples(a[:, j]) for j in range(a.shape[1])],
            index=df.columns,
            name="n_independent",
        )
        self.window_ = (df.index[0], df.index[-1])
        self.high = self.thresholds_
        return self

    def transform(self, r: ArrayLike) -> ArrayLike:
        """Symptoms with the learned thresholds (see :meth:`FixedThresholds.transform`)."""
        if self.thresholds_ is None:
            raise RuntimeError("LearnedThresholds is not fitted")
        if isinstance(r, pd.DataFrame):
            self.high = self.thresholds_
        else:
            self.high = self.thresholds_.to_numpy()
        return super().transform(r)

    def to_state(self) -> dict[str, Any]:
        """Thresholds and their window as plain JSON (timestamps as ISO strings)."""

        def ts(x: Any) -> Any:
            if isinstance(x, pd.Timestamp):
                return x.isoformat()
            return x.item() if isinstance(x, np.generic) else x

        return {
            "quantile": self.quantile,
            "margin": self.margin,
            "signed": self.signed,
            "thresholds": None
            if self.thresholds_ is None
            else {str(k): float(v) for k, v in self.thresholds_.items()},
            "n_samples": None
            if self.n_samples_ is None
            else {str(k): int(v) for k, v in self.n_samples_.items()},
            "window": None if self.window_ is None else [ts(self.window_[0]), ts(self.window_[1])],
        }

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> LearnedThresholds:
        """Rebuild from :meth:`to_state` output (window bounds stay as stored)."""
        lt = cls(state["quantile"], state["margin"], state.get("signed", True))
        if state.get("thresholds") is not None:
            lt.thresholds_ = pd.Series(state["thresholds"], dtype=float, name="threshold")
            lt.high = lt.thresholds_
            if state.get("n_samples") is not None:
                lt.n_samples_ = pd.Series(state["n_samples"], dtype=np.int64, name="n")
            w = state.get("window")
            lt.window_ = None if w is None else (w[0], w[1])
        return lt


class FuzzyThreeValued:
    """Fuzzy three-valued residual evaluation: memberships of N, 0, P.

    Seed 001's rules (10)–(14) (Sect. 5) evaluate each residual as big or small (B, S), the
    fuzzy counterpart of its crisp ``d_j`` with threshold ``K``; their N and P name the fault's
    conclusion (``e_j = N`` ELSE ``e_j = P``), not residual sets. The signed three-valued sets
    N, 0, P are ours: B is ``max(μN, μP)`` and S is ``μ0``, and a sign in a matrix entry reads
    μN or μP alone (:meth:`diag_plugin.diagnose.matrix.DiagnosticMatrix.fuzzy`). Here P is a
    trapezoid (a ramp) rising from 0 at ``K − width/2`` to 1 at ``K + width/2``, N its mirror
    image at ``−K``, and ``μ0 = 1 − μN − μP`` (a trapezoid, 1 on ``[−K + width/2, K −
    width/2]``). The three sum to 1, μP is non-decreasing and μN non-increasing in ``r``;
    ``width → 0`` gives the crisp :class:`FixedThresholds`. ``width ≤ 2K`` so N and P never
    overlap. NaN residuals give NaN memberships (unknown).
    """

    def __init__(self, threshold: Any, width: Any) -> None:
        self.threshold = threshold
        self.width = width

    def transform(self, r: ArrayLike) -> tuple[ArrayLike, ArrayLike, ArrayLike]:
        """Return ``(μN, μ0, μP)``, each shaped like ``r`` (B = max(μN, μP), S = μ0)."""
        a, wrap = _as_2d(r)
        cols, m = _columns(r), a.shape[1]
        k = _per_column(self.threshold, cols, m, "threshold")
        w = _per_column(self.width, cols, m, "width")
        if np.any(k <= 0) or np.any(w < 0) or np.any(w > 2 * k):
            raise ValueError("need threshold > 0 and 0 ≤ width ≤ 2·threshold")
        half = w / 2.0
        mu = three_valued(a, -k - half, -k + half, k - half, k + half)
        return tuple(wrap(x) for x in mu)  # type: ignore[return-value]


def three_valued(
    r: np.ndarray, n1: Any, n0: Any, p0: Any, p1: Any
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Memberships ``(μN, μ0, μP)`` of residuals ``r`` (n_samples × n_tests) in the three
    trapezoidal sets N, 0, P (ours; seed 001's rules read B = max(μN, μP), S = μ0), given per test
    by four breakpoints ``n1 ≤ n0 ≤ p0 ≤ p1``: μN is 1 up to ``n1`` and falls to 0 at ``n0``; μP
    rises from 0 at ``p0`` to 1 at ``p1``; ``μ0 = 1 − μN − μP`` is 1 on ``[n0, p0]``. A zero-width
    ramp is a step (``r < n0`` is N, ``r > p0`` is P), the crisp three-valued evaluation. NaN
    residuals give NaN memberships (unknown)."""
    a = np.asarray(r, dtype=float)
    n1, n0, p0, p1 = (np.broadcast_to(np.asarray(x, float), a.shape[-1:]) for x in (n1, n0, p0, p1))
    with np.errstate(invalid="ignore", divide="ignore"):
        up, wp = a - p0, p1 - p0
        mu_p = np.where(wp > 0, np.clip(up / np.where(wp > 0, wp, 1.0), 0.0, 1.0), up > 0)
        dn, wn = n0 - a, n0 - n1
        mu_n = np.where(wn > 0, np.clip(dn / np.where(wn > 0, wn, 1.0), 0.0, 1.0), dn > 0)
    mu_p = mu_p.astype(float)
    mu_n = mu_n.astype(float)
    mu_z = 1.0 - mu_n - mu_p
    nan = np.isnan(a)
    for mu in (mu_n, mu_z, mu_p):
        mu[nan] = np.nan
    return mu_n, mu_z, mu_p


@numba.njit(cache=True, nogil=True)
def _delay_kernel(  # pragma: no cover - numba
    raw, on_delay, off_delay, window, long, state, count, gone, hold, out
):
    # row by row (memory order); each column's state machine is its own; ``out`` may be
    # ``raw`` itself (each element read before it is written). gone: samples since the
    # column's last symptom ended (window: none to count); hold: its current off-delay
    # (long for a symptom raised again on its side within window samples of that side's
    # last end: gone[j, 0] counts the + side's samples since, gone[j, 1] the − side's; a +
    # then a −, a transient swinging back, is two first alarms, not one raised again)
    n, m = raw.shape
    for i in range(n):
        for j in range(m):
            x = raw[i, j]
            if np.isnan(x):
                out[i, j] = np.nan  # unknown: counted neither as on nor off
                continue
            s = state[j]
            c = count[j]
            v = 0.0 if x == 0 else (1.0 if x > 0 else -1.0)
            for k in range(2):
                if gone[j, k] < window:
                    gone[j, k] += 1
            if s == 0.0:
                # c counts consecutive samples with the same nonzero sign (sign in its sign).
                if v == 0.0:
                    c = 0
                elif c * v > 0:
                    c += int(v)
                else:
                    c = int(v)
                if abs(c) >= on_delay:
                    s = v
                    c = 0
                    hold[j] = long if gone[j, 0 if v > 0 else 1] < window else off_delay
            else:
                # c counts consecutive samples not equal to the active symptom.
                if v == s:
                    c = 0
                else:
                    c += 1
                    if c >= hold[j]:
                        gone[j, 0 if s > 0 else 1] = 0
                        s = 0.0
                        c = int(v)
                        if v != 0.0 and on_delay <= 1:
                            s = v
                            c = 0
                            hold[j] = long if gone[j, 0 if v > 0 else 1] < window else off_delay
            out[i, j] = s
            state[j] = s
            count[j] = c
    return out


class OnOffDelay:
    """On/off delays against chattering, with state carried across chunks (issue 9).

    A symptom turns on only after ``on_delay`` consecutive samples over the threshold (same
    sign) and off after ``off_delay`` consecutive samples not showing it. ``on_delay=1`` /
    ``off_delay=1`` pass the raw symptom through. Input: raw symptoms −1/0/+1 or 0/1 with NaN
    for :data:`UNKNOWN` (e.g. from :class:`FixedThresholds`); output the same coding. An unknown
    sample outputs :data:`UNKNOWN` and is counted as neither on nor off: the counters skip it.

    ``realarm = (window, long)`` (samples; ``(0, 0)``: none): the re-alarm hold, per column
    (a test), per side (ISA: a high and a low alarm are two alarms): a symptom raised again on
    a side within ``window`` samples of that side's last end turns off after ``long``
    samples, not ``off_delay`` (issue 34 item 6;
    :class:`~diag_plugin.diagnose.unitloops.AlarmHold` holds the unit's alarm likewise).
    """

    def __init__(
        self, on_delay: int = 1, off_delay: int = 1, realarm: tuple[int, int] = (0, 0)
    ) -> None:
        if on_delay < 1 or off_delay < 1:
            raise ValueError("delays are counted in samples and must be ≥ 1")
        self.on_delay = int(on_delay)
        self.off_delay = int(off_delay)
        self.window = max(0, int(realarm[0]))
        self.long = max(int(realarm[1]), self.off_delay)
        self.state_: np.ndarray | None = None  # active value per column: -1, 0, +1
        self.count_: np.ndarray | None = None
        self.gone_: np.ndarray | None = None  # per side, samples since its symptom ended
        self.hold_: np.ndarray | None = None  # the current symptom's off-delay

    def reset(self) -> OnOffDelay:
        """Forget the carried state (all symptoms off, counters zero)."""
        self.state_ = None
        self.count_ = None
        self.gone_ = None
        self.hold_ = None
        return self

    def transform(self, symptoms: ArrayLike, overwrite: bool = False) -> ArrayLike:
        """Delayed symptoms, continuing from the carried state. ``overwrite=True``: written
        into ``symptoms`` itself where it is a C-ordered float array (the caller's own, not
        read again; no new array of its size), else into a new one."""
        a, wrap = _as_2d(symptoms, copy=False)  # read only unless overwrite
        m = a.shape[1]
        if self.state_ is None:
            self.state_ = np.zeros(m)
            self.count_ = np.zeros(m, dtype=np.int64)
        if self.gone_ is None or self.gone_.shape != (self.state_.shape[0], 2):
            self.gone_ = np.full((self.state_.shape[0], 2), self.window, dtype=np.int64)
            self.hold_ = np.full(self.state_.shape[0], self.off_delay, dtype=np.int64)
        if self.state_.shape[0] != m:
            raise ValueError(f"delay state has {self.state_.shape[0]} columns, input has {m}")
        x = np.ascontiguousarray(a)
        inplace = (
            overwrite and x is a and isinstance(symptoms, np.ndarray) and x.ndim == symptoms.ndim
        )
        out = x if inplace else np.empty_like(x)
        args = (self.window, self.long, self.state_, self.count_, self.gone_, self.hold_)
        return wrap(_delay_kernel(x, self.on_delay, self.off_delay, *args, out))

    def to_state(self) -> dict[str, Any]:
        """Delays and carried state as plain JSON."""
        return {
            "on_delay": self.on_delay,
            "off_delay": self.off_delay,
            "state": None if self.state_ is None else self.state_.tolist(),
            "count": None if self.count_ is None else self.count_.tolist(),
            **(
                {}
                if not self.window
                else {
                    "realarm": [self.window, self.long],
                    "gone": None if self.gone_ is None else self.gone_.tolist(),
                    "hold": None if self.hold_ is None else self.hold_.tolist(),
                }
            ),
        }

    def restored(self, state: dict[str, Any]) -> OnOffDelay:
        """:meth:`from_state` with this delay's re-alarm hold (a state saved before it has
        none; its symptoms then count no last end)."""
        d = self.from_state(state)
        d.window, d.long = self.window, self.long
        if d.state_ is not None and d.gone_ is None:
            d.gone_ = np.full((d.state_.shape[0], 2), d.window, dtype=np.int64)
            d.hold_ = np.full(d.state_.shape[0], d.off_delay, dtype=np.int64)
        return d

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> OnOffDelay:
        """Rebuild from :meth:`to_state` output."""
        d = cls(state["on_delay"], state["off_delay"], tuple(state.get("realarm", (0, 0))))
        if state.get("state") is not None:
            d.state_ = np.asarray(state["state"], dtype=float)
            d.count_ = np.asarray(state["count"], dtype=np.int64)
            if state.get("gone") is not None:
                d.gone_ = np.asarray(state["gone"], dtype=np.int64)
                d.hold_ = np.asarray(state["hold"], dtype=np.int64)
        return d
