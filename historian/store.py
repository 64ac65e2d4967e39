"""The historian: tags, samples and aligned windows, on SQLite or PostgreSQL.

:class:`Historian` is this core plus three mixins, each in its own module:
:class:`~historian.coldmonths.ColdMonths` (months rolled to the Parquet cold store),
:class:`~historian.registry.Registry` (model versions, experiments, diagnostic events) and
:class:`~historian.tagreport.TagReport` (``diag tags``).

>>> with Historian.open("sqlite:///diag.db") as h:          # doctest: +SKIP
...     h.write_samples(frame)                               # wide frame, one column per tag
...     w = h.window(["U17", "F17"], "2024-01-01", "2024-07-01", period="10s")
...     w.attrs["quality"]                                   # per-tag data-quality summary
"""

from __future__ import annotations

import math
import os
import sqlite3
import threading
from collections.abc import Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pandas as pd

from . import coldstore
from .backends import SQLITE_PRAGMAS, PostgresBulk, SqliteBulk
from .coldmonths import ColdMonths
from .frames import sorted_unique, tag_arrays
from .lazy import LazyModule
from .quality import BAD, GOOD
from .registry import Registry
from .sampling import SAMPLING_ROWS, Sampling, hold_us, sampling_of, snap_near, snap_up
from .sqlitefile import SqliteFile
from .sqlitemeta import SqliteMeta, sqlite_path
from .tagreport import TagReport
from .times import from_us, index_us, period_us, to_us, us_index
from .window import align, align_pieces, summarize, summary_attrs

#: SQLAlchemy and the historian's tables in it, imported on first use: a SQLite historian's
#: metadata reads need neither (:mod:`historian.sqlitemeta`)
sa = LazyModule("sqlalchemy")
schema = LazyModule("historian.schema")

DEFAULT_BATCH_ROWS = 500_000
#: the most threads of parallel per-tag reads in window(); a window of n tags uses
#: min(n, cores, this), each thread with its own database connection (SQLite: its own ADBC
#: connection, a WAL reader; PostgreSQL: one of the engine's pool). The ADBC driver steps
#: SQLite and builds the Arrow batches without the GIL (adbc_driver_manager runs
#: ``AdbcStatementExecuteQuery`` ``nogil``, pyarrow's ``read_all`` too): a pure-Python thread
#: got 0.27-0.45 s of CPU during one tag's 0.25 s read (issue 37, branch i37-pread)
READ_THREADS = 4


def read_threads(tags: int) -> int:
    """Threads of a window's per-tag reads: min(tags, the cores this process may run on,
    :data:`READ_THREADS`); 1 reads in the calling thread. More threads than cores only add
    connections: the reads are CPU-bound (SQLite's decode and the driver's Arrow building)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(1, min(tags, cores or 1, READ_THREADS))


class Historian(ColdMonths, Registry, TagReport):
    """Time-series store for plant tags on SQLite (default) or PostgreSQL.

    ``url``: ``sqlite:///path/diag.db`` or ``postgresql://user@127.0.0.1:5432/db``.
    ``cold_dir``: folder of the Parquet cold store. Default: the folder the database recorded
    when it first rolled months into another than SQLite's default, ``<db file>.cold`` beside
    the database (PostgreSQL has no default: give it to the first roll).
    ``busy_timeout``: seconds a SQLite write waits for another writer's lock before it fails
    (the live loop's writer uses a short one and retries on its own).
    ``timeout``: seconds any one statement may take at most, a wait for a lock included, and
    a connection too (PostgreSQL: ``statement_timeout`` and ``connect_timeout``; SQLite: the
    busy timeout, when shorter): a reader that must not hang on a locked or slow database
    (the live plug-in's catch-up and warm-up) fails after it instead. None: no bound.

    SQLite: the metadata (SQLAlchemy, the system's SQLite) and the samples (ADBC, its own
    SQLite) are two copies of SQLite in one process; every write transaction of either holds
    the file's in-process write lock and connections close only under it
    (:mod:`historian.sqlitefile`). The lock is waited for at most the busy timeout. The small
    metadata reads (tags, time ranges, rolled months, the cold folder) go through one
    ``sqlite3`` connection (:mod:`historian.sqlitemeta`), and :attr:`engine` is made on its
    first use, so a reading command does not import SQLAlchemy.
    """

    def __init__(
        self,
        url: str = "sqlite:///diag.db",
        *,
        cold_dir: str | Path | None = None,
        busy_timeout: float = 60.0,
        timeout: float | None = None,
    ):
        self.url = str(url)
        if timeout is not None and not timeout > 0:
            raise ValueError(f"timeout must be a positive number of seconds, not {timeout!r}")
        self._engine = None
        self._engine_lock = threading.Lock()
        self._meta: SqliteMeta | None = None
        plain = sqlite_path(self.url)  # sqlite:///path, read without SQLAlchemy
        u = None if plain is not None else _make_url(self.url)
        if plain is not None or u.get_backend_name() == "sqlite":
            database = plain if u is None else u.database
            if not database or database == ":memory:":
                raise ValueError("the SQLite historian needs a file: sqlite:///path/to/diag.db")
            path = Path(database)
            if timeout is not None:
                busy_timeout = min(busy_timeout, timeout)
            busy_ms = max(1, int(busy_timeout * 1000))
            self._bulk = SqliteBulk(path, busy_timeout_ms=busy_ms)
            self._file = self._bulk.file
            self._busy_ms = busy_ms
            self._lock_s: float | None = busy_ms / 1000
            self._default_cold_dir = path.with_name(path.name + ".cold")
            if u is None:  # a URL with options (a query) keeps SQLAlchemy's reads
                self._meta = SqliteMeta(path, self._file, busy_ms, SQLITE_PRAGMAS)
            else:
                self.engine  # noqa: B018 - made now, as the URL's options are SQLAlchemy's
        elif u.get_backend_name() == "postgresql":
            args = {}
            if timeout is not None:
                ms = max(1, int(timeout * 1000))
                args = {"connect_timeout": max(1, math.ceil(timeout))}
                args["options"] = f"-c statement_timeout={ms}"
            self._engine = sa.create_engine(
                u.set(drivername="postgresql+psycopg"), connect_args=args
            )
            self._bulk = PostgresBulk(self._engine)
            self._file = None
            self._default_cold_dir = None
        else:
            raise ValueError(f"unsupported database URL {self.url!r} (sqlite or postgresql)")
        self._closed = False
        if self._file is None:
            create_schema(self.engine)
        else:
            self._file.attach(self._prepare, self._lock_s)
        self.cold_dir = (
            Path(cold_dir) if cold_dir else self._recorded_cold_dir() or self._default_cold_dir
        )
        self._tags: dict[str, tuple[int, float | None, float | None]] = {}
        self._sampling: dict[str, Sampling] = {}  # per tag, for holds()
        self._pool: ThreadPoolExecutor | None = None

    # -- life cycle ----------------------------------------------------------------------
    @classmethod
    def open(cls, url: str = "sqlite:///diag.db", **kw) -> Historian:
        return cls(url, **kw)

    @property
    def engine(self):
        """The SQLAlchemy engine: writes and the registry's reads (on SQLite made on first
        use, its connections counted as reads of the file like the metadata's own)."""
        engine = self._engine
        if engine is not None:
            return engine
        with self._engine_lock:
            if self._engine is None:
                u = _make_url(self.url)
                engine = sa.create_engine(u.set(drivername="sqlite"))
                _count_reads(engine, self._file, self._busy_ms)
                self._engine = engine
            return self._engine

    def _prepare(self) -> None:
        """The schema of a SQLite file, under its write lock (``attach``): made by
        SQLAlchemy unless the metadata connection finds every table and index there."""
        if self._meta is not None:
            try:
                if self._meta.has_schema():
                    return
            except sqlite3.OperationalError as exc:  # another process making the file:
                if "locked" not in str(exc).lower():  # SQLAlchemy's create_schema retries
                    raise
        create_schema(self.engine)

    def _insert(self, table):
        if self.backend == "sqlite":
            from sqlalchemy.dialects.sqlite import insert as dialect_insert
        else:
            from sqlalchemy.dialects.postgresql import insert as dialect_insert
        return dialect_insert(table)

    @property
    def backend(self) -> str:
        """'sqlite' or 'postgresql'."""
        return self._bulk.name

    def _readers(self) -> ThreadPoolExecutor:
        """The threads of parallel per-tag reads, kept for the historian's life (starting
        them for every window of a chunked read cost more than some reads). The executor
        starts a thread only when no started one is idle, so a window of ``n`` tags runs
        :func:`read_threads` of them at most; their connections close with the historian."""
        if self._pool is None:
            self._pool = ThreadPoolExecutor(
                read_threads(READ_THREADS), thread_name_prefix="historian-read"
            )
        return self._pool

    @contextmanager
    def _writing(self):
        """``engine.begin()`` for a write transaction through SQLAlchemy; on SQLite under
        the file's in-process write lock (never beside a write of the ADBC connections)."""
        if self._file is None:
            with self.engine.begin() as c:
                yield c
            return
        with self._file.writing(self._lock_s), self.engine.begin() as c:
            yield c

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None
        if self._closed:
            return
        self._closed = True
        if self._file is None:
            self._bulk.close()
            self.engine.dispose()
        else:  # under the write lock: no close drops the locks of a transaction open
            self._file.detach(self._close_own)

    def _close_own(self) -> None:
        """A SQLite historian's connections (``detach``, under the file's write lock)."""
        try:
            self._bulk.close()
            if self._meta is not None:
                self._meta.close()
        finally:
            if self._engine is not None:
                self._engine.dispose()

    def __enter__(self) -> Historian:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- tags ----------------------------------------------------------------------------
    def ensure_tag(
        self,
        name: str,
        unit: str | None = None,
        lo: float | None = None,
        hi: float | None = None,
        description: str | None = None,
        source: str | None = None,
    ) -> int:
        """Id of tag ``name``, created if new; given (non-None) metadata is stored."""
        fields = {
            k: v
            for k, v in dict(
                unit=unit, lo=lo, hi=hi, description=description, source=source
            ).items()
            if v is not None
        }
        t = schema.tags
        with self._writing() as c:
            c.execute(self._insert(t).values(name=name).on_conflict_do_nothing())
            tag_id = c.execute(sa.select(t.c.id).where(t.c.name == name)).scalar_one()
            if fields:
                c.execute(sa.update(t).where(t.c.id == tag_id).values(**fields))
        self._tags.pop(name, None)
        return int(tag_id)

    def tags(self) -> pd.DataFrame:
        """All tags: columns id, name, unit, lo, hi, description, source (ordered by name)."""
        if self._meta is not None:
            rows = self._meta.rows(f"SELECT {', '.join(TAG_COLUMNS)} FROM tags ORDER BY name")
            return pd.DataFrame(rows, columns=list(TAG_COLUMNS))
        t = schema.tags
        with self.engine.connect() as c:
            rows = c.execute(sa.select(t).order_by(t.c.name)).all()
        return pd.DataFrame(rows, columns=[col.name for col in t.columns])

    def last_sample_tag(self) -> int:
        """The highest tag id holding a sample in the database (0: none), where the
        samples' ``(tag_id, ts)`` key ends; months rolled to the cold store aside."""
        if self._meta is not None:
            return int(self._meta.rows("SELECT max(tag_id) FROM samples")[0][0] or 0)
        with self.engine.connect() as c:
            return int(c.execute(sa.select(sa.func.max(schema.samples.c.tag_id))).scalar() or 0)

    def _tag(self, name: str, create: bool = False) -> tuple[int, float | None, float | None]:
        hit = self._tags.get(name)
        if hit is not None:
            return hit
        if self._meta is not None:
            found = self._meta.rows("SELECT id, lo, hi FROM tags WHERE name = ?", (name,))
            row = found[0] if found else None
        else:
            t = schema.tags
            with self.engine.connect() as c:
                row = c.execute(sa.select(t.c.id, t.c.lo, t.c.hi).where(t.c.name == name)).first()
        if row is None:
            if not create:
                raise KeyError(f"unknown tag {name!r}")
            self.ensure_tag(name)
            return self._tag(name)
        self._tags[name] = (int(row[0]), row[1], row[2])
        return self._tags[name]

    # -- writing -------------------------------------------------------------------------
    def write_samples(
        self,
        data: pd.DataFrame | pd.Series,
        quality: int | pd.DataFrame = GOOD,
        *,
        policy: str = "ignore",
        batch_rows: int = DEFAULT_BATCH_ROWS,
        create_tags: bool = True,
    ) -> int:
        """Store samples; returns the number of rows added (``policy="update"``: added or
        changed). Idempotent: a re-sent sample with a stored (tag, ts) is left alone
        (``policy="ignore"``, the default) or overwrites it (``"update"``; one holding the same
        value and quality is left alone and not counted).

        This holds for months rolled to the cold store too: the rolled (tag, ts) of the
        affected months are looked up in their Parquet file first. A new (late) sample, or
        with ``"update"`` a changed one, goes to the database; it wins over the cold file on
        read and is merged into the month at its next roll.

        Accepted shapes:

        - wide frame: DatetimeIndex (or a ``ts`` column), one column per tag; NaN cells are
          "no sample" and skipped; ``quality`` a code or a frame of codes of the same shape;
        - long frame: columns ``tag``, ``ts``, ``value`` and optionally ``quality``;
        - Series named by its tag, with a DatetimeIndex.

        Naive times are taken as UTC. Rows go in batches of ``batch_rows``, one transaction
        each, so an interrupted write keeps every completed batch.
        """
        if policy not in ("ignore", "update"):
            raise ValueError(f"policy must be 'ignore' or 'update', not {policy!r}")
        rolled = self._segments(None, None)
        total = 0
        for tag_id, ts, value, q in self._batches(data, quality, batch_rows, create_tags):
            if rolled:
                new = self._not_in_cold(rolled, tag_id, ts, value, q, policy)
                tag_id, ts, value, q = tag_id[new], ts[new], value[new], q[new]
            if len(ts):
                total += self._bulk.insert(tag_id, ts, value, q, policy=policy)
        return total

    def write_wide(
        self, values: pd.DataFrame, quality: pd.DataFrame, *, policy: str = "ignore"
    ) -> int:
        """Store a wide piece of an import; returns the rows added (``"update"``: added or
        changed), as :meth:`write_samples` counts them. ``values``: a DatetimeIndex, one
        column per existing tag; ``quality``: the codes, the same shape. Unlike
        :meth:`write_samples`, a cell is a sample when it holds a number *or* its quality is
        Bad (a cell of text kept as a Bad sample). A time given twice keeps its first row.

        On SQLite the piece goes in one transaction, staged as wide rows
        (:meth:`~historian.backends.SqliteBulk.insert_wide`); on PostgreSQL, or where it
        reaches a month rolled to the cold store, as the long rows of :meth:`write_samples`."""
        if policy not in ("ignore", "update"):
            raise ValueError(f"policy must be 'ignore' or 'update', not {policy!r}")
        ts = index_us(values.index)
        if not len(ts):
            return 0
        v = values.to_numpy(np.float64).T
        q = quality.to_numpy(np.int64).T
        if len(ts) > 1 and not np.all(ts[1:] > ts[:-1]):
            order = np.argsort(ts, kind="stable")
            ts, v, q = ts[order], v[:, order], q[:, order]
            first = np.r_[True, ts[1:] != ts[:-1]]
            ts, v, q = ts[first], v[:, first], q[:, first]
        ids = np.array([self._tag(str(name))[0] for name in values.columns], np.int64)
        rolled = self._segments(int(ts[0]), int(ts[-1]) + 1)
        if not rolled and hasattr(self._bulk, "insert_wide"):
            return self._bulk.insert_wide(ts, ids, v, q, policy=policy)
        c, r = np.nonzero(~np.isnan(v) | (q == BAD))  # tag-major, each tag in time order
        tag_id, ts, v, q = ids[c], ts[r], v[c, r], q[c, r]
        if rolled:
            new = self._not_in_cold(rolled, tag_id, ts, v, q, policy)
            tag_id, ts, v, q = tag_id[new], ts[new], v[new], q[new]
        total = 0
        for i in range(0, len(ts), DEFAULT_BATCH_ROWS):
            part = slice(i, i + DEFAULT_BATCH_ROWS)
            total += self._bulk.insert(tag_id[part], ts[part], v[part], q[part], policy=policy)
        return total

    def _batches(self, data, quality, batch_rows, create_tags):
        """Tag-major batches of at most ``batch_rows`` rows (tag_id, ts, value, quality)."""
        pending: list[tuple[np.ndarray, ...]] = []
        size = 0
        for name, ts, value, q in tag_arrays(data, quality):
            tag_id = self._tag(str(name), create=create_tags)[0]
            ts, value, q = sorted_unique(ts, value, q)
            pending.append((np.full(len(ts), tag_id, np.int64), ts, value, q))
            size += len(ts)
            while size >= batch_rows:
                cols = [np.concatenate(col) for col in zip(*pending, strict=True)]
                yield tuple(col[:batch_rows] for col in cols)
                rest = tuple(col[batch_rows:] for col in cols)
                pending, size = [rest], len(rest[0])
        if size:
            yield tuple(np.concatenate(col) for col in zip(*pending, strict=True))

    # -- reading -------------------------------------------------------------------------
    def _read_raw(self, tag_id: int, start: int, end: int, segments=None, usable=False):
        """(ts, value, quality) of one tag in [start, end), hot and cold rows combined.
        ``segments``: the list of rolled months, when the caller read it before this read;
        ``usable``: database rows may come with Bad samples as NaN values of GOOD quality
        (the same to an aligned window, and faster to read from SQLite)."""
        pieces = self._read_pieces(tag_id, start, end, segments, usable)
        if len(pieces) == 1:
            return pieces[0]
        return tuple(np.concatenate(col) for col in zip(*pieces, strict=True))

    def _read_pieces(
        self,
        tag_id: int,
        start: int,
        end: int,
        segments: list[dict] | None = None,
        usable: bool = False,
    ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """:meth:`_read_raw` as consecutive pieces in time order, not joined: the rolled
        months' row groups as they were decoded when the database holds no rows there, else
        one piece (the hot and cold rows merged)."""
        # hot first, then the segment list: a roll committing in between gives duplicates
        # (removed below), never a loss
        hot = self._bulk.read(tag_id, start, end, usable=usable)
        parts = self._read_cold(tag_id, start, end, segments)
        if not parts:
            return [hot]
        if not len(hot[0]):
            return parts
        parts.append(hot)
        ts, v, q = (np.concatenate(col) for col in zip(*parts, strict=True))
        order = np.argsort(ts, kind="stable")  # cold before hot at equal times
        ts, v, q = ts[order], v[order], q[order]
        last = np.r_[ts[1:] != ts[:-1], True]  # the hot row wins: an update
        return [(ts[last], v[last], q[last])]

    def read_samples(
        self, tag: str, start=None, end=None, *, with_quality: bool = False
    ) -> pd.Series | pd.DataFrame:
        """Raw samples of one tag with start <= ts < end (None: unbounded), as a Series of
        values indexed by tz-aware UTC ``ts`` (bad samples included as stored); with
        ``with_quality=True`` a frame with columns ``value`` and ``quality``."""
        tag_id = self._tag(tag)[0]
        s = to_us(start) if start is not None else np.iinfo(np.int64).min
        e = to_us(end) if end is not None else np.iinfo(np.int64).max
        ts, v, q = self._read_raw(tag_id, s, e)
        idx = us_index(ts)
        if with_quality:
            return pd.DataFrame({"value": v, "quality": q.astype(np.int8)}, index=idx)
        return pd.Series(v, index=idx, name=tag)

    def time_range(self, tags: Iterable[str] | None = None):
        """(first, last) sample time over the given tags (all when None); (None, None) if
        there are no samples. Rolled months answer from their files' row-group statistics."""
        ids = None if tags is None else [self._tag(t)[0] for t in tags]
        lo = hi = None
        for a, b in self._hot_bounds(ids):
            lo = a if lo is None or (a is not None and a < lo) else lo
            hi = b if hi is None or (b is not None and b > hi) else hi
        segments = self._segments(None, None)
        if ids is None:
            for seg in segments:
                lo = seg["ts_min"] if lo is None else min(lo, seg["ts_min"])
                hi = seg["ts_max"] if hi is None else max(hi, seg["ts_max"])
        elif segments:
            for tid in ids:
                a, b = self._cold_bounds(tid, segments)
                if a is not None:
                    lo = a if lo is None else min(lo, a)
                    hi = b if hi is None else max(hi, b)
        return from_us(lo), from_us(hi)

    def _hot_bounds(self, ids: list[int] | None) -> list[tuple[int | None, int | None]]:
        """(first, last) time of each tag's database rows (None, None without any); one
        pair over all tags when ``ids`` is None. Rolled months aside."""
        out = []
        if self._meta is not None:
            with self._meta.reading() as query:
                for tid in ids if ids is not None else [None]:
                    where, args = ("", ()) if tid is None else (" WHERE tag_id = ?", (tid,))
                    ends = []
                    for order in ("", " DESC"):
                        sql = f"SELECT ts FROM samples{where} ORDER BY ts{order} LIMIT 1"
                        found = query(sql, args)
                        ends.append(found[0][0] if found else None)
                    out.append((ends[0], ends[1]))
            return out
        s = schema.samples
        with self.engine.connect() as c:
            for tid in ids if ids is not None else [None]:
                base = sa.select(s.c.ts)
                if tid is not None:
                    base = base.where(s.c.tag_id == tid)
                a = c.execute(base.order_by(s.c.ts).limit(1)).scalar()
                b = c.execute(base.order_by(s.c.ts.desc()).limit(1)).scalar()
                out.append((a, b))
        return out

    def _grid(self, tags, start, end, period):
        """The requested range in µs and its grid: the first grid point at or after the
        start, and the period; open ends come from the tags' stored samples (the end one
        period past the last sample's grid point)."""
        p = period_us(period)
        if start is None or end is None:
            lo, hi = self.time_range(tags)
            if lo is None:
                raise ValueError(f"no samples for {list(tags)}")
            start = lo if start is None else start
            end = from_us(snap_near(to_us(hi), p) + p) if end is None else end
        s, e = to_us(start), to_us(end)
        if e <= s:
            raise ValueError("end must be after start")
        return s, e, snap_up(s, p), p

    # -- sampling --------------------------------------------------------------------------
    def sampling(self, tags: Iterable[str], start=None, end=None) -> dict[str, Sampling]:
        """How each tag is sampled over [start, end) (its whole history when both are None):
        the median and 95th-percentile spacing of its stored samples (:mod:`historian.sampling`)."""
        out = {}
        for name in tags:
            tag_id = self._tag(name)[0]
            s = to_us(start) if start is not None else np.iinfo(np.int64).min
            e = to_us(end) if end is not None else np.iinfo(np.int64).max
            ts, _, _ = self._read_raw(tag_id, s, e)
            out[name] = sampling_of(name, ts)
        return out

    def holds(self, tags: Iterable[str], period) -> dict[str, int]:
        """Per tag, how long its last sample stands in for later grid points of ``period``
        (µs, :func:`historian.sampling.hold_us`), from its most recent samples (measured once
        per tag and open historian, so every chunk of a job aligns alike)."""
        p = period_us(period)
        out = {}
        for name in tags:
            if name not in self._sampling:
                self._sampling[name] = sampling_of(name, self._recent_ts(self._tag(name)[0]))
            out[name] = hold_us(self._sampling[name], p)
        return out

    def _recent_ts(self, tag_id: int, n: int = SAMPLING_ROWS) -> np.ndarray:
        """Times of the tag's last ``n`` samples (the database first, then rolled months)."""
        ts = self._bulk.recent_ts(tag_id, n)
        if len(ts) >= n:
            return ts
        for seg in reversed(self._segments(None, None)):
            m0, m1 = coldstore.month_bounds(seg["month"])
            index = self._segment_index(seg)  # only the row groups holding the last rows
            cold, _, _ = index.read(tag_id, max(m0, index.tail_start(tag_id, n - len(ts))), m1)
            ts = np.r_[cold, ts]
            if len(ts) >= n:
                break
        return ts[-n:]

    # -- windows -----------------------------------------------------------------------------
    def window(
        self,
        tags: Iterable[str],
        start=None,
        end=None,
        period="10s",
        how: str = "mean",
        *,
        gap=None,
        flat="30min",
        hold: dict[str, int] | None = None,
        summary: bool = True,
    ) -> pd.DataFrame:
        """Tags aligned on the grid ``k·period`` (epoch-anchored): one row per grid point in
        [start, end), labelled by it, by the rule of :mod:`historian.sampling` (the mean or
        last usable sample within half a period; slower, irregular and on-change tags hold
        their last value for ``hold[tag]`` µs, default :meth:`holds`; else NaN). Index:
        tz-aware UTC, named ``ts``; one float column per tag. ``frame.attrs["quality"]``
        holds the per-tag data-quality summary as ``{tag: {field: value}}`` (fields in
        :func:`historian.window.summarize`; ``historian.quality_table(frame)`` gives it as a
        DataFrame); ``gap``/``flat`` are Timedelta-likes overriding the defaults.
        ``summary=False`` skips the summary (a training job reading months in chunks has no
        use for it; ``attrs`` stays empty).
        """
        tags = list(tags)
        s, e, t0, p = self._grid(tags, start, end, period)
        hold = self.holds(tags, period) if hold is None else hold
        return self._window(tags, e, t0, p, how, gap, flat, hold, summary)

    def _window(self, tags, e, t0, p, how, gap, flat, hold, summary=True) -> pd.DataFrame:
        n = max(0, -(-(e - t0) // p))
        half = p // 2
        lo, hi = t0 - half, t0 + n * p - half  # the bins of the rows
        gap_us = period_us(gap) if gap is not None else None
        flat_us = period_us(flat) if flat is not None else None
        meta = [self._tag(name) for name in tags]
        # the rolled months, listed once for all tags; checked again after the reads
        back_max = max((int(v) for v in hold.values()), default=0)
        segments = self._segments(lo - back_max, hi)

        # the frame's block, one row per tag, each tag's values aligned straight into it
        block = np.full((len(tags), n), np.nan)
        # without a hold, the database alone holding the rows (no rolled month) and the mean
        # or last of a bin: a tag's one sample on each grid point is its aligned column
        # (:func:`~historian.window.align`), read without its times
        grid = not segments and how in ("mean", "last") and hasattr(self._bulk, "read_grid")

        def one(i):
            tag_id, t_lo, t_hi = meta[i]
            back = int(hold.get(tags[i], 0))
            if not summary and grid and back == 0:  # a regular series on the grid: its values
                values = self._bulk.read_grid(tag_id, t0, p, n)
                if values is not None:
                    block[i] = values
                    return block[i], None
            if not summary:  # the pieces as read, each put on the grid where it lies
                pieces = self._read_pieces(tag_id, lo - back, hi, segments, usable=True)
                return align_pieces(pieces, t0, p, n, how, back, out=block[i]), None
            ts, v, q = self._read_raw(tag_id, lo - back, hi, segments)
            col = block[i]
            col[:] = align(ts, v, q, t0, p, n, how, back)
            inside = np.searchsorted(ts, lo)
            ts, v, q = ts[inside:], v[inside:], q[inside:]
            return col, summarize(
                ts, v, q, lo, hi, p, lo=t_lo, hi=t_hi, gap=gap_us, flat=flat_us, aligned=col
            )

        # tags in parallel: the database read, Parquet decoding and numpy release the GIL
        if read_threads(len(tags)) > 1:
            results = list(self._readers().map(one, range(len(tags))))
        else:
            results = [one(i) for i in range(len(tags))]
        if segments != self._segments(lo - back_max, hi):  # a roll committed meanwhile
            return self._window(tags, e, t0, p, how, gap, flat, hold, summary)
        index = us_index(t0 + p * np.arange(n, dtype=np.int64))
        frame = pd.DataFrame(block.T, index=index, columns=tags, copy=False)
        if summary:
            frame.attrs["quality"] = summary_attrs(
                {name: summ for name, (_, summ) in zip(tags, results, strict=True)}
            )
        return frame

    def iter_windows(
        self,
        tags: Iterable[str],
        start=None,
        end=None,
        period="10s",
        how: str = "mean",
        *,
        chunk="7D",
        gap=None,
        flat="30min",
        hold: dict[str, int] | None = None,
        summary: bool = True,
    ) -> Iterator[pd.DataFrame]:
        """Consecutive chunks of :meth:`window` (``chunk`` long, rounded to whole periods);
        ``pd.concat`` of them equals ``window(tags, start, end, period, how)`` exactly. Each
        chunk carries its own ``attrs["quality"]`` (unless ``summary=False``)."""
        tags = list(tags)
        s, e, t0, p = self._grid(tags, start, end, period)
        hold = self.holds(tags, period) if hold is None else hold
        step = max(1, period_us(chunk) // p) * p
        left = t0
        while left < e:
            right = min(left + step, e)
            yield self._window(tags, right, left, p, how, gap, flat, hold, summary)
            left += step

    # -- checks and upkeep ---------------------------------------------------------------
    def integrity_check(self, progress=None) -> list[str]:
        """Problems found (empty when sound), never raised: SQLite ``PRAGMA integrity_check``
        (or that it cannot run); for PostgreSQL duplicate keys, NULL keys and the primary-key
        index; each cold file readable and holding the row count recorded for its month.
        Every sample's tag must exist: samples under a tag id with no row in ``tags`` (left
        by a tag insert that was rolled back, e.g. on a full disk) are reported with their
        count. ``progress(done, total)`` is called after each cold file."""
        problems = list(self._bulk.integrity_check())
        try:
            orphans = self.orphan_samples()
        except Exception as exc:  # noqa: BLE001 - a check reports, never raises
            if not problems:  # else the database's own check already said it cannot be read
                problems.append(f"cannot check the samples' tags: {exc}")
        else:
            if orphans:
                ids = ", ".join(str(i) for i in list(orphans)[:10])
                more = f" and {len(orphans) - 10} more" if len(orphans) > 10 else ""
                problems.append(
                    f"{sum(orphans.values())} samples under {len(orphans)} tag ids that are "
                    f"in no row of tags (ids {ids}{more}): stored under the id of a tag "
                    "whose insert was rolled back; their tag is unknown"
                )
        return problems + self._cold_problems(progress)

    def orphan_samples(self) -> dict[int, int]:
        """Tag id → sample count, for sample tag ids that have no row in ``tags``. Walks the
        distinct tag ids through the primary key (one index seek each), so it costs the
        number of tags, not of samples."""
        s, t = schema.samples, schema.tags
        out: dict[int, int] = {}
        with self.engine.connect() as c:
            known = {int(i) for (i,) in c.execute(sa.select(t.c.id))}
            last = None
            while True:
                q = sa.select(sa.func.min(s.c.tag_id))
                if last is not None:
                    q = q.where(s.c.tag_id > last)
                last = c.execute(q).scalar()
                if last is None:
                    break
                if int(last) not in known:
                    n = c.execute(
                        sa.select(sa.func.count()).select_from(s).where(s.c.tag_id == last)
                    ).scalar()
                    out[int(last)] = int(n or 0)
        return out

    def storage(self) -> dict:
        """Where the data are and how much room they take: ``backend``, ``db_bytes`` (file
        and log, or the PostgreSQL database), ``free_bytes`` (SQLite: free pages a vacuum
        returns to the disk; None on PostgreSQL), ``cold_dir``, ``cold_months`` and
        ``cold_rows``/``cold_bytes`` of the rolled months' files."""
        segments = self._segments(None, None)
        cold_bytes = 0
        for seg in segments:
            try:
                cold_bytes += self._cold_path(seg["path"]).stat().st_size
            except OSError:  # reported by integrity_check
                pass
        return {
            "backend": self.backend,
            "db_bytes": self._bulk.size_bytes(),
            "free_bytes": self._bulk.free_bytes(),
            "cold_dir": None if self.cold_dir is None else str(self.cold_dir),
            "cold_months": [seg["month"] for seg in segments],
            "cold_rows": int(sum(seg["rows"] for seg in segments)),
            "cold_bytes": cold_bytes,
        }

    def vacuum(self, *, full: bool = False) -> dict:
        """Give the room of deleted rows (months rolled to the cold store) back: SQLite
        ``VACUUM`` (the file shrinks; it needs as much free disk as the database takes while
        it runs), PostgreSQL ``VACUUM (ANALYZE)`` of the historian's tables (the room becomes
        reusable; ``full=True``: ``VACUUM (FULL, ANALYZE)``, which gives it back to the disk
        but locks each table while it rewrites it). Returns ``db_bytes`` before and after."""
        before = self._bulk.size_bytes()
        if self.backend == "postgresql":
            self._bulk.vacuum(full, tuple(schema.metadata.tables))
        else:
            self._bulk.vacuum(full)
        return {
            "backend": self.backend,
            "before_bytes": before,
            "after_bytes": self._bulk.size_bytes(),
        }


#: the columns of ``tags`` (:data:`historian.schema.tags`), in its order
TAG_COLUMNS = ("id", "name", "unit", "lo", "hi", "description", "source")


def _make_url(url: str):
    """SQLAlchemy's reading of a database URL."""
    from sqlalchemy.engine import make_url

    return make_url(url)


def create_schema(engine, tries: int = 8) -> None:
    """Create the historian's tables and indexes that do not exist yet. Two processes starting
    on a new database at once race between "does it exist?" and CREATE ("table tags already
    exists", or on PostgreSQL a duplicate type name): the loser looks again — the check is
    repeated on a fresh connection, so what the winner made is seen and kept."""
    import time

    from sqlalchemy.exc import DBAPIError

    for attempt in range(tries):
        try:
            schema.metadata.create_all(engine, checkfirst=True)
            return
        except DBAPIError as exc:
            text = str(getattr(exc, "orig", exc)).lower()
            if attempt == tries - 1 or not (
                "already exists" in text or "duplicate" in text or "locked" in text
            ):
                raise
            time.sleep(0.05 * (attempt + 1))


def _count_reads(engine, file: SqliteFile, busy_ms: int) -> None:
    """SQLAlchemy's connections on the SQLite file: the historian's pragmas on each new one,
    and a connection in use (checked out of the pool) counted as a read of the file until it
    is returned (rolled back), so no checkpoint runs under it (:mod:`historian.sqlitefile`)."""
    wait_s = busy_ms / 1000

    def connect(dbapi_conn, _record) -> None:
        with file.reading(wait_s):
            _sqlite_pragmas(dbapi_conn, busy_ms)

    def checkout(_dbapi_conn, record, _proxy) -> None:
        file.enter_read(wait_s)
        record.record_info["reading"] = True

    def checkin(_dbapi_conn, record) -> None:
        # only a counted checkout: the pool checks a connection in after a failed one too
        if record.record_info.pop("reading", False):
            file.leave_read()

    sa.event.listen(engine, "connect", connect)
    sa.event.listen(engine, "checkout", checkout)
    sa.event.listen(engine, "checkin", checkin)


def _sqlite_pragmas(dbapi_conn, busy_ms: int = 60_000) -> None:
    cur = dbapi_conn.cursor()
    cur.execute(f"PRAGMA busy_timeout={int(busy_ms)}")
    for pragma in SQLITE_PRAGMAS:
        cur.execute(pragma)
    cur.close()
