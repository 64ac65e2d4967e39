"""The live writer rolls closed months to the cold store by itself (issue 37).

Real SQLite and PostgreSQL, a real writer fed by ``put``; the time is a clock handed to the
writer (``clock=``), so a month closes when the test says. After the first store of a new
month the writer rolls the closed month in a thread of its own: the month leaves the table,
the current month stays, reads are the same; stores go on while a big month is rolled; a roll
that fails is logged, an event, and tried again an hour later; a stop does not wait for a
roll longer than its close timeout."""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import sqlalchemy as sa

from diag_plugin.live.writer import HistorianWriter
from historian import schema
from historian.livestore import LiveStore
from historian.store import Historian

TAGS = [f"T{i:02d}" for i in range(6)]
FEB = pd.Timestamp("2026-02-27 00:00:00", tz="UTC")
MAR = pd.Timestamp("2026-03-01 00:00:00", tz="UTC")


class Clock:
    """The writer's idea of now, moved by the test."""

    def __init__(self, now: pd.Timestamp) -> None:
        self.now = now

    def __call__(self) -> pd.Timestamp:
        return self.now


def value(tag: str, t: pd.Timestamp) -> float:
    return int(tag[1:]) * 1e6 + (t - FEB).total_seconds()


def put_cycles(w: HistorianWriter, start: pd.Timestamp, n: int, step: str = "60s") -> None:
    for k in range(n):
        t = start + k * pd.Timedelta(step)
        w.put(t, np.array([value(tag, t) for tag in w.tags]), np.zeros(len(w.tags), np.uint8))


async def until(cond, timeout: float = 60.0) -> None:
    end = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < end, "timed out"
        await asyncio.sleep(0.02)


async def drained(w: HistorianWriter) -> None:
    """Everything put is stored, and no roll is running."""
    w._wake.set()
    await until(lambda: not w.backlog and not w._mem)
    await until(lambda: w._roll_task is None or w._roll_task.done())


def table_months(url: str) -> dict[str, int]:
    """Rows of the samples table per month."""
    s = schema.samples
    with Historian(url) as h, h.engine.connect() as c:
        ts = np.array([r[0] for r in c.execute(sa.select(s.c.ts))], np.int64)
    months = pd.to_datetime(ts, unit="us", utc=True).strftime("%Y-%m")
    return dict(pd.Series(months).value_counts()) if len(ts) else {}


def reads(url: str) -> dict[str, pd.Series]:
    with Historian(url) as h:
        return {t: h.read_samples(t) for t in TAGS}


def events(url: str) -> list[str]:
    with Historian(url) as h:
        return list(h.events()["message"])


@pytest.fixture(params=["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def url(request, tmp_path):
    """A fresh database; PostgreSQL with a cold folder recorded (as the first ``diag
    historian roll --cold-dir`` records it)."""
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'plant.db'}"
        return
    u = request.getfixturevalue("pg_url")
    with Historian(u, cold_dir=tmp_path / "cold") as h:
        h._record_cold_dir()
    yield u


def writer(url: str, tmp_path: Path, clock: Clock, **kw) -> HistorianWriter:
    kw = {"flush_every": 5, "cycle": 0.02, "busy_timeout": 0.5, **kw}
    return HistorianWriter(url, TAGS, spill_dir=tmp_path / "spill", clock=clock, **kw)


def test_first_store_of_a_new_month_rolls_the_closed_month(url, tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="diag_plugin.live.writer")
    clock = Clock(FEB)

    async def run():
        w = writer(url, tmp_path, clock)
        await w.start()
        put_cycles(w, FEB, 300)  # Feb 27, the current month: nothing closed
        await drained(w)
        assert w.rolled == [] and table_months(url) == {"2026-02": 300 * len(TAGS)}
        before = reads(url)
        clock.now = MAR + pd.Timedelta("30s")
        put_cycles(w, MAR, 50)
        await drained(w)
        await w.close()
        return w, before

    w, before = asyncio.run(run())
    assert [m for m, _, _ in w.rolled] == ["2026-02"]
    assert w.rolled[0][1] == 300 * len(TAGS)
    assert table_months(url) == {"2026-03": 50 * len(TAGS)}  # the current month stays
    with Historian(url) as h:
        assert h.cold_months() == ["2026-02"]
        assert h.integrity_check() == [] and h.cold_orphans() == []
    after = reads(url)
    for tag in TAGS:
        pd.testing.assert_series_equal(after[tag][after[tag].index < MAR], before[tag])
        assert len(after[tag]) == 350
        np.testing.assert_array_equal(
            after[tag].to_numpy(), [value(tag, t) for t in after[tag].index]
        )
    assert any("rolled 2026-02 to the cold store: 1800 samples" in m for m in events(url))
    assert "rolled 2026-02 to the cold store" in caplog.text


def test_the_month_the_cycles_go_into_is_never_rolled(tmp_path):
    """A feed writing into the past (the embedded simulation, a replay): the month its cycles
    go into stays in the table, though the clock has it closed; the month before it rolls."""
    url = f"sqlite:///{tmp_path / 'plant.db'}"
    clock = Clock(pd.Timestamp("2026-11-29 12:00", tz="UTC"))

    async def run():
        w = writer(url, tmp_path, clock)
        await w.start()
        put_cycles(w, FEB, 20)  # February, closed by the clock, and the cycles' month
        await drained(w)
        assert w.rolled == [] and table_months(url) == {"2026-02": 120}
        put_cycles(w, MAR, 21)  # the feed moves on to March: February rolls
        await drained(w)
        await until(lambda: w.rolled)
        await w.close()
        return w

    w = asyncio.run(run())
    assert [m for m, _, _ in w.rolled] == ["2026-02"]
    assert table_months(url) == {"2026-03": 126}
    with Historian(url) as h:
        assert h.cold_months() == ["2026-02"] and h.integrity_check() == []


def test_switched_off_it_keeps_every_month(tmp_path):
    url = f"sqlite:///{tmp_path / 'plant.db'}"
    clock = Clock(FEB)

    async def run():
        w = writer(url, tmp_path, clock, roll_months=False)
        await w.start()
        put_cycles(w, FEB, 20)
        await drained(w)
        clock.now = MAR + pd.Timedelta("30s")
        put_cycles(w, MAR, 20)
        await drained(w)
        await w.close()
        return w

    w = asyncio.run(run())
    assert w.rolled == [] and w._roll_thread is None
    assert table_months(url) == {"2026-02": 120, "2026-03": 120}


def test_postgres_without_cold_folder_says_so_once(pg_url, tmp_path, caplog):
    clock = Clock(MAR)

    async def run():
        w = writer(pg_url, tmp_path, clock, roll_every=60)
        await w.start()
        put_cycles(w, FEB, 20)
        await drained(w)
        clock.now = pd.Timestamp("2026-04-01 00:00:30", tz="UTC")
        put_cycles(w, MAR, 20)
        await drained(w)
        await w.close()
        return w

    w = asyncio.run(run())
    assert w.rolled == []
    assert table_months(pg_url) == {"2026-02": 120, "2026-03": 120}
    assert caplog.text.count("no cold folder recorded") == 1


def test_failing_roll_is_logged_and_retried_an_hour_later(url, tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="diag_plugin.live.writer")
    with Historian(url) as h:
        cold = h.cold_dir
    cold.parent.mkdir(parents=True, exist_ok=True)
    cold.write_text("not a folder")  # the month files cannot be written
    clock = Clock(MAR + pd.Timedelta("10s"))

    async def run():
        w = writer(url, tmp_path, clock)
        await w.start()
        put_cycles(w, FEB, 30)
        put_cycles(w, MAR, 10)
        await drained(w)
        assert w.rolled == [] and w._roll_pending
        assert "rolling closed months failed" in caplog.text
        cold.unlink()
        clock.now += pd.Timedelta("30min")  # not yet an hour: no new try
        put_cycles(w, MAR + pd.Timedelta("10min"), 10)
        await drained(w)
        assert w.rolled == []
        clock.now += pd.Timedelta("31min")
        put_cycles(w, MAR + pd.Timedelta("20min"), 10)
        await drained(w)
        await w.close()
        return w

    w = asyncio.run(run())
    assert [m for m, _, _ in w.rolled] == ["2026-02"]
    assert table_months(url) == {"2026-03": 30 * len(TAGS)}
    msgs = events(url)
    assert sum("rolling closed months failed" in m for m in msgs) == 1
    assert any("rolled 2026-02" in m for m in msgs)
    with Historian(url) as h:
        assert h.cold_orphans() == []


BIG_TAGS = [f"B{i:03d}" for i in range(100)]


def seed_big_month(url: str, days: int = 28, step_s: int = 120) -> int:
    """February 2026 for BIG_TAGS every ``step_s`` seconds, through the live bulk path."""
    ts0 = int(pd.Timestamp("2026-02-01", tz="UTC").value // 1000)
    n = days * 86_400 // step_s
    ts = ts0 + np.arange(n, dtype=np.int64) * step_s * 1_000_000
    store = LiveStore(url)
    try:
        for i in range(0, n, 2_000):
            k = len(ts[i : i + 2_000])
            v = np.random.default_rng(i).normal(size=(k, len(BIG_TAGS)))
            store.write_block(BIG_TAGS, ts[i : i + 2_000], v, np.zeros(v.shape, np.uint8))
    finally:
        store.close()
    return n * len(BIG_TAGS)


def test_stores_go_on_while_a_big_month_rolls(url, tmp_path):
    samples = seed_big_month(url)
    clock = Clock(MAR + pd.Timedelta("10s"))
    store_times: list[float] = []
    put_s: list[float] = []

    async def run():
        w = writer(url, tmp_path, clock)
        await w.start()
        put_cycles(w, MAR, 5)
        await until(lambda: w._roll_task is not None)  # the first store started the roll
        roll = w._roll_task
        k, stored = 5, w.stats.stored
        while not roll.done():
            t0 = time.perf_counter()
            put_cycles(w, MAR + k * pd.Timedelta("60s"), 1)
            put_s.append(time.perf_counter() - t0)
            k += 1
            if w.stats.stored != stored:
                stored = w.stats.stored
                store_times.append(time.monotonic())
            await asyncio.sleep(0.02)
        await drained(w)
        await w.close()
        return w, k

    w, k = asyncio.run(run())
    assert [m for m, _, _ in w.rolled] == ["2026-02"] and w.rolled[0][1] == samples
    roll_s = w.rolled[0][2]

    # (2.02 M samples: 0.9-2.6 s on SQLite here, 15 s on PostgreSQL; a store every ~0.1 s,
    # so at least 0.6 s of roll leaves room for the five stores asserted below)
    assert roll_s > 0.6, "the month is too small to show anything"
    # stores went on during the roll: a block every ~0.1 s, gaps no longer than a slow
    # database makes them (the lock waited for at most busy_timeout, then a retry); at least
    # three (a clean clone's make test at a load of 14 saw four in a short roll; a store
    # blocked by the roll sees one at most)
    assert len(store_times) >= 3, store_times
    gaps = np.diff(store_times)
    assert gaps.max() < 5.0, gaps.max()
    assert max(put_s) < 0.5
    assert table_months(url) == {"2026-03": k * len(TAGS)}


def test_stop_does_not_wait_for_a_roll(url, tmp_path):
    seed_big_month(url)
    clock = Clock(MAR + pd.Timedelta("10s"))

    async def run():
        w = writer(url, tmp_path, clock)
        await w.start()
        put_cycles(w, MAR, 5)
        await until(lambda: w._roll_thread is not None)
        thread: threading.Thread = w._roll_thread._t
        await asyncio.sleep(0.3)
        assert not w._roll_task.done()
        t0 = time.monotonic()
        await w.close(timeout=0.5)
        return time.monotonic() - t0, thread.is_alive(), thread

    took, alive, thread = asyncio.run(run())
    assert took < 2.0, took
    assert alive  # close returned while the roll went on
    thread.join(120)  # the roll ends on its own (one month)
    assert not thread.is_alive()
    with Historian(url) as h:
        assert h.integrity_check() == [] and h.cold_orphans() == []
        assert len(h.read_samples(BIG_TAGS[7])) == 28 * 720
        assert len(h.read_samples(TAGS[0])) == 5
