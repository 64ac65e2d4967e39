"""Derived model inputs on the plant's stacked fast path (issue 34: a unit whose test reads a
level's ``rate()`` stays on it).

:class:`~diag_plugin.diagnose.plant.Plant` keeps a ring buffer of the plant's tags, one row a
cycle (row 0 the newest), and reads every model input as ``history[lag, column]``.
:class:`DerivedInputs` appends one column per distinct derived feature (a spec's base, e.g.
``rate(LT101,3)``, by plant tags) and fills its row 0 each cycle from the tags' rows, the same
numbers :class:`~diag_plugin.regressors.DesignBuilder` computes for :meth:`Unit.evaluate`
(the module doc of :mod:`diag_plugin.regressors`):

=================  =====================================================================
``rate(T,L)``      ``(T[k] − T[k−L]) / L`` (``L = 1`` for ``rate(T)``): rows 0 and ``L``
``mean(T,L)``      ``(T[k] + … + T[k−L+1]) / L``: rows 0 to ``L − 1``
``diff(A,B)``      ``A[k] − B[k]``
``const(v)``       ``v``
``share(X,R…)``    ``X[k] / (1 + n)``, ``n`` the run tags ``R…`` at 1 (:func:`~diag_plugin.
                   regressors.shared`)
``hour()``         hours since midnight of the cycle's timestamp (:func:`~diag_plugin.
                   regressors.clock`)
``days()``         days since 2000-01-01 (:func:`~diag_plugin.regressors.clock`)
``dir(T,h)``       the play operator of :func:`~diag_plugin.regressors.direction`, one
                   sample a cycle for all features at once, its reference and direction
                   carried (and saved with the plant's state)
=================  =====================================================================

A lagged feature (``rate(T)[k-2]``) is then read as any lagged tag, from the column's earlier
rows; a row before the feature could be computed is NaN, as the builder's carried state is at a
start. ``dir(T)`` without a threshold is not taken: the builder freezes its threshold from the
first piece it sees, which depends on how the rows are cut, so such units stay one by one.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from diag_plugin.regressors import InputSpec, clock, rate_samples, shared

#: the functions the fast path computes (``dir`` only with its threshold written)
FUNCTIONS = ("", "rate", "mean", "diff", "const", "hour", "days", "dir", "share")


def stackable(spec: InputSpec) -> bool:
    """True when the fast path can read ``spec`` (a plain tag or a feature it computes)."""
    return spec.fn in FUNCTIONS and (spec.fn != "dir" or spec.param is not None)


class DerivedInputs:
    """The derived features of the fast path's units: columns after the tags' in the plant's
    history, filled by :meth:`update` each cycle (module doc)."""

    def __init__(self) -> None:
        self.keys: dict[tuple, int] = {}  # (fn, plant tags, param) → feature number

    def add(self, spec: InputSpec, tags: tuple[str, ...]) -> int:
        """The feature number of ``spec``'s base reading the plant tags ``tags``."""
        key = (spec.fn, tags, spec.param)
        return self.keys.setdefault(key, len(self.keys))

    def __len__(self) -> int:
        return len(self.keys)

    @property
    def depth(self) -> int:
        """Rows of history the features read (a ``rate(T,L)`` reads row ``L``, a
        ``mean(T,L)`` rows to ``L − 1``)."""
        return max((_samples(p) - (fn == "mean") for fn, _, p in self.keys
                    if fn in ("rate", "mean")), default=0)  # fmt: skip

    def freeze(self, columns: dict[str, int]) -> None:
        """Fix the features' columns after the tags' (``columns``: plant tag → column, every
        tag a feature reads among them): per function, the arrays :meth:`update` reads."""
        n = len(columns)
        by: dict[str, list[tuple[int, tuple[str, ...], float | None]]] = {}
        for (fn, tags, param), k in self.keys.items():
            by.setdefault(fn, []).append((n + k, tags, param))

        def cols(fn: str, i: int = 0) -> np.ndarray:
            return np.array([columns[t[i]] for _, t, _ in by.get(fn, [])], np.intp)

        def dst(fn: str) -> np.ndarray:
            return np.array([c for c, _, _ in by.get(fn, [])], np.intp)

        samples = np.array([_samples(p) for _, _, p in by.get("rate", [])], np.intp)
        self.rate = (dst("rate"), cols("rate"), samples)
        self.rate_div = samples.astype(float)
        self.mean = [(c, columns[t[0]], _samples(p)) for c, t, p in by.get("mean", [])]
        self.diff = (dst("diff"), cols("diff"), cols("diff", 1))
        self.share = [(c, columns[t[0]], np.array([columns[r] for r in t[1:]], np.intp))
                      for c, t, _ in by.get("share", [])]  # fmt: skip
        self.const = (dst("const"), np.array([p for _, _, p in by.get("const", [])], float))
        self.clock = [(c, fn) for fn in ("hour", "days") for c, _, _ in by.get(fn, [])]
        self.dir = (dst("dir"), cols("dir"), np.array([p for _, _, p in by.get("dir", [])], float))
        self.reset()

    def reset(self) -> None:
        """Each ``dir`` feature's reference and direction unknown (a fresh start)."""
        self.ref = np.full(self.dir[0].size, np.nan)
        self.state = np.full(self.dir[0].size, np.nan)

    def update(self, hist: np.ndarray, ts: pd.Timestamp) -> None:
        """Row 0 of the features' columns of ``hist`` (rows × columns, row 0 this cycle's
        tags) from the tags' rows; advances the ``dir`` features' carried state."""
        dst, src, lag = self.rate
        if dst.size:  # (T[k] − T[k−L]) / L, as _FeatureState.compute
            hist[0, dst] = (hist[0, src] - hist[lag, src]) / self.rate_div
        for c, x, n in self.mean:  # as regressors.window_mean, oldest row first
            total = hist[n - 1, x]
            for j in range(n - 2, -1, -1):
                total += hist[j, x]
            hist[0, c] = total / n
        dst, a, b = self.diff
        if dst.size:
            hist[0, dst] = hist[0, a] - hist[0, b]
        for c, x, runs in self.share:
            hist[0, c] = shared(hist[0, [x]], hist[0, runs][:, None])[0]
        dst, value = self.const
        if dst.size:
            hist[0, dst] = value
        if self.clock:  # one index a cycle, each clock function once
            idx = pd.DatetimeIndex([ts])
            now = {fn: clock(idx, fn)[0] for fn in {fn for _, fn in self.clock}}
            for c, fn in self.clock:
                hist[0, c] = now[fn]
        dst, src, threshold = self.dir
        if dst.size:
            hist[0, dst] = direction_step(hist[0, src], threshold, self.ref, self.state)

    @property
    def carry(self) -> np.ndarray:
        """The ``dir`` features' carried reference (row 0) and direction (row 1)."""
        return np.stack([self.ref, self.state])

    def fits(self, carry: np.ndarray) -> bool:
        """True when ``carry`` (:attr:`carry` as saved) is one for these features."""
        return np.size(carry) == 2 * self.ref.size

    def load_carry(self, carry: np.ndarray) -> None:
        """Back from :attr:`carry` (one that :meth:`fits`)."""
        carry = np.asarray(carry, float).reshape(2, self.ref.size)
        self.ref, self.state = carry[0].copy(), carry[1].copy()


def direction_step(
    v: np.ndarray, threshold: np.ndarray, ref: np.ndarray, state: np.ndarray
) -> np.ndarray:
    """One sample of :func:`~diag_plugin.regressors.direction` for many features at once:
    ``v`` their values, ``ref`` and ``state`` their carried reference and direction (updated
    in place). A move above the threshold sets the direction (+1 up, −1 down) and the
    reference; a NaN value makes both unknown; the first value after that is the reference.
    Returns the directions."""
    with np.errstate(invalid="ignore"):
        up = v - ref > threshold
        down = ref - v > threshold
    moved = up | down
    state[up] = 1.0
    state[down] = -1.0
    start = np.isnan(ref)
    ref[moved | start] = v[moved | start]
    gone = np.isnan(v)
    ref[gone] = np.nan
    state[gone] = np.nan
    return state.copy()


def _samples(param: float | None) -> int:
    """The samples ``L`` of ``rate(T,L)`` (:func:`~diag_plugin.regressors.rate_samples`)."""
    return rate_samples(InputSpec("rate", ("",), 0, param))
