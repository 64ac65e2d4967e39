"""The SQLite historian's small metadata reads through the standard library's ``sqlite3``.

``diag diagnose`` on a SQLite historian reads a few rows of metadata before and around its
read of the samples: the tag registry, each tag's id and range, the tags' first and last
times, the rolled months and the recorded cold folder. Through SQLAlchemy those cost its
import (~0.1–0.3 CPU s of a start-up) and a few hundred µs of overhead a query; here they
are plain SQL on one connection of the process's historian, shared by its threads under a
lock, and SQLAlchemy is imported only when something writes or reads the other tables
(issue 34: a 50-tag unit's replay).

The connection is of the same SQLite library as SQLAlchemy's (the system's, through
``sqlite3``), so it keeps the rules of :mod:`historian.sqlitefile`: each read is counted
(:meth:`~historian.sqlitefile.SqliteFile.reading`) for as long as its statements run, so no
checkpoint nor ``VACUUM`` of the process runs under it and it waits while one runs; its
pragmas are the historian's (no checkpoint of its own); it closes under the file's write
lock with the historian (:meth:`SqliteMeta.close`, from ``detach``). It runs in autocommit
mode: each statement reads the last committed state, as SQLAlchemy's pooled connections
did (a write transaction open on another connection, of this process or another, is not
seen until it commits; the historian never reads metadata inside its own write
transaction: those reads go through the transaction's connection).
"""

from __future__ import annotations

import sqlite3
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from .sqlitefile import SqliteFile

#: the historian's tables and indexes (:mod:`historian.schema`): when the file has them all,
#: opening it creates nothing and SQLAlchemy's ``create_all`` is not needed
TABLES = frozenset(
    {"tags", "samples", "model_versions", "experiments", "diag_events", "cold_segments", "settings"}
)
INDEXES = frozenset({"ix_experiments_model", "ix_diag_events_ts", "ix_diag_events_unit"})

#: tries of a new connection's pragmas while another process makes the file (a lock error)
CONNECT_TRIES = 8

Query = Callable[[str, Sequence[Any]], list[tuple]]


def sqlite_path(url: str) -> str | None:
    """The database path of a plain ``sqlite:///path`` URL (no query, no %-escapes), as
    SQLAlchemy's ``make_url`` reads it; None for any other URL (parse it with ``make_url``)."""
    head = "sqlite:///"
    if not url.startswith(head):
        return None
    path = url[len(head) :]
    if any(c in path for c in "?%"):
        return None
    return path


class SqliteMeta:
    """One ``sqlite3`` read connection on a historian's SQLite file, opened on first use.

    ``file``: the process's :class:`~historian.sqlitefile.SqliteFile` of the database;
    ``busy_ms``: the historian's busy timeout (also the longest wait for a checkpoint)."""

    def __init__(self, path: Path, file: SqliteFile, busy_ms: int, pragmas: Sequence[str]):
        self.path = path
        self.file = file
        self.busy_ms = int(busy_ms)
        self._pragmas = tuple(pragmas)
        self._conn: sqlite3.Connection | None = None
        self._lock = threading.RLock()  # a nested read of the same thread

    @contextmanager
    def reading(self) -> Iterator[Query]:
        """One counted read of the file: yields ``query(sql, params) -> rows`` (all rows of
        each statement fetched), the connection held by this thread until the block ends."""
        with self.file.reading(self.busy_ms / 1000), self._lock:
            conn = self._conn if self._conn is not None else self._connect()

            def query(sql: str, params: Sequence[Any] = ()) -> list[tuple]:
                cur = conn.execute(sql, params)
                try:
                    return cur.fetchall()
                finally:
                    cur.close()

            yield query

    def rows(self, sql: str, params: Sequence[Any] = ()) -> list[tuple]:
        """The rows of one statement, in a read of its own."""
        with self.reading() as query:
            return query(sql, params)

    def has_schema(self) -> bool:
        """Whether the file holds every table and index of :mod:`historian.schema`."""
        names = {n for (n,) in self.rows("SELECT name FROM sqlite_master")}
        return TABLES <= names and INDEXES <= names

    def _connect(self) -> sqlite3.Connection:
        conn = sqlite3.connect(
            str(self.path),
            timeout=self.busy_ms / 1000,
            check_same_thread=False,  # shared by the historian's threads, under self._lock
            isolation_level=None,  # autocommit: no transaction left open between reads
        )
        try:
            conn.execute(f"PRAGMA busy_timeout={self.busy_ms}").fetchall()
            for attempt in range(CONNECT_TRIES):
                try:
                    for pragma in self._pragmas:
                        conn.execute(pragma).fetchall()
                    break
                except sqlite3.OperationalError as exc:
                    # a new file made by another process at once: its switch to WAL is not
                    # waited for by the busy handler (create_schema retries alike)
                    if attempt == CONNECT_TRIES - 1 or "locked" not in str(exc).lower():
                        raise
                    time.sleep(0.05 * (attempt + 1))
        except BaseException:
            conn.close()
            raise
        self._conn = conn
        return conn

    def close(self) -> None:
        """Close the connection (the caller holds the file's write lock: ``detach``)."""
        with self._lock:
            conn, self._conn = self._conn, None
        if conn is not None:
            conn.close()
