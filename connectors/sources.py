"""Several tag sources polled as one: Modbus devices and OPC UA servers side by side.

The live loop reads the plant as one vector of tags per cycle. A plant seldom has one
controller, so :class:`SourceSet` polls each source concurrently (each with its own timeout,
inside the connector) and lays their tags side by side in one :class:`connectors.modbus.Poll`.
A source that fails makes only its own tags Bad; the others are read as usual. The cycle waits
for the sources only until its poll deadline: a source still busy then is Bad for that
cycle and its poll runs on in the background (:meth:`SourceSet.poll`).

:class:`OpcUaSource` gives an :class:`connectors.opcua_client.OpcUaReader` the same ``names`` /
``poll()`` shape as :class:`connectors.modbus.ModbusTagClient`: the latest ``DataValue`` of
every node (one Read request when polling, the subscription's last notification otherwise),
NaN where the StatusCode is Bad.

:meth:`SourceSet.transitions` reports each source going down and coming back once, with the
outage interval (the gap), for the loop's event log.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import Any

import numpy as np

from connectors.base import TagQuality, name_tags, now
from connectors.modbus import Poll

_BAD = int(TagQuality.BAD)


class OpcUaSource:
    """An :class:`~connectors.opcua_client.OpcUaReader` as a poll source (see module doc)."""

    def __init__(self, reader: Any, name: str | None = None) -> None:
        self.reader = reader
        self.names = list(reader.config.nodes)
        self.name = name or reader.config.url

    async def start(self) -> None:
        """Start the reader and wait up to its request timeout for the first connection and,
        with a subscription, for the first values (so the first cycles are not Bad only
        because the session was still being opened)."""
        await self.reader.start()
        timeout = self.reader.config.timeout
        if await self.reader.wait_connected(timeout):
            end = time.monotonic() + timeout
            while time.monotonic() < end:
                waiting = [s for s in await self.reader.read() if s.reason == "not connected yet"]
                if not waiting:
                    break
                await asyncio.sleep(0.05)

    @property
    def bad_nodes(self) -> dict[str, str]:
        """Tags whose node id is unusable on the server, and why."""
        return dict(self.reader.bad_nodes)

    async def poll(self) -> Poll:
        t0 = time.perf_counter()
        ts = now()
        samples = await self.reader.read()
        values = np.array([s.value for s in samples], np.float64)
        quality = np.array([int(s.quality) for s in samples], np.uint8)
        src = np.array([s.ts.timestamp() for s in samples], np.float64)
        values[quality == TagQuality.BAD] = np.nan
        reasons = [s.reason for s in samples]
        # a Read that got no answer within its timeout is late, not down (its tags Bad)
        late = np.full(len(samples), bool(getattr(self.reader, "timed_out", False)))
        return Poll(ts, values, quality, reasons, time.perf_counter() - t0, src, late)

    async def close(self) -> None:
        await self.reader.close()


@dataclass
class Transition:
    """A source went down (``up`` False, ``since`` its start) or came back (``up`` True, the
    gap from ``since`` to ``until``)."""

    source: str
    up: bool
    since: datetime
    until: datetime | None
    reason: str


class SourceSet:
    """Sources polled concurrently as one tag vector (tag names must be unique). A source
    has ``names`` (its tags, in the order its ``poll()`` returns them), ``poll()`` and
    ``close()``, and may have ``start()``."""

    def __init__(self, sources: Sequence[Any], names: Sequence[str] | None = None) -> None:
        self.sources = list(sources)
        self.source_names = list(names) if names else [_name(s) for s in self.sources]
        self.names: list[str] = []
        self._slices: list[slice] = []
        for s in self.sources:
            tags = list(s.names)
            self._slices.append(slice(len(self.names), len(self.names) + len(tags)))
            self.names.extend(tags)
        dup = sorted(t for t, k in Counter(self.names).items() if k > 1)
        if dup:
            raise ValueError(f"tag(s) read from more than one source: {', '.join(dup)}")
        self._down: dict[str, tuple[datetime, str]] = {}
        self._last: list[str] = []  # per source: why it is down after the last poll, or ""
        #: per source: its poll still running from an earlier cycle (past the deadline)
        self._pending: list[asyncio.Future[Any] | None] = [None] * len(self.sources)
        #: per source name: cycles it gave no answer within the deadline
        self.late_polls: dict[str, int] = {}

    def tags_of(self, source: str) -> list[str]:
        return self.names[self._slices[self.source_names.index(source)]]

    async def start(self) -> None:
        for s in self.sources:
            if hasattr(s, "start"):
                await s.start()

    async def poll(self, deadline: float | None = None) -> Poll:
        """One poll of every source at once; a source that raises gives Bad tags.

        ``deadline``: seconds the cycle waits for the sources. A source that has not
        answered by then gives Bad tags ("no answer within ...") this cycle but is not
        cancelled: its poll runs on (bounded by its own timeout), the next cycle waits for
        that same poll instead of starting another, and takes its answer if it comes in
        time. So one slow source never holds the others' samples or the cycle."""
        t0 = time.perf_counter()
        ts = now()
        for i, s in enumerate(self.sources):
            if self._pending[i] is None:
                self._pending[i] = asyncio.ensure_future(s.poll())
        tasks = [t for t in self._pending if t is not None]
        if tasks:
            await asyncio.wait(tasks, timeout=deadline)
        n = len(self.names)
        values = np.full(n, np.nan)
        quality = np.full(n, TagQuality.BAD, np.uint8)
        source_ts = np.full(n, np.nan)
        reasons = [""] * n
        late = np.zeros(n, bool)
        self._last = []
        for i, (name, sl) in enumerate(zip(self.source_names, self._slices, strict=True)):
            task = self._pending[i]
            assert task is not None
            if not task.done():
                why = f"{name}: no answer within the cycle's poll deadline ({deadline:.2f} s)"
                reasons[sl] = [why] * (sl.stop - sl.start)
                late[sl] = True
                # late is not down: the source keeps its state until its poll answers
                self._last.append(self._down[name][1] if name in self._down else "")
                self.late_polls[name] = self.late_polls.get(name, 0) + 1
                continue
            self._pending[i] = None
            p: Any = task.exception() if not task.cancelled() else asyncio.CancelledError()
            if p is None:
                p = task.result()
            if isinstance(p, BaseException):
                if isinstance(p, asyncio.CancelledError):  # never ours: say so, not "()"
                    named = name_tags(list(self.names[sl]))
                    why = f"{name}: poll of {named} cancelled inside the source (no answer)"
                else:
                    why = f"{name}: poll failed: {p!r}"
                reasons[sl] = [why] * (sl.stop - sl.start)
                self._last.append(why)
                continue
            values[sl], quality[sl], reasons[sl] = p.values, p.quality, p.reasons
            if p.source_ts is not None:
                source_ts[sl] = p.source_ts
            # a source is down when none of its tags could be read (vectorised: 5,000 tags);
            # one whose request got no answer within its own timeout is late, as above (an
            # OPC UA Read, a Modbus block and the rest of its poll on a loaded machine; issue
            # 34): those tags are late and the source keeps its state
            if p.late is not None and bool(p.late.any()):
                late[sl] = p.late
                self._last.append(self._down[name][1] if name in self._down else "")
                continue
            down = len(p.reasons) > 0 and bool((p.quality == _BAD).all())
            self._last.append((p.reasons[0] or "no tag readable") if down else "")
        return Poll(ts, values, quality, reasons, time.perf_counter() - t0, source_ts, late)

    def slices(self) -> list[tuple[str, slice]]:
        """Each source's name and the slice of its tags in the tag vector."""
        return list(zip(self.source_names, self._slices, strict=True))

    def bad_nodes(self) -> dict[str, dict[str, str]]:
        """Per source: tags whose node id is unusable (OPC UA sources), and why."""
        return {
            name: s.bad_nodes
            for name, s in zip(self.source_names, self.sources, strict=True)
            if getattr(s, "bad_nodes", None)
        }

    def transitions(self, ts: datetime) -> list[Transition]:
        """Sources that went down or came back in the last :meth:`poll`."""
        out = []
        for name, why in zip(self.source_names, self._last, strict=False):
            if why and name not in self._down:
                self._down[name] = (ts, why)
                out.append(Transition(name, False, ts, None, why))
            elif not why and name in self._down:
                since, was = self._down.pop(name)
                out.append(Transition(name, True, since, ts, was))
        return out

    async def close(self) -> None:
        for i, task in enumerate(self._pending):
            if task is not None:
                task.cancel()
                with contextlib.suppress(BaseException):
                    await task
                self._pending[i] = None
        for s in self.sources:
            try:
                await s.close()
            except Exception:  # noqa: BLE001 - closing the others matters more
                pass


def _name(source: Any) -> str:
    return str(getattr(source, "name", None) or type(source).__name__)
