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
    so another process can write while our transaction is open;
(c) a checkpoint run by one copy does not see the other copy's readers: their read marks
    are POSIX locks of the same process, so its exclusive probe of them succeeds and it
    copies pages newer than their snapshot into the database file (or restarts the log)
    under them. An ADBC read of a tag running across a metadata commit that checkpointed
    failed with "database disk image is malformed" (test_historian_two_sqlites).

The rule, per database file and process (:class:`SqliteFile`):

- every write transaction of either library runs under one lock (:meth:`SqliteFile.writing`),
  so the two never overlap; a write of one library inside one of the other in the same
  thread is refused (it would hold both at once);
- while any historian of the process has the file open, one idle connection of each library
  (a *keeper*, having read once, so it holds its copy's shared lock and ``-shm`` mapping) stays
  open: no other connection's close is then a copy's last, so neither copy deletes the log
  or closes a descriptor holding locks (SQLite defers those closes while its copy holds a
  lock on the file). The keepers close when the last historian on the file closes, under
  the lock;
- no connection checkpoints on its own (``wal_autocheckpoint=0`` on all of them): every read
  of either library is counted (:meth:`SqliteFile.reading`), and the historian checkpoints
  (``TRUNCATE``, on the ADBC keeper) after a write once the log has passed
  :data:`CHECKPOINT_BYTES`, only while no read of the process is open and under the write
  lock, both taken without waiting (else it is skipped and tried after the next write or
  when the last read ends). Reads starting meanwhile wait for it; once the log has passed
  :data:`DRAIN_BYTES` because reads never paused, new reads wait until the open ones end
  and the checkpoint ran, so the log stays bounded.

A forked child must not use SQLite connections opened by its parent (sqlite.org FAQ 6): a
historian inherited across ``fork`` refuses to read or write, and its ``close`` forgets its
connections without touching them (:class:`ForkedHistorian`).
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

#: what "the database is busy" looks like when the lock is not had within the busy timeout
#: (the message SQLite gives for the same case, so callers treat both alike)
LOCKED = "database is locked (another write of this process holds it)"

#: bytes of write-ahead log after which a write is followed by a checkpoint: 1,000 pages of
#: the historian's 16 KiB (SQLite's own automatic checkpoint is at 1,000 pages)
CHECKPOINT_BYTES = 1000 * 16384
#: bytes of log after which new reads wait for the open ones to end and the checkpoint to run
DRAIN_BYTES = 4 * CHECKPOINT_BYTES


class DatabaseLocked(TimeoutError):
    """The in-process write lock of a SQLite file was not had within the busy timeout."""


class ForkedHistorian(RuntimeError):
    """A historian opened by a parent process was used in a forked child."""


class SqliteFile:
    """The in-process write lock, read count and keeper connections of one SQLite file."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.wal = path.with_name(path.name + "-wal")
        self._pid = os.getpid()
        self._lock = threading.Lock()
        self._owner: int | None = None
        self._users = 0  # historians attached
        self._refs = 0  # SqliteBulk objects holding this file
        self._keepers: list = []
        self._gate = threading.Condition()
        self._readers = 0  # reads of either library open in the process
        self._depth = threading.local()  # this thread's open reads
        self._checkpointing = False
        self._draining = False
        self.checkpoints = 0  # checkpoints run, and their seconds (tests and benchmarks)
        self.checkpoint_s = 0.0

    def _check_process(self) -> None:
        if os.getpid() != self._pid:
            raise ForkedHistorian(
                f"{self.path}: this historian was opened by process {self._pid}; a forked "
                "child cannot use its parent's SQLite connections: open a Historian in the child"
            )

    # -- the write lock ------------------------------------------------------------------
    @contextmanager
    def writing(self, timeout_s: float | None = None) -> Iterator[None]:
        """Hold the file's write lock (waiting at most ``timeout_s`` seconds, None: no bound)
        for one write transaction of either library; a checkpoint is tried after it."""
        self._check_process()
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
        self.checkpoint_if_due()

    # -- reads and checkpoints -----------------------------------------------------------
    @contextmanager
    def reading(self, timeout_s: float | None = None) -> Iterator[None]:
        """Count one read transaction of either library for as long as it is open (waiting
        at most ``timeout_s`` while a checkpoint runs or the log drains)."""
        self.enter_read(timeout_s)
        try:
            yield
        finally:
            self.leave_read()

    def enter_read(self, timeout_s: float | None = None) -> None:
        """A read of either library starts (see :meth:`reading`)."""
        self._check_process()
        depth = getattr(self._depth, "n", 0)
        me = threading.get_ident()
        with self._gate:
            # a draining log does not hold up this thread's nested reads nor the write lock's
            # holder (the checkpoint waits for their reads, or for their lock)
            ok = self._gate.wait_for(
                lambda: (
                    not self._checkpointing
                    and (not self._draining or depth > 0 or self._owner == me)
                ),
                timeout_s,
            )
            if not ok:
                raise DatabaseLocked(f"{self.path}: {LOCKED}")
            self._readers += 1
        self._depth.n = depth + 1

    def leave_read(self) -> None:
        """A read of either library ended; the last one runs a checkpoint the log waits for."""
        self._depth.n = max(0, getattr(self._depth, "n", 0) - 1)
        with self._gate:
            self._readers -= 1
            last = self._readers == 0
            if last:
                self._gate.notify_all()
        if last and self._draining:
            self.checkpoint_if_due()

    def checkpoint_if_due(self) -> bool:
        """Checkpoint if the log has passed :data:`CHECKPOINT_BYTES` and neither a read of
        the process nor the write lock is held (nothing is waited for); True if one ran."""
        if os.getpid() != self._pid:
            return False
        if not self._keepers or _wal_bytes(self.wal) < CHECKPOINT_BYTES:
            if self._draining:  # emptied meanwhile (another process): reads need not wait
                with self._gate:
                    self._draining = False
                    self._gate.notify_all()
            return False
        if not self._lock.acquire(blocking=False):
            return False
        self._owner = threading.get_ident()
        try:
            with self._gate:
                if self._readers:
                    if _wal_bytes(self.wal) >= DRAIN_BYTES:
                        self._draining = True
                    return False
                self._checkpointing = True
            self._run_checkpoint(0)
            return True
        finally:
            self._owner = None
            self._lock.release()

    def checkpoint(self, timeout_s: float | None = None) -> bool:
        """Checkpoint now, truncating the log (``vacuum``): waits at most ``timeout_s`` for
        the write lock, the open reads of the process and another process's readers; True
        if the log was emptied."""
        self._check_process()
        start = time.monotonic()
        if not self._lock.acquire(timeout=-1 if timeout_s is None else max(0.0, timeout_s)):
            raise DatabaseLocked(f"{self.path}: {LOCKED}")
        self._owner = threading.get_ident()
        try:
            left = None if timeout_s is None else max(0.0, timeout_s - time.monotonic() + start)
            with self._gate:
                self._draining = True
                if not self._gate.wait_for(lambda: self._readers == 0, left):
                    self._draining = False
                    self._gate.notify_all()
                    raise DatabaseLocked(f"{self.path}: {LOCKED}")
                self._checkpointing = True
            ms = 60_000 if left is None else max(0, int(left * 1000))
            return self._run_checkpoint(ms)
        finally:
            self._owner = None
            self._lock.release()

    def _run_checkpoint(self, busy_ms: int) -> bool:
        """``PRAGMA wal_checkpoint(TRUNCATE)`` on the ADBC keeper (the caller holds the write
        lock and has set ``_checkpointing`` with no read open); True if the log was emptied."""
        start = time.perf_counter()
        try:
            if not self._keepers:
                return False
            cur = self._keepers[1].cursor()
            try:
                cur.execute(f"PRAGMA busy_timeout={int(busy_ms)}")
                cur.fetchall()
                cur.execute("PRAGMA wal_checkpoint(TRUNCATE)")
                busy = int(cur.fetchone()[0])
                cur.fetchall()
            finally:
                cur.close()
            self.checkpoints += 1
            self.checkpoint_s += time.perf_counter() - start
            return busy == 0
        finally:
            with self._gate:
                self._checkpointing = self._draining = False
                self._gate.notify_all()

    # -- users and keepers ---------------------------------------------------------------
    def attach(self, prepare: Callable[[], object], timeout_s: float | None = None) -> None:
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

    def detach(self, close_own: Callable[[], object]) -> None:
        """A historian closes: ``close_own()`` closes its connections under the lock (no
        write of the process runs meanwhile); the keepers close after the last historian,
        and the process forgets the file once nothing holds it. In a forked child the
        parent's connections are left alone (closing them is not the child's to do)."""
        if os.getpid() != self._pid:
            return
        with self.writing():
            try:
                close_own()
            finally:
                self._users -= 1
                if self._users == 0:
                    keepers, self._keepers = self._keepers, []
                    for conn in keepers:
                        conn.close()
                    self._forget_if_unused()

    def release(self) -> None:
        """A :class:`~historian.backends.SqliteBulk` of the file closed."""
        with _FILES_LOCK:
            self._refs -= 1
        if self._users == 0:
            self._forget_if_unused()

    def _forget_if_unused(self) -> None:
        with _FILES_LOCK:
            key = str(self.path)
            if self._refs <= 0 and self._users == 0 and _FILES.get(key) is self:
                del _FILES[key]


def _wal_bytes(wal: Path) -> int:
    try:
        return os.stat(wal).st_size
    except FileNotFoundError:
        return 0


def _open_keepers(path: Path) -> list:
    """One connection of each library, each having read the file once (so each copy of
    SQLite holds its shared lock and the ``-shm`` mapping for as long as it is open); the
    ADBC one runs the checkpoints."""
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


#: a keeper's statements: WAL (the historian's mode; no change when set), no checkpoint of
#: its own, and one read
_KEEPER_SQL = (
    "PRAGMA journal_mode=WAL",
    "PRAGMA wal_autocheckpoint=0",
    "SELECT count(*) FROM sqlite_master",
)


_FILES: dict[str, SqliteFile] = {}
_FILES_LOCK = threading.Lock()


def sqlite_file(path: str | Path) -> SqliteFile:
    """The process's :class:`SqliteFile` of the database at ``path`` (one per real file,
    however the path is spelled), held until :meth:`SqliteFile.release`."""
    key = os.path.realpath(path)
    with _FILES_LOCK:
        f = _FILES.get(key)
        if f is None:
            f = _FILES[key] = SqliteFile(Path(key))
        f._refs += 1
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
