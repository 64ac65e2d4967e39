"""The live loop: poll the plant, store, diagnose, publish, once per cycle.

Each cycle :class:`LiveLoop`

1. lets an optional ``feed(i)`` hook run (the embedded default puts the next simulated row
   on its Modbus PLC there and returns the row's simulated time stamp);
2. polls the plant over Modbus (:class:`connectors.modbus.ModbusTagClient`); a tag with Bad
   quality reaches the diagnosis as NaN;
3. buffers the samples and writes them to the historian every ``flush_every`` cycles and on
   exit (idempotent; Bad samples are stored as NaN with their quality);
4. evaluates every unit (:meth:`diag_plugin.diagnose.plant.Plant.cycle`);
5. publishes each :class:`UnitStatus` to the OPC UA server (which drives the unit's
   ISA-18.2 alarm) and to the Modbus status server (``U.alarm`` = :data:`ALARM_CODES` of the
   alarm state); acknowledgements written to a unit's Modbus ``U.ack`` coil acknowledge the
   OPC UA alarm;
6. reports alarm transitions as events (raised / acknowledged / cleared) and counts cycle
   overruns (a cycle whose work took longer than the period).

SIGINT and SIGTERM stop the loop after the current cycle; the buffer is flushed and
:meth:`LiveLoop.run` returns 0. On a terminal a ``rich`` live table shows the units; otherwise
only the event lines are printed.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import signal
import sys
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from connectors.alarms import AlarmState
from connectors.base import TagQuality
from diag_plugin.diagnose.status import UnitStatus

if TYPE_CHECKING:
    from connectors.sources import SourceSet, Transition

#: the number published in the Modbus ``U.alarm`` register for each alarm state
ALARM_CODES: dict[AlarmState, int] = {
    AlarmState.NORMAL: 0,
    AlarmState.ACTIVE_UNACK: 1,
    AlarmState.ACTIVE_ACK: 2,
    AlarmState.RTN_UNACK: 3,
    AlarmState.SHELVED: 4,
}


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
    work_ms: list[float] = field(default_factory=list)  # per cycle: poll, store, diagnose, publish
    stored: int = 0
    units: dict[str, UnitView] = field(default_factory=dict)
    events: list[str] = field(default_factory=list)
    #: source outages seen by the loop: (source, from, to), wall-clock UTC
    gaps: list[tuple[str, Any, Any]] = field(default_factory=list)


class LiveLoop:
    """One live loop (module doc). ``source``: a :class:`connectors.sources.SourceSet` (its
    outage transitions become event lines); ``opcua`` and ``status_server`` must be started by
    the caller.

    ``feed(i)``: optional async hook run before the poll of cycle ``i``; it may return the
    time stamp of the sample (default: the poll's wall time). ``after(loop, i, statuses)``:
    optional async hook run after publishing (the embedded scenario's operator). ``duration``
    in seconds (0: until a signal or :meth:`stop`). ``out``: event lines go there when not on
    a terminal; ``tty`` forces the live table on or off.
    """

    def __init__(
        self,
        plant: Any,
        source: SourceSet,
        *,
        historian: Any = None,
        opcua: Any = None,
        status_server: Any = None,
        cycle: float = 1.0,
        flush_every: int = 20,
        duration: float = 0.0,
        feed: Callable[[int], Awaitable[pd.Timestamp | None]] | None = None,
        after: Callable[[LiveLoop, int, list[UnitStatus]], Awaitable[None]] | None = None,
        tty: bool | None = None,
        out: Any = None,
    ) -> None:
        self.plant, self.source = plant, source
        self.historian, self.opcua, self.status_server = historian, opcua, status_server
        self.cycle_s = float(cycle)
        self.flush_every = max(1, int(flush_every))
        self.duration = float(duration)
        self.feed, self.after = feed, after
        self.out = out or sys.stdout
        self.tty = self.out.isatty() if tty is None else tty
        self.stats = LiveStats()
        self._stop = asyncio.Event()
        self._buffer: list[pd.DataFrame] = []
        self._live: Any = None
        self._tags = list(source.names)

    # ------------------------------------------------------------------ control
    def stop(self) -> None:
        self._stop.set()

    def event(self, text: str, ts: pd.Timestamp | None = None) -> None:
        """Report one event line (above the live table, or on ``out``)."""
        stamp = f"{ts:%Y-%m-%d %H:%M:%S} " if ts is not None else ""
        line = f"{stamp}{text}"
        self.stats.events.append(line)
        if self._live is not None:
            self._live.console.print(line)
        else:
            print(line, file=self.out, flush=True)

    async def acknowledge(self, unit: str, who: str = "operator") -> None:
        """Acknowledge ``unit``'s alarm (the OPC UA server's alarm; published next cycle)."""
        if self.opcua is None:
            return
        before = self._alarm(unit)
        t = await self.opcua.acknowledge(unit)
        if t.changed:
            view = self.stats.units.get(unit)
            if view is not None:
                view.alarm = t.after
            ts = view.status.ts if view is not None else None
            self.event(f"{unit}: alarm acknowledged by {who} ({before} -> {t.after})", ts)
            await self._publish_alarm(unit)

    def _alarm(self, unit: str) -> AlarmState:
        if self.opcua is None or unit not in self.opcua.alarms:
            return AlarmState.NORMAL
        return self.opcua.alarms[unit].state

    async def _publish_alarm(self, unit: str) -> None:
        view = self.stats.units.get(unit)
        if self.status_server is not None and view is not None:
            await self.status_server.publish(view.status, alarm=ALARM_CODES[self._alarm(unit)])

    # ------------------------------------------------------------------ storage
    def _buffer_poll(self, ts: pd.Timestamp, values: np.ndarray, quality: np.ndarray) -> None:
        self._buffer.append(
            pd.DataFrame(
                {
                    "tag": self._tags,
                    "ts": [ts] * len(self._tags),
                    "value": values.astype(np.float64),
                    "quality": quality.astype(np.int64),
                }
            )
        )

    async def flush(self) -> int:
        """Write the buffered samples to the historian (in a worker thread)."""
        if self.historian is None or not self._buffer:
            self._buffer.clear()
            return 0
        frame = pd.concat(self._buffer, ignore_index=True)
        self._buffer.clear()
        n = await asyncio.to_thread(self.historian.write_samples, frame)
        self.stats.stored += n
        return n

    # ------------------------------------------------------------------ one cycle
    async def step(self, i: int) -> list[UnitStatus]:
        ts = await self.feed(i) if self.feed is not None else None
        poll = await self.source.poll()
        if ts is None:
            ts = pd.Timestamp(poll.ts)
        if ts.tzinfo is None:
            ts = ts.tz_localize("UTC")
        self._buffer_poll(ts, poll.values, poll.quality)
        if (i + 1) % self.flush_every == 0:
            await self.flush()
        for t in self.source.transitions(poll.ts):
            self._source_event(t, ts)
        # only Good samples reach the diagnosis: Bad or Uncertain ones make the tests that
        # read them unknown (CHECK_FUNCTION), never a symptom
        diag_values = np.where(poll.quality == TagQuality.GOOD, poll.values, np.nan)
        values = dict(zip(self._tags, diag_values.tolist(), strict=True))
        statuses = self.plant.cycle(ts, values)
        if self.status_server is not None:
            while not self.status_server.acks.empty():
                await self.acknowledge(self.status_server.acks.get_nowait(), "Modbus client")
        for s in statuses:
            before = self._alarm(s.unit)
            if self.opcua is not None:
                await self.opcua.publish(s)
            after = self._alarm(s.unit)
            prev = self.stats.units.get(s.unit)
            self.stats.units[s.unit] = UnitView(s, after)
            if self.status_server is not None:
                await self.status_server.publish(s, alarm=ALARM_CODES[after])
            if after is not before:
                self._alarm_event(s, before, after)
            elif prev is not None and s.faults and s.faults != prev.status.faults:
                # the isolation narrowed or moved while the alarm stands: say so once
                was = ", ".join(prev.status.faults) or "none"
                self.event(f"{s.unit}: isolated {', '.join(s.faults)} (was {was})", s.ts)
        if self.after is not None:
            await self.after(self, i, statuses)
        return statuses

    def _source_event(self, t: Transition, ts: pd.Timestamp) -> None:
        """A source went down or came back: one event line, the gap kept in the stats."""
        if not t.up:
            self.event(f"source {t.source} unavailable, its tags Bad: {t.reason}", ts)
            return
        gap = (t.until - t.since).total_seconds()
        self.stats.gaps.append((t.source, t.since, t.until))
        self.event(
            f"source {t.source} back after {gap:.1f} s (gap {t.since:%H:%M:%S}-"
            f"{t.until:%H:%M:%S} UTC, stored as Bad samples)",
            ts,
        )

    def _alarm_event(self, s: UnitStatus, before: AlarmState, after: AlarmState) -> None:
        what = {
            AlarmState.ACTIVE_UNACK: "alarm raised",
            AlarmState.NORMAL: "alarm cleared",
            AlarmState.RTN_UNACK: "condition returned to normal (alarm not yet acknowledged)",
            AlarmState.ACTIVE_ACK: "alarm acknowledged",
            AlarmState.SHELVED: "alarm shelved",
        }[after]
        faults = f" faults {', '.join(s.faults)}" if s.faults else ""
        self.event(f"{s.unit}: {what}: {s.status.name}{faults} ({before} -> {after})", s.ts)

    # ------------------------------------------------------------------ the loop
    async def run(self) -> int:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            with contextlib.suppress(NotImplementedError, RuntimeError):
                loop.add_signal_handler(sig, self.stop)
        end = time.monotonic() + self.duration if self.duration > 0 else math.inf
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
                i = 0
                next_t = time.monotonic()
                while not self._stop.is_set() and time.monotonic() < end:
                    t0 = time.monotonic()
                    await self.step(i)
                    work = time.monotonic() - t0
                    self.stats.cycles = i + 1
                    self.stats.last_ms = work * 1000
                    self.stats.work_ms.append(work * 1000)
                    if work > self.cycle_s:
                        self.stats.overruns += 1
                    if live is not None:
                        live.update(self.table())
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
            await self.flush()
            for sig in (signal.SIGINT, signal.SIGTERM):
                with contextlib.suppress(NotImplementedError, RuntimeError):
                    loop.remove_signal_handler(sig)
        ms = sorted(self.stats.work_ms) or [0.0]
        self.event(
            f"stopped after {self.stats.cycles} cycles, {self.stats.overruns} overruns, "
            f"{self.stats.stored} new samples stored; cycle work median {ms[len(ms) // 2]:.1f} ms, "
            f"p95 {ms[int(0.95 * (len(ms) - 1))]:.1f} ms, max {ms[-1]:.1f} ms"
        )
        return 0

    def table(self) -> Any:
        """The rich table of the units (one row each)."""
        from rich.table import Table

        st = self.stats
        t = Table(
            title=f"diag run: cycle {st.cycles}, {st.last_ms:.1f} ms, "
            f"{st.overruns} overruns, {st.stored} new samples stored"
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


async def close_all(*parts: Any) -> None:
    """Close what a run opened, each on its own: sources and clients (``close()``), servers
    (``stop()``) and the historian (``close()``, synchronous); ``None`` is skipped and one
    part's failure never keeps the others open."""
    for part in parts:
        if part is None:
            continue
        with contextlib.suppress(Exception):
            done = part.stop() if hasattr(part, "stop") else part.close()
            if asyncio.iscoroutine(done):
                await done
