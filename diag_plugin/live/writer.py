"""The live loop's storage side: the loop hands over samples and never waits for the database.

:meth:`HistorianWriter.put` appends one cycle's tag vector to a queue in memory and returns;
a task writes the queue to the historian in the background, through one thread of its own
(:class:`historian.livestore.LiveStore`, short idempotent transactions). Flushes are
incremental: one block of at most ``chunk_rows`` samples per transaction, so no single write
holds anything up, and the first write creates all tags in one transaction.

When the database does not take a block (locked by another writer, stopped, slow) the writer
keeps the samples and tries again with backoff; the queue in memory holds ``memory_rows``
samples, older ones go to the spill folder (:class:`historian.spool.Spool`). Everything is
written back oldest first — the block in flight, then the spill segments, then memory — and
idempotently (the samples' primary key), so each sample lands exactly once. A failed write,
or one taking longer than ``stall_after`` seconds, makes the writer *degraded*; it reports
that once through ``notify(degraded, text)`` and once when everything waiting is stored
again. It never raises into the loop. :meth:`close` tries to store what is left within a
time limit and spills the rest, so a later start stores it.

Every cycle is also appended to a journal file in the spill folder before it waits in memory
(:class:`historian.journal.Journal`), and each journal file is deleted once all its cycles are
stored or spilled; a process killed with SIGKILL leaves its unstored cycles there, and the
next start hands them to the spill replay — at most the cycle being written at the kill is
lost. The time the plug-in was not running (from the last cycle of the previous run, journal
or clean stop, to the first of this one) is marked in the historian: one Bad sample per tag
at the first missed cycle (it ends any hold in windows and counts as Bad in ``diag tags``)
and an event ``restart gap: ...``.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import json
import logging
import queue
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from historian.coldstore import month_start
from historian.journal import Journal, JournalCorrupt
from historian.livestore import LiveStore, RollResult, roll_closed
from historian.quality import BAD
from historian.spool import Block, SegmentCorrupt, Spool

log = logging.getLogger(__name__)


@dataclass
class WriterStats:
    stored: int = 0  #: samples added to the database
    events: int = 0  #: events added to the database
    spilled: int = 0  #: samples written to spill segments
    replayed: int = 0  #: samples read back from spill segments and stored
    failures: int = 0  #: failed write attempts
    writes: int = 0  #: successful block writes
    max_backlog: int = 0  #: most samples waiting at once
    max_write_s: float = 0.0  #: longest successful write
    degraded_s: float = 0.0  #: time spent degraded
    misfiled_tags: int = 0  #: tags found missing or renumbered when storage came back
    quarantined: int = 0  #: spill segments found damaged and renamed .corrupt
    journal_errors: int = 0  #: cycles that could not be journaled (kept in memory only)
    recovered: int = 0  #: samples read back from a crashed run's journal at start


class _DbThread:
    """One daemon thread running the database calls in order: a call that hangs (a lock, a
    server gone silent) never holds up the event loop or the process's exit."""

    def __init__(self, name: str) -> None:
        self._q: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._t = threading.Thread(target=self._run, name=name, daemon=True)
        self._t.start()

    def _run(self) -> None:
        while True:
            item = self._q.get()
            if item is None:
                return
            fut, fn, args = item
            if not fut.set_running_or_notify_cancel():
                continue
            try:
                fut.set_result(fn(*args))
            except BaseException as exc:  # noqa: BLE001 - handed to the awaiting task
                fut.set_exception(exc)

    def submit(self, fn: Callable[..., Any], *args: Any) -> asyncio.Future[Any]:
        cf: concurrent.futures.Future[Any] = concurrent.futures.Future()
        self._q.put((cf, fn, args))
        return asyncio.wrap_future(cf)

    def stop(self) -> None:
        self._q.put(None)


@dataclass
class _Item:
    block: Block
    segment: Path | None = None  # the spill segment it came from
    seqs: list[int] | None = None  # the journal file of each of its cycles (from memory)


#: where a clean stop leaves the time of its last cycle (the next start's gap begins there)
LAST_FILE = "journal-last.json"


class HistorianWriter:
    """Background historian writes for the live loop (module doc).

    ``tags``: the tag names of every ``put`` vector, in order. ``spill_dir``: the spill
    folder. ``flush_every``: cycles per block in normal operation. ``notify(degraded, text)``:
    told once when storage degrades and once when it is whole again (also of the first
    spill)."""

    def __init__(
        self,
        url: str,
        tags: Sequence[str],
        *,
        spill_dir: str | Path,
        flush_every: int = 20,
        cycle: float = 1.0,
        memory_rows: int = 2_000_000,
        chunk_rows: int = 200_000,
        busy_timeout: float = 2.0,
        stall_after: float | None = None,
        notify: Callable[[bool, str], None] | None = None,
        roll_months: bool = True,
        roll_every: float = 3600.0,
        clock: Callable[[], pd.Timestamp] | None = None,
    ) -> None:
        self.url = url
        self.tags = list(tags)
        self.spool = Spool(spill_dir)
        self.flush_every = max(1, int(flush_every))
        self.cycle = float(cycle)
        self.memory_rows = max(len(self.tags), int(memory_rows))
        self.chunk_cycles = max(1, min(int(chunk_rows) // max(1, len(self.tags)), 10_000))
        self.stall_after = (
            float(stall_after)
            if stall_after is not None
            else max(5.0, 3 * self.flush_every * self.cycle)
        )
        self.notify = notify
        self.store = LiveStore(url, busy_timeout=busy_timeout)
        self.stats = WriterStats()
        self.degraded = False
        self.reason = ""
        self._since = 0.0
        self._late = 0
        self._spool_rows = 0
        self._replayed0 = 0
        self._told_spill = False
        self._mem: deque[tuple[int, np.ndarray, np.ndarray, int]] = deque()
        self._events: list[dict[str, Any]] = []
        self._event_seqs: list[int] = []  # the journal file of each pending event
        self._spool_any = False  # spill segments may wait (some with events only)
        self._inflight: _Item | None = None
        #: a spill being written in its thread: (the write, its block, its journal cycles)
        self._spilling: tuple[asyncio.Future[Path], Block, list[int]] | None = None
        self._wake = asyncio.Event()
        self._stopping = False
        self._closed = False
        self._finished = False
        self._task: asyncio.Task[None] | None = None
        self._db = _DbThread(f"historian {url}")
        self._fail_streak = 0
        self._quarantined_told = 0
        self.journal = Journal(self.spool.folder, self.tags, self.cycle)
        self._pending: dict[int, int] = {}  # journal file → its cycles not yet durable
        self._journal_ok = True
        #: the previous run: its last ts, its data's period µs (None: it saw one cycle), crashed
        self._prev: tuple[int, int | None, bool] | None = None
        self._first_put = True
        self._gap_first: int | None = None  # the first cycle, while the gap waits for a period
        self._last_ts: int | None = None
        self._steps: deque[int] = deque(maxlen=20)
        #: (start, end) of the restart gap marked at the first cycle, if any
        self.restart_gap: tuple[pd.Timestamp, pd.Timestamp] | None = None
        #: told each note (restart gap, recovered journal, damaged files) as one line; by
        #: default it goes to the log and the historian's event log
        self.on_note: Callable[[str], None] | None = None
        #: every note so far (those of :meth:`start` come before a listener can be set)
        self.notes: list[str] = []
        #: roll closed months to the cold store (module doc); ``clock()``: the time now (UTC)
        self.roll_months = bool(roll_months)
        self.roll_every = float(roll_every)
        self.clock = clock or (lambda: pd.Timestamp.now(tz="UTC"))
        #: every month rolled so far: (month, samples, seconds)
        self.rolled: list[tuple[str, int, float]] = []
        self._roll_task: asyncio.Task[None] | None = None
        self._roll_thread: _DbThread | None = None
        self._roll_checked: pd.Timestamp | None = None  # the clock at the last check
        self._roll_data: pd.Timestamp | None = None  # the cycles' month at the last check
        self._roll_pending = False  # the last check left closed months in the table
        self._told_no_cold = False

    # ------------------------------------------------------------------ the loop's side
    @property
    def backlog(self) -> int:
        """Samples waiting: in flight, in memory, being spilled and in the spill (the spill
        as last counted)."""
        n = len(self._mem) * len(self.tags)
        if self._inflight is not None:
            n += self._inflight.block.rows
        if self._spilling is not None:
            n += self._spilling[1].rows
        return n + self._spool_rows

    def put(self, ts: pd.Timestamp, values: np.ndarray, quality: np.ndarray) -> None:
        """Queue one cycle's samples (journaled first; never waits on the database)."""
        t = int(ts.value // 1000)
        first = self._first_put
        self._first_put = False
        self._queue(t, np.array(values, np.float64), np.array(quality, np.uint8))
        if first:
            with contextlib.suppress(OSError):  # this run's own stop will write it again
                (self.spool.folder / LAST_FILE).unlink(missing_ok=True)
            self._gap_first = t if self._prev is not None else None
        if self._gap_first is not None and self._gap_period() is not None:
            first_t, self._gap_first = self._gap_first, None
            self._mark_gap(first_t)
        self.stats.max_backlog = max(self.stats.max_backlog, self.backlog)
        if len(self._mem) >= self.flush_every or len(self._mem) * len(self.tags) > self.memory_rows:
            self._wake.set()

    def _queue(self, t: int, v: np.ndarray, q: np.ndarray) -> None:
        self._mem.append((t, v, q, self._journal_append(t, v, q)))
        if self._last_ts is not None and t > self._last_ts:
            self._steps.append(t - self._last_ts)
        self._last_ts = t if self._last_ts is None else max(self._last_ts, t)

    @property
    def period_us(self) -> int | None:
        """The sampling period seen in the data (median of the last 20 steps, µs; until two
        cycles are seen, the previous run's; None when neither saw two) — the embedded
        plant's samples are 10 s apart at a 0.04–0.25 s cycle, so the gap is judged on the
        data's own period, never on the cycle."""
        if self._steps:
            return int(np.median(self._steps))
        return None if self._prev is None else self._prev[1]

    def _gap_period(self) -> int | None:
        """The period the restart gap is judged on: the previous run's, else this run's
        first step (the gap waits for the second cycle: a run of one cycle whose period
        nobody saw marks none)."""
        if self._prev is not None and self._prev[1] is not None:
            return self._prev[1]
        return int(np.median(self._steps)) if self._steps else None

    def _journal_append(
        self,
        t: int = 0,
        v: np.ndarray | None = None,
        q: np.ndarray | None = None,
        event: dict[str, Any] | None = None,
    ) -> int:
        """Append one cycle (or ``event``) to the journal; the number of its file (0: not
        journaled)."""
        j = self.journal
        try:
            if j.seq and j.cycles >= self.flush_every:
                old = j.seq
                j.rotate()
                if not self._pending.get(old):
                    j.remove(old)
            seq = j.append_event(event) if event is not None else j.append(t, v, q)
        except OSError as exc:
            self.stats.journal_errors += 1
            if self._journal_ok:
                self._journal_ok = False
                log.error(
                    "historian: cannot journal cycles in %s (%s): until it can, a crash loses "
                    "what waits in memory",
                    j.folder,
                    exc,
                )
            return 0
        if not self._journal_ok:
            self._journal_ok = True
            log.warning("historian: journaling cycles again in %s", j.folder)
        self._pending[seq] = self._pending.get(seq, 0) + 1
        return seq

    def _release(self, seqs: list[int] | None) -> None:
        """These cycles are stored or spilled: a journal file none of whose cycles waits any
        longer is deleted (the current one once it rotates)."""
        for seq in seqs or ():
            if not seq:
                continue
            left = self._pending.get(seq, 0) - 1
            if left > 0:
                self._pending[seq] = left
                continue
            self._pending.pop(seq, None)
            if seq != self.journal.seq:
                with contextlib.suppress(OSError):
                    self.journal.remove(seq)

    async def settle(self, deadline: float) -> bool:
        """Wait until the earlier runs' spill (and recovered journal) is stored, or until
        ``time.monotonic()`` passes ``deadline``; True when stored."""
        while self._spool_rows or self._spool_any or self._inflight is not None:
            if time.monotonic() >= deadline or self._task is None or self._task.done():
                return False
            await asyncio.sleep(0.05)
        return True

    def samples_until(self, ts: pd.Timestamp) -> None:
        """The historian holds samples up to ``ts`` from elsewhere (the catch-up found them):
        the restart gap, if any, begins after them."""
        if self._prev is None:
            return
        last, step, crashed = self._prev
        self._prev = (max(last, int(ts.value // 1000)), step, crashed)

    def _mark_gap(self, t: int) -> None:
        """``t``, the first cycle of this run: mark the time since the previous run's last
        cycle (one Bad sample per tag at the first missed cycle, and a note)."""
        if self._prev is None:
            return
        last, _, crashed = self._prev
        step = self._gap_period()
        if step is None or t - last <= 1.5 * step:
            return
        start = last + step
        n = len(self.tags)
        self._queue(start, np.full(n, np.nan), np.full(n, BAD, np.uint8))
        a, b = pd.Timestamp(start, unit="us", tz="UTC"), pd.Timestamp(t, unit="us", tz="UTC")
        self.restart_gap = (a, b)
        why = "the previous run ended without closing (killed?)" if crashed else "not running"
        self._note(
            f"restart gap: no samples from {a:%Y-%m-%d %H:%M:%S} to {b:%H:%M:%S} UTC "
            f"({(t - start) / 1e6:.1f} s, {why}); marked by a Bad sample of every tag at "
            f"{a:%H:%M:%S}"
        )

    def _note(self, text: str) -> None:
        log.warning("%s", text)
        self.notes.append(text)
        if self.on_note is not None:
            try:
                self.on_note(text)
                return
            except Exception:  # noqa: BLE001 - a listener must not stop storage
                log.exception("historian note failed")
        self.put_event(pd.Timestamp.now(tz="UTC"), "diag run", text)

    def put_event(self, ts: pd.Timestamp, unit: str, message: str, **fields: Any) -> None:
        """Queue one event for the historian's event log (never waits)."""
        if self._finished:  # told after close took what was left: nowhere to go (as ever)
            log.debug("historian closed: event not stored: %s", message)
            return
        event = {"ts": int(pd.Timestamp(ts).value // 1000), "unit": unit, "message": message}
        event.update(fields)
        self._events.append(event)
        self._event_seqs.append(self._journal_append(event=event))
        if len(self._events) > 10_000:
            self._wake.set()

    # ------------------------------------------------------------------ lifecycle
    async def start(self) -> None:
        """Recover a crashed run's journal into the spill, then start the background task
        (returns at once; the database may be away)."""
        await asyncio.to_thread(self._recover)
        self._spool_rows = await asyncio.to_thread(self.spool.rows)
        self._spool_any = bool(await asyncio.to_thread(self.spool.segments))
        self._report_quarantined()
        if self._spool_rows:
            log.warning(
                "historian: %d samples from an earlier run wait in %s; storing them first",
                self._spool_rows,
                self.spool.folder,
            )
        self._task = asyncio.create_task(self._run(), name=f"historian writer {self.url}")

    def _recover(self) -> None:
        """Journal files left by an earlier run (killed, or its spill failed at exit) become
        spill segments, stored first; the time of the earlier run's last cycle is kept for
        the restart gap."""
        last: int | None = None
        period: int | None = None  # the data's, from the last file or the journal
        crashed = False
        state = self.spool.folder / LAST_FILE
        if state.is_file():
            try:
                doc = json.loads(state.read_text(encoding="utf-8"))
                last = int(doc["ts"])
                if doc.get("period_us") is not None:
                    period = max(1, int(doc["period_us"]))
            except (OSError, ValueError, KeyError, TypeError) as exc:
                log.warning("historian: %s unreadable (%s); no restart gap marked", state, exc)
        else:
            crashed = True  # a clean stop leaves the state file; journal files alone: a kill
        cycles = samples = torn = events = 0
        files = self.journal.files()
        for path in files:
            try:
                r = Journal.read(path)
            except JournalCorrupt as exc:
                moved = self.journal.quarantine(path, str(exc))
                self._note(f"historian: journal file {path} is damaged; renamed {moved.name}")
                continue
            except OSError as exc:
                log.error("historian: journal file %s unreadable: %s", path, exc)
                continue
            if len(r.ts) or r.events:
                try:
                    self.spool.write(Block(r.tags, r.ts, r.values, r.quality, r.events))
                except OSError as exc:
                    log.error(
                        "historian: cannot move journal file %s to the spill (%s); kept for "
                        "the next start",
                        path,
                        exc,
                    )
                    continue
                events += len(r.events)
                cycles += len(r.ts)
                samples += int(r.values.size)
                top = int(r.ts.max()) if len(r.ts) else None
                if top is not None and (last is None or top > last):
                    last = top
                    if len(r.ts) > 1:
                        period = int(np.median(np.diff(np.sort(r.ts))))
            torn += r.torn
            path.unlink(missing_ok=True)
        if last is not None:
            self._prev = (last, period, crashed and bool(cycles))
        if files and (cycles or events):
            self.stats.recovered += samples
            self._note(
                f"historian: {cycles} cycles ({samples} samples) and {events} events of a run "
                f"that ended without closing recovered from its journal ({len(files)} files"
                + (f", a torn last record of {torn} bytes dropped" if torn else "")
                + "); stored first"
            )

    async def close(self, timeout: float = 10.0) -> None:
        """Store what is left within ``timeout`` seconds; spill the rest; stop the thread."""
        if self._closed:
            return
        self._closed = True
        self._stopping = True
        self._wake.set()
        end = time.monotonic() + timeout
        if self._task is not None:
            done, _ = await asyncio.wait({self._task}, timeout=timeout)
            if not done:
                self._task.cancel()
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await self._task
        await (
            self._settle_spill()
        )  # a spill the cancel caught half-way (back in memory if it failed)
        left: list[tuple[Block, list[int]]] = []
        if self._inflight is not None and self._inflight.segment is None:
            # may be stored too: idempotent at replay
            left.append((self._inflight.block, self._inflight.seqs or []))
        if self._mem or self._events:
            left.append(self._take(len(self._mem)))
        self._finished = True
        for block, seqs in left:
            if block.rows or block.events:
                try:
                    path = await asyncio.to_thread(self.spool.write, block)
                    self._release(seqs)
                    self.stats.spilled += block.rows
                    self._spool_rows += block.rows
                    self._tell(
                        True,
                        f"historian away at exit: {block.rows} samples kept in {path} for "
                        "the next start",
                    )
                except OSError as exc:
                    log.error(
                        "historian: %d samples neither stored nor spilled at exit (%s); %s",
                        block.rows,
                        exc,
                        "the journal keeps them for the next start" if all(seqs) else "lost",
                    )
            else:
                self._release(seqs)
        await asyncio.to_thread(self._close_journal)
        self._db.submit(LiveStore.close, self.store)
        self._db.stop()
        await self._stop_roll(end)

    async def _stop_roll(self, end: float) -> None:
        """Wait for a running roll until ``end`` (``time.monotonic()``), no longer: a roll
        left running stops after its month in its own thread, or dies with the process (an
        orphan file at worst, :meth:`historian.store.Historian.cold_orphans`)."""
        task, self._roll_task = self._roll_task, None
        if task is not None and not task.done():
            done, _ = await asyncio.wait({task}, timeout=max(0.0, end - time.monotonic()))
            if not done:
                task.cancel()
                log.warning(
                    "historian: a roll of closed months was still running at stop; left to "
                    "end after its month (a kill leaves at worst an orphan file)"
                )
        if self._roll_thread is not None:
            self._roll_thread.stop()
            self._roll_thread = None

    def _close_journal(self) -> None:
        """At a clean stop: delete the journal files whose cycles are all durable, and
        leave the time of the last cycle for the next start's restart gap."""
        self.journal.close()
        for seq in self.journal.created:  # never a file an earlier run left
            if not self._pending.get(seq):
                self.journal.path(seq).unlink(missing_ok=True)
        if self._last_ts is not None:
            try:
                self.spool.folder.mkdir(parents=True, exist_ok=True)
                (self.spool.folder / LAST_FILE).write_text(
                    json.dumps({"ts": self._last_ts, "period_us": self.period_us}), encoding="utf-8"
                )
            except OSError as exc:
                log.warning("historian: cannot note the last cycle's time: %s", exc)

    # ------------------------------------------------------------------ rolling months
    def _check_roll(self) -> None:
        """After a stored block: start a roll of closed months on the roll thread at the
        first store, at the first store of each new UTC month (by ``clock()``, or of the
        cycles' own times), and every ``roll_every`` seconds while the last check left closed
        months in the table."""
        if not self.roll_months or self._stopping:
            return
        if self._roll_task is not None and not self._roll_task.done():
            return
        now = self.clock()
        last = self._roll_checked
        data = None if self._last_ts is None else month_start(self._last_ts)
        if last is not None and month_start(now) == month_start(last) and data == self._roll_data:
            if not self._roll_pending or (now - last).total_seconds() < self.roll_every:
                return
        self._roll_checked, self._roll_data = now, data
        self._roll_task = asyncio.create_task(self._roll(now), name=f"historian roll {self.url}")

    async def _roll(self, now: pd.Timestamp) -> None:
        """Roll the months closed at ``now`` and before the newest cycle's month in the roll
        thread (its own connection; only
        the final delete of each month takes the write lock), then log and record each."""
        if self._roll_thread is None:
            self._roll_thread = _DbThread(f"historian roll {self.url}")
        before = month_start(now)
        if self._last_ts is not None:  # never the month the cycles go into (a feed in the past,
            # a simulation or a replay: its month would be rewritten at every check)
            before = min(before, month_start(self._last_ts))
        try:
            r = await self._roll_thread.submit(
                lambda: roll_closed(self.url, before, stop=lambda: self._stopping)
            )
        except Exception as exc:  # noqa: BLE001 - roll_closed returns its failures
            r = RollResult(error=exc, left=True)
        self._roll_pending = r.left
        for month, rows, seconds in r.done:
            self.rolled.append((month, rows, seconds))
            text = f"historian: rolled {month} to the cold store: {rows} samples in {seconds:.1f} s"
            log.info("%s", text)
            self.put_event(now, "diag run", text)
        if r.no_cold:
            if not self._told_no_cold:
                self._told_no_cold = True
                log.warning(
                    "historian: %s has no cold folder recorded: closed months stay in the "
                    "samples table (diag historian roll --cold-dir DIR records one)",
                    self.url,
                )
            return
        if r.error is not None:
            text = (
                f"historian: rolling closed months failed ({_why(r.error)}); "
                f"retried in {self.roll_every:g} s"
            )
            log.error("%s", text)
            self.put_event(now, "diag run", text)

    # ------------------------------------------------------------------ the task
    def _take(self, cycles: int) -> tuple[Block, list[int]]:
        """The oldest ``cycles`` cycles of memory (and every pending event) as a block, and
        the journal file of each cycle."""
        items = [self._mem.popleft() for _ in range(min(cycles, len(self._mem)))]
        events, self._events = self._events, []
        event_seqs, self._event_seqs = self._event_seqs, []
        n = len(self.tags)
        if not items:
            empty = Block(
                self.tags,
                np.empty(0, np.int64),
                np.empty((0, n)),
                np.empty((0, n), np.uint8),
                events,
            )
            return empty, event_seqs
        ts = np.fromiter((it[0] for it in items), np.int64, count=len(items))
        block = Block(
            self.tags,
            ts,
            np.stack([it[1] for it in items]),
            np.stack([it[2] for it in items]),
            events,
        )
        return block, [it[3] for it in items] + event_seqs

    async def _next(self) -> _Item | None:
        """What to store next: the oldest spill segment (read in a thread), else a block
        from memory (taken here, in the loop's thread, where ``put`` appends)."""
        if self._spool_rows or self._spool_any:
            segments = await asyncio.to_thread(self.spool.segments)
            for seg in segments:
                try:
                    return _Item(await asyncio.to_thread(self.spool.read, seg), seg)
                except SegmentCorrupt:
                    self._report_quarantined()
            self._spool_rows = 0
            self._spool_any = False
        if self._mem or self._events:
            block, seqs = self._take(self.chunk_cycles)
            return _Item(block, None, seqs)
        return None

    def _due(self) -> bool:
        if self._inflight is not None or self._spool_rows or self._spool_any or self._stopping:
            return True
        if len(self._mem) >= self.flush_every or len(self._events) > 10_000:
            return True
        return bool(self._mem) and self._fail_streak > 0

    async def _run(self) -> None:
        backoff = 0.5
        while True:
            if not self._due():
                self._wake.clear()
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(self.flush_every * self.cycle):
                        await self._wake.wait()
                if not self._due() and not self._mem and not self._events:
                    continue
            if self._inflight is None:
                self._inflight = await self._next()
                if self._inflight is None:
                    if self._stopping:
                        return
                    continue
            ok = await self._store(self._inflight)
            if ok:
                item, self._inflight = self._inflight, None
                self._release(item.seqs)
                if item.segment is not None:
                    await asyncio.to_thread(self.spool.remove, item.segment)
                    self.stats.replayed += item.block.rows
                    self._spool_rows = max(0, self._spool_rows - item.block.rows)
                if self.degraded:
                    self._late += item.block.rows
                    if not self._spool_rows and len(self._mem) < self.flush_every:
                        await self._recovered()
                backoff = 0.5
                self._fail_streak = 0
                self._check_roll()
                continue
            if self._stopping:
                return
            await self._spill_if_full()
            # the timeout covers the wait alone: a spill is never cut off by it
            end = time.monotonic() + backoff
            while not self._stopping and (wait := end - time.monotonic()) > 0:
                try:
                    await asyncio.wait_for(self._wake.wait(), wait)
                except TimeoutError:
                    break
                self._wake.clear()
                await self._spill_if_full()
            backoff = min(backoff * 2, 10.0)

    async def _store(self, item: _Item) -> bool:
        """One write of ``item`` in the database thread; watch it, spill memory meanwhile."""
        b = item.block
        t0 = time.monotonic()

        def write(store: LiveStore) -> tuple[int, int]:
            try:
                n = store.write_block(b.tags, b.ts, b.values, b.quality) if b.rows else 0
                e = store.write_events(b.events)
            except Exception:
                store.reset()
                raise
            return n, e

        fut = self._db.submit(write, self.store)
        while True:
            done, _ = await asyncio.wait({fut}, timeout=1.0)
            if done:
                break
            if time.monotonic() - t0 > self.stall_after:
                self._degrade(f"no answer for {time.monotonic() - t0:.0f} s")
            await self._spill_if_full()
        try:
            n, e = fut.result()
        except Exception as exc:  # noqa: BLE001 - any failure means "keep and retry"
            self.stats.failures += 1
            self._fail_streak += 1
            self._degrade(_why(exc))
            return False
        dt = time.monotonic() - t0
        self.stats.writes += 1
        self.stats.stored += n
        self.stats.events += e
        self.stats.max_write_s = max(self.stats.max_write_s, dt)
        if dt > self.stall_after:
            log.warning("historian: a write took %.1f s", dt)
        return True

    async def _spill_if_full(self) -> None:
        """Move the oldest memory cycles to a spill segment while memory is over its bound."""
        await self._settle_spill()  # one an earlier call began and was cancelled out of
        n = len(self.tags)
        if len(self._mem) * n <= self.memory_rows:
            return
        block, seqs = self._take(len(self._mem) - self.memory_rows // (2 * n))
        write = asyncio.ensure_future(asyncio.to_thread(self.spool.write, block))
        self._spilling = (write, block, seqs)
        await self._settle_spill()

    async def _settle_spill(self) -> None:
        """Wait for the spill segment being written, then account for it: written, its
        journal cycles are released; failed, the block goes back to the front of memory.

        The write is shielded and stays in ``_spilling`` until settled: a cancel of the
        caller (``close()`` out of time, a timeout around a wait) never leaves a block both
        spilled and journaled, nor drops it; the next call, or ``close()``, settles it."""
        if self._spilling is None:
            return
        write, block, seqs = self._spilling
        try:
            path = await asyncio.shield(write)
        except OSError as exc:
            self._spilling = None
            log.error(
                "historian: cannot spill to %s: %s; keeping in memory", self.spool.folder, exc
            )
            for i in range(len(block.ts) - 1, -1, -1):
                self._mem.appendleft((int(block.ts[i]), block.values[i], block.quality[i], seqs[i]))
            self._events[:0] = block.events
            self._event_seqs[:0] = seqs[len(block.ts) :]
            return
        self._spilling = None
        self._release(seqs)
        self._spool_any = True
        self.stats.spilled += block.rows
        self._spool_rows += block.rows
        if not self._told_spill:
            self._told_spill = True
            self._tell(
                True,
                f"historian away: memory holds {self.memory_rows} samples, older ones go "
                f"to {path.parent}",
            )

    def _report_quarantined(self) -> None:
        """Each spill segment found damaged: an event (the spool has logged it by name)."""
        while len(self.spool.quarantined) > self._quarantined_told:
            path, moved, why = self.spool.quarantined[self._quarantined_told]
            self._quarantined_told += 1
            self.stats.quarantined += 1
            self._note(
                f"historian: spill file {path} is damaged ({why}); renamed {moved.name}, "
                "its samples are not stored"
            )

    def _degrade(self, reason: str) -> None:
        if not self.degraded:
            self.degraded = True
            self._since = time.monotonic()
            self._late = 0
            self.reason = reason
            self._replayed0 = self.stats.replayed
            self._tell(
                True,
                f"historian degraded: {reason}; samples wait in memory (up to "
                f"{self.memory_rows} samples), then in {self.spool.folder}",
            )

    async def _recovered(self) -> None:
        """Whole again: say so, and "none lost" only once every tag the samples were filed
        under is checked to be that tag's row in the database."""
        try:
            wrong = await self._db.submit(LiveStore.missing_tags, self.store)
        except Exception as exc:  # noqa: BLE001 - checked again at the next recovery
            self.stats.failures += 1
            self._fail_streak += 1
            log.warning("historian: cannot check the stored tags yet: %s", _why(exc))
            return
        dt = time.monotonic() - self._since
        self.stats.degraded_s += dt
        self.degraded = False
        self._told_spill = False
        replayed = self.stats.replayed - self._replayed0
        if wrong:
            self.stats.misfiled_tags += len(wrong)
            self._tell(
                False,
                f"historian back after {dt:.1f} s: {self._late} samples stored late, but "
                f"{len(wrong)} tags ({', '.join(wrong[:5])}{', ...' if len(wrong) > 5 else ''})"
                " were not in the database as written: samples may be filed under no tag "
                "('diag historian check' counts them)",
            )
            return
        self._tell(
            False,
            f"historian back after {dt:.1f} s: {self._late} samples stored late "
            f"({replayed} of them from the spill folder), none lost (every tag checked)",
        )

    def _tell(self, degraded: bool, text: str) -> None:
        (log.warning if degraded else log.info)("%s", text)
        if self.notify is not None:
            try:
                self.notify(degraded, text)
            except Exception:  # noqa: BLE001 - a listener must not stop storage
                log.exception("historian notify failed")


def _why(exc: BaseException) -> str:
    """A one-line reason from a database exception (SQLAlchemy wraps the driver's)."""
    text = str(getattr(exc, "orig", None) or exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}"[:300]
