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
(:class:`RunningSpread`: over the window ``W = spread_window_s``, the median absolute
deviation from the window's median, ``1.4826 · med_W |r_k − med_W(r)|`` (Hampel, 1974; robust:
the brief transient of a set-point step, a few samples, does not move it; a loop cycling for
more than half the window does), learned and thresholded like any test's residual; ``diag unit
build`` writes one beside each loop's level test and names the loop's actuator for it.

**An oscillation is one alarm** (:class:`OscillationHold`; issue 34 item 6, ISA-18.2: one
standing alarm for a standing fault). A sticking valve's limit cycle swings the residuals of
the tags it moves (the flow through the valve, the controller's output) across both
thresholds in turn; with plain on/off delays each swing is an alarm of its own (63 episodes
in two days of the chemical plant's ``tv104_stiction``, one each half cycle). A limit cycle
repeats: once a test's symptom has changed side :data:`OSCILLATION_CHANGES` times (+ − + or
− + −) within as many ``oscillation_window_s``, the hold is armed, and it stays on, on the
side last on, while the symptom is on or both sides were on within the last
``oscillation_window_s``; it drops once one side has not been on for that long. A single
bipolar transient (+ then −: a load moved onto a twin when it stops and back when it
restarts) is one change and never held. ``diag unit build`` writes four spread windows
(:data:`~diag_plugin.unitbuild.build.OSCILLATION_WINDOWS`): the spread test's running MAD
over ``W`` sees a cycle of period up to ``2W``, both sides' alarms of such a cycle fall
within one period, and a stick-slip cycle's period varies by a factor of two. A fault-free
residual rarely swings across both thresholds, so the false alarms do not rise (none more on
the chemical plant's tuning runs). The price: an alarm held by it ends up to the window after
the oscillation stops, and an oscillation's first swing there and back is alarms of its own.

**A standing stiction alarm is released on the long window** (:class:`ReleaseHold`; issue
34 item 6, ISA-18.2's deadband/release: an alarm raised on one condition, cleared on
another). The spread test raises on its window ``W`` as above; once on, its symptom is held
while the running spread (the same MAD) of the same residual over the longer
``release_window_s`` stays above the test's ``release`` threshold. ``diag unit build``
writes the window as the one whose MAD of the loop's fault-free control error rests on
``(1.166 / 0.2)² = 34`` independent samples (the MAD known to 20 %; the error's
autocorrelation summed to its first zero) and ``release`` as the largest such spread over
the build's window: a fault-free run's alarm is extended only where the long spread is
beyond anything the build saw. The long window never raises (the detection delay, the
settle's quiet time and the fault-free raising stay the short window's); a limit cycle
whose short MAD drops under its threshold once a cycle (the 7-tag line's sticking valve:
one 33-sample cycle in a 40-sample window) stays one alarm. The hold is raised too by one of
the loop's own tests (its measurement's, its actuator's) on where the long spread is already
above ``release`` — the loop's alarm before the short window first fires — and the combined
test, once on, is held while any loop's long spread is above its release; within a settle's
bound after an operator's step nothing raises either. A loop whose valve is pinned at an
edge of its span (:class:`PinnedValves`: within :data:`PINNED` of its span from the same
edge, or past it, on this sample and the one before) cannot act: its error is the process
running away from a saturated valve, not a cycling one, so its long spread is unknown from
then until a release window after the valve last sat there — nothing raises the hold, a
hold raised before drops, and the combined test is not held on that loop (a tank's inflow
surge with its level valve shut: the saturated loop's error looked like stiction to the long
window, and the surge was named on the level and the valve instead of the tank,
tests/test_unit_build.py; at 10 s and 1 s, off the grid, and with a valve transmitter that
reads its limit with noise, never the same twice, tests/test_unit_pinned_rates.py).
(Releasing the unit's own alarm the same way was measured and not kept: it carried an
operator's step's alarm past its settle, docs/how-to/unit-loops.md.)

**The named tag held through an episode** (:class:`EpisodeHold`): each tag's share of the
alarm is averaged over the samples of the current alarm episode, and the tags are ranked by
that mean, so the tags named do not flicker from sample to sample within one alarm (as the
isolated faults are held, :mod:`~diag_plugin.diagnose.isolation`).
"""

from __future__ import annotations

import math
import warnings
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


def oscillation_samples(ev: dict[str, Any], period: str) -> int:
    """Samples in the oscillation hold's window, ``ceil(oscillation_window_s / period)``
    (0: no hold, a unit file without the key)."""
    sec = float(ev.get("oscillation_window_s", 0.0) or 0.0)
    s = pd.Timedelta(period).total_seconds()
    return max(1, math.ceil(sec / s - 1e-9)) if sec > 0 and s > 0 else 0


def spread_samples(window_s: float, period: str) -> int:
    """Samples in a spread test's window of ``window_s`` seconds at ``period`` (at least 5)."""
    s = pd.Timedelta(period).total_seconds()
    return max(5, math.ceil(float(window_s) / s - 1e-9)) if s > 0 else 5


class RunningSpread:
    """Running robust spread per column (see module doc): ``1.4826 · median_W |r − med_W(r)|``
    (the running median absolute deviation, each sample's deviation from the median of the
    window ending at it), known once a quarter of the window is; the last ``W − 1`` residuals
    and deviations carried across pieces."""

    def __init__(self, window: int, columns: int) -> None:
        self.window = int(window)
        self.r_tail = np.full((0, columns), np.nan)
        self.d_tail = np.full((0, columns), np.nan)
        self.left_ = np.zeros((0, columns), np.int64)

    def _rolling_median(
        self, tail: np.ndarray, x: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The rolling median of ``x`` (continuing ``tail``), the new tail, and per row how
        many known values its window holds."""
        both = np.r_[tail, x]
        k = self.least
        if len(x) == 1:  # the live loop's one sample a cycle: the last window's median alone
            last = both[-self.window :]
            known = np.isfinite(last).sum(axis=0)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # an all-unknown column
                med = np.where(known >= k, np.nanmedian(last, axis=0), np.nan)[None, :]
            count = known[None, :]
        else:
            med = pd.DataFrame(both).rolling(self.window, min_periods=k).median().to_numpy()
            med = med[len(tail) :]
            cs = np.r_[np.zeros((1, both.shape[1]), np.int64), np.isfinite(both).cumsum(axis=0)]
            end = np.arange(len(tail), len(both)) + 1
            count = cs[end] - cs[np.maximum(end - self.window, 0)]
        keep = both[-(self.window - 1) :] if self.window > 1 else both[:0]
        return med, keep, count

    @property
    def least(self) -> int:
        """Known values a window needs for its median: a quarter of it, at least 3."""
        return max(3, self.window // 4)

    def transform(self, x: np.ndarray) -> np.ndarray:
        """The running spread of each column (NaN where unknown); :attr:`left_` is set to the
        known samples each row's column still needed (0 where its spread is known)."""
        a = np.asarray(x, float).reshape(len(x), -1)
        if a.shape[1] == 0 or len(a) == 0:
            self.left_ = np.zeros(a.shape, np.int64)
            return a.copy()
        med, self.r_tail, n_r = self._rolling_median(self.r_tail, a)
        dev = np.abs(a - med)
        mad, self.d_tail, n_d = self._rolling_median(self.d_tail, dev)
        # the warm-up: k known residuals for the median, then k known deviations from it
        # (the sample that completes the median gives the first deviation)
        k = self.least
        lr = np.maximum(k - n_r, 0)
        self.left_ = np.where(lr > 0, lr + np.maximum(k - 1 - n_d, 0), np.maximum(k - n_d, 0))
        return np.where(np.isfinite(a), 1.4826 * mad, np.nan)

    def to_state(self) -> dict[str, Any]:
        def rows(a: np.ndarray) -> list:
            return [[float(v) if np.isfinite(v) else None for v in r] for r in a]

        return {"r": rows(self.r_tail), "d": rows(self.d_tail)}

    def load_state(self, state: dict[str, Any]) -> None:
        m = self.r_tail.shape[1]

        def arr(rows: list) -> np.ndarray:
            a = np.array([[np.nan if v is None else v for v in r] for r in rows], float)
            return a.reshape(len(rows), m)

        self.r_tail, self.d_tail = arr(state["r"]), arr(state["d"])


@numba.njit(cache=True, nogil=True)
def _deadband_kernel(r, lo, hi, keep, state):  # pragma: no cover - numba
    # row by row (memory order); each column's state is its own
    n, m = r.shape
    out = np.empty((n, m))  # every element written once (NaN where unknown), no fill first
    for i in range(n):
        for j in range(m):
            x = r[i, j]
            if np.isnan(x) or np.isnan(hi[j]):
                out[i, j] = np.nan
                continue
            s = state[j]
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


#: side changes that arm the oscillation hold (:class:`OscillationHold`): two, a swing there
#: and back (+ − + or − + −), within two windows. One change is a single bipolar transient
#: (a load moved onto a twin when it stops and back when it restarts: + then −), not a
#: cycle. The window takes one change of a cycle (half a period: both sides, up to ``2W``
#: for a period ``4W``, twice what the spread test's ``W`` sees), so ``K`` changes are asked
#: within ``K`` windows (a full period for ``K = 2``; the jacket's stick-slip periods run
#: 43–244 samples against a window of 160). ``K = 1`` is the hold of e2ea008 exactly
OSCILLATION_CHANGES = 2
#: samples without a symptom of a column that has never had one
CALM = 1 << 40


@numba.njit(cache=True, nogil=True)
def _swing_kernel(
    s, window, on_at, ends, last, armed, opens, group, quiet, left, calm
):  # pragma: no cover - numba
    # row by row (memory order), in place; rows counted from this piece's first (earlier
    # ones negative): on_at, the row the symptom was last on; ends[j, b], the last row of the
    # (b+1)-th run before the current one (a run: the on samples of one side, the off ones
    # between ignored); last: the side it was last on; armed: the hold is on. It holds where
    # the hold of K = 1 does (the run before the current one ended within the window: both
    # sides on within it) once armed: armed when the K-th run back ended within K windows
    # (K side changes, K = ends.shape[1]), kept while the symptom is on or both sides are
    # on within the window. A settle (opens[i, group[j]] > 0: its bound in samples) opening
    # on a column quiet for ``quiet`` samples (calm) disarms it and forgets its runs; for
    # ``left`` samples its symptoms pass as they are, unseen by the hold (a known transient)
    n, m = s.shape
    k = ends.shape[1]
    for i in range(n):
        for j in range(m):
            x = s[i, j]
            on = x > 0 or x < 0
            o = opens[i, group[j]]
            if o > 0 and calm[j] >= quiet[j]:
                left[j] = max(left[j], o)
                armed[j] = False
                last[j] = 0.0
                for b in range(k):
                    ends[j, b] = i - k * window[j]
            if left[j] > 0:
                left[j] -= 1
                calm[j] = 0 if on else calm[j] + 1
                continue
            if on:
                side = 1.0 if x > 0 else -1.0
                if last[j] != 0.0 and side != last[j]:  # a side change: one run more back
                    for b in range(k - 1, 0, -1):
                        ends[j, b] = ends[j, b - 1]
                    ends[j, 0] = on_at[j]
                on_at[j] = i
                last[j] = side
            both = i - ends[j, 0] < window[j]  # both sides on within the window
            armed[j] = (
                both and (i - ends[j, k - 1] < k * window[j] or armed[j]) or (armed[j] and on)
            )
            if x == 0 and armed[j]:
                s[i, j] = last[j]
            calm[j] = 0 if (on or (x == 0 and armed[j])) else calm[j] + 1
    return s


class OscillationHold:
    """Delayed symptoms −1/0/+1 (NaN unknown) held on, on the side last on, from the sample
    the test has changed side ``changes`` times within the last ``changes`` × ``window``
    samples until, off, one side has not been on for ``window`` samples (per column; 0:
    never held; see module doc); state carried across pieces. A settle's opening (an
    operator's step, a hand valve's move, a state change, a piece's start: ``opens`` of
    :meth:`transform`) on a column without a symptom for ``quiet`` samples (per column: its
    unit's settle quiet time) disarms it, and
    the column's symptoms until the settle's bound are a known transient: they neither arm
    nor feed it."""

    def __init__(
        self, window: np.ndarray, changes: int = OSCILLATION_CHANGES, quiet: Any = 1
    ) -> None:
        if changes < 1:
            raise ValueError("the hold asks for at least one side change")
        self.window = np.asarray(window, np.int64).copy()
        m = len(self.window)
        self.quiet = np.broadcast_to(np.asarray(quiet, np.int64), (m,)).copy()
        self.since = self.window.copy()  # nothing on within the window yet
        self.ends = self._far(int(changes))  # no run before: none within the windows
        self.last = np.zeros(m)
        self.armed = np.zeros(m, bool)
        self.left = np.zeros(m, np.int64)  # samples of an open settle left
        self.calm = np.full(m, CALM, np.int64)  # samples without a symptom (held or not)

    def _far(self, changes: int) -> np.ndarray:
        """Per column and run back, samples since a run out of all ``changes`` windows."""
        return np.repeat((changes * self.window)[:, None], changes, axis=1)

    def transform(
        self, s: np.ndarray, opens: np.ndarray | None = None, group: np.ndarray | None = None
    ) -> np.ndarray:
        """``s`` held (in place when it is a C-ordered float array, as the delays give).
        ``opens``: rows × groups, a settle's bound in samples where one opens (0 elsewhere;
        None: none); ``group``: each column's group (None: all in group 0)."""
        a = np.ascontiguousarray(np.asarray(s, float))
        if not self.window.any():
            return a
        n, m = a.shape
        if opens is None:
            opens = np.zeros((n, 1), np.int64)
        opens = np.ascontiguousarray(np.asarray(opens, np.int64).reshape(n, -1))
        group = np.zeros(m, np.intp) if group is None else np.asarray(group, np.intp)
        # the counts (samples since, as of the last row) as rows of this piece and back
        on_at, ends = -1 - self.since, -1 - self.ends
        _swing_kernel(a, self.window, on_at, ends, self.last, self.armed, opens, group,
                      self.quiet, self.left, self.calm)  # fmt: skip
        n = len(a)
        self.since, self.ends = n - 1 - on_at, n - 1 - ends
        return a

    def to_state(self) -> dict[str, Any]:
        return {"since": self.since.tolist(), "ends": self.ends.tolist(),
                "last": self.last.tolist(), "armed": self.armed.tolist(),
                "left": self.left.tolist(), "calm": self.calm.tolist()}  # fmt: skip

    def load_state(self, state: dict[str, Any]) -> None:
        """Go on from :meth:`to_state`. A state saved before the side changes were counted
        (``p``, ``n``: samples since each side was on) gives the run before the current one
        (the other side's last sample), none further back and the hold off: the next change
        arms it if that run is recent enough. A state of another ``changes`` is cut, or
        padded with runs out of the windows. A state saved before the settles were seen
        (no ``left``, ``calm``): no settle open, every column quiet."""
        self.last = np.asarray(state["last"], float)
        m = len(self.window)
        self.left = np.asarray(state.get("left", np.zeros(m)), np.int64)
        self.calm = np.asarray(state.get("calm", np.full(m, CALM)), np.int64)
        ends = self._far(self.ends.shape[1])
        if "ends" in state:
            old = np.asarray(state["ends"], np.int64).reshape(len(self.window), -1)
            k = min(old.shape[1], ends.shape[1])
            ends[:, :k] = old[:, :k]
            self.since = np.asarray(state["since"], np.int64)
            self.armed = np.asarray(state["armed"], bool)
        else:
            p, n = np.asarray(state["p"], np.int64), np.asarray(state["n"], np.int64)
            self.since = np.where(self.last > 0, p, np.where(self.last < 0, n, np.minimum(p, n)))
            ends[:, 0] = np.where(self.last > 0, n, np.where(self.last < 0, p, ends[:, 0]))
            self.armed = np.zeros(len(self.window), bool)
        self.ends = ends


@numba.njit(cache=True, nogil=True)
def _release_kernel(
    s, cols, spread, release, held, opens, group, left, fcols, fwhich
):  # pragma: no cover
    # row by row, in place: a spread column on raises its hold, and so does one of its
    # loop's own tests on (fcols, fwhich: the follower's column and its spread's index in
    # cols) where the loop's long spread is above its release; off (0), the spread column is
    # held on while its long spread is above its release threshold (NaN: not), else the
    # hold drops; an unknown symptom (NaN) stays unknown and leaves the hold as it is. For a
    # settle's bound after it opens on its group (opens[i, group[j]] > 0: the bound in
    # samples) nothing raises the hold (a known transient); one raised before goes on
    n = s.shape[0]
    for i in range(n):
        for k in range(cols.shape[0]):
            j = cols[k]
            o = opens[i, group[j]]
            if o > 0:
                left[k] = max(left[k], o)
            settling = left[k] > 0
            if settling:
                left[k] -= 1
            x = s[i, j]
            wide = spread[i, k] > release[k]
            arm = x > 0
            if wide and not arm:
                for f in range(fcols.shape[0]):
                    if fwhich[f] == k:
                        y = s[i, fcols[f]]
                        if y > 0 or y < 0:
                            arm = True
            if arm and not settling:
                held[k] = True
            if x == 0 and held[k]:
                if wide:
                    s[i, j] = 1.0
                else:
                    held[k] = False
    return s


_NONE = np.zeros(0, np.int64)

#: a valve reads "pinned" within this share of its span from an edge (or past it), on this
#: sample and the one before: the tank's level valve, clipped at 0 and 100 %, has a span
#: learned as -1.99 … 101.6 and sits 1.5 % (at 100) and 1.9 % (at 0) of it from the edge.
#: Not "the same reading as the sample before" (until branch i34-pinrates): a transmitter
#: that reads its limit with noise (99.98, 100.01, …) was never pinned, and its surge was
#: named on the valve alone at 60 s, 10 s and 1 s (tests/test_unit_pinned_rates.py); on
#: the tank's fault-free runs both pin the same samples but a handful (2/2, 37/36, 438/433
#: of 6 days at 60 s, 10 s, 1 s). The price: a valve that works past the span its build
#: window saw, two samples in a row, counts as pinned too.
PINNED = 0.02


class PinnedValves:
    """Per column (a loop's long spread) its valve's span; :meth:`mask` makes the long spread
    unknown from a sample on which the valve is pinned at an edge (within :data:`PINNED` of
    its span from the same edge, or past it, there and on the sample before; see module
    doc) until ``window`` samples after the last such. The last reading and the samples left
    of the window carried across pieces (and the live loop's cycles)."""

    def __init__(self, window: int, lo: np.ndarray, hi: np.ndarray) -> None:
        self.window = int(window)
        self.lo = np.asarray(lo, float)
        self.hi = np.asarray(hi, float)
        self.last = np.full(len(self.lo), np.nan)  # the valve's previous reading
        self.left = np.zeros(len(self.lo), np.int64)  # samples the spread stays unknown

    def pinned(self, act: np.ndarray) -> np.ndarray:
        """Per row and column whether the valve ``act`` (samples × columns) is pinned."""
        a = np.asarray(act, float).reshape(-1, len(self.lo))
        prev = np.r_[self.last[None, :], a[:-1]]
        tol = PINNED * (self.hi - self.lo)
        with np.errstate(invalid="ignore"):
            low, high = self.lo + tol, self.hi - tol
            return ((a <= low) & (prev <= low)) | ((a >= high) & (prev >= high))

    def mask(self, spread: np.ndarray, act: np.ndarray) -> np.ndarray:
        """``spread`` (samples × columns, in place) NaN where the valve is or was pinned
        within the window; advances the carried state."""
        pin = self.pinned(act)
        n = len(pin)
        if not n or not len(self.lo):
            return spread
        i = np.arange(n)[:, None]
        last = np.maximum.accumulate(np.where(pin, i, -self.window - 1), axis=0)
        unknown = (i - last < self.window) | (i < self.left[None, :])
        spread[unknown] = np.nan
        self.left = np.maximum(np.maximum(self.left - n, last[-1] + self.window - n), 0)
        a = np.asarray(act, float).reshape(n, -1)
        self.last = a[-1].copy()
        return spread

    def to_state(self) -> dict[str, Any]:
        return {"last": [float(v) if np.isfinite(v) else None for v in self.last],
                "left": self.left.tolist()}  # fmt: skip

    def load_state(self, state: dict[str, Any] | None) -> None:
        """A state of the same columns; none (saved before it) or another's: from rest."""
        if not state or len(state.get("left", ())) != len(self.lo):
            return
        self.last = np.array([np.nan if v is None else v for v in state["last"]], float)
        self.left = np.asarray(state["left"], np.int64)


class ReleaseHold:
    """A spread test's symptom, once on, held on while the running spread of its residual
    over the release window stays above its ``release`` threshold (see module doc); the
    hold raised too by one of its loop's own tests (``followers``: the tests of the loop's
    measurement and actuator) on while that spread is above it; the combined test held the
    same way (:meth:`combined`). The long window's tail and each column's hold carried
    across pieces."""

    def __init__(
        self,
        window: int,
        cols: np.ndarray,
        release: np.ndarray,
        followers: list[np.ndarray] | None = None,
        valves: list[tuple[str, float, float] | None] | None = None,
    ) -> None:
        self.cols = np.asarray(cols, np.int64)
        self.release = np.asarray(release, float)
        #: per column its loop's valve (the tag the unit's columns read, its span), or None
        self.valves = list(valves or [None] * len(self.cols))
        spans = np.array([(v[1], v[2]) if v else (np.nan, np.nan) for v in self.valves], float)
        self.pinned = PinnedValves(window, *spans.reshape(-1, 2).T)
        fol = [np.asarray(f, np.int64) for f in (followers or [])]
        #: the loops' own tests that raise the hold (their columns), and their spread's index
        self.fcols = np.concatenate([_NONE, *fol]).astype(np.int64)
        self.fwhich = np.concatenate(
            [_NONE, *[np.full(len(f), k, np.int64) for k, f in enumerate(fol)]]
        ).astype(np.int64)
        self.spread = RunningSpread(window, len(self.cols))
        self.held = np.zeros(len(self.cols), np.bool_)
        self.left = np.zeros(len(self.cols), np.int64)  # samples of an open settle left
        self.t2_held = np.zeros(1, np.bool_)  # the combined test's hold (combined)
        self.t2_left = np.zeros(1, np.int64)

    def valve_readings(self, values, n: int) -> np.ndarray:
        """Each column's valve reading over ``n`` samples (samples × columns; NaN where it
        has none): ``values(tag)`` reads a tag's column, as :class:`~.unit.Columns` does."""
        out = np.full((n, len(self.cols)), np.nan)
        for k, v in enumerate(self.valves):
            if v is not None:
                out[:, k] = np.asarray(values(v[0]), float)
        return out

    def long_spread(self, raw: np.ndarray, act: np.ndarray | None = None) -> np.ndarray:
        """The long window's running spread of the spread columns' raw residuals
        (``raw``: samples × the spread columns), unknown where a loop's valve (``act``:
        :meth:`valve_readings` of the same rows) is or was pinned (:class:`PinnedValves`)."""
        sp = self.spread.transform(raw)
        return sp if act is None else self.pinned.mask(sp, act)

    def transform(
        self,
        s: np.ndarray,
        spread: np.ndarray,
        opens: np.ndarray | None = None,
        group: np.ndarray | None = None,
    ) -> np.ndarray:
        """``s`` (samples × tests, delayed symptoms; in place when C-ordered float) with the
        spread columns held; ``spread``: :meth:`long_spread` of the same rows; ``opens``,
        ``group``: where a settle opens, as :meth:`OscillationHold.transform` (within its
        bound nothing raises the hold; one raised before goes on)."""
        a = np.ascontiguousarray(np.asarray(s, float))
        if not self.cols.size:
            return a
        n, m = a.shape
        sp = np.ascontiguousarray(np.asarray(spread, float).reshape(n, len(self.cols)))
        if opens is None:
            opens = np.zeros((n, 1), np.int64)
        opens = np.ascontiguousarray(np.asarray(opens, np.int64).reshape(n, -1))
        group = np.zeros(m, np.intp) if group is None else np.asarray(group, np.intp)
        return _release_kernel(a, self.cols, sp, self.release, self.held, opens, group,
                               self.left, self.fcols, self.fwhich)  # fmt: skip

    def combined(
        self, s_t2: np.ndarray, spread: np.ndarray, opens: np.ndarray | None = None
    ) -> np.ndarray:
        """The combined test's symptom ``s_t2`` (samples; a new array) held the same way:
        once on (outside a settle's bound, group 0 of ``opens``), on while any loop's long
        spread ``spread`` is above its release."""
        a = np.ascontiguousarray(np.asarray(s_t2, float).reshape(-1, 1)).copy()
        n = len(a)
        if not self.cols.size or not n:
            return a[:, 0]
        sp = np.asarray(spread, float).reshape(n, len(self.cols))
        with np.errstate(invalid="ignore"):
            ratio = np.where(np.isnan(sp), -np.inf, sp / self.release).max(axis=1)
        op = np.zeros((n, 1), np.int64) if opens is None else np.asarray(opens, np.int64)
        op = np.ascontiguousarray(op.reshape(n, -1)[:, :1])
        return combined_release(a, np.ascontiguousarray(ratio), op, self.t2_held, self.t2_left)

    def to_state(self) -> dict[str, Any]:
        return {"spread": self.spread.to_state(), "held": self.held.tolist(),
                "left": self.left.tolist(),
                "t2": [bool(self.t2_held[0]), int(self.t2_left[0])],
                "pinned": self.pinned.to_state()}  # fmt: skip

    def load_state(self, state: dict[str, Any]) -> None:
        """A state of the same columns; one saved over other columns (before a spread test
        without a ``release`` was left out) starts the hold from rest; the combined test's
        hold of a state saved before it, too."""
        if len(state["held"]) != len(self.cols):
            return
        self.spread.load_state(state["spread"])
        self.held = np.asarray(state["held"], np.bool_).reshape(len(self.cols))
        self.left = np.asarray(state.get("left", np.zeros(len(self.cols))), np.int64)
        t2 = state.get("t2") or [False, 0]
        self.t2_held = np.array([bool(t2[0])], np.bool_)
        self.t2_left = np.array([int(t2[1])], np.int64)
        self.pinned.load_state(state.get("pinned"))


def combined_release(
    s_t2: np.ndarray, ratio: np.ndarray, opens: np.ndarray, held: np.ndarray, left: np.ndarray
) -> np.ndarray:
    """The combined test's release (:meth:`ReleaseHold.combined`; the live path's too):
    ``s_t2`` (samples × 1, in place) held on while ``ratio`` (per sample the largest of the
    unit's loops' long spread over its release) is above 1; ``opens`` (samples × 1) the
    unit's settle openings; ``held``, ``left`` (1 each) the carried hold, in place."""
    n = len(s_t2)
    return _release_kernel(s_t2, np.zeros(1, np.int64), ratio.reshape(n, 1), np.ones(1), held,
                           opens, np.zeros(1, np.intp), left, _NONE, _NONE)[:, 0]  # fmt: skip


class EpisodeHold:
    """Each tag's share averaged over the current alarm episode (see module doc)."""

    def __init__(self, tags: int) -> None:
        self.total = np.zeros(tags)
        self.count = 0

    def transform(self, share: np.ndarray, active: np.ndarray) -> np.ndarray:
        """Per sample the mean share since its episode began (NaN outside alarms)."""
        act = np.asarray(active, bool)
        out = np.full(share.shape, np.nan)
        out[act] = self.transform_at(share[act], act)
        return out

    def transform_at(self, share_at: np.ndarray, active: np.ndarray) -> np.ndarray:
        """:meth:`transform` at the alarm samples only, from their shares ``share_at``
        (``active.sum()`` × tags, in order): the running means there.

        Worked over the alarm samples only (running sums over them are those over all
        samples with zeros between: the same numbers, at the cost of the alarms alone)."""
        act = np.asarray(active, bool)
        n = act.size
        at = np.flatnonzero(act)
        if at.size == 0:
            if n:
                self.total, self.count = np.zeros(share_at.shape[1]), 0
            return share_at[:0].astype(float)
        m = at.size
        start = ~np.r_[self.count > 0, act[:-1]][at]
        cs = np.cumsum(np.nan_to_num(share_at, nan=0.0), axis=0)
        cc = np.arange(1, m + 1, dtype=float)
        last = np.maximum.accumulate(np.where(start, np.arange(m), -1))
        before = np.clip(last - 1, 0, None)
        base_s = np.where((last > 0)[:, None], cs[before], 0.0)
        base_c = np.where(last > 0, cc[before], 0.0)
        carry = last < 0  # the episode the previous piece left open
        total = cs - base_s + np.where(carry[:, None], self.total, 0.0)
        count = cc - base_c + np.where(carry, self.count, 0)
        with np.errstate(invalid="ignore", divide="ignore"):
            out = total / np.maximum(count, 1)[:, None]
        if act[-1]:
            self.total, self.count = total[-1].copy(), int(count[-1])
        else:
            self.total, self.count = np.zeros(share_at.shape[1]), 0
        return out

    def to_state(self) -> dict[str, Any]:
        return {"total": self.total.tolist(), "count": self.count}

    def load_state(self, state: dict[str, Any]) -> None:
        self.total = np.asarray(state["total"], float)
        self.count = int(state["count"])


class AlarmHold:
    """The unit's own off-delay (ISA-18.2): once the unit alarms, it stays in alarm until
    no test has shown a symptom for ``off`` samples — each test's off-delay spaces its own
    alarms, but tests taking turns would otherwise make the unit's alarm chatter. For each
    sample the row whose diagnosis it repeats (:meth:`sources`).

    Vectorised over units: ``off`` an array (one off-delay per unit, 0: no hold) holds each
    column of ``active`` on its own — :class:`~diag_plugin.diagnose.plant.Plant` holds all
    its units with one, a :class:`~diag_plugin.diagnose.unit.Unit` (scalar ``off``) itself."""

    def __init__(self, off: int | np.ndarray) -> None:
        self.single = np.ndim(off) == 0
        self.off = np.atleast_1d(np.asarray(off, np.int64)).copy()
        self.since = self.off.copy()  # samples since the last alarm sample (≥ off: none held)

    def sources(self, active: np.ndarray) -> np.ndarray:
        """Per sample (and unit: ``active`` samples × units, or samples for a single unit):
        itself (−2) when in alarm or outside any hold, the last alarm row of this piece it
        repeats (≥ 0), or −1 for the previous piece's last alarm row."""
        act = np.asarray(active, bool)
        shape = act.shape
        act = act.reshape(len(act), len(self.off))
        n = len(act)
        idx = np.arange(n)[:, None]
        last = np.maximum.accumulate(np.where(act, idx, -1), axis=0) if n else act.astype(int)
        gap = np.where(last >= 0, idx - last, idx + 1 + self.since[None, :])
        held = ~act & (gap < self.off[None, :])
        out = np.where(held, np.where(last >= 0, last, -1), -2)
        if n:
            self.since = gap[-1].astype(np.int64)  # 0 where the last sample is in alarm
        return out.reshape(shape)

    def to_state(self) -> dict[str, Any]:
        return {"since": int(self.since[0]) if self.single else self.since.tolist()}

    def load_state(self, state: dict[str, Any]) -> None:
        self.since = np.atleast_1d(np.asarray(state["since"], np.int64)).copy()


def warm_up(
    unknown: np.ndarray,
    raw_known: np.ndarray,
    seen: np.ndarray | int,
    depth: np.ndarray,
    spread_left: np.ndarray,
    spread_test: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Which unknown tests are unknown only because the unit has not yet seen enough samples
    since it started, and how many more samples each needs (rows × tests).

    ``seen``: samples before each row since the start; ``depth``: per test the longest lag
    its model reads (unknown while ``seen < depth``); ``spread_left``:
    :attr:`RunningSpread.left_` per row for the spread tests (0 elsewhere); ``spread_test``:
    the spread tests; ``raw_known``: their residual known before the spread. A spread test
    behind its lags needs its lags' samples, then its window's."""
    lag_left = np.maximum(np.asarray(depth)[None, :] - np.reshape(seen, (-1, 1)), 0)
    lag_warm = lag_left > 0
    spread = spread_test[None, :] & (spread_left > 0) & (raw_known | lag_warm)
    warm = unknown & (lag_warm | spread)
    return warm, lag_left + np.where(spread_test[None, :], spread_left, 0)


def warm_labels(tests: list[str], depth: np.ndarray, spread_test: np.ndarray) -> list[str]:
    """Per test what it waits for in a warm-up (:func:`warming_up`)."""
    out = []
    for name, d, sp in zip(tests, depth, spread_test, strict=True):
        if sp:
            out.append(f"the spread window of {name}")
        else:
            out.append(f"{int(d)} samples of history for {name}")
    return out


def warming_up(
    why: np.ndarray,
    warm: np.ndarray,
    left: np.ndarray,
    report: np.ndarray,
    labels: list[str],
    period_s: float,
) -> np.ndarray:
    """``why`` (a reason per row) with the warm-up put first on the rows in ``report`` where a
    test is unknown only because the unit has not seen enough samples since it started
    (``warm``, ``left``: :func:`warm_up`; ``labels``: :func:`warm_labels`):
    ``warming up, N s left (the spread window of TEST)`` — the unit is not at fault."""
    out = why.copy()
    for i in np.flatnonzero(report & warm.any(axis=1)):
        cols = np.flatnonzero(warm[i])
        secs = float(left[i, cols].max()) * period_s
        text = f"warming up, {secs:.0f} s left ({'; '.join(labels[c] for c in cols)})"
        out[i] = f"{text}; {out[i]}" if out[i] else text
    return out
