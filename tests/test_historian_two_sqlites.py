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
        event.listen(engine, "after_cursor_execute", self._after)

    def _after(self, conn, cursor, statement, params, context, executemany) -> None:
        if not self._done and statement.lstrip().upper().startswith("INSERT INTO TAGS"):
            self._done = True
            self.inside.set()
            self._go.wait(60)

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
        seen["tags_open"] = "committed" not in out

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
