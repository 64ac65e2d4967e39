"""The live loop: poll the plant, store, diagnose, publish, once per cycle.

Each cycle :class:`LiveLoop`

1. lets an optional ``feed(i)`` hook run (the embedded default puts the next simulated row
   on its Modbus PLC there and returns the row's simulated time stamp);
2. polls every source (:class:`connectors.sources.SourceSet`) concurrently, waiting for them
   only until the poll deadline (:meth:`LiveLoop.poll_deadline`): a slow source is Bad for
   the cycle, never holding it or the other sources; a Good value that is not a
   finite number (NaN, ±Inf) turns Bad, a frozen one turns Uncertain
   (:class:`~diag_plugin.live.stale.StaleDetector`);
3. hands the samples to the historian writer (:class:`~diag_plugin.live.writer.
   HistorianWriter`): queued, never awaited — a locked or absent database delays storage,
   never the cycle;
4. evaluates every unit (:meth:`diag_plugin.diagnose.plant.Plant.cycle`) on the Good samples
   only; a unit still filling its history is CHECK_FUNCTION/Uncertain "initialising", and a
   CHECK_FUNCTION gets a message naming its unknown tests and the tags behind them;
5. publishes each :class:`UnitStatus` to the OPC UA server (which drives the unit's
   ISA-18.2 alarm; without one the loop drives the alarm itself, alike) and to the Modbus
   status server (``U.alarm`` = :data:`ALARM_CODES`); acknowledgements written to a unit's
   Modbus ``U.ack`` coil acknowledge that alarm;
6. reports events — alarm transitions, operator actions with their user (OPC UA and Modbus
   alike), sources going and coming back, frozen sources, the historian degraded and whole
   again — as lines and in the historian's event log; the plug-in's own conditions (a source
   out, the historian away) are OPC UA notices in the maintenance band.

SIGINT and SIGTERM stop the loop after the current cycle; the writer stores what is left
(or spills it) and :meth:`LiveLoop.run` returns 0. On a terminal a ``rich`` live table shows
the units; otherwise only the event lines are printed.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import math
import signal
import sys
import time
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from connectors.alarms import Alarm, AlarmState, condition
from connectors.base import TagQuality
from diag_plugin.live.stale import StaleDetector
from diag_plugin.status import NE107, Quality, UnitStatus

if TYPE_CHECKING:
    from connectors.opcua_server import Action
    from connectors.sources import SourceSet, Transition
    from diag_plugin.live.catchup import CatchUp, CatchUpPlan
    from diag_plugin.live.writer import HistorianWriter

#: the number published in the Modbus ``U.alarm`` register for each alarm state
ALARM_CODES: dict[AlarmState, int] = {
    AlarmState.NORMAL: 0,
    AlarmState.ACTIVE_UNACK: 1,
    AlarmState.ACTIVE_ACK: 2,
    AlarmState.RTN_UNACK: 3,
    AlarmState.SHELVED: 4,
}
_PAST = {
    "acknowledge": "acknowledged",
    "confirm": "confirmed",
    "comment": "commented",
    "shelve": "shelved",
    "unshelve": "unshelved",
}


#: cycle times kept for the summary's percentiles (a day at 1 s), and event lines and source
#: gaps kept in memory (all of them go to the event log): a run of months holds no more
KEEP_CYCLES = 86_400
KEEP_EVENTS = 1_000


@dataclass
class UnitView:
    """What the live table shows for one unit."""

    status: UnitStatus
    alarm: AlarmState = AlarmState.NORMAL


@dataclass
class LiveStats:
    cycles: int = 0
    overruns: int = 0
    last_ms: float = 0.0
    #: per cycle: poll, store, diagnose, publish; the last :data:`KEEP_CYCLES` (a day at 1 s)
    work_ms: deque[float] = field(default_factory=lambda: deque(maxlen=KEEP_CYCLES))
    units: dict[str, UnitView] = field(default_factory=dict)
    events: deque[str] = field(default_factory=lambda: deque(maxlen=KEEP_EVENTS))
    #: source outages seen by the loop: (source, from, to), wall-clock UTC
    gaps: deque[tuple[str, Any, Any]] = field(default_factory=lambda: deque(maxlen=KEEP_EVENTS))
    stale: int = 0  #: stale samples seen
    not_finite: int = 0  #: Good samples that were NaN or ±Inf (made Bad)


class LiveLoop:
    """One live loop (module doc). ``source``: a :class:`connectors.sources.SourceSet`;
    ``opcua`` and ``status_server`` must be started by the caller; ``historian``: a started
    :class:`~diag_plugin.live.writer.HistorianWriter` (or None), closed by :meth:`run`.

    ``stale``: a fitted :class:`~diag_plugin.live.stale.StaleDetector` over the source's tags
    (default: limits learned live). ``feed(i)``: optional async hook run before the poll of
    cycle ``i``; it may return the time stamp of the sample (default: the poll's wall time).
    ``after(loop, i, statuses)``: optional async hook run after publishing (the embedded
    scenario's operator). ``duration`` in seconds from the first cycle (0: until a signal or
    :meth:`stop`).
    ``out``: event lines go there when not on a terminal; ``tty`` forces the live table.
    ``state``: where the plant's state is saved (:mod:`~diag_plugin.live.state`) every
    ``state_every`` cycles and on stop (None: not saved). ``catch_up``: with a restored
    state, the cycles missed while the plug-in was down are diagnosed from the historian
    before the first cycle, within the plan's time-out; without one, the units warm up on
    the historian's last lead-in instead of starting cold (:mod:`~diag_plugin.live.catchup`).
    """

    def __init__(
        self,
        plant: Any,
        source: SourceSet,
        *,
        historian: HistorianWriter | None = None,
        opcua: Any = None,
        status_server: Any = None,
        cycle: float = 1.0,
        duration: float = 0.0,
        stale: StaleDetector | None = None,
        stale_history: asyncio.Future[Any] | None = None,
        feed: Callable[[int], Awaitable[pd.Timestamp | None]] | None = None,
        after: Callable[[LiveLoop, int, list[UnitStatus]], Awaitable[None]] | None = None,
        tty: bool | None = None,
        out: Any = None,
        state: Path | None = None,
        state_every: int = 60,
        catch_up: CatchUpPlan | None = None,
    ) -> None:
        self.plant, self.source = plant, source
        self.catch_up = catch_up
        #: what the catch-up before the first cycle did (None: none ran)
        self.caught_up: CatchUp | None = None
        self.state_path, self.state_every = state, int(state_every)
        self._state_task: asyncio.Task[None] | None = None
        self.historian, self.opcua, self.status_server = historian, opcua, status_server
        self.cycle_s = float(cycle)
        self.duration = float(duration)
        self.feed, self.after = feed, after
        self.out = out or sys.stdout
        self.tty = self.out.isatty() if tty is None else tty
        self.stats = LiveStats()
        self._stop = asyncio.Event()
        self._live: Any = None
        self._tags = list(source.names)
        self._index = {t: i for i, t in enumerate(self._tags)}
        self.stale = stale or StaleDetector(self._tags)
        self._stale_history = stale_history
        self._bad_nodes: dict[str, dict[str, str]] = {}
        self._ts = pd.Timestamp.now(tz="UTC")
        self._frozen: set[str] = set()
        self._cycle_i = 0
        self._warmup = int(getattr(plant, "depth", 0)) + 1
        self._diagnosed: set[str] = set()
        self._test_tags = _test_tags(plant)
        self._quality = np.zeros(len(self._tags), np.uint8)
        self._reasons: list[str] = [""] * len(self._tags)
        self._stale_mask = np.zeros(len(self._tags), bool)
        self._late: np.ndarray | None = None
        self._age = np.zeros(len(self._tags))
        self._notify_tasks: set[asyncio.Task[None]] = set()
        #: each unit's ISA-18.2 alarm where no OPC UA server keeps it (a Modbus-only SCADA:
        #: ``U.alarm``, the ack coil and the alarm event lines still follow it)
        self._alarms: dict[str, Alarm] = {}
        #: the last 60 cycles' work besides polling (store, diagnose, publish), seconds
        self._other_s: deque[float] = deque(maxlen=60)
        self._poll_s = 0.0
        if opcua is not None:
            opcua.on_action = self.on_action
        if historian is not None:
            historian.notify = self._historian_state
            # a restart gap, a crashed run's journal recovered, a damaged spill file
            historian.on_note = lambda text: self.event(text, self._ts)

    def poll_deadline(self) -> float | None:
        """Seconds a cycle waits for its sources: the cycle less twice the median other work
        (store, diagnose, publish) of the last 60 cycles, within 50-90 % of the cycle. A
        source slower than that is Bad for the cycle and keeps polling in the background
        (:meth:`SourceSet.poll`). None (wait for every source, each within its own timeout)
        in the first cycle, whose polls open the connections."""
        if not self._other_s:
            return None
        budget = self.cycle_s - 2.0 * float(np.median(self._other_s))
        return min(0.9 * self.cycle_s, max(0.5 * self.cycle_s, budget))

    @property
    def late(self) -> np.ndarray | None:
        """Per tag, whether the last cycle's poll of its source was late (no answer within
        the cycle's poll deadline or the source's own timeout): the tag was not read that
        cycle. None before the first cycle, or from a source that does not say."""
        return self._late

    # ------------------------------------------------------------------ control
    def stop(self) -> None:
        self._stop.set()

    def event(
        self, text: str, ts: pd.Timestamp | None = None, unit: str | None = None, **fields: Any
    ) -> None:
        """Report one event line (above the live table, or on ``out``) and store it in the
        historian's event log under ``unit`` (default: the plug-in, ``diag run``)."""
        stamp = f"{ts:%Y-%m-%d %H:%M:%S} " if ts is not None else ""
        line = f"{stamp}{text}"
        self.stats.events.append(line)
        if self._live is not None:
            self._live.console.print(line)
        else:
            print(line, file=self.out, flush=True)
        if self.historian is not None:
            self.historian.put_event(
                ts if ts is not None else self._ts, unit or "diag run", text, **fields
            )

    def on_action(self, a: Action) -> None:
        """An operator action on the OPC UA server (or its refusal): one event line, stored."""
        if a.action == "refused":
            self.event(f"OPC UA: {a.user} refused: {a.detail} (operators only)", self._ts)
            return
        if a.action == "login":  # a refused login, or a run of identical ones merged
            self.event(a.detail, self._ts)
            return
        verb = _PAST.get(a.action, a.action)
        via = "" if a.via == "local" else f" over {a.via}"
        if a.ok:
            detail = f" ({a.detail})" if a.detail else ""
            text = f"{a.unit}: alarm {verb} by {a.user}{via}{detail}"
        else:
            text = f"{a.unit}: {a.action} by {a.user}{via} refused: {a.detail}"
        self.event(text, self._ts, a.unit)
        view = self.stats.units.get(a.unit or "")
        if view is not None:
            view.alarm = self._alarm(a.unit or "")

    async def acknowledge(self, unit: str, who: str = "operator", via: str = "local") -> None:
        """Acknowledge ``unit``'s alarm (the OPC UA server's alarm, else the loop's own;
        published at once)."""
        if self.opcua is None:
            alarm = self._alarms.get(unit)
            if alarm is None:
                return
            t = alarm.acknowledge()
            over = "" if via == "local" else f" over {via}"
            if t.changed:
                text = f"{unit}: alarm acknowledged by {who}{over} ({t.before} -> {t.after})"
            else:
                text = f"{unit}: acknowledge by {who}{over}: nothing to acknowledge ({t.before})"
            self.event(text, self._ts, unit)
            view = self.stats.units.get(unit)
            if view is not None:
                view.alarm = alarm.state
        elif unit in self.opcua.alarms:
            await self.opcua.acknowledge(unit, who=who, via=via)
        else:
            return
        await self._publish_alarm(unit)

    def _alarm_of(self, unit: str) -> Alarm | None:
        return self._alarms.get(unit) if self.opcua is None else self.opcua.alarms.get(unit)

    def _alarm(self, unit: str) -> AlarmState:
        alarm = self._alarm_of(unit)
        return AlarmState.NORMAL if alarm is None else alarm.state

    def _drive_alarm(self, s: UnitStatus) -> None:
        """The unit's alarm without an OPC UA server, driven as that server drives its own
        (:meth:`connectors.opcua_server.OpcUaServer.publish`): on in FAILURE, OFF_SPEC and
        MAINTENANCE_REQUIRED, held through CHECK_FUNCTION (the diagnosis cannot be trusted)."""
        alarm = self._alarms.setdefault(s.unit, Alarm(s.unit))
        top = max((v for v in s.certainties.values() if math.isfinite(v)), default=0.0)
        on, sev = condition(s.status, top, alarm.condition, alarm.severity)
        alarm.update(on, sev, now=datetime.now(UTC))

    async def _publish_alarm(self, unit: str) -> None:
        view = self.stats.units.get(unit)
        if self.status_server is not None and view is not None:
            await self.status_server.publish(view.status, alarm=ALARM_CODES[self._alarm(unit)])

    def _historian_state(self, degraded: bool, text: str) -> None:
        """The writer degraded or whole again: an event line and the OPC UA notice."""
        self.event(text, self._ts)
        self._notice("Historian", degraded, text)

    def _notice(self, name: str, active: bool, text: str) -> None:
        if self.opcua is None:
            return
        task = asyncio.get_running_loop().create_task(self.opcua.notice(name, active, text))
        self._notify_tasks.add(task)
        task.add_done_callback(self._notify_tasks.discard)

    # ------------------------------------------------------------------ one cycle
    async def step(self, i: int) -> list[UnitStatus]:
        ts = await self.feed(i) if self.feed is not None else None
        t_poll = time.monotonic()
        poll = await self.source.poll(deadline=self.poll_deadline())
        self._poll_s = time.monotonic() - t_poll
        if ts is None:
            ts = pd.Timestamp(poll.ts)
        if ts.tzinfo is None:
            ts = ts.tz_localize("UTC")
        self._ts = ts
        self._cycle_i = i
        self._learn_stale_limits()
        values, quality = poll.values, poll.quality.copy()
        good = quality == TagQuality.GOOD
        absurd = good & ~np.isfinite(values)
        if absurd.any():  # NaN, +Inf, -Inf read as Good: Bad
            quality[absurd] = TagQuality.BAD
            self.stats.not_finite += int(absurd.sum())
        stale, self._age = self.stale.update(
            ts.value / 1e9, values, quality, poll.source_ts, poll.late
        )
        if stale.any():
            quality[stale] = TagQuality.UNCERTAIN
            self.stats.stale += int(stale.sum())
        self._quality, self._reasons, self._stale_mask = quality, poll.reasons, stale
        self._late = poll.late
        if self.historian is not None:
            self.historian.put(ts, values, quality)
        for t in self.source.transitions(poll.ts):
            self._source_event(t, ts)
        self._node_problems(ts)
        self._frozen_sources(stale, quality, ts)
        # only Good samples reach the diagnosis: Bad or Uncertain ones make the tests that
        # read them unknown (CHECK_FUNCTION), never a symptom
        diag_values = np.where(quality == TagQuality.GOOD, values, np.nan)
        values_by_tag = dict(zip(self._tags, diag_values.tolist(), strict=True))
        statuses = [self._explain(s) for s in self.plant.cycle(ts, values_by_tag)]
        if self.status_server is not None:
            while not self.status_server.acks.empty():
                unit = self.status_server.acks.get_nowait()
                client = getattr(unit, "client", "")  # ip:port of the writer, for the audit
                who = f"Modbus client {client}" if client else "Modbus client"
                await self.acknowledge(str(unit), who, "Modbus")
        modbus = []
        for s in statuses:
            before = self._alarm(s.unit)
            if self.opcua is not None:
                await self.opcua.publish(s)
            else:
                self._drive_alarm(s)
            after = self._alarm(s.unit)
            prev = self.stats.units.get(s.unit)
            self.stats.units[s.unit] = UnitView(s, after)
            modbus.append((s, {"alarm": ALARM_CODES[after]}))
            if after is not before:
                self._alarm_event(s, before, after)
            elif prev is not None and s.faults and s.faults != prev.status.faults:
                # the isolation narrowed or moved while the alarm stands: say so once
                was = ", ".join(prev.status.faults) or "none"
                self.event(f"{s.unit}: isolated {', '.join(s.faults)} (was {was})", s.ts, s.unit)
        if self.status_server is not None:
            await self.status_server.publish_many(modbus)
        if self.historian is not None and self.opcua is not None:
            await self.opcua.set_plugin_value("Historian", "Backlog", self.historian.backlog)
        if self.after is not None:
            await self.after(self, i, statuses)
        return statuses

    def _explain(self, s: UnitStatus) -> UnitStatus:
        """Initialising before the first diagnosis; a CHECK_FUNCTION names its unknown tests
        and the tags behind them."""
        known = any(math.isfinite(v) for v in s.symptoms.values())
        if known:
            self._diagnosed.add(s.unit)
        if s.status != NE107.CHECK_FUNCTION:
            return s
        tests = self._test_tags.get(s.unit, {})
        unknown = [t for t, v in s.symptoms.items() if not math.isfinite(v)]
        why = {t: self._tag_problems(tests.get(t, [])) for t in unknown}
        if s.message and not any(why.values()):  # the unit's own reason says it all
            return s
        if not s.message and s.unit not in self._diagnosed and self._cycle_i < self._warmup:
            if not any(why.values()):
                msg = f"initialising: {self._cycle_i + 1} of {self._warmup} samples of history"
                return replace(s, quality=Quality.UNCERTAIN, message=msg)
        parts = []
        for t in unknown:
            if why[t]:
                parts.append(f"{t} ({'; '.join(why[t])})")
            else:
                parts.append(f"{t} (inputs Good: outside the trained region or history too short)")
        # the tags' own problems (stale, Bad) first, then the unit's reason (an input outside
        # what it learned, inputs without a value)
        msg = "; ".join(
            m for m in (f"unknown tests: {', '.join(parts)}" if parts else "", s.message) if m
        )
        return replace(s, message=msg)

    def _tag_problems(self, tags: list[str]) -> list[str]:
        out = []
        for tag in tags:
            i = self._index.get(tag)
            if i is None:
                out.append(f"{tag} not read by any source")
            elif self._quality[i] == TagQuality.BAD:
                why = self._reasons[i] or "not a finite number"
                out.append(f"{tag} Bad: {why}"[:160])
            elif self._stale_mask[i]:
                out.append(f"{tag} stale: unchanged for {self._age[i]:.0f} s")
            elif self._quality[i] == TagQuality.UNCERTAIN:
                out.append(f"{tag} Uncertain: {self._reasons[i]}"[:160])
        return out

    def _learn_stale_limits(self) -> None:
        """Apply the stale limits learned from the history once they have been read."""
        f = self._stale_history
        if f is None or not f.done():
            return
        self._stale_history = None
        try:
            runs = f.result()
        except Exception as exc:  # noqa: BLE001 - the history is a help, not a need
            self.event(f"stale limits: history not readable ({exc!r}); learned live instead")
            return
        self.stale.fit(runs)
        if self.stale.stale_after is not None:
            self.event(f"stale after {self.stale.stale_after:g} s unchanged (plant.toml)")
            return
        lim = self.stale.limit_
        finite = lim[np.isfinite(lim)]
        learned = (
            f"from the history of {len(runs)} tags: median {np.median(finite):.0f} s, "
            f"{int(np.isinf(lim).sum())} never-changing tags never stale; "
            if len(finite)
            else "no history yet; "
        )
        self.event(
            f"stale limits {learned}{int(np.isnan(lim).sum())} tags judged once seen "
            f"changing, after {self.stale.fallback:.0f} s unchanged"
        )

    def _node_problems(self, ts: pd.Timestamp) -> None:
        """Node ids an OPC UA source cannot use: one line each, when first seen."""
        bad = self.source.bad_nodes()
        for src, tags in bad.items():
            seen = self._bad_nodes.get(src, {})
            for tag, why in tags.items():
                if seen.get(tag) != why:
                    self.event(f"source {src}: tag {tag}: {why}", ts, f"source {src}")
        self._bad_nodes = bad

    def _frozen_sources(self, stale: np.ndarray, quality: np.ndarray, ts: pd.Timestamp) -> None:
        """A source whose judged tags are all frozen: reported once, and once when it moves.
        A cycle that reads none of its judged tags (all Bad: its poll late on a loaded
        machine, or failed) says nothing either way: a frozen source stays frozen until a
        cycle reads it moving (a late poll in a frozen stretch reported it "moving again",
        then "frozen" once more, under load: issue 34)."""
        judged = self.stale.judged
        for name, sl in self.source.slices():
            j = judged[sl] & (quality[sl] != TagQuality.BAD)
            if not j.any() and name in self._frozen:
                continue
            frozen = bool(j.any()) and bool(stale[sl][j].all())
            if frozen and name not in self._frozen:
                self._frozen.add(name)
                age = float(np.nanmin(self._age[sl][j]))
                text = (
                    f"source {name}: all {int(j.sum())} tags frozen (unchanged for "
                    f"{age:.0f} s or more): stale, stored Uncertain"
                )
                self.event(text, ts, f"source {name}")
                self._notice(f"Source_{name}", True, text)
            elif not frozen and name in self._frozen:
                self._frozen.discard(name)
                text = f"source {name}: values moving again"
                self.event(text, ts, f"source {name}")
                self._notice(f"Source_{name}", False, text)

    def _source_event(self, t: Transition, ts: pd.Timestamp) -> None:
        """A source went down or came back: one event line, the gap kept in the stats, and a
        maintenance-band notice that returns to normal by itself."""
        if not t.up:
            text = f"source {t.source} unavailable, its tags Bad: {t.reason}"
            self.event(text, ts, f"source {t.source}")
            self._notice(f"Source_{t.source}", True, text)
            return
        gap = (t.until - t.since).total_seconds()
        self.stats.gaps.append((t.source, t.since, t.until))
        text = (
            f"source {t.source} back after {gap:.1f} s (gap {t.since:%H:%M:%S}-"
            f"{t.until:%H:%M:%S} UTC, stored as Bad samples)"
        )
        self.event(text, ts, f"source {t.source}")
        self._notice(f"Source_{t.source}", False, text)

    def _alarm_event(self, s: UnitStatus, before: AlarmState, after: AlarmState) -> None:
        if before is AlarmState.SHELVED:
            what = {
                AlarmState.ACTIVE_UNACK: "shelving over, alarm raised again",
                AlarmState.NORMAL: "shelving over, condition normal",
            }.get(after, f"shelving over ({after})")
        else:
            what = {
                AlarmState.ACTIVE_UNACK: "alarm raised",
                AlarmState.NORMAL: "alarm cleared",
                AlarmState.RTN_UNACK: "condition returned to normal (alarm not yet acknowledged)",
                AlarmState.ACTIVE_ACK: "alarm acknowledged",
                AlarmState.SHELVED: "alarm shelved",
            }[after]
        faults = f" faults {', '.join(s.faults)}" if s.faults else ""
        alarm = self._alarm_of(s.unit)
        sev = alarm.severity if alarm is not None else None
        self.event(
            f"{s.unit}: {what}: {s.status.name}{faults} ({before} -> {after})",
            s.ts,
            s.unit,
            status=int(s.status),
            severity=sev,
            quality=int(s.quality),
            fault=",".join(s.faults) or None,
        )

    # ------------------------------------------------------------------ the loop
    async def run(self) -> int:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            with contextlib.suppress(NotImplementedError, RuntimeError):
                loop.add_signal_handler(sig, self.stop)
        live_cm: Any = contextlib.nullcontext()
        if self.tty:
            from rich.console import Console
            from rich.live import Live

            live_cm = Live(
                self.table(), console=Console(file=self.out), refresh_per_second=4, transient=False
            )
        try:
            with live_cm as live:
                self._live = live
                if self.catch_up is not None:
                    await self._catch_up(self.catch_up)
                # the duration counts from the first cycle (after the catch-up)
                end = time.monotonic() + self.duration if self.duration > 0 else math.inf
                i = 0
                next_t = time.monotonic()
                while not self._stop.is_set() and time.monotonic() < end:
                    t0 = time.monotonic()
                    await self.step(i)
                    work = time.monotonic() - t0
                    self._other_s.append(max(0.0, work - self._poll_s))
                    self.stats.cycles = i + 1
                    self.stats.last_ms = work * 1000
                    self.stats.work_ms.append(work * 1000)
                    if work > self.cycle_s:
                        self.stats.overruns += 1
                    if live is not None:
                        live.update(self.table())
                    if self.state_every > 0 and (i + 1) % self.state_every == 0:
                        self._save_in_background()
                    i += 1
                    next_t += self.cycle_s
                    delay = next_t - time.monotonic()
                    if delay < 0:
                        next_t = time.monotonic()
                        delay = 0
                    with contextlib.suppress(TimeoutError):
                        await asyncio.wait_for(self._stop.wait(), min(delay, max(0, end - t0)))
        finally:
            self._live = None
            if self._state_task is not None:
                with contextlib.suppress(Exception):
                    await self._state_task
            self.save_state()
            if self.historian is not None:
                await self.historian.close()
            for sig in (signal.SIGINT, signal.SIGTERM):
                with contextlib.suppress(NotImplementedError, RuntimeError):
                    loop.remove_signal_handler(sig)
        self.event(self.summary())
        return 0

    async def _catch_up(self, plan: CatchUpPlan) -> None:
        """Before the first cycle, within ``plan.timeout`` seconds: the earlier run's spill
        stored first, then, with a restored state, the missed cycles diagnosed from the
        historian (:func:`~diag_plugin.live.catchup.catch_up`), or, without one, the units
        warmed up on its last lead-in (:func:`~diag_plugin.live.catchup.warm_up`); its lines
        and episodes reported. The work runs in a thread of its own the loop waits for no
        longer than the time-out: a historian that does not answer by then (slow, locked)
        leaves the units as they are (a fresh start cold), and says so."""
        from diag_plugin.live.catchup import Gate, catch_up, warm_up

        fresh = self.plant.last_ts is None
        what = "warm-up" if fresh else "catch-up"
        deadline = time.monotonic() + plan.timeout
        if self.historian is not None and not await self.historian.settle(deadline):
            self.event(
                f"{what}: the earlier run's samples in {self.historian.spool.folder} are "
                f"not stored yet after {plan.timeout:g} s: they are not in the {what}"
            )
        until = pd.Timestamp.now(tz="UTC")
        gate = Gate()
        job = warm_up if fresh else functools.partial(catch_up, max_gap_s=plan.max_gap_s)
        work = functools.partial(
            job, self.plant, plan.url, until, self.cycle_s, deadline=deadline, gate=gate
        )
        try:
            res = await _bounded_thread(work, deadline)
        except TimeoutError:
            gate.close()  # from here on the plant is the loop's alone
            why = (
                f"{gate.fed} samples fed when it came"
                if gate.fed
                else f"the historian did not answer within {plan.timeout:g} s (slow or locked)"
            )
            if fresh:
                self.plant.reset()
                self.event(
                    f"warm-up: no state to go on from; stopped at its time-out: {why}: the "
                    "units start cold (warming up live)"
                )
            else:  # the state restored, or as far as the catch-up got (a warm-up: reset)
                last = self.plant.last_ts
                where = f"their state of {last:%Y-%m-%d %H:%M:%S}" if last is not None else "cold"
                self.event(
                    f"catch-up stopped at its time-out: {why}; the units go on from {where}; "
                    "the rest is not diagnosed (`diag diagnose UNIT --from ... --to ...`)"
                )
            return
        except Exception as exc:  # noqa: BLE001 - the catch-up is a help, never a stop
            gate.close()
            if fresh:
                self.plant.reset()
            then = "the units start cold (warming up live)" if fresh else "the units go on"
            self.event(f"{what} failed ({type(exc).__name__}: {exc}); {then}")
            return
        self.caught_up = res
        if res is None:
            return
        for ts, text, fields in res.lines():
            unit = fields.pop("unit", None)
            self.event(text, ts, unit, **fields)
        if self.historian is not None and res.last_sample is not None:
            self.historian.samples_until(res.last_sample)

    def save_state(self) -> None:
        """Save the plant's state now (when a path is given); a failure is an event, never a
        stop of the loop."""
        if self.state_path is None or self.stats.cycles == 0:
            return
        from diag_plugin.live.state import save_state

        try:
            save_state(self.plant, self.state_path)
        except (OSError, ValueError, TypeError) as exc:
            self.event(f"state {self.state_path} not saved: {exc}", self._ts)

    def _save_in_background(self) -> None:
        """The periodic save: the snapshot taken between cycles, written (and fsynced) by a
        thread so the disk never holds up a cycle; skipped while the last one still writes."""
        if self.state_path is None or (self._state_task and not self._state_task.done()):
            return
        from diag_plugin.live.state import state_text, write_atomic

        path = self.state_path
        try:
            text = state_text(self.plant)
        except (ValueError, TypeError) as exc:
            self.event(f"state {path} not saved: {exc}", self._ts)
            return

        async def write() -> None:
            try:
                await asyncio.to_thread(write_atomic, text, path)
            except OSError as exc:
                self.event(f"state {path} not saved: {exc}", self._ts)

        self._state_task = asyncio.get_running_loop().create_task(write())

    def summary(self) -> str:
        """The closing line: cycles, overruns, cycle work percentiles, storage figures."""
        ms = np.sort(np.array(self.stats.work_ms)) if self.stats.work_ms else np.zeros(1)

        def pct(p: float) -> float:
            return float(ms[min(len(ms) - 1, int(math.ceil(p * len(ms))) - 1)])

        text = (
            f"stopped after {self.stats.cycles} cycles, {self.stats.overruns} overruns, "
            f"{self.stored} new samples stored; cycle work median {pct(0.5):.1f} ms, "
            f"p95 {pct(0.95):.1f} ms, p99 {pct(0.99):.1f} ms, max {ms[-1]:.1f} ms"
        )
        if self.stats.cycles > len(ms):
            text += f" (work figures of the last {len(ms)} cycles)"
        if self.historian is not None:
            w = self.historian.stats
            text += (
                f"; historian: {w.writes} writes (longest {w.max_write_s * 1000:.0f} ms), "
                f"{w.failures} failed, {w.spilled} samples spilled, {w.replayed} replayed, "
                f"{self.historian.backlog} waiting"
            )
        if self.stats.stale or self.stats.not_finite:
            text += f"; {self.stats.stale} stale and {self.stats.not_finite} non-finite samples"
        return text

    @property
    def stored(self) -> int:
        return self.historian.stats.stored if self.historian is not None else 0

    def table(self) -> Any:
        """The rich table of the units (one row each)."""
        from rich.table import Table

        st = self.stats
        backlog = f", historian backlog {self.historian.backlog}" if self.historian else ""
        t = Table(
            title=f"diag run: cycle {st.cycles}, {st.last_ms:.1f} ms, "
            f"{st.overruns} overruns, {self.stored} new samples stored{backlog}"
        )
        for col in (
            "unit",
            "NE 107",
            "quality",
            "faults",
            "top certainty",
            "residuals %",
            "alarm",
            "cycle ms",
            "overruns",
        ):
            t.add_column(col)
        for name, v in st.units.items():
            s = v.status
            top = max(
                ((f, c) for f, c in s.certainties.items() if math.isfinite(c)),
                key=lambda x: x[1],
                default=("", math.nan),
            )
            res = " ".join(
                f"{k}={r:+.1f}" if math.isfinite(r) else f"{k}=?" for k, r in s.residuals.items()
            )
            colour = "green" if s.status.name == "NORMAL" else "red"
            t.add_row(
                name,
                f"[{colour}]{s.status.name}[/]",
                s.quality.name,
                ", ".join(s.faults) or "-",
                f"{top[0]} {top[1]:.2f}" if top[0] else "-",
                res,
                str(v.alarm),
                f"{st.last_ms:.1f}",
                str(st.overruns),
            )
        return t


def _test_tags(plant: Any) -> dict[str, dict[str, list[str]]]:
    """Per unit, per test: the plant tags its model reads (the unit file's ``[tags]`` names)."""
    out: dict[str, dict[str, list[str]]] = {}
    for name, u in getattr(plant, "units", {}).items():
        out[name] = {
            t: [u.file.tags.get(x, x) for x in m.tags] for t, m in getattr(u, "models", {}).items()
        }
    return out


async def close_all(*parts: Any) -> None:
    """Close what a run opened, each on its own: sources and clients (``close()``), servers
    (``stop()``) and the historian (``close()``); ``None`` is skipped and one part's failure
    never keeps the others open."""
    for part in parts:
        if part is None:
            continue
        with contextlib.suppress(Exception):
            done = part.stop() if hasattr(part, "stop") else part.close()
            if asyncio.iscoroutine(done):
                await done


async def _bounded_thread(work: Callable[[], Any], deadline: float) -> Any:
    """``work()`` in a daemon thread of its own, awaited until ``deadline``
    (``time.monotonic()``) at most: TimeoutError then, the thread left to finish alone (not
    the event loop's default executor, which ``asyncio.run`` joins at its end: a read hanging
    on a locked database would hold up the plug-in's exit)."""
    import threading

    loop = asyncio.get_running_loop()
    done: asyncio.Future[Any] = loop.create_future()

    def settle(ok: bool, value: Any) -> None:
        if not done.done():
            (done.set_result if ok else done.set_exception)(value)

    def run() -> None:
        try:
            out: tuple[bool, Any] = (True, work())
        except BaseException as exc:  # noqa: BLE001 - handed to the awaiting loop
            out = (False, exc)
        with contextlib.suppress(RuntimeError):  # the event loop closed meanwhile
            loop.call_soon_threadsafe(settle, *out)

    threading.Thread(target=run, name="diag-catch-up", daemon=True).start()
    return await asyncio.wait_for(done, max(0.0, deadline - time.monotonic()))
