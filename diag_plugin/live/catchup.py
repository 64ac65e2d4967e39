"""Catching up on the samples the plug-in missed while it was down.

A restart restores the units' state of the last cycle saved (:mod:`~diag_plugin.live.state`),
time ``T_stop``. The samples between ``T_stop`` and now that the historian holds (stored by
another collector meanwhile, or the earlier run's own cycles after its last state save,
recovered from its journal) are diagnosed before the first cycle, so that the alarms that
happened meanwhile are known and the live loop goes on from where an uninterrupted plug-in
would be. :func:`catch_up` does it in one of three ways, by the gap's length:

``replayed``
    a gap of at most the units' lead-in (:func:`~diag_plugin.diagnose.leadin.lead_in`: the
    low-pass filter's settling, the delays, the lags and spread windows; 1,210 samples for
    the example valve unit): every sample is fed to :meth:`Plant.cycle
    <diag_plugin.diagnose.plant.Plant.cycle>` on the live loop's cycle grid, from the
    restored state — the live path itself (equal to :meth:`Unit.evaluate` over the same rows,
    tested), so the state the loop goes on from is the one it would have had;
``history``
    a longer gap, up to ``max_gap_s`` (7 days): the gap is diagnosed through the replay's own
    path, unit by unit — ``diag diagnose UNIT --from T_stop --to now``: its lead-in before
    ``T_stop``, each unit's period, :meth:`Unit.evaluate` vectorised over chunks — for the
    alarm episodes; the live plant starts fresh and warms up on the historian's last lead-in
    before now (after a lead-in a replay's state is the running plug-in's, which is why a
    longer gap needs no more);
``warm-up``
    a gap longer than ``max_gap_s``: only the warm-up; the gap is reported as not diagnosed.

A start without a state to go on from (the first, or the unit files changed since it was
saved) has no gap: :func:`warm_up` feeds the historian's last lead-in before now through the
fresh plant (mode ``fresh``), so the first cycle starts with its lags, filters, delays, spread
windows and holds where a plug-in running all along would have them, not cold.

Episodes follow the OPC UA server's alarm rule (FAILURE, OFF_SPEC and MAINTENANCE_REQUIRED
raise the condition, CHECK_FUNCTION holds it): one that began and ended in the gap is
reported as past, with its times, never raised now; one still on at the end is raised by the
first cycle, as any alarm. Before the gap's first stored sample the plant jumps (as a restart
without catch-up); where the historian holds nothing (time range, tags), it is said.

Bounded: the live plant's part (replay or warm-up) is at most a lead-in of samples, done
first; the history goes on while time is left. ``deadline`` (``time.monotonic()``) stops
either between two samples (replay) or two chunks (history); the rest is reported as not
diagnosed; a fresh start's warm-up cut so starts cold. Each historian statement is bounded by
the time left too (``Historian(timeout=...)``: a locked or slow database fails the read
instead of hanging on). The caller runs it in a thread of its own before the live loop's
first cycle and waits for it no longer than the deadline
(:meth:`~diag_plugin.live.loop.LiveLoop.run`); the thread touches the live plant only through
a :class:`Gate` the loop closes when it stops waiting, so nothing moves the plant after.
"""

from __future__ import annotations

import copy
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from connectors.alarms import ALARM_STATUSES  # the OPC UA server's rule; CHECK_FUNCTION holds

CHECK_FUNCTION = 2
#: the longest gap diagnosed; longer: the units only warm up on the last lead-in
MAX_GAP_S = 7 * 86_400.0
#: rows read from the historian per step (the deadline is checked between chunks)
CHUNK_ROWS = 2_000


class Gate:
    """The live plant shared by the catch-up's thread and the live loop: the thread changes
    the plant only under :attr:`lock` while the gate is open (one :meth:`Plant.cycle
    <diag_plugin.diagnose.plant.Plant.cycle>` at a time); :meth:`close`, once the loop stops
    waiting, waits for the cycle under way, so from then on the plant is the loop's alone."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.closed = False
        self.fed = 0  #: samples the thread fed through the plant (under the lock)

    def close(self) -> None:
        with self.lock:
            self.closed = True


@dataclass
class CatchUpPlan:
    """How :class:`~diag_plugin.live.loop.LiveLoop` catches up before its first cycle: the
    historian ``url``, at most ``timeout`` seconds (the first cycle waits no longer), gaps
    up to ``max_gap_s`` diagnosed (longer: warm-up only)."""

    url: str
    timeout: float = 30.0
    max_gap_s: float = MAX_GAP_S


@dataclass
class Episode:
    """One unit's alarm condition while the plug-in was down: from ``start`` to ``end``
    (None: still on at the end of what was diagnosed). ``at_gap_start``: already on at the
    gap's first sample (it may have begun before). ``faults``: every fault isolated during
    the episode, in order of appearance; ``tags``: the tags named (units isolating to tags)."""

    unit: str
    start: pd.Timestamp
    status: int
    end: pd.Timestamp | None = None
    at_gap_start: bool = False
    faults: list[str] = field(default_factory=list)
    tags: list[str] = field(default_factory=list)
    quality: int = 0


@dataclass
class CatchUp:
    """What :func:`catch_up` did (module doc for ``mode``: ``none`` when no cycle was
    missed). ``first``/``last``: the live plant's samples; ``history_to``: where each unit's
    history replay ended; ``timed_out``: the deadline stopped it."""

    since: pd.Timestamp | None  #: the restored state's last cycle (None: a fresh start)
    until: pd.Timestamp
    period_s: float
    mode: str = "none"
    timed_out: bool = False
    rows: int = 0  #: samples the live plant evaluated
    total: int = 0  #: cycles missed (from the state's next cycle to ``until``)
    first: pd.Timestamp | None = None
    last: pd.Timestamp | None = None
    history_rows: int = 0  #: samples the history replay evaluated (all units)
    history_to: dict[str, pd.Timestamp] = field(default_factory=dict)
    last_sample: pd.Timestamp | None = None  #: the last time with any sample
    episodes: list[Episode] = field(default_factory=list)
    seen: dict[str, bool] = field(default_factory=dict)  #: tag → any sample in the gap
    not_stored: list[str] = field(default_factory=list)  #: tags the historian does not know
    lead: int = 0  #: the lead-in, samples
    max_gap_s: float = MAX_GAP_S
    cpu_s: float = 0.0
    window_from: pd.Timestamp | None = None  #: a fresh start's warm-up: where it read from

    @property
    def gap_start(self) -> pd.Timestamp:
        if self.since is None:  # a fresh start: the warm-up's window
            return self.window_from if self.window_from is not None else self.until
        return next_row(self.since, pd.Timedelta(seconds=self.period_s))

    @property
    def no_samples(self) -> list[str]:
        """Tags the historian holds nothing of in the gap."""
        return [t for t, s in self.seen.items() if not s]

    def lines(self) -> list[tuple[pd.Timestamp | None, str, dict[str, Any]]]:
        """The log: (time, text, event fields); the episodes at their own times, ``unit``
        in their fields."""
        a, b = self.gap_start, self.until
        if self.since is None:
            return [(None, x, {}) for x in self._fresh_lines()]
        gap = _span((b - self.since).total_seconds())
        head = f"catch-up: the state is of {_t(self.since)} UTC, {gap} before now"
        if self.mode == "none":
            return [(None, f"{head}: no cycle missed", {})]
        p = pd.Timedelta(seconds=self.period_s)
        out: list[str] = []
        if self.not_stored:
            out.append(f"catch-up: tags {', '.join(self.not_stored)} are not in the historian")
        if self.mode == "empty":
            out.append(
                f"{head}: the historian holds no samples of {', '.join(self.no_samples)} "
                f"from {_t(a)} to {_t(b)}: nothing to diagnose, the units go on from the state"
            )
            return [(None, x, {}) for x in out]
        cpu = f"{self.cpu_s:.2f} s CPU"
        if self.mode == "replayed":
            out.append(
                f"{head}: {self.rows} missed cycles from {_t(self.first)} to {_t(self.last)} "
                f"diagnosed from the historian ({cpu}); the units go on from there; "
                f"{len(self.episodes)} alarm episodes"
            )
        elif self.mode == "history":
            done = [u for u, t in self.history_to.items() if t >= self.last_sample_or(b)]
            out.append(
                f"{head}: longer than the units' lead-in ({self.lead} samples), so the gap "
                f"was replayed unit by unit as `diag diagnose` does ({self.history_rows} "
                f"samples, {len(done)} of {len(self.history_to)} units to the end) for its "
                f"alarms: {len(self.episodes)} episodes; the units started fresh and warmed up "
                f"on the historian's last {self.rows} samples ({_t(self.first)} to "
                f"{_t(self.last)}) ({cpu})"
            )
        else:
            out.append(
                f"{head}: longer than the {_span(self.max_gap_s)} diagnosed at most: "
                f"{_t(a)} to {_t(self.first or b)} is not diagnosed (replay it with "
                f"`diag diagnose UNIT --from {a:%Y-%m-%dT%H:%M:%S} --to ...`); the units start "
                f"fresh and warmed up on the historian's last {self.rows} samples "
                f"({_t(self.first)} to {_t(self.last)}) ({cpu})"
            )
        if self.mode == "replayed" and self.first is not None and self.first - a >= p:
            out.append(
                f"catch-up: the historian holds no samples from {_t(a)} to "
                f"{_t(self.first - p)}: the units jumped "
                "over it"
            )
        out.extend(self._holes("catch-up"))
        if self.timed_out:
            short = [
                f"{u} to {_t(t)}" for u, t in self.history_to.items() if t < self.last_sample_or(b)
            ]
            live = (
                f"the units go on from {_t(self.last or self.since)}"
                if self.mode == "replayed"
                else f"the warm-up has {self.rows} of {self.lead} samples"
            )
            out.append(
                "catch-up stopped at its time-out: "
                + (
                    f"{self.rows} of {self.total} missed cycles diagnosed; "
                    if self.mode == "replayed"
                    else ""
                )
                + (f"history replayed only {', '.join(short)}; " if short else "")
                + f"{live}; the rest is not diagnosed (`diag diagnose UNIT --from ... --to ...`)"
            )
        lines: list[tuple[pd.Timestamp | None, str, dict[str, Any]]] = [(None, x, {}) for x in out]
        for e in self.episodes:
            lines.extend(_episode_lines(e))
        return lines

    def _holes(self, what: str) -> list[str]:
        """Tags without a sample, and the time after the last sample, in what was read."""
        a, b = self.gap_start, self.until
        out = []
        if self.no_samples:
            out.append(
                f"{what}: the historian holds no samples of {', '.join(self.no_samples)} "
                f"from {_t(a)} to {_t(b)} (the tests reading them were unknown)"
            )
        p = pd.Timedelta(seconds=self.period_s)
        if self.last_sample is not None and self.last_sample < b - p:
            out.append(
                f"{what}: the historian holds no samples after {_t(self.last_sample)} "
                f"(to {_t(b)}): the units jumped over it"
            )
        return out

    def _fresh_lines(self) -> list[str]:
        """A fresh start's warm-up (:func:`warm_up`), said."""
        head = "warm-up: no state to go on from"
        out = []
        if self.not_stored:
            out.append(f"warm-up: tags {', '.join(self.not_stored)} are not in the historian")
        if self.timed_out:
            out.append(
                f"{head}; the warm-up on the historian's last lead-in ({self.lead} samples) "
                f"stopped at its time-out after {self.rows}: the units start cold (warming "
                f"up live) ({self.cpu_s:.2f} s CPU)"
            )
            return out
        if not self.rows:
            out.append(
                f"{head}, and the historian holds no samples of the units' tags from "
                f"{_t(self.gap_start)} to {_t(self.until)} (their lead-in, {self.lead} samples, "
                "before now): the units start cold (warming up live)"
            )
            return out
        short = f" of the lead-in's {self.lead}" if self.rows < self.lead else ""
        out.append(
            f"{head}: the units warmed up on the historian's last {self.rows}{short} samples "
            f"({_t(self.first)} to {_t(self.last)}) before the first cycle, their lags, "
            f"filters, delays and holds where a running plug-in's would be "
            f"({self.cpu_s:.2f} s CPU)"
        )
        return out + self._holes("warm-up")

    def last_sample_or(self, b: pd.Timestamp) -> pd.Timestamp:
        return self.last_sample if self.last_sample is not None else b


def catch_up(
    plant: Any,
    url: str,
    until: pd.Timestamp,
    period_s: float,
    *,
    deadline: float = math.inf,
    max_gap_s: float = MAX_GAP_S,
    chunk_rows: int = CHUNK_ROWS,
    gate: Gate | None = None,
) -> CatchUp | None:
    """Diagnose what the historian at ``url`` holds between the plant's last cycle
    (``plant.last_ts``, the restored state's) and ``until``, the live plant on a grid of
    ``period_s`` (the live loop's cycle); module doc. None when the plant has no last cycle
    (nothing restored). ``gate``: the live loop's (:class:`Gate`)."""
    from historian.sampling import snap_near
    from historian.times import to_us

    since = plant.last_ts
    if since is None:
        return None
    cpu0 = time.process_time()
    until = pd.Timestamp(until)
    p = pd.Timedelta(seconds=float(period_s))
    res = CatchUp(since, until, float(period_s), max_gap_s=float(max_gap_s))
    start = next_row(since, p)
    end = snap_near(to_us(until), _us(p))  # the row a sample stamped ``until`` goes into
    if end < to_us(start):
        return res
    res.total = int((end - to_us(start)) // _us(p)) + 1
    res.lead = _plant_lead_in(plant)
    gate = gate or Gate()
    tags = list(plant.tags)
    h = _open(url, deadline)
    try:
        read = _stored(h, tags, res)
        gap_s = (until - since).total_seconds()
        if res.total <= res.lead:
            res.mode = "replayed"
            _feed(plant, h, read, start, until, p, deadline, res, chunk_rows, gate, track=True)
        else:
            res.mode = "history" if gap_s <= max_gap_s else "warm-up"
            lo = max(start, until - (res.lead - 1) * p)
            _feed(plant, h, read, lo, until, p, deadline, res, chunk_rows, gate, track=False)
            if res.mode == "history":
                _history(plant, h, start, until, deadline, res, chunk_rows)
    finally:
        h.close()
    if res.first is None and not res.history_rows and not res.timed_out:
        res.mode = "empty"  # the plant was left as restored
    res.episodes.sort(key=lambda e: (e.start, e.unit))
    res.cpu_s = time.process_time() - cpu0
    return res


def warm_up(
    plant: Any,
    url: str,
    until: pd.Timestamp,
    period_s: float,
    *,
    deadline: float = math.inf,
    chunk_rows: int = CHUNK_ROWS,
    gate: Gate | None = None,
) -> CatchUp:
    """A fresh start (no state restored): the plant warmed up on the historian's samples of
    its lead-in before ``until`` (the units' longest :func:`~diag_plugin.diagnose.leadin.
    lead_in`, one :meth:`Plant.cycle` per row on the live loop's grid of ``period_s``, as
    :func:`catch_up` warms up after a long gap), so the first cycle goes on from the state a
    plug-in running all along would have. Cut by ``deadline``, or nothing stored in the
    window: the plant is left cold (reset), and :meth:`CatchUp.lines` says so."""
    cpu0 = time.process_time()
    until = pd.Timestamp(until)
    p = pd.Timedelta(seconds=float(period_s))
    res = CatchUp(None, until, float(period_s), mode="fresh")
    res.lead = _plant_lead_in(plant)
    res.window_from = until - (res.lead - 1) * p
    gate = gate or Gate()
    tags = list(plant.tags)
    h = _open(url, deadline)
    try:
        read = _stored(h, tags, res)
        _feed(
            plant, h, read, res.window_from, until, p, deadline, res, chunk_rows, gate, track=False
        )
    finally:
        h.close()
    if res.timed_out:
        with gate.lock:
            if not gate.closed:
                plant.reset()  # a part of a lead-in, then a jump to now: start cold instead
    res.cpu_s = time.process_time() - cpu0
    return res


def _open(url: str, deadline: float) -> Any:
    """The historian, each statement bounded by the time left (at least 1 s: a read started
    just before the deadline may finish) — never a read hanging on a locked database."""
    from historian.store import Historian

    left = deadline - time.monotonic()
    return Historian.open(url, timeout=None if math.isinf(left) else max(1.0, left))


def _stored(h: Any, tags: list[str], res: CatchUp) -> list[str]:
    """The ``tags`` the historian knows (the others noted in ``res``), none seen yet."""
    known = set(h.tags()["name"])
    res.not_stored = [t for t in tags if t not in known]
    res.seen = dict.fromkeys(tags, False)
    return [t for t in tags if t in known]


def _plant_lead_in(plant: Any) -> int:
    """Rows the live plant reads to warm up: the units' longest lead-in, plus the row at
    its start."""
    return max((_lead_in(u) for u in plant.units.values()), default=0) + 1


def _feed(
    plant: Any,
    h: Any,
    read: list[str],
    lo: pd.Timestamp,
    until: pd.Timestamp,
    p: pd.Timedelta,
    deadline: float,
    res: CatchUp,
    chunk_rows: int,
    gate: Gate,
    *,
    track: bool,
) -> None:
    """The live plant through the historian's rows ``lo``..``until`` from the first to the
    last one holding a sample (before and after them the plant jumps, as a bare restart;
    rows without a sample between them go through as missing values, as the live loop's Bad
    samples do), one :meth:`Plant.cycle` each, each under the ``gate``; episodes tracked
    when ``track``."""
    if not read:
        return
    on: dict[str, bool] = {}
    open_: dict[str, Episode] = {}
    nan = dict.fromkeys(read, math.nan)
    empty: list[pd.Timestamp] = []  # rows without a sample since the last one fed

    def cycle(ts: pd.Timestamp, row: dict[str, float]) -> bool:
        with gate.lock:
            if gate.closed or time.monotonic() > deadline:
                res.timed_out = True
                return False
            statuses = plant.cycle(ts, row)
            gate.fed += 1
        res.rows += 1
        res.last = ts
        if track:
            for s in statuses:
                _step(s.unit, int(s.status), s.faults, s.tags, int(s.quality), ts, on, open_, res)
        return True

    # rows up to the one a sample stamped ``until`` goes into (not the next: its samples are
    # later than ``until``)
    frames = h.iter_windows(read, lo, next_row(until, p), p, chunk=chunk_rows * p, summary=False)
    for frame in frames:
        vals = frame.to_numpy(np.float64)
        has = np.isfinite(vals)
        _seen(res, read, has, frame.index)
        any_row = has.any(axis=1)
        for i in range(len(frame)):
            ts = frame.index[i]
            if not any_row[i]:
                if res.first is not None:
                    empty.append(ts)
                continue
            if res.first is None:  # before the first sample the plant jumps
                res.first = ts
                if not track:  # the warm-up: fresh units, once there is something to warm on
                    with gate.lock:
                        if gate.closed:
                            res.timed_out = True
                            return
                        plant.reset()
            for t in empty:
                if not cycle(t, nan):
                    return
            empty.clear()
            if not cycle(ts, dict(zip(read, vals[i].tolist(), strict=True))):
                return


def _history(
    plant: Any,
    h: Any,
    start: pd.Timestamp,
    until: pd.Timestamp,
    deadline: float,
    res: CatchUp,
    chunk_rows: int,
) -> None:
    """Each unit's alarm episodes in the gap by the replay's path (``diag diagnose UNIT
    --from start --to until``: the lead-in before ``start``, the unit's own period,
    :meth:`Unit.evaluate` chunk by chunk), on a copy of the unit started fresh."""
    from diag_plugin.diagnose.leadin import lead_in, since

    known = set(h.tags()["name"])
    for name, live_unit in plant.units.items():
        if time.monotonic() > deadline:
            res.timed_out = True
            res.history_to.setdefault(name, start)
            continue
        if any(t not in known for t in live_unit.tags):
            continue  # reported as not in the historian
        unit = copy.deepcopy(live_unit).reset()
        period = pd.Timedelta(unit.period)
        a, _ = h.time_range(unit.tags)
        if a is None:
            continue
        t0 = min(start, max(a, start - lead_in(unit) * period))
        on: dict[str, bool] = {}
        open_: dict[str, Episode] = {}
        res.history_to[name] = start
        for frame in h.iter_windows(
            unit.tags, t0, next_row(until, period), period, chunk=chunk_rows * period, summary=False
        ):
            if time.monotonic() > deadline:
                res.timed_out = True
                break
            frame.attrs = {}
            d = unit.evaluate(frame)
            gap = frame.index >= start
            _seen(res, unit.tags, np.isfinite(frame.to_numpy(np.float64))[gap], frame.index[gap])
            d = since(d, start)
            if not len(d.status):
                continue
            res.history_rows += len(d.status)
            res.history_to[name] = d.status.index[-1]
            tops = _top_tags(d)
            for j, (ts, code, q, fl) in enumerate(
                zip(
                    d.status.index,
                    d.status.to_numpy(),
                    d.quality.to_numpy(),
                    d.faults.tolist(),
                    strict=True,
                )
            ):
                faults = [f for f in str(fl or "").replace("|", ",").split(",") if f]
                _step(name, int(code), faults, tops[j], int(q), ts, on, open_, res)


def _top_tags(d: Any) -> list[list[tuple[str, float]]]:
    n = len(d.status)
    if d.top is None or "top1" not in d.top:
        return [[]] * n
    cols = [c for c in ("top1", "top2", "top3") if c in d.top]
    vals = d.top[cols].to_numpy(object)
    return [[(str(t), 0.0) for t in row if isinstance(t, str) and t] for row in vals]


def _seen(res: CatchUp, tags: list[str], has: np.ndarray, index: pd.Index) -> None:
    if not has.size:
        return
    for t, any_ in zip(tags, has.any(axis=0).tolist(), strict=True):
        if any_:
            res.seen[t] = True
    rows = np.flatnonzero(has.any(axis=1))
    if rows.size:
        last = index[rows[-1]]
        if res.last_sample is None or last > res.last_sample:
            res.last_sample = last


def _step(
    unit: str,
    code: int,
    faults: list[str],
    tags: list[tuple[str, float]],
    quality: int,
    ts: pd.Timestamp,
    on: dict[str, bool],
    open_: dict[str, Episode],
    res: CatchUp,
) -> None:
    """One unit's alarm condition over one sample; episodes as they start and end."""
    first = unit not in on
    now = on.get(unit, False) if code == CHECK_FUNCTION else code in ALARM_STATUSES
    on[unit] = now
    e = open_.get(unit)
    if now:
        if e is None:
            e = Episode(unit, ts, code, at_gap_start=first, quality=quality)
            open_[unit] = e
            res.episodes.append(e)
        e.faults.extend(f for f in faults if f not in e.faults)
        e.tags.extend(t for t, _ in tags if t not in e.tags)
    elif e is not None:
        e.end = ts
        del open_[unit]


def next_row(since: pd.Timestamp, p: pd.Timedelta) -> pd.Timestamp:
    """The historian's grid row (``k·p``, epoch-anchored; a sample belongs to its nearest
    point) after the one the cycle at ``since`` went into: where a catch-up starts. A live
    cycle is stamped with its poll's time, off the grid under load; ``since + p`` rounded up
    to the grid skipped the next cycle's row whenever the last one came late by less than
    half a period."""
    from historian.sampling import snap_near
    from historian.times import from_us, to_us

    return from_us(snap_near(to_us(since), _us(p)) + _us(p))


def _us(p: pd.Timedelta) -> int:
    return int(p // pd.Timedelta(1, "us"))


def _lead_in(unit: Any) -> int:
    from diag_plugin.diagnose.leadin import lead_in

    return int(lead_in(unit))


def _episode_lines(e: Episode) -> list[tuple[pd.Timestamp, str, dict[str, Any]]]:
    from diag_plugin.status import NE107

    name = NE107(e.status).name
    faults = f" faults {', '.join(e.faults)}" if e.faults else ""
    tags = f" (tags {', '.join(e.tags[:3])})" if e.tags else ""
    began = f"on at the gap's start {_t(e.start)}" if e.at_gap_start else f"from {_t(e.start)}"
    fields = {
        "unit": e.unit,
        "status": e.status,
        "quality": e.quality,
        "fault": ",".join(e.faults) or None,
    }
    head = f"{e.unit}: while diag run was down: alarm condition {name}{faults}{tags} {began}"
    if e.end is None:
        return [(e.start, f"{head}, still on at the end of the catch-up", fields)]
    dur = _span((e.end - e.start).total_seconds())
    return [
        (
            e.start,
            f"{head} to {_t(e.end)} ({dur}), caught up from the historian: over, not raised now",
            fields,
        ),
        (
            e.end,
            f"{e.unit}: while diag run was down: condition returned to normal at {_t(e.end)} "
            "(caught up)",
            {"unit": e.unit, "status": 0, "quality": 0, "fault": None},
        ),
    ]


def _t(ts: pd.Timestamp | None) -> str:
    return "-" if ts is None else f"{ts:%Y-%m-%d %H:%M:%S}"


def _span(s: float) -> str:
    if s < 120:
        return f"{s:.0f} s"
    if s < 7200:
        return f"{s / 60:.0f} min"
    if s < 172_800:
        return f"{s / 3600:.1f} h"
    return f"{s / 86400:.1f} d"
