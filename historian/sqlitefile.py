"""One SQLite database file used through two SQLite libraries in one process.

The historian writes metadata through SQLAlchemy (the standard library's ``sqlite3``, the
system's SQLite) and samples through ADBC (``adbc_driver_sqlite``, which bundles its own
SQLite). POSIX advisory locks belong to the process, and each copy of SQLite tracks only
its own ("How To Corrupt An SQLite Database File" §2.2.1), so without a rule of ours:

(a) both copies can hold a write transaction on the file at once: both append to the
    write-ahead log from the same frame, and one commit silently overwrites the other
    (a committed ADBC batch was lost that way: test_historian_two_sqlites);
(b) when one copy closes its last connection to the file it believes it is the last one in
    the process: it checkpoints and deletes the ``-wal`` and ``-shm`` files under the other
    copy's connections, and closing its descriptors drops every lock the other copy holds,
    so another process can write while our transaction is open.

The rule, per database file and process (:class:`SqliteFile`):

- every write transaction of either library runs under one lock (:meth:`SqliteFile.writing`),
  so the two never overlap; a write of one library inside one of the other in the same
  thread is refused (it would hold both at once);
- while any historian of the process has the file open, one idle connection of each library
  (a *keeper*, having read once, so it holds its copy's shared lock and ``-shm`` mapping) stays
  open: no other connection's close is then a copy's last, so neither copy deletes the log
  or closes a descriptor holding locks (SQLite defers those closes while its copy holds a
  lock on the file). The keepers close when the last historian on the file closes, under
  the lock.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

#: what "the database is busy" looks like when the lock is not had within the busy timeout
#: (the message SQLite gives for the same case, so callers treat both alike)
LOCKED = "database is locked (another write of this process holds it)"


class DatabaseLocked(TimeoutError):
    """The in-process write lock of a SQLite file was not had within the busy timeout."""


class SqliteFile:
    """The in-process write lock and the keeper connections of one SQLite file."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._lock = threading.Lock()
        self._owner: int | None = None
        self._users = 0
        self._keepers: list = []

    # -- the write lock ------------------------------------------------------------------
    @contextmanager
    def writing(self, timeout_s: float | None = None) -> Iterator[None]:
        """Hold the file's write lock (waiting at most ``timeout_s`` seconds, None: no bound)
        for one write transaction of either library."""
        me = threading.get_ident()
        if self._owner == me:
            raise RuntimeError(
                f"a write transaction on {self.path} was opened inside another of this thread "
                "(the two SQLite libraries would hold write locks at once)"
            )
        if not self._lock.acquire(timeout=-1 if timeout_s is None else max(0.0, timeout_s)):
            raise DatabaseLocked(f"{self.path}: {LOCKED}")
        self._owner = me
        try:
            yield
        finally:
            self._owner = None
            self._lock.release()

    # -- users and keepers ---------------------------------------------------------------
    def attach(self, prepare, timeout_s: float | None = None) -> None:
        """A historian of this process opens the file: ``prepare()`` (its schema check, on
        its own connection) runs under the lock, then the keepers open if this is the first
        historian (after ``prepare``: the file exists and is in WAL mode)."""
        with self.writing(timeout_s):
            self._users += 1
            try:
                prepare()
                if not self._keepers:
                    self._keepers = _open_keepers(self.path)
            except BaseException:
                self._users -= 1
                raise

    def detach(self, close_own) -> None:
        """A historian closes: ``close_own()`` closes its connections under the lock (no
        write of the process runs meanwhile); the keepers close after the last historian."""
        with self.writing():
            try:
                close_own()
            finally:
                self._users -= 1
                if self._users == 0:
                    keepers, self._keepers = self._keepers, []
                    for conn in keepers:
                        conn.close()


def _open_keepers(path: Path) -> list:
    """One connection of each library, each having read the file once (so each copy of
    SQLite holds its shared lock and the ``-shm`` mapping for as long as it is open)."""
    import sqlite3

    import adbc_driver_sqlite.dbapi as adbc

    std = sqlite3.connect(str(path), timeout=60.0, check_same_thread=False, isolation_level=None)
    for sql in _KEEPER_SQL:
        std.execute(sql).fetchall()
    bundled = adbc.connect(str(path), autocommit=True)
    cur = bundled.cursor()
    try:
        for sql in ("PRAGMA busy_timeout=60000", *_KEEPER_SQL):
            cur.execute(sql)
            cur.fetchall()
    finally:
        cur.close()
    return [std, bundled]


#: a keeper's statements: WAL (the historian's mode; no change when set) and one read
_KEEPER_SQL = ("PRAGMA journal_mode=WAL", "SELECT count(*) FROM sqlite_master")


_FILES: dict[str, SqliteFile] = {}
_FILES_LOCK = threading.Lock()


def sqlite_file(path: str | Path) -> SqliteFile:
    """The process's :class:`SqliteFile` of the database at ``path`` (one per real file,
    however the path is spelled)."""
    key = os.path.realpath(path)
    with _FILES_LOCK:
        f = _FILES.get(key)
        if f is None:
            f = _FILES[key] = SqliteFile(Path(key))
        return f


def _forget_in_child() -> None:
    """A forked child starts with no files: its parent's locks may be held by threads the
    child does not have, and its parent's connections are not the child's to use or close
    (POSIX locks are not inherited, so the child holds none of them)."""
    global _FILES_LOCK
    _FILES.clear()
    _FILES_LOCK = threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_in_child)
