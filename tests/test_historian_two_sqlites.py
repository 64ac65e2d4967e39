"""Two SQLite libraries in one process: the stdlib's (SQLAlchemy: tags, events, months) and
the copy bundled in the ADBC driver (samples). POSIX locks of one copy are invisible to the
other ("How To Corrupt An SQLite Database File" §2.2.1), so the historian must keep them
from (a) holding write transactions at once and (b) dropping each other's locks by closing
a file. Real files, real threads, a real second process; the live writer's own code paths
(``LiveStore.tag_ids``) are paused mid-transaction by a SQLAlchemy event listener."""

from __future__ import annotations

import subprocess
import sys
import threading

import numpy as np
import pandas as pd
import pytest
from sqlalchemy import event

from historian.livestore import LiveStore
from historian.store import Historian

#: seconds a thread is given to get past a point it must not pass while another holds
#: the write: long enough to pass it on a loaded machine when nothing stops it
PASS_S = 3.0


def _samples(tag: str, n: int, start: str = "2024-01-01") -> pd.DataFrame:
    idx = pd.date_range(start, periods=n, freq="10s", tz="UTC")
    return pd.DataFrame({tag: np.arange(n, dtype=float)}, index=idx)


class _Paused:
    """Pauses the first INSERT into ``tags`` on ``engine`` (inside its transaction) until
    :meth:`go`; :attr:`inside` is set once the transaction holds the insert."""

    def __init__(self, engine):
        self.inside, self._go, self._done = threading.Event(), threading.Event(), False
        #: set when the paused transaction commits (before its COMMIT runs: a write seen
        #: after it is after the transaction, however late its thread returns)
        self.committed = threading.Event()
        self._conn = None
        event.listen(engine, "after_cursor_execute", self._after)
        event.listen(engine, "commit", self._commit)

    def _after(self, conn, cursor, statement, params, context, executemany) -> None:
        if not self._done and statement.lstrip().upper().startswith("INSERT INTO TAGS"):
            self._done, self._conn = True, conn
            self.inside.set()
            self._go.wait(60)

    def _commit(self, conn) -> None:
        if self._conn is not None and conn is self._conn:
            self.committed.set()

    def go(self) -> None:
        self._go.set()  # the listener stays (a no-op now): removing it inside its call fails


def _tags_tx(store: LiveStore, names: list[str], out: dict) -> threading.Thread:
    def run():
        try:
            out["ids"] = store.tag_ids(names)
        except Exception as exc:  # noqa: BLE001 - reported by the test
            out["error"] = exc
        out["committed"] = True

    t = threading.Thread(target=run)
    t.start()
    return t


def test_sample_write_waits_for_a_tag_transaction_of_the_other_library(tmp_path):
    """(a) The live writer's tag transaction (stdlib) is open; samples written through the
    same historian from another thread (ADBC) must wait for it: not both at once."""
    url = f"sqlite:///{tmp_path / 'h.db'}"
    store = LiveStore(url, busy_timeout=30.0)
    h = store.open()
    h.write_samples(_samples("A", 100))
    paused = _Paused(h.engine)
    out: dict = {}
    t1 = _tags_tx(store, ["N1", "N2"], out)
    assert paused.inside.wait(30)
    seen: dict = {}

    def samples():
        seen["rows"] = h.write_samples(_samples("A", 5000, "2024-02-01"), create_tags=False)
        # the tag transaction's own commit, not its thread's return (which a loaded
        # machine may delay past this line: a race of the test, not of the historian)
        seen["tags_open"] = not paused.committed.is_set()

    t2 = threading.Thread(target=samples)
    t2.start()
    t2.join(PASS_S)
    paused.go()
    t1.join(60)
    t2.join(60)
    assert "error" not in out
    assert seen["rows"] == 5000
    assert not seen["tags_open"], "an ADBC write committed inside the stdlib write transaction"
    assert h.integrity_check() == []
    assert set(h.tags()["name"]) == {"A", "N1", "N2"}
    assert len(h.read_samples("A")) == 5100
    store.close()


_BEGIN = """
import sqlite3, sys
con = sqlite3.connect(sys.argv[1], isolation_level=None, timeout=0)
try:
    con.execute("BEGIN IMMEDIATE")
except sqlite3.OperationalError as exc:
    print("busy", exc)
else:
    con.execute("INSERT INTO settings (key, value) VALUES ('other', 'process')")
    con.execute("COMMIT")
    print("wrote")
"""


def test_closing_another_historian_keeps_the_write_lock_of_an_open_transaction(tmp_path):
    """(b) The live writer's tag transaction (stdlib) is open; another historian of the
    process on the same file (a catch-up reader: ADBC reads) closes. A second process must
    still find the database locked, and the file must stay sound."""
    db = tmp_path / "h.db"
    url = f"sqlite:///{db}"
    store = LiveStore(url, busy_timeout=30.0)
    h = store.open()
    h.write_samples(_samples("A", 100))
    store.close()
    store = LiveStore(url, busy_timeout=30.0)
    h = store.open()  # the writer, before its first block: no ADBC connection yet
    reader = Historian(url)
    assert len(reader.window(["A"], period="10s")) == 100  # ADBC reads
    paused = _Paused(h.engine)
    out: dict = {}
    t1 = _tags_tx(store, ["N1"], out)
    assert paused.inside.wait(30)
    closer = threading.Thread(target=reader.close)
    closer.start()
    closer.join(PASS_S)
    other = subprocess.run(
        [sys.executable, "-c", _BEGIN, str(db)], capture_output=True, text=True, timeout=60
    )
    paused.go()
    t1.join(60)
    closer.join(60)
    assert "error" not in out
    assert other.stdout.startswith("busy"), other.stdout + other.stderr
    assert (db.parent / "h.db-wal").exists() or not closer.is_alive()
    assert h.integrity_check() == []
    assert set(h.tags()["name"]) == {"A", "N1"}
    store.close()
    with Historian(url) as again:
        assert again.integrity_check() == []
        assert set(again.tags()["name"]) == {"A", "N1"}
        assert len(again.read_samples("A")) == 100


def test_a_write_of_one_library_inside_one_of_the_other_is_refused(tmp_path):
    """A write of one library opened inside one of the other in the same thread would hold
    two write transactions at once: refused, and the outer one rolled back."""
    url = f"sqlite:///{tmp_path / 'h.db'}"
    with Historian(url) as h:
        h.write_samples(_samples("A", 10))
        with pytest.raises(RuntimeError, match="inside another"):
            with h._writing() as c:
                c.exec_driver_sql("INSERT INTO settings (key, value) VALUES ('k', 'v')")
                h.write_samples(_samples("A", 10, "2024-03-01"), create_tags=False)
        assert h.integrity_check() == []
        assert len(h.read_samples("A")) == 10
        with h.engine.connect() as c:
            assert c.exec_driver_sql("SELECT count(*) FROM settings").scalar() == 0


def test_keepers_close_with_the_last_historian_of_the_file(tmp_path):
    """The keeper connections live while a historian of the process has the file open and
    close with the last: the log is then checkpointed and removed, as SQLite does."""
    db = tmp_path / "h.db"
    url = f"sqlite:///{db}"
    a, b = Historian(url), Historian(url)
    a.write_samples(_samples("A", 1000))
    a.close()
    assert (tmp_path / "h.db-wal").exists()  # b and the keepers still have it open
    assert len(b.read_samples("A")) == 1000
    b.close()
    b.close()  # a second close is a no-op
    assert not (tmp_path / "h.db-wal").exists()
    with Historian(url) as c:
        assert len(c.read_samples("A")) == 1000


@pytest.mark.skipif(not hasattr(__import__("os"), "fork"), reason="needs fork")
def test_a_forked_child_opens_the_file_while_the_parent_holds_its_lock(tmp_path):
    """A child forked while a thread of the parent holds the file's write lock starts with
    a lock of its own: it writes (after the parent's write commits, SQLite's own lock)."""
    import multiprocessing

    url = f"sqlite:///{tmp_path / 'h.db'}"
    with Historian(url) as h:
        h.write_samples(_samples("A", 10))
        ctx = multiprocessing.get_context("fork")
        with h._bulk.file.writing():
            child = ctx.Process(target=_child_write, args=(url,))
            child.start()
        child.join(120)
        assert child.exitcode == 0
        assert len(h.read_samples("A")) == 20


def _child_write(url: str) -> None:
    with Historian(url, busy_timeout=60.0) as h:
        h.write_samples(_samples("A", 10, "2024-03-01"), create_tags=False)


# -- (c) checkpoints: one library's checkpoint does not see the other library's readers -----


def _pause_read(h: Historian, tag_id: int, out: dict) -> tuple[threading.Thread, threading.Event]:
    """An ADBC read of a tag (the historian's own read path) in another thread, paused after
    its first batch; returns the thread and the event that lets it read the rest."""
    inside, go = threading.Event(), threading.Event()

    def run():
        try:
            sql = f"SELECT ts, value FROM samples WHERE tag_id = {tag_id} ORDER BY ts"
            with h._bulk.batches(sql) as batches:
                first = batches.read_next_batch()
                inside.set()
                go.wait(60)
                rest = batches.read_all()
            out["values"] = np.concatenate(
                [first.column(1).to_numpy(), rest.column(1).to_numpy(zero_copy_only=False)]
            )
        except Exception as exc:  # noqa: BLE001 - reported by the test
            out["error"] = exc
        finally:
            inside.set()

    t = threading.Thread(target=run)
    t.start()
    assert inside.wait(60)
    return t, go


def test_a_read_of_one_library_keeps_its_snapshot_across_a_checkpoint_of_the_other(
    tmp_path, monkeypatch
):
    """An ADBC read of a tag is open (a training read mid-fetch) while samples are rewritten
    and more than 1,000 log pages are committed, then a metadata commit (stdlib) follows.
    Before the rule, that commit's automatic checkpoint copied the rewritten pages into the
    database file under the open read: it failed ("database disk image is malformed") or
    saw values written after it began. The read must see its snapshot: the old values."""
    from historian import backends

    monkeypatch.setattr(backends, "READ_BATCH_ROWS", 1024)
    url = f"sqlite:///{tmp_path / 'h.db'}"
    h = Historian(url)
    h.write_samples(_samples("A", 20_000) * 0.0)
    h.close()  # the last close checkpoints: the samples are in the database file
    h = Historian(url)
    tag_id = int(h.tags().set_index("name").loc["A", "id"])
    out: dict = {}
    reader, go = _pause_read(h, tag_id, out)
    h.write_samples(_samples("A", 20_000) * 0.0 + 1.0, create_tags=False, policy="update")
    h.write_samples(_samples("B", 1_000_000))  # 20 MB of log: past 1,000 pages of 16 KiB
    h.ensure_tag("C")  # a stdlib commit: its copy checkpointed here
    go.set()
    reader.join(60)
    assert "error" not in out, out.get("error")
    assert len(out["values"]) == 20_000
    assert (out["values"] == 0.0).all(), f"{int((out['values'] != 0).sum())} newer values seen"
    assert (h.read_samples("A") == 1.0).all()
    assert h.integrity_check() == []
    h.close()


@pytest.mark.parametrize("via", ["sqlite3", "sqlalchemy"])
def test_a_metadata_read_keeps_its_snapshot_across_vacuum(tmp_path, via):
    """A read of the tag list is open (paused inside its statement) while ``vacuum`` (ADBC)
    rebuilds the file and checkpoints. Before the rule the checkpoint ran under the read,
    which then read pages of the rebuilt file. The read must finish with every tag, and the
    vacuum wait for it: through the historian's ``sqlite3`` metadata connection
    (``tags()``, :mod:`historian.sqlitemeta`) and through SQLAlchemy's engine alike."""
    url = f"sqlite:///{tmp_path / 'h.db'}"
    h = Historian(url)
    names = [f"T{i:05d}" for i in range(6000)]
    store = LiveStore(url)
    store.tag_ids(names)
    store.close()
    with h._writing() as c:  # free room in the tags' pages: VACUUM moves them around
        c.exec_driver_sql("DELETE FROM tags WHERE id % 2 = 0")
    names = list(h.tags()["name"])
    assert len(names) == 3000
    h.close()  # the last close checkpoints: the tags are in the database file
    h = Historian(url)
    inside, go, out = threading.Event(), threading.Event(), {}

    def pause(*_args):
        if not inside.is_set():
            inside.set()
            go.wait(60)
        return 0

    if via == "sqlite3":
        assert h._meta is not None
        h._meta.rows("SELECT 1")  # its connection opened, then paused inside the next read
        h._meta._conn.set_progress_handler(pause, 1000)

        def read():
            return list(h.tags()["name"])

    else:

        def after(conn, cursor, statement, params, context, executemany):
            if statement.lstrip().upper().startswith("SELECT NAME FROM TAGS"):
                pause()

        event.listen(h.engine, "after_cursor_execute", after)

        def read():
            with h.engine.connect() as c:
                return [n for (n,) in c.exec_driver_sql("SELECT name FROM tags ORDER BY name")]

    def run():
        try:
            out["names"] = read()
        except Exception as exc:  # noqa: BLE001 - reported by the test
            out["error"] = exc

    t = threading.Thread(target=run)
    t.start()
    assert inside.wait(30)
    vac = threading.Thread(target=h.vacuum)
    vac.start()
    vac.join(PASS_S)
    assert vac.is_alive()  # waits for the open read
    go.set()
    t.join(60)
    vac.join(60)
    assert "error" not in out, out.get("error")
    assert out["names"] == names
    assert h.integrity_check() == []
    h.close()


def test_the_log_stays_bounded_under_a_live_writer_and_reads_that_overlap(tmp_path, monkeypatch):
    """A live writer stores blocks while two threads read a tag back to back, so a read is
    open nearly all the time: checkpoints are skipped while one is, then new reads wait for
    the open ones to end (the log past DRAIN_BYTES) and the checkpoint runs. The log stays
    under DRAIN_BYTES plus a block or two, and every read sees the tag whole."""
    from historian import sqlitefile

    monkeypatch.setattr(sqlitefile, "CHECKPOINT_BYTES", 1 << 20)
    monkeypatch.setattr(sqlitefile, "DRAIN_BYTES", 4 << 20)
    db = tmp_path / "h.db"
    url = f"sqlite:///{db}"
    store = LiveStore(url, busy_timeout=30.0)
    h = store.open()
    h.write_samples(_samples("S", 100_000))
    reader = Historian(url)
    stop, reads, bad = threading.Event(), [0], []

    def read():
        while not stop.is_set():
            s = reader.read_samples("S")
            if len(s) != 100_000 or s.iloc[-1] != 99_999.0:
                bad.append(len(s))
            reads[0] += 1

    threads = [threading.Thread(target=read) for _ in range(2)]
    for t in threads:
        t.start()
    tags = [f"L{i}" for i in range(50)]
    wal, ts0 = [], 1_700_000_000_000_000
    for b in range(120):
        ts = ts0 + (np.arange(100) + 100 * b) * 1_000_000
        store.write_block(tags, ts, np.random.default_rng(b).random((100, 50)), np.zeros((100, 50)))
        wal.append((db.parent / "h.db-wal").stat().st_size)
    stop.set()
    for t in threads:
        t.join(60)
    # log bytes of one block (~2 MB)
    block = max(b - a for a, b in zip(wal[:-1], wal[1:], strict=True))
    assert not bad and reads[0] > 10
    assert h._file.checkpoints >= 3
    # without new reads waiting, 1 checkpoint in 120 blocks and a log of 281 MB at the end
    assert max(wal) < (4 << 20) + 4 * block, (max(wal), block)
    assert len(h.read_samples("L0")) == 12_000
    assert h.integrity_check() == []
    reader.close()
    store.close()


def test_the_process_forgets_a_file_when_its_last_historian_closes(tmp_path):
    """The process's entry of a file lives while a historian has it open, no longer."""
    from historian import sqlitefile

    url = f"sqlite:///{tmp_path / 'h.db'}"
    key = str((tmp_path / "h.db").resolve())
    a, b = Historian(url), Historian(url)
    assert sqlitefile._FILES[key] is a._file is b._file
    a.close()
    assert key in sqlitefile._FILES
    b.close()
    assert key not in sqlitefile._FILES
    with Historian(url) as c:
        assert sqlitefile._FILES[key] is c._file is not a._file
        c.write_samples(_samples("A", 10))
    assert key not in sqlitefile._FILES


@pytest.mark.skipif(not hasattr(__import__("os"), "fork"), reason="needs fork")
def test_a_forked_child_cannot_use_a_historian_of_its_parent(tmp_path):
    """SQLite connections must not cross a fork: an inherited historian refuses reads and
    writes in the child (its parent's lock was held at the fork: before, the child was told
    it nested two writes, and its close raised too) and its close leaves the parent's
    connections alone; a historian the child opens works, and so does the parent's."""
    import multiprocessing

    url = f"sqlite:///{tmp_path / 'h.db'}"
    with Historian(url) as h:
        h.write_samples(_samples("A", 10))
        ctx = multiprocessing.get_context("fork")
        with h._bulk.file.writing():
            child = ctx.Process(target=_child_with_inherited, args=(h, url))
            child.start()
        child.join(120)
        assert child.exitcode == 0
        assert len(h.read_samples("A")) == 20
        h.write_samples(_samples("A", 10, "2024-05-01"), create_tags=False)
        assert h.integrity_check() == []


def _child_with_inherited(h: Historian, url: str) -> None:
    from historian.sqlitefile import ForkedHistorian

    for use in (
        lambda: h.read_samples("A"),
        lambda: h.tags(),
        lambda: h.write_samples(_samples("A", 10, "2024-04-01"), create_tags=False),
    ):
        with pytest.raises(ForkedHistorian):
            use()
    h.close()
    _child_write(url)
