"""Tags the unit only ever saw at one value: when one moves, a new operating point, named
(issue 34, item 5).

A tag constant over the build window — a standby pump's run feedback and motor current, 0
all day because the pump never ran, a fixed valve — teaches no model anything: the build
tests none of them and no test reads them (:func:`~diag_plugin.unitbuild.build.choose_tests`,
"constant over the window"). When such a tag moves at run time the plant is at an operating
point the unit never learned (the pump that takes duty at a daily rotation), but no test
knows it, and the tests of the other pumps alarm (docs/explanation/acceptance-pumps.md: 74–79
% of a fault-free day in alarm from the 06:00 duty swap on). So the build records each such
tag that is not a set-point nor a hand valve (they have their own handling) in the unit
file, with the value the window held it at::

    [fixed]
    PMP3_ON = { min = 0.0, max = 0.0, margin = 1e-09 }

``margin`` is the build's own test of "constant" (:func:`tolerance`: a spread of at most
``1e-9 · max(1, |value|)`` over the window): a value beyond it is one the build would have
called a variation, so one the unit never saw. The tag is read at run time
(:attr:`~diag_plugin.diagnose.unit.Unit.tags`); where it is outside ``[min − margin, max +
margin]`` for the unit's on-delay (``on_delay`` samples: a blip shorter than what raises an
alarm raises nothing), the unit is CHECK_FUNCTION — no alarm, no fault, its diagnosis unknown
— with ``PMP3_ON = 1 outside what the unit learned (0 over its window) since T`` (``T`` the
first sample outside), until the tag has been back for the unit's off-delay (``off_delay``
samples: the alarm an unlearned point raised is held that long). A sample without a value is
neither outside nor back: it changes nothing. ``diag unit accept`` of a period where the tag
moved widens ``min``/``max`` to what that period showed (:func:`~.manual.merged`): the
operator confirmed the point, and the unit answers there after. The state (each tag's run
outside, its start, the samples back) is carried from piece to piece and across a live
restart (:meth:`FixedGuard.to_state`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numba
import numpy as np
import pandas as pd

from diag_plugin.diagnose.manual import ManualSpan, read_manual

#: the build's test of a constant tag: its spread over the window at most this share of
#: ``max(1, |value|)`` (:func:`~diag_plugin.unitbuild.build.choose_tests`)
CONSTANT_REL = 1e-9


def tolerance(value: float) -> float:
    """The largest spread the build calls constant at ``value``: ``1e-9 · max(1, |value|)``."""
    return CONSTANT_REL * max(1.0, abs(float(value)))


def fixed_span(tag: str, value: float) -> ManualSpan:
    """A constant tag's row: ``min = max = value``, ``margin`` :func:`tolerance`."""
    return ManualSpan(tag, float(value), float(value), tolerance(value))


def read_fixed(table: Mapping, error, line_of) -> dict[str, ManualSpan]:
    """The ``[fixed]`` table of a unit file (rows as ``[manual]``'s,
    :func:`~.manual.read_manual`)."""
    return read_manual(table, error, line_of, name="fixed")


def learned_text(s: ManualSpan) -> str:
    """What the unit learned of the tag: ``0 over its window`` or ``0 … 1``."""
    if s.min == s.max:
        return f"{s.min:.4g} over its window"
    return f"{s.min:.4g} … {s.max:.4g}"


@numba.njit(cache=True, nogil=True)
def _kernel(code, ns, on_delay, off_delay, run, back, active, start, since, last, x):
    # per tag (column), row by row: ``code`` 1 outside, 0 back inside, -1 no value. Returns
    # per row and tag whether the guard is on and since when (UTC ns)
    n, k = code.shape
    on = np.zeros((n, k), np.bool_)
    when = np.zeros((n, k), np.int64)
    val = np.full((n, k), np.nan)
    for j in range(k):
        for i in range(n):
            c = code[i, j]
            if c == 1:
                run[j] += 1
                back[j] = 0
                last[j] = x[i, j]
                if run[j] == 1:
                    start[j] = ns[i]
                if not active[j] and run[j] >= on_delay:
                    active[j] = True
                    since[j] = start[j]
            elif c == 0:
                run[j] = 0
                if active[j]:
                    back[j] += 1
                    if back[j] >= off_delay:
                        active[j] = False
                        back[j] = 0
            on[i, j] = active[j]
            when[i, j] = since[j]
            val[i, j] = last[j]
    return on, when, val


class FixedGuard:
    """The unit's constant tags (``spans``: model tag → its ``[fixed]`` row; ``names``: model
    tag → plant tag) and the state of each one's excursion (module doc)."""

    def __init__(
        self,
        spans: Mapping[str, ManualSpan],
        names: Mapping[str, str],
        on_delay: int,
        off_delay: int,
    ):
        self.spans = dict(spans)
        self.tags = list(self.spans)
        self.plant = [names.get(t, t) for t in self.tags]
        self.lo = np.array([s.lo for s in self.spans.values()], float)
        self.hi = np.array([s.hi for s in self.spans.values()], float)
        self.on_delay = max(1, int(on_delay))
        self.off_delay = max(1, int(off_delay))
        self.reset()

    @classmethod
    def of(cls, unit) -> FixedGuard | None:
        """The guard of a :class:`~diag_plugin.diagnose.unit.Unit` (None without ``[fixed]``)."""
        spans = getattr(unit.file, "fixed", {})
        if not spans:
            return None
        return cls(spans, unit.file.tags, unit.ev["on_delay"], unit.ev["off_delay"])

    def reset(self) -> FixedGuard:
        k = len(self.tags)
        self.run = np.zeros(k, np.int64)  # samples outside in a row
        self.back = np.zeros(k, np.int64)  # samples back inside while on
        self.active = np.zeros(k, bool)
        self.start = np.zeros(k, np.int64)  # the run outside's first sample (UTC ns)
        self.since = np.zeros(k, np.int64)  # the guard's (the run that turned it on)
        self.last = np.full(k, np.nan)  # the last value outside
        return self

    def to_state(self) -> dict[str, Any]:
        """The carried state as JSON (each tag's run outside, its start, the samples back)."""
        return {
            "run": self.run.tolist(),
            "back": self.back.tolist(),
            "active": self.active.tolist(),
            "start": self.start.tolist(),
            "since": self.since.tolist(),
            "last": [None if v != v else float(v) for v in self.last.tolist()],
        }

    def load_state(self, state: Mapping[str, Any]) -> FixedGuard:
        """Back from :meth:`to_state` (a state of other tags: from rest)."""
        if len(state.get("run", ())) != len(self.tags):
            return self.reset()
        self.run = np.asarray(state["run"], np.int64)
        self.back = np.asarray(state["back"], np.int64)
        self.active = np.asarray(state["active"], bool)
        self.start = np.asarray(state["start"], np.int64)
        self.since = np.asarray(state["since"], np.int64)
        self.last = np.array([np.nan if v is None else v for v in state["last"]], float)
        return self

    def idle(self, x: np.ndarray) -> bool:
        """True when :meth:`transform` of the one row ``x`` (plant values) would hold nothing
        and change nothing: no tag outside now nor in a run outside before (the live loop's
        shortcut, most cycles)."""
        if self.active.any() or self.run.any():
            return False
        with np.errstate(invalid="ignore"):
            return not ((x < self.lo) | (x > self.hi)).any()

    def transform(self, index, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per row of ``x`` (rows × :attr:`tags`, plant values; ``index`` their times)
        whether the unit is held CHECK_FUNCTION, and why (``""`` elsewhere). Advances the
        state."""
        x = np.asarray(x, float).reshape(len(index), len(self.tags))
        with np.errstate(invalid="ignore"):
            off = (x < self.lo) | (x > self.hi)
        code = np.where(np.isnan(x), -1, off.astype(np.int8)).astype(np.int8)
        times = pd.DatetimeIndex(index)
        ns = times.as_unit("ns").asi8
        on, when, val = _kernel(code, ns, self.on_delay, self.off_delay, self.run, self.back,
                                self.active, self.start, self.since, self.last, x)  # fmt: skip
        held = on.any(axis=1)
        why = np.full(len(index), "", dtype=object)
        rows = np.flatnonzero(held)
        for j in range(len(self.tags)):  # each tag's sentences, written value by value
            at = on[rows, j]
            if not at.any():
                continue
            r = rows[at]
            starts, inv = np.unique(when[r, j], return_inverse=True)
            tails = [self._tail(j, w, times.tz) for w in starts.tolist()]
            head = f"{self.plant[j]} = "
            text = np.array([f"{head}{v:.4g}{tails[i]}"
                             for v, i in zip(val[r, j].tolist(), inv.reshape(-1).tolist(),
                                             strict=True)], dtype=object)  # fmt: skip
            before = why[r]
            why[r] = np.where(before == "", text, before + "; " + text)
        return held, why

    def _tail(self, j: int, ns: int, tz) -> str:
        """:meth:`sentence` after the value."""
        s = self.spans[self.tags[j]]
        when = pd.Timestamp(int(ns), tz="UTC")
        if tz is not None:
            when = when.tz_convert(tz)
        return f" outside what the unit learned ({learned_text(s)}) since {when.isoformat()}"

    def sentence(self, j: int, value: float, ns: int, tz) -> str:
        """``PMP3_ON = 1 outside what the unit learned (0 over its window) since T``."""
        return f"{self.plant[j]} = {value:.4g}{self._tail(j, ns, tz)}"


def apply(held: np.ndarray, status: np.ndarray, faults: np.ndarray, detected: np.ndarray) -> None:
    """The held samples CHECK_FUNCTION, no fault, the diagnosis unknown, in place."""
    from diag_plugin.status import NE107

    status[held] = NE107.CHECK_FUNCTION
    faults[held] = ""
    detected[held] = np.nan


def fixed_spans(values: Mapping[str, float]) -> list[ManualSpan]:
    """The ``[fixed]`` rows of the build's constant tags (tag → its value)."""
    return [fixed_span(t, v) for t, v in values.items()]


def widen(old: Mapping[str, ManualSpan], frame: pd.DataFrame) -> dict[str, ManualSpan]:
    """The rows widened to hold ``frame`` (an accepted window, models' tag names): ``min`` and
    ``max`` merged exactly with its extremes, the margin kept; only the rows that changed."""
    out = {}
    for tag, s in old.items():
        if tag not in frame.columns:
            continue
        x = frame[tag].to_numpy(float)
        x = x[np.isfinite(x)]
        if not x.size:
            continue
        new = ManualSpan(tag, min(s.min, float(x.min())), max(s.max, float(x.max())), s.margin)
        if new != s:
            out[tag] = new
    return out
