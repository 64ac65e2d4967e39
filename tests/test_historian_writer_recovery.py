"""The live loop's historian writer says "back, none lost" only when nothing waits any more
(issue 38, bug 11), against a real SQLite historian write-locked by a second process.

While the lock is held the writer keeps the samples, spills the overflow to its spill folder
and says "degraded" once. Released, it stores the block it was holding first; the spilled
samples are still waiting then, so "back" must wait until they are stored too: at the moment
it is said the spill folder is empty and the historian holds every sample put but the newest
few still in memory (fewer than one flush), and in the end every sample, exactly once.
"""

from __future__ import annotations

import asyncio
import time

import numpy as np
import pandas as pd

from tests.helpers import Locker


async def until(pred, timeout: float = 30.0) -> bool:
    end = asyncio.get_running_loop().time() + timeout
    while asyncio.get_running_loop().time() < end:
        if pred():
            return True
        await asyncio.sleep(0.02)
    return False


def test_back_none_lost_is_said_only_when_the_spilled_samples_are_stored(tmp_path):
    from diag_plugin.live.writer import HistorianWriter
    from historian.store import Historian

    db = tmp_path / "h.db"
    url = f"sqlite:///{db}"
    Historian(url).close()  # the schema (WAL) exists before the lock is taken
    spill = tmp_path / "spill"
    tags = ["A", "B"]
    said: list[tuple[bool, str, int, list]] = []
    t0 = pd.Timestamp("2026-03-01T00:00:00.3Z")  # off the second
    n = 60

    async def main() -> None:
        w: HistorianWriter

        def notify(degraded: bool, text: str) -> None:
            # what waits at the moment it is said: spill segments, and samples not stored
            with Historian(url) as h:
                stored = list(h.read_samples("A").index) if len(h.tags()) else []
            said.append((degraded, text, len(list(spill.glob("spill-*.npz"))), stored))

        w = HistorianWriter(
            url,
            tags,
            spill_dir=spill,
            flush_every=50,
            cycle=0.01,
            memory_rows=16,  # 8 cycles in memory, the rest spilled
            busy_timeout=0.1,
            notify=notify,
        )
        lock = Locker(db)
        try:
            await w.start()
            for i in range(n):
                ts = t0 + pd.Timedelta(seconds=i)
                w.put(ts, np.array([float(i), -float(i)]), np.zeros(2, np.uint8))
                await asyncio.sleep(0.01)
            assert await until(lambda: w.degraded and len(list(spill.glob("spill-*.npz"))) > 1)
            # nothing stored yet: every sample waits (the spill is counted as its writer
            # finishes a segment, so under load the count may come a moment later)
            assert await until(lambda: w.backlog == n * len(tags), 10.0), w.backlog
        finally:
            lock.release()
        assert await until(lambda: not w.degraded and w.backlog == 0)
        await w.close()

    asyncio.run(main())
    degraded = [s for s in said if s[0]]
    back = [s for s in said if not s[0]]
    assert degraded and "historian degraded" in degraded[0][1]
    assert "database is locked" in degraded[0][1]  # the database's own reason
    assert len(back) == 1 and "none lost" in back[0][1], said
    _, text, segments_left, stored = back[0]
    assert segments_left == 0, text
    put = [t0 + pd.Timedelta(seconds=i) for i in range(n)]
    assert stored == put[: len(stored)], text  # the oldest first, none skipped
    assert n - len(stored) < 50, text  # what is left is less than one flush, in memory
    with Historian(url) as h:
        a = h.read_samples("A")
    assert a.index.is_unique and len(a) == n
    assert a.tolist() == [float(i) for i in range(n)]
    assert a.index[0] == t0


def test_a_spill_folder_that_cannot_be_written_keeps_the_samples_in_memory(tmp_path, caplog):
    """The spill folder's place is taken by a file: the overflow stays in memory (said in the
    log) and, once the database is back, every sample is stored once, in order."""
    from diag_plugin.live.writer import HistorianWriter
    from historian.store import Historian

    db = tmp_path / "h.db"
    url = f"sqlite:///{db}"
    Historian(url).close()
    (tmp_path / "taken").write_text("not a folder")
    t0 = pd.Timestamp("2026-03-01T00:00:00Z")
    n = 40

    async def main() -> None:
        w = HistorianWriter(
            url,
            ["A", "B"],
            spill_dir=tmp_path / "taken" / "spill",
            flush_every=50,
            cycle=0.01,
            memory_rows=16,
            busy_timeout=0.1,
        )
        lock = Locker(db)
        try:
            await w.start()
            for i in range(n):
                w.put(t0 + pd.Timedelta(seconds=i), np.array([i, i + 0.5]), np.zeros(2, np.uint8))
                await asyncio.sleep(0.01)
            assert await until(lambda: "cannot spill" in caplog.text)
        finally:
            lock.release()
        assert await until(lambda: not w.degraded and w.backlog == 0)
        await w.close()
        assert w.stats.spilled == 0 and w.stats.stored == 2 * n

    asyncio.run(main())
    with Historian(url) as h:
        a, b = h.read_samples("A"), h.read_samples("B")
    assert a.tolist() == [float(i) for i in range(n)]
    assert b.tolist() == [i + 0.5 for i in range(n)] and b.index.is_unique


def test_blocks_are_as_large_as_chunk_rows_allows_and_counted(tmp_path, caplog):
    """One tag, ``chunk_rows=10``: 25 cycles go in three transactions (10, 10, 5 samples),
    and the writer's figures say so; times keep their microseconds exactly."""
    from diag_plugin.live.writer import HistorianWriter
    from historian.store import Historian

    url = f"sqlite:///{tmp_path / 'h.db'}"
    t0 = pd.Timestamp("2026-03-01T00:00:00.123457Z")  # not a float's multiple of 256 ns

    async def main():
        w = HistorianWriter(
            url, ["A"], spill_dir=tmp_path / "spill", flush_every=25, cycle=0.01, chunk_rows=10
        )
        await w.start()
        for i in range(25):
            w.put(t0 + pd.Timedelta(seconds=i), np.array([float(i)]), np.zeros(1, np.uint8))
        assert await until(lambda: w.backlog == 0 and w.stats.stored == 25)
        await w.close()
        return w.stats

    began = time.monotonic()
    stats = asyncio.run(main())
    took = time.monotonic() - began
    assert (stats.writes, stats.stored, stats.failures, stats.spilled) == (3, 25, 0, 0)
    assert 0 < stats.max_write_s <= took and "a write took" not in caplog.text
    with Historian(url) as h:
        a = h.read_samples("A")
    assert a.tolist() == [float(i) for i in range(25)]
    assert list(a.index) == [t0 + pd.Timedelta(seconds=i) for i in range(25)]


def test_a_source_time_finer_than_a_microsecond_is_stored_as_write_samples_stores_it(tmp_path):
    """OPC UA source times count 100 ns: the live writer puts such a sample on the same µs
    as :meth:`Historian.write_samples` (the importer's path) does, so the two never disagree
    about one sample's time."""
    from diag_plugin.live.writer import HistorianWriter
    from historian.store import Historian

    url = f"sqlite:///{tmp_path / 'h.db'}"
    ts = [
        pd.Timestamp("2026-03-01T00:00:00Z") + pd.Timedelta(nanoseconds=100 * k)
        for k in range(1, 40)
    ]

    async def main() -> None:
        w = HistorianWriter(url, ["LIVE"], spill_dir=tmp_path / "spill", flush_every=1)
        await w.start()
        for i, t in enumerate(ts):
            w.put(t + pd.Timedelta(seconds=i), np.array([1.0]), np.zeros(1, np.uint8))
        assert await until(lambda: w.stats.stored == len(ts))
        await w.close()

    asyncio.run(main())
    with Historian(url) as h:
        h.write_samples(
            pd.DataFrame(
                {"BATCH": 1.0}, index=[t + pd.Timedelta(seconds=i) for i, t in enumerate(ts)]
            )
        )
        assert list(h.read_samples("LIVE").index) == list(h.read_samples("BATCH").index)


def test_a_spill_segment_gone_before_it_was_read_does_not_stop_the_writer(tmp_path):
    """A segment an earlier run left is counted at start, then removed by hand before the
    writer reads it: the writer notices there is nothing to replay and goes on storing."""
    from diag_plugin.live.writer import HistorianWriter
    from historian.spool import Block, Spool
    from historian.store import Historian

    url = f"sqlite:///{tmp_path / 'h.db'}"
    spill = tmp_path / "spill"
    old = Spool(spill).write(
        Block(["A"], np.array([0], np.int64), np.zeros((1, 1)), np.zeros((1, 1), np.uint8), [])
    )
    t0 = pd.Timestamp("2026-03-01T00:00:00Z")

    async def main() -> None:
        w = HistorianWriter(url, ["A"], spill_dir=spill, flush_every=5, cycle=0.01)
        await w.start()
        old.unlink()  # before the writer's task ran at all
        await asyncio.sleep(0.2)  # it looks for the segment and finds none
        for i in range(5):
            w.put(t0 + pd.Timedelta(seconds=i), np.array([float(i)]), np.zeros(1, np.uint8))
        assert await until(lambda: w.stats.stored == 5, timeout=20)
        await w.close()

    asyncio.run(main())
    with Historian(url) as h:
        assert h.read_samples("A").tolist() == [0.0, 1.0, 2.0, 3.0, 4.0]


def test_a_write_is_stalled_after_three_flushes_but_never_under_5_s(tmp_path):
    """The default ``stall_after`` follows the loop: three flush intervals, at least 5 s."""
    from diag_plugin.live.writer import HistorianWriter

    def stall(flush_every: int, cycle: float) -> float:
        url = f"sqlite:///{tmp_path / 'h.db'}"
        w = HistorianWriter(url, ["A"], spill_dir=tmp_path, flush_every=flush_every, cycle=cycle)
        asyncio.run(w.close())
        return w.stall_after

    assert stall(1, 0.1) == 5.0
    assert stall(20, 0.05) == 5.0
    assert stall(20, 1.0) == 60.0
    assert stall(5, 60.0) == 900.0


def test_closing_twice_while_the_historian_is_away_spills_each_sample_once(tmp_path):
    from diag_plugin.live.writer import HistorianWriter
    from historian.spool import Spool
    from historian.store import Historian

    db = tmp_path / "h.db"
    url = f"sqlite:///{db}"
    Historian(url).close()
    spill = tmp_path / "spill"
    told: list[str] = []
    t0 = pd.Timestamp("2026-03-01T00:00:00Z")

    async def main() -> HistorianWriter:
        w = HistorianWriter(
            url,
            ["A", "B"],
            spill_dir=spill,
            flush_every=5,
            cycle=0.01,
            busy_timeout=0.1,
            notify=lambda d, text: told.append(text),
        )
        lock = Locker(db)
        try:
            await w.start()
            for i in range(12):
                w.put(t0 + pd.Timedelta(seconds=i), np.array([i, -i]), np.zeros(2, np.uint8))
                await asyncio.sleep(0.01)
            assert await until(lambda: w.degraded)
            await w.close(timeout=1.0)
            await w.close(timeout=1.0)  # a second close (a caller's finally) adds nothing
        finally:
            lock.release()
        return w

    w = asyncio.run(main())
    assert Spool(spill).rows() == 12 * 2 == w.stats.spilled
    assert sum("historian away at exit" in t for t in told) >= 1
    spool = Spool(spill)
    blocks = [spool.read(p) for p in spool.segments()]
    ts = np.concatenate([b.ts for b in blocks])
    assert len(ts) == len(set(ts.tolist())) == 12


def _spilling_writer(tmp_path):
    """A writer over a fresh SQLite historian whose memory holds 4 cycles of two tags, so a
    locked database spills at once; and its spill folder."""
    from diag_plugin.live.writer import HistorianWriter
    from historian.store import Historian

    url = f"sqlite:///{tmp_path / 'h.db'}"
    Historian(url).close()
    spill = tmp_path / "spill"
    w = HistorianWriter(
        url, ["A", "B"], spill_dir=spill, flush_every=5, cycle=0.01, memory_rows=8,
        busy_timeout=0.1,
    )  # fmt: skip
    return w, spill


def _put(w, i: int) -> None:
    t0 = pd.Timestamp("2026-03-01T00:00:00Z")
    w.put(t0 + pd.Timedelta(seconds=i), np.array([i, -i]), np.zeros(2, np.uint8))


def _spilled_once_and_no_journal(w, spill, n: int) -> None:
    """Every one of the ``n`` cycles put is in the spill folder once, counted as spilled,
    and the clean stop left no journal file."""
    from historian.spool import Spool

    spool = Spool(spill)
    ts = np.concatenate([spool.read(p).ts for p in spool.segments()])
    assert len(ts) == len(set(ts.tolist())) == n
    assert spool.rows() == 2 * n == w.stats.spilled
    assert not list(spill.glob("journal-*.bin")), sorted(p.name for p in spill.iterdir())


def test_a_close_that_cancels_a_spill_half_way_leaves_it_spilled_and_no_journal(tmp_path):
    """close() out of time cancels the writer's task; if the task is inside a spill's write
    then (the database locked, memory full), the thread finishes the segment and close()
    releases its cycles: every sample spilled exactly once and the journal deleted, so the
    next start has nothing to replay twice (the flaky test_live_hardened assertion)."""
    import threading

    entered, go = threading.Event(), threading.Event()
    w, spill = _spilling_writer(tmp_path)
    real = w.spool.write

    def held_write(block):  # the real write, held until the cancel has happened
        entered.set()
        go.wait(10)
        return real(block)

    async def main() -> int:
        w.spool.write = held_write
        lock = Locker(tmp_path / "h.db")
        try:
            await w.start()
            i = 0
            while not entered.is_set() and i < 200:
                _put(w, i)
                i += 1
                await asyncio.sleep(0.01)
            assert entered.is_set(), "no spill began"
            w.spool.write = real  # close()'s own spill of what is left writes at once
            closing = asyncio.ensure_future(w.close(timeout=0.2))
            await asyncio.sleep(0.5)  # the task is cancelled while the thread is held
            go.set()
            await closing
        finally:
            go.set()
            lock.release()
        return i

    n = asyncio.run(main())
    _spilled_once_and_no_journal(w, spill, n)


def test_a_spill_slower_than_the_retry_wait_is_not_cut_off_by_it(tmp_path):
    """While the database is locked the writer waits between retries and spills memory
    meanwhile; a spill whose write outlasts that wait was cancelled by the wait's timeout
    (the block written but its cycles never released: journal files left at a clean stop,
    one run in three of test_live_hardened's locked exit). Every spill write here takes
    0.7 s, longer than the first waits (0.5 s, 1 s)."""
    import time as _time

    n = 60
    w, spill = _spilling_writer(tmp_path)
    real = w.spool.write

    def slow_write(block):  # the real write, slower than a retry wait
        _time.sleep(0.7)
        return real(block)

    async def main() -> None:
        w.spool.write = slow_write
        lock = Locker(tmp_path / "h.db")
        try:
            await w.start()
            for i in range(n):
                _put(w, i)
                await asyncio.sleep(0.05)
            await asyncio.sleep(2.0)
            w.spool.write = real
            await w.close(timeout=5.0)
        finally:
            lock.release()

    asyncio.run(main())
    _spilled_once_and_no_journal(w, spill, n)
