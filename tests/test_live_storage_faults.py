"""Storage failures under the live writer (issue 35, item 1): a tag insert rolled back by a
full disk must not leave samples filed under its ids.

Two real faults: a database on a 2 MB tmpfs filled to the last byte mid-run (root only), and
a commit refused at the SQLAlchemy layer (an event hook raising SQLite's own "database or
disk is full"), which every machine can run. After each, a restart with the register map in
the reverse order must find every tag's history holding its own values, and the check must
find no sample without its tag."""

from __future__ import annotations

import asyncio
import contextlib
import errno
import os
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import sqlalchemy as sa
from sqlalchemy import event
from sqlalchemy.engine import Engine

from diag_plugin.live.writer import HistorianWriter
from historian.livestore import LiveStore
from historian.store import Historian
from tests.helpers import require

TAGS = [f"T{i:02d}" for i in range(8)]
T0 = pd.Timestamp("2026-03-01 00:00:00", tz="UTC")


def value(tag: str, k: int) -> float:
    """What tag ``tag`` reads at cycle ``k``: its number in the thousands, so a sample filed
    under another tag shows at once."""
    return int(tag[1:]) * 1000.0 + k


async def run_cycles(url: str, spill: Path, tags: list[str], cycles: range, during=None):
    """Put ``cycles`` through a real writer (a block every 5 cycles); ``during(k, w)`` runs
    after cycle k's put; then close (stores or spills what is left)."""
    w = HistorianWriter(url, tags, spill_dir=spill, flush_every=5, cycle=0.02, busy_timeout=0.5)
    told: list[str] = []
    w.notify = lambda degraded, text: told.append(text)
    await w.start()
    for k in cycles:
        w.put(
            T0 + pd.Timedelta(seconds=k),
            np.array([value(t, k) for t in tags]),
            np.zeros(len(tags), np.uint8),
        )
        if during is not None:
            await during(k, w)
        await asyncio.sleep(0.02)
    for _ in range(400):  # let the backlog drain before closing
        if not w.backlog and not w.degraded:
            break
        await asyncio.sleep(0.05)
    await w.close(timeout=10)
    return w, told


def own_values(url: str, n_cycles: int) -> None:
    """Every tag holds its own value at every cycle, and the check finds no orphan."""
    with Historian(url) as h:
        assert h.integrity_check() == []
        assert h.orphan_samples() == {}
        assert sorted(h.tags()["name"]) == sorted(TAGS)
        for t in TAGS:
            s = h.read_samples(t)
            assert len(s) == n_cycles, t
            k = ((s.index - T0).total_seconds()).astype(int)
            np.testing.assert_array_equal(s.to_numpy(), [value(t, int(i)) for i in k])


class RefuseCommits:
    """Every commit of a transaction that inserted into ``tags`` fails as SQLite fails on a
    full disk, while ``on``; the samples' bulk path (ADBC, no SQLAlchemy) is untouched — as
    when the disk got room again between the two writes."""

    def __init__(self) -> None:
        self.on = False
        self.refused = 0

    def before(self, conn, cursor, statement, params, context, many):
        if statement.lstrip().upper().startswith("INSERT INTO TAGS"):
            conn.info["tags_insert"] = True

    def commit(self, conn):
        if conn.info.pop("tags_insert", False) and self.on:
            self.refused += 1
            raise sa.exc.OperationalError("COMMIT", {}, Exception("database or disk is full"))

    def rollback(self, conn):
        conn.info.pop("tags_insert", None)

    def __enter__(self):
        event.listen(Engine, "before_cursor_execute", self.before)
        event.listen(Engine, "commit", self.commit)
        event.listen(Engine, "rollback", self.rollback)
        return self

    def __exit__(self, *exc):
        event.remove(Engine, "before_cursor_execute", self.before)
        event.remove(Engine, "commit", self.commit)
        event.remove(Engine, "rollback", self.rollback)


def test_rolled_back_tag_insert_files_no_sample_under_its_ids(tmp_path):
    url = f"sqlite:///{tmp_path / 'h.db'}"
    spill = tmp_path / "h.db.spill"
    with RefuseCommits() as fault:

        async def during(k, w):
            # the first two blocks' tag inserts are rolled back — and, on a loaded machine
            # whose writer thread has not reached its first block by cycle 12, every one
            # until a first is refused (a window of cycles alone let the fault pass unseen)
            fault.on = k < 12 or fault.refused == 0

        w, told = asyncio.run(run_cycles(url, spill, TAGS, range(0, 30), during))
    assert fault.refused >= 1
    assert w.stats.failures >= 1 and w.stats.misfiled_tags == 0
    assert any("none lost (every tag checked)" in t for t in told), told
    # a restart with the register map in the reverse order
    asyncio.run(run_cycles(url, spill, TAGS[::-1], range(30, 50)))
    own_values(url, 50)


def test_check_counts_samples_whose_tag_does_not_exist(tmp_path):
    """The check can fail: samples written under an id no tag has are counted and named."""
    url = f"sqlite:///{tmp_path / 'h.db'}"
    with Historian(url) as h:
        h.write_samples(pd.DataFrame({"A": [1.0, 2.0]}, index=[T0, T0 + pd.Timedelta("1s")]))
        h._bulk.insert(
            np.array([77, 77, 78]), np.array([1, 2, 3]), np.ones(3), np.zeros(3), "ignore"
        )
        assert h.orphan_samples() == {77: 2, 78: 1}
        problems = h.integrity_check()
    assert any("3 samples under 2 tag ids" in p and "77, 78" in p for p in problems), problems


def test_writer_says_when_tags_it_wrote_under_are_gone(tmp_path):
    """The writer's "none lost" is checked: a tag whose row vanished under it is named."""
    url = f"sqlite:///{tmp_path / 'h.db'}"
    store = LiveStore(url)
    store.write_block(["A", "B"], np.array([1, 2]), np.ones((2, 2)), np.zeros((2, 2)))
    assert store.missing_tags() == []
    with store.open().engine.begin() as c:
        c.execute(sa.text("DELETE FROM tags WHERE name = 'B'"))
    assert store.missing_tags() == ["B"]
    assert store._ids == {}  # dropped: the next write creates B again
    store.write_block(["A", "B"], np.array([3]), np.ones((1, 2)), np.zeros((1, 2)))
    assert store.missing_tags() == []
    store.close()


@contextlib.contextmanager
def tmpfs(path: Path, size: str):
    path.mkdir()
    r = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
        capture_output=True,
        text=True,
    )
    require("a tmpfs mount", r.returncode == 0, "run as root (mount -t tmpfs)")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], check=False)


def fill(folder: Path) -> Path:
    """Fill the file system of ``folder`` to the last byte with a ballast file."""
    ballast = folder / "ballast"
    with open(ballast, "wb", buffering=0) as f:
        for size in (1 << 16, 512, 1):
            try:
                while True:
                    f.write(b"\0" * size)
            except OSError as exc:
                assert exc.errno == errno.ENOSPC
    with contextlib.suppress(OSError):
        os.sync()
    return ballast


@pytest.mark.skipif(os.geteuid() != 0, reason="mounting a tmpfs needs root")
def test_full_disk_mid_run_then_restart_in_another_order(tmp_path):
    with tmpfs(tmp_path / "disk", "2m") as disk:
        url = f"sqlite:///{disk / 'h.db'}"
        # the schema while there is room, and a reader that keeps the WAL file open (as a
        # running plant's readers do): the next commits must grow it on the full disk
        keeper = Historian(url)
        keeper.record_event(T0, "test", message="disk still has room")
        spill = tmp_path / "spill"  # the spill elsewhere: only the database's disk is full
        state = {"ballast": None}

        async def during(k, w):
            if k == 0:
                state["ballast"] = fill(disk)  # full before the first block (tags created)
            elif k == 15:
                assert w.stats.failures >= 1  # the full disk was felt
                state["ballast"].unlink()

        try:
            w, told = asyncio.run(run_cycles(url, spill, TAGS, range(0, 30), during))
        finally:
            keeper.close()
        assert w.stats.failures >= 1 and w.stats.misfiled_tags == 0
        assert any("none lost (every tag checked)" in t for t in told), told
        asyncio.run(run_cycles(url, spill, TAGS[::-1], range(30, 50)))
        own_values(url, 50)
