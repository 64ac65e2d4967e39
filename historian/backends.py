"""Bulk sample I/O per database: SQLite (Arrow via ADBC) and PostgreSQL (binary COPY).

Both classes move plain numpy arrays: ``tag_id`` (int), ``ts`` (int64 µs UTC), ``value``
(float64, NaN for none) and ``quality`` (int). Metadata goes through SQLAlchemy in
:mod:`historian.store` (on SQLite its small reads through :mod:`historian.sqlitemeta`); only
the hot paths live here.
"""

from __future__ import annotations

import struct
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa

from .quality import BAD, GOOD
from .sqlitefile import sqlite_file

if TYPE_CHECKING:
    from sqlalchemy.engine import Engine

#: ``update`` leaves a row holding the same value and quality alone, so the row count the
#: database reports is the rows added or changed (``IS DISTINCT FROM`` is NULL-safe; SQLite
#: has it since 3.39, the ADBC driver bundles a newer one)
_INSERT_POLICY = {
    "ignore": "ON CONFLICT (tag_id, ts) DO NOTHING",
    "update": "ON CONFLICT (tag_id, ts) DO UPDATE SET value = excluded.value, "
    "quality = excluded.quality WHERE samples.value IS DISTINCT FROM excluded.value "
    "OR samples.quality IS DISTINCT FROM excluded.quality",
}


def _policy(policy: str) -> str:
    try:
        return _INSERT_POLICY[policy]
    except KeyError:
        raise ValueError(f"policy must be 'ignore' or 'update', not {policy!r}") from None


def _off_grid(t0: int, period: int) -> str:
    """SQL of a sample's distance from the grid ``t0 + k·period`` (µs), 0 on a grid point.
    An epoch-anchored grid (``t0`` a multiple of the period, as the historian's windows
    are) needs no subtraction: ``P | ts − t0`` is ``P | ts`` there (SQLite's ``%`` takes
    the dividend's sign, so 0 on exactly those ``ts``, before the epoch too)."""
    if int(t0) % int(period) == 0:
        return f"ts % {int(period)}"
    return f"(ts - {int(t0)}) % {int(period)}"


def _empty():
    return np.empty(0, np.int64), np.empty(0, np.float64), np.empty(0, np.int64)


#: bytes of the database file a connection reads through a memory map (SQLite caps it at
#: its compile-time limit, 2 GB by default): a training read of months of samples costs a
#: sixth less CPU than through read() calls into SQLite's page cache (bench_train). Reads
#: only: SQLite still writes through its journal, so durability is unchanged.
MMAP_BYTES = 1 << 31
#: rows per Arrow batch of a SQLite read (the driver's default is 1,024): a training read of
#: a 30-day chunk comes as one batch instead of 253, and four tags' half-year costs the
#: fetch 13 % less CPU (0.93 → 0.81 s, issue 37; the arrays are the same)
READ_BATCH_ROWS = 1 << 18
#: the ADBC SQLite driver's statement option for it (adbc_driver_sqlite.StatementOptions)
_BATCH_ROWS_OPTION = "adbc.sqlite.query.batch_rows"

#: page size of a new SQLite database (an existing file keeps its own): a bulk load of 6 M
#: samples cost 0.50 µs CPU a sample with 16 KiB pages, 0.58 with SQLite's 4 KiB, and a
#: tag's read the same (bench in the i37-import2 commit); larger pages gain little more
#: (0.46 at 64 KiB) and make each small live commit write four times as much to the log
PAGE_BYTES = 16384

#: what every SQLite connection of the historian sets first (``page_size`` only takes on a
#: database not yet written)
SQLITE_PRAGMAS = (
    f"PRAGMA page_size={PAGE_BYTES}",
    "PRAGMA journal_mode=WAL",
    "PRAGMA synchronous=FULL",
    # the historian checkpoints, never a connection on its own (historian.sqlitefile (c))
    "PRAGMA wal_autocheckpoint=0",
)


class SqliteBulk:
    """SQLite hot path on one ADBC connection (Arrow in, Arrow out).

    WAL journal and ``synchronous=FULL`` are set on every connection, so a committed batch
    survives a crash of the process (and of the machine); pages are read through a memory
    map (:data:`MMAP_BYTES`). Each write transaction holds the file's in-process write lock
    (:mod:`historian.sqlitefile`), waiting for it at most the busy timeout; each read is
    counted there while it is open (no checkpoint runs under it).
    """

    name = "sqlite"

    def __init__(self, path: Path, busy_timeout_ms: int = 60_000):
        self.path = Path(path)
        self.busy_timeout_ms = busy_timeout_ms
        self.file = sqlite_file(self.path)
        self._local = threading.local()  # one connection per thread (parallel tag reads)
        self._all: list = []
        self._lock = threading.Lock()
        self._released = False

    @property
    def conn(self):
        conn = getattr(self._local, "conn", None)
        if conn is None:
            import adbc_driver_sqlite.dbapi as adbc

            conn = adbc.connect(str(self.path), autocommit=True)
            cur = conn.cursor()
            with self.file.reading(self.busy_timeout_ms / 1000):
                for pragma in (
                    f"PRAGMA busy_timeout={int(self.busy_timeout_ms)}",
                    *SQLITE_PRAGMAS,
                    "PRAGMA temp_store=MEMORY",
                    "PRAGMA cache_size=-65536",
                    f"PRAGMA mmap_size={MMAP_BYTES}",
                ):
                    cur.execute(pragma)
                    cur.fetchall()
            cur.close()
            self._local.conn = conn
            with self._lock:
                self._all.append(conn)
        return conn

    def close(self) -> None:
        with self._lock:
            conns, self._all = self._all, []
        for conn in conns:
            conn.close()
        self._local = threading.local()
        if not self._released:
            self._released = True
            self.file.release()

    def insert(self, tag_id, ts, value, quality, policy: str = "ignore") -> int:
        """Insert one batch in one transaction; returns rows inserted (or changed)."""
        clause = _policy(policy)
        table = pa.table(
            {
                "tag_id": pa.array(np.asarray(tag_id, np.int64)),
                "ts": pa.array(np.asarray(ts, np.int64)),
                "value": pa.array(np.asarray(value, np.float64), from_pandas=True),
                "quality": pa.array(np.asarray(quality, np.int64)),
            }
        )
        move = (
            "INSERT INTO samples (tag_id, ts, value, quality) "
            f"SELECT tag_id, ts, value, quality FROM temp._stage WHERE true {clause}"
        )
        return self._staged("_stage", table, [move])

    def _staged(self, name: str, table: pa.Table, moves: list[str]) -> int:
        """``table`` into the temporary table ``name``, then in one transaction each
        statement of ``moves`` (from it into ``samples``); returns the rows they changed.
        The staging writes only the connection's temporary database, so it runs before the
        transaction takes the write lock: the lock is held for the moves alone."""
        n = 0
        cur = self.conn.cursor()
        try:
            cur.execute(f"DROP TABLE IF EXISTS temp.{name}")
            cur.adbc_ingest(name, table, mode="create", temporary=True)
            with self.file.writing(self.busy_timeout_ms / 1000):
                cur.execute("BEGIN IMMEDIATE")
                try:
                    for sql in moves:
                        cur.execute(sql)
                        cur.execute("SELECT changes()")
                        n += int(cur.fetchone()[0])
                    cur.execute("COMMIT")
                except BaseException:
                    cur.execute("ROLLBACK")
                    raise
            cur.execute(f"DROP TABLE temp.{name}")
        finally:
            cur.close()
        return n

    def insert_wide(self, ts, tag_ids, values, quality, policy: str = "ignore") -> int:
        """Insert samples given as wide rows in one transaction; returns rows inserted (or
        changed). ``ts``: one time per row, none twice; ``values`` and ``quality``: arrays of
        shape (tags, rows), one row per id of ``tag_ids``; a cell is a sample when its value
        is a number or its quality is Bad.

        The rows are staged as they are, one staged row per time (a column per tag, and a
        quality column only for a tag whose codes vary), then moved into ``samples`` tag by
        tag. SQLite's cost of staging is per staged row far more than per value: staging
        the samples one row each cost as much as inserting them into ``samples``."""
        clause = _policy(policy)
        cols = {"ts": pa.array(np.asarray(ts, np.int64))}
        moves = []
        for j, tag_id in enumerate(tag_ids):
            v = np.asarray(values[j], np.float64)
            q = np.asarray(quality[j], np.int64)
            nan = np.isnan(v)
            if not len(q) or (q[0] != BAD and (q == q[0]).all()):  # one code: no column
                if nan.all():
                    continue
                code, present = str(int(q[0]) if len(q) else GOOD), f"v{j} IS NOT NULL"
            else:
                absent = nan & (q != BAD)
                if absent.all():
                    continue
                cols[f"q{j}"] = pa.array(q, mask=absent)
                code, present = f"q{j}", f"q{j} IS NOT NULL"
            cols[f"v{j}"] = pa.array(v, from_pandas=True)  # NaN: NULL
            moves.append(
                "INSERT INTO samples (tag_id, ts, value, quality) "
                f"SELECT {int(tag_id)}, ts, v{j}, {code} FROM temp._wide WHERE {present} {clause}"
            )
        return self._staged("_wide", pa.table(cols), moves) if moves else 0

    def read(self, tag_id: int, start: int, end: int, usable: bool = False):
        """Samples of one tag with start <= ts < end, ordered by ts. ``usable``: a Bad
        sample comes as a NaN value and every quality as GOOD, which an aligned window
        treats alike (not usable), and the driver fetches one column less per row (a third
        of a SQLite read's time: the driver's per-value work, not the scan, is the cost)."""
        value_sql = f"CASE WHEN quality < {BAD} THEN value END" if usable else "value, quality"
        tb = self.fetch(
            f"SELECT ts, {value_sql} FROM samples "
            f"WHERE tag_id = {int(tag_id)} AND ts >= {int(start)} AND ts < {int(end)} "
            "ORDER BY ts"
        )
        if tb.num_rows == 0:
            return _empty()
        ts = tb.column(0).to_numpy().astype(np.int64, copy=False)
        value = tb.column(1).cast(pa.float64()).to_numpy(zero_copy_only=False)
        if usable:
            return ts, value, np.zeros(len(ts), np.int64)
        quality = tb.column(2).to_numpy().astype(np.int64, copy=False)
        return ts, value, quality

    def read_grid(self, tag_id: int, t0: int, period: int, n: int) -> np.ndarray | None:
        """The tag's usable values at the grid points ``t0 + k·period`` (k < n) when its
        samples in ``[t0 − period/2, t0 + n·period − period/2)`` are exactly one on each of
        them (a regular series on the grid), else None (nothing is known then: read the
        samples with :meth:`read`). A Bad sample is NaN, as in an aligned window.

        One column per row instead of (ts, value): the driver's per-value work is most of a
        read's cost (issue 34: 1,000,000 rows of one tag 0.21 → 0.15 CPU s). A sample off
        the grid answers +inf, a marker no usable value is (an infinite value is not usable
        either: :func:`~historian.window.align`); then, or with a grid point without a
        sample (fewer rows than ``n``), None. The usable sample on the grid is asked first
        (the common row: 200,000 rows of one tag 0.031 → 0.027 CPU s against the grid's
        test first, issue 34), and the grid's distance from the epoch alone where the grid
        is the epoch's (:func:`_off_grid`)."""
        if n <= 0:
            return None
        half = period // 2
        lo, hi = t0 - half, t0 + n * period - half
        off = _off_grid(t0, period)
        tb = self.fetch(
            f"SELECT CASE WHEN quality < {BAD} AND {off} = 0 THEN value "
            f"WHEN {off} THEN 9e999 END FROM samples "
            f"WHERE tag_id = {int(tag_id)} AND ts >= {int(lo)} AND ts < {int(hi)} ORDER BY ts"
        )
        if tb.num_rows != n:
            return None
        col = tb.column(0)
        if not (pa.types.is_floating(col.type) or pa.types.is_null(col.type)):
            return None  # values stored as another type: the full read decides
        value = col.cast(pa.float64()).to_numpy(zero_copy_only=False)
        if np.isinf(value).any():  # a sample off the grid (or an infinite value)
            return None
        return value

    def fetch(self, sql: str) -> pa.Table:
        """The rows of a query as an Arrow table, in batches of :data:`READ_BATCH_ROWS`."""
        with self.batches(sql) as reader:
            return reader.read_all()

    @contextmanager
    def batches(self, sql: str) -> Iterator[pa.RecordBatchReader]:
        """The rows of a query as a stream of Arrow batches of :data:`READ_BATCH_ROWS`,
        read while the context is open (one read transaction, counted as open meanwhile)."""
        with self.file.reading(self.busy_timeout_ms / 1000):
            cur = self.conn.cursor()
            try:
                cur.adbc_statement.set_options(**{_BATCH_ROWS_OPTION: str(READ_BATCH_ROWS)})
                cur.execute(sql)
                yield cur.fetch_record_batch()
            finally:
                cur.close()

    def recent_ts(self, tag_id: int, n: int) -> np.ndarray:
        """Times of the tag's last ``n`` samples in the database, ascending."""
        tb = self.fetch(
            f"SELECT ts FROM samples WHERE tag_id = {int(tag_id)} ORDER BY ts DESC LIMIT {int(n)}"
        )
        return tb.column(0).to_numpy().astype(np.int64, copy=False)[::-1]

    def size_bytes(self) -> int:
        """Bytes the database takes on disk: the file and its write-ahead log."""
        wal = self.path.with_name(self.path.name + "-wal")
        return sum(p.stat().st_size for p in (self.path, wal) if p.exists())

    def free_bytes(self) -> int:
        """Bytes of free pages in the file (reused by later writes; ``vacuum`` returns them)."""
        with self.file.reading(self.busy_timeout_ms / 1000):
            cur = self.conn.cursor()
            try:
                cur.execute("PRAGMA page_size")
                page = int(cur.fetchone()[0])
                cur.execute("PRAGMA freelist_count")
                return page * int(cur.fetchone()[0])
            finally:
                cur.close()

    def vacuum(self, full: bool = False) -> None:
        """``VACUUM`` (rebuilds the file without its free pages; needs as much free disk as
        the database takes), then a truncating checkpoint so the file shrinks now. ``full``
        changes nothing on SQLite."""
        cur = self.conn.cursor()
        try:
            with self.file.writing(self.busy_timeout_ms / 1000):
                cur.execute("VACUUM")
                cur.fetchall()
        finally:
            cur.close()
        try:
            self.file.checkpoint(self.busy_timeout_ms / 1000)
        except TimeoutError:  # reads kept the log: a later write's checkpoint empties it
            pass

    def integrity_check(self) -> list[str]:
        """``PRAGMA integrity_check``; a file too damaged for it to run is reported too."""
        import adbc_driver_sqlite.dbapi as adbc

        with self.file.reading(self.busy_timeout_ms / 1000):
            cur = self.conn.cursor()
            try:
                cur.execute("PRAGMA integrity_check")
                rows = [str(r[0]) for r in cur.fetchall()]
            except adbc.Error as exc:
                return [f"PRAGMA integrity_check failed: {exc}"]
            finally:
                cur.close()
        return [] if rows == ["ok"] else rows


_PGHEADER = b"PGCOPY\n\xff\r\n\x00" + struct.pack(">ii", 0, 0)
_PGTRAILER = struct.pack(">h", -1)
_PG_IN = np.dtype(
    [
        ("n", ">i2"),
        ("l1", ">i4"),
        ("tag_id", ">i4"),
        ("l2", ">i4"),
        ("ts", ">i8"),
        ("l3", ">i4"),
        ("value", ">f8"),
        ("l4", ">i4"),
        ("quality", ">i2"),
    ]
)
_PG_OUT = np.dtype(
    [
        ("n", ">i2"),
        ("l1", ">i4"),
        ("ts", ">i8"),
        ("l2", ">i4"),
        ("value", ">f8"),
        ("l3", ">i4"),
        ("quality", ">i2"),
    ]
)


class PostgresBulk:
    """PostgreSQL hot path: binary COPY into a temporary staging table, then
    ``INSERT … SELECT … ON CONFLICT``; reads with binary ``COPY (SELECT …) TO STDOUT``.
    Rows are fixed-width, so both directions are a numpy structured-array view."""

    name = "postgresql"

    def __init__(self, engine: Engine):
        self.engine = engine

    def close(self) -> None:
        pass

    def insert(self, tag_id, ts, value, quality, policy: str = "ignore") -> int:
        clause = _policy(policy)
        n = len(ts)
        rows = np.empty(n, dtype=_PG_IN)
        rows["n"] = 4
        rows["l1"] = 4
        rows["tag_id"] = tag_id
        rows["l2"] = 8
        rows["ts"] = ts
        rows["l3"] = 8
        rows["value"] = value
        rows["l4"] = 2
        rows["quality"] = quality
        with self._cursor(commit=True) as cur:
            cur.execute(
                "CREATE TEMP TABLE IF NOT EXISTS _stage "
                "(tag_id int4, ts int8, value float8, quality int2) ON COMMIT DELETE ROWS"
            )
            with cur.copy("COPY _stage FROM STDIN (FORMAT binary)") as cp:
                cp.write(_PGHEADER)
                cp.write(rows.tobytes())
                cp.write(_PGTRAILER)
            cur.execute(
                "INSERT INTO samples (tag_id, ts, value, quality) "
                f"SELECT tag_id, ts, value, quality FROM _stage {clause}"
            )
            inserted = cur.rowcount
        return int(inserted)

    @contextmanager
    def _cursor(self, commit: bool) -> Iterator[Any]:
        """A psycopg cursor on a pooled connection's driver connection; at the end the work
        is committed (``commit``) or rolled back (a read), and rolled back on an error."""
        raw = self.engine.raw_connection()
        try:
            pg = raw.driver_connection
            with pg.cursor() as cur:
                yield cur
            if commit:
                pg.commit()
            else:
                pg.rollback()
        except BaseException:
            raw.driver_connection.rollback()
            raise
        finally:
            raw.close()

    def read(self, tag_id: int, start: int, end: int, usable: bool = False):
        """Samples of one tag with start <= ts < end, ordered by ts (rows are fixed-width
        here: ``usable`` changes nothing)."""
        chunks = []
        with self._cursor(commit=False) as cur:
            with cur.copy(
                "COPY (SELECT ts, coalesce(value, 'NaN'::float8), quality FROM samples "
                f"WHERE tag_id = {int(tag_id)} AND ts >= {int(start)} AND ts < {int(end)} "
                "ORDER BY ts) TO STDOUT (FORMAT binary)"
            ) as cp:
                for data in cp:
                    chunks.append(bytes(data))
        buf = b"".join(chunks)
        body = buf[len(_PGHEADER) : len(buf) - len(_PGTRAILER)]
        if not body:
            return _empty()
        rows = np.frombuffer(body, dtype=_PG_OUT)
        return (
            rows["ts"].astype(np.int64),
            rows["value"].astype(np.float64),
            rows["quality"].astype(np.int64),
        )

    def recent_ts(self, tag_id: int, n: int) -> np.ndarray:
        """Times of the tag's last ``n`` samples in the database, ascending."""
        with self.engine.connect() as c:
            rows = c.exec_driver_sql(
                "SELECT ts FROM samples WHERE tag_id = %(t)s ORDER BY ts DESC LIMIT %(n)s",
                {"t": int(tag_id), "n": int(n)},
            ).scalars()
            return np.fromiter(rows, np.int64)[::-1]

    def size_bytes(self) -> int:
        """Bytes the database takes (``pg_database_size``)."""
        with self.engine.connect() as c:
            return int(c.exec_driver_sql("SELECT pg_database_size(current_database())").scalar())

    def free_bytes(self) -> None:
        """Not known without an extension (pgstattuple): dead rows are reclaimed by
        ``vacuum`` for reuse, ``vacuum(full=True)`` gives them back to the disk."""
        return None

    def vacuum(self, full: bool = False, tables: tuple[str, ...] = ()) -> None:
        """``VACUUM (ANALYZE)`` of the given tables (all of the database when empty): dead rows
        become reusable space and the planner's statistics are renewed; ``full`` rewrites the
        tables compactly and gives the space back to the disk (``VACUUM (FULL, ANALYZE)``,
        holding an exclusive lock on each table while it runs)."""
        opts = "FULL, ANALYZE" if full else "ANALYZE"
        with self.engine.connect().execution_options(isolation_level="AUTOCOMMIT") as c:
            c.exec_driver_sql(f"VACUUM ({opts}) {', '.join(tables)}".rstrip())

    def integrity_check(self) -> list[str]:
        """A sane check for PostgreSQL: no duplicate keys and the primary-key index is valid."""
        problems = []
        with self._cursor(commit=False) as cur:
            cur.execute(
                "SELECT count(*) FROM (SELECT tag_id, ts FROM samples "
                "GROUP BY tag_id, ts HAVING count(*) > 1) d"
            )
            dups = cur.fetchone()[0]
            if dups:
                problems.append(f"{dups} duplicated (tag_id, ts) keys in samples")
            cur.execute(
                "SELECT i.indisvalid FROM pg_index i JOIN pg_class c ON c.oid = i.indrelid "
                "WHERE c.relname = 'samples' AND i.indisprimary"
            )
            row = cur.fetchone()
            if row is None or not row[0]:
                problems.append("primary-key index of samples missing or invalid")
            cur.execute("SELECT count(*) FROM samples WHERE ts IS NULL OR tag_id IS NULL")
            if cur.fetchone()[0]:
                problems.append("samples with NULL keys")
        return problems
