"""The historian: tags, samples, aligned windows, experiment log, diagnostic events.

>>> with Historian.open("sqlite:///diag.db") as h:          # doctest: +SKIP
...     h.write_samples(frame)                               # wide frame, one column per tag
...     w = h.window(["U17", "F17"], "2024-01-01", "2024-07-01", period="10s")
...     w.attrs["quality"]                                   # per-tag data-quality summary
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pandas as pd
from sqlalchemy import create_engine, delete, event, insert, select, update
from sqlalchemy.engine import make_url

from . import coldstore, schema
from .backends import PostgresBulk, SqliteBulk
from .quality import GOOD
from .times import from_us, index_us, period_us, to_us, us_index
from .window import align, summarize, summary_attrs, summary_frame

DEFAULT_BATCH_ROWS = 500_000
#: parallel per-tag reads in window()
READ_THREADS = 4


def _now_us() -> int:
    return int(time.time() * 1_000_000)


class Historian:
    """Time-series store for plant tags on SQLite (default) or PostgreSQL.

    ``url``: ``sqlite:///path/diag.db`` or ``postgresql://user@127.0.0.1:5432/db``.
    ``cold_dir``: folder of the Parquet cold store (default for SQLite: ``<db file>.cold``
    beside the database; PostgreSQL needs it given to roll or read rolled months).
    """

    def __init__(self, url: str = "sqlite:///diag.db", *, cold_dir: str | Path | None = None):
        self.url = str(url)
        u = make_url(self.url)
        if u.get_backend_name() == "sqlite":
            if not u.database or u.database == ":memory:":
                raise ValueError("the SQLite historian needs a file: sqlite:///path/to/diag.db")
            path = Path(u.database)
            self.engine = create_engine(u.set(drivername="sqlite"))
            event.listen(self.engine, "connect", _sqlite_pragmas)
            self._bulk = SqliteBulk(path)
            self.cold_dir = Path(cold_dir) if cold_dir else path.with_name(path.name + ".cold")
        elif u.get_backend_name() == "postgresql":
            self.engine = create_engine(u.set(drivername="postgresql+psycopg"))
            self._bulk = PostgresBulk(self.engine)
            self.cold_dir = Path(cold_dir) if cold_dir else None
        else:
            raise ValueError(f"unsupported database URL {self.url!r} (sqlite or postgresql)")
        schema.metadata.create_all(self.engine)
        self._tags: dict[str, tuple[int, float | None, float | None]] = {}

    # -- life cycle ----------------------------------------------------------------------
    @classmethod
    def open(cls, url: str = "sqlite:///diag.db", **kw) -> Historian:
        return cls(url, **kw)

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

    def close(self) -> None:
        self._bulk.close()
        self.engine.dispose()

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
        with self.engine.begin() as c:
            c.execute(self._insert(t).values(name=name).on_conflict_do_nothing())
            tag_id = c.execute(select(t.c.id).where(t.c.name == name)).scalar_one()
            if fields:
                c.execute(update(t).where(t.c.id == tag_id).values(**fields))
        self._tags.pop(name, None)
        return int(tag_id)

    def tags(self) -> pd.DataFrame:
        """All tags: columns id, name, unit, lo, hi, description, source (ordered by name)."""
        t = schema.tags
        with self.engine.connect() as c:
            rows = c.execute(select(t).order_by(t.c.name)).all()
        return pd.DataFrame(rows, columns=[col.name for col in t.columns])

    def _tag(self, name: str, create: bool = False) -> tuple[int, float | None, float | None]:
        hit = self._tags.get(name)
        if hit is not None:
            return hit
        t = schema.tags
        with self.engine.connect() as c:
            row = c.execute(select(t.c.id, t.c.lo, t.c.hi).where(t.c.name == name)).first()
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

    def _batches(self, data, quality, batch_rows, create_tags):
        """Tag-major batches of at most ``batch_rows`` rows (tag_id, ts, value, quality)."""
        pending: list[tuple[np.ndarray, ...]] = []
        size = 0
        for name, ts, value, q in _iter_tag_arrays(data, quality):
            tag_id = self._tag(str(name), create=create_tags)[0]
            ts, value, q = _sorted_unique(ts, value, q)
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
    def _read_raw(self, tag_id: int, start: int, end: int):
        # hot first, then the segment list: a roll committing in between gives duplicates
        # (removed below), never a loss
        hot = self._bulk.read(tag_id, start, end)
        segs = self._segments(start, end)
        if not segs:
            return hot
        parts = []
        for seg in segs:
            m0, m1 = coldstore.month_bounds(seg["month"])
            _, ts, v, q = coldstore.read_segment(
                self._cold_path(seg["path"]), tag_id, max(start, m0), min(end, m1)
            )
            parts.append((ts, v, q))
        parts.append(hot)
        ts, v, q = (np.concatenate(col) for col in zip(*parts, strict=True))
        if len(parts) > 1 and len(hot[0]):
            order = np.argsort(ts, kind="stable")  # cold before hot at equal times
            ts, v, q = ts[order], v[order], q[order]
            last = np.r_[ts[1:] != ts[:-1], True]  # the hot row wins: an update
            ts, v, q = ts[last], v[last], q[last]
        return ts, v, q

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
        there are no samples."""
        s = schema.samples
        ids = None if tags is None else [self._tag(t)[0] for t in tags]
        lo = hi = None
        with self.engine.connect() as c:
            for tid in ids if ids is not None else [None]:
                base = select(s.c.ts)
                if tid is not None:
                    base = base.where(s.c.tag_id == tid)
                a = c.execute(base.order_by(s.c.ts).limit(1)).scalar()
                b = c.execute(base.order_by(s.c.ts.desc()).limit(1)).scalar()
                lo = a if lo is None or (a is not None and a < lo) else lo
                hi = b if hi is None or (b is not None and b > hi) else hi
        for seg in self._segments(None, None):
            lo = seg["ts_min"] if lo is None else min(lo, seg["ts_min"])
            hi = seg["ts_max"] if hi is None else max(hi, seg["ts_max"])
        if ids is not None and self._segments(None, None):
            lo, hi = self._time_range_exact(ids, lo, hi)
        return from_us(lo), from_us(hi)

    def _time_range_exact(self, ids, lo, hi):
        """Per-tag bounds when cold segments exist (segment bounds cover all tags)."""
        first = last = None
        for tid in ids:
            ts, _, _ = self._read_raw(tid, lo, hi + 1)
            if len(ts):
                first = ts[0] if first is None else min(first, ts[0])
                last = ts[-1] if last is None else max(last, ts[-1])
        return first, last

    def _grid(self, tags, start, end, period):
        p = period_us(period)
        if start is None or end is None:
            lo, hi = self.time_range(tags)
            if lo is None:
                raise ValueError(f"no samples for {list(tags)}")
            start = lo if start is None else start
            end = hi + pd.Timedelta(1, "us") if end is None else end
        s, e = to_us(start), to_us(end)
        if e <= s:
            raise ValueError("end must be after start")
        t0 = s - (s % p)  # grid anchored on the epoch, so chunks and windows line up
        return s, e, t0, p

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
    ) -> pd.DataFrame:
        """Tags aligned on the regular grid ``k·period`` (epoch-anchored) over [start, end).

        Each row is labelled by the left edge of its period and holds the mean (``how="mean"``)
        or the last (``how="last"``) usable sample in it; bad-quality samples count as missing,
        so a period without a usable sample is NaN. Index: tz-aware UTC, named ``ts``; one
        float column per tag. ``frame.attrs["quality"]`` holds the per-tag data-quality
        summary as ``{tag: {field: value}}`` (fields in :func:`historian.window.summarize`;
        ``historian.quality_table(frame)`` gives it as a DataFrame); ``gap``/``flat`` are
        Timedelta-likes overriding the defaults.
        """
        tags = list(tags)
        s, e, t0, p = self._grid(tags, start, end, period)
        return self._window(tags, s, e, t0, p, how, gap, flat)

    def _window(self, tags, s, e, t0, p, how, gap, flat) -> pd.DataFrame:
        n = -(-(e - t0) // p)
        cols, summary = {}, {}
        gap_us = period_us(gap) if gap is not None else None
        flat_us = period_us(flat) if flat is not None else None
        meta = [self._tag(name) for name in tags]

        def one(i):
            tag_id, lo, hi = meta[i]
            ts, v, q = self._read_raw(tag_id, s, e)
            col = align(ts, v, q, t0, p, n, how)
            return col, summarize(
                ts, v, q, s, e, p, lo=lo, hi=hi, gap=gap_us, flat=flat_us, aligned=col
            )

        # one thread per tag: the database read and numpy release the GIL
        if len(tags) > 1:
            with ThreadPoolExecutor(min(len(tags), READ_THREADS)) as ex:
                results = list(ex.map(one, range(len(tags))))
        else:
            results = [one(0)] if tags else []
        for name, (col, summ) in zip(tags, results, strict=True):
            cols[name] = col
            summary[name] = summ
        index = us_index(t0 + p * np.arange(n, dtype=np.int64))
        frame = pd.DataFrame(cols, index=index, columns=tags)
        frame.attrs["quality"] = summary_attrs(summary)
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
    ) -> Iterator[pd.DataFrame]:
        """Consecutive chunks of :meth:`window` (``chunk`` long, rounded to whole periods);
        ``pd.concat`` of them equals ``window(tags, start, end, period, how)`` exactly. Each
        chunk carries its own ``attrs["quality"]``."""
        tags = list(tags)
        s, e, t0, p = self._grid(tags, start, end, period)
        step = max(1, period_us(chunk) // p) * p
        left = t0
        while left < e:
            right = min(left + step, e)
            yield self._window(tags, max(s, left), right, left, p, how, gap, flat)
            left += step

    # -- cold store ----------------------------------------------------------------------
    def _cold_path(self, name: str) -> Path:
        if self.cold_dir is None:
            raise RuntimeError("this database has rolled months: open it with cold_dir=...")
        return self.cold_dir / name

    def _segments(self, start: int | None, end: int | None) -> list[dict]:
        t = schema.cold_segments
        with self.engine.connect() as c:
            rows = c.execute(select(t).order_by(t.c.month)).mappings().all()
        if start is None:
            return [dict(r) for r in rows]
        out = []
        for r in rows:
            m0, m1 = coldstore.month_bounds(r["month"])
            if m0 < end and m1 > start:
                out.append(dict(r))
        return out

    def _not_in_cold(self, rolled, tag_id, ts, value, q, policy: str) -> np.ndarray:
        """Mask of the batch rows the database still needs: rows in a rolled month whose
        (tag, ts) the cold file holds are dropped (with ``"update"``: only when it holds the
        same value and quality). Reads, per affected month, only the batch's tags and span."""
        keep = np.ones(len(ts), bool)
        for seg in rolled:
            m0, m1 = coldstore.month_bounds(seg["month"])
            rows = np.flatnonzero((ts >= m0) & (ts < m1))
            if not len(rows):
                continue
            tids = np.unique(tag_id[rows])
            c_tid, c_ts, c_v, c_q = coldstore.read_segment(
                self._cold_path(seg["path"]), tids, int(ts[rows].min()), int(ts[rows].max()) + 1
            )
            starts = np.searchsorted(c_tid, tids, "left")
            ends = np.searchsorted(c_tid, tids, "right")
            for tid, a, b in zip(tids, starts, ends, strict=True):
                if a == b:
                    continue
                mine = rows[tag_id[rows] == tid]
                pos = np.minimum(np.searchsorted(c_ts[a:b], ts[mine]), b - a - 1) + a
                stored = c_ts[pos] == ts[mine]
                if policy == "update":
                    same_value = (c_v[pos] == value[mine]) | (
                        np.isnan(c_v[pos]) & np.isnan(value[mine])
                    )
                    stored &= same_value & (c_q[pos] == q[mine])
                keep[mine[stored]] = False
        return keep

    def cold_months(self) -> list[str]:
        return [r["month"] for r in self._segments(None, None)]

    def roll_months(self, before=None) -> list[str]:
        """Move every closed month (ending at or before ``before``, default: the start of the
        current UTC month) from the database to the Parquet cold store. Returns the months
        rolled. Reads see the same data before and after."""
        if self.cold_dir is None:
            raise RuntimeError("roll_months needs cold_dir=... for this database")
        limit = (
            to_us(before)
            if before is not None
            else to_us(pd.Timestamp.now(tz="UTC").normalize().replace(day=1))
        )
        s = schema.samples
        with self.engine.connect() as c:
            lo = c.execute(select(s.c.ts).order_by(s.c.ts).limit(1)).scalar()
        if lo is None:
            return []
        rolled = []
        for month in coldstore.months_between(lo, limit):
            m0, m1 = coldstore.month_bounds(month)
            if m1 > limit:
                break
            if self._roll_month(month, m0, m1):
                rolled.append(month)
        return rolled

    def _roll_month(self, month: str, m0: int, m1: int) -> bool:
        s, t = schema.samples, schema.cold_segments
        ids = [int(i) for i in self.tags()["id"]]
        parts = []
        for tid in sorted(ids):
            ts, v, q = self._bulk.read(tid, m0, m1)
            if len(ts):
                parts.append((np.full(len(ts), tid, np.int64), ts, v, q))
        if not parts:
            return False
        old = self._segments(m0, m1)
        if old:  # merge: hot rows at a (tag, ts) of the cold file are updates, they win
            parts = [coldstore.read_segment(self._cold_path(old[0]["path"]))] + parts
        tid, ts, v, q = (np.concatenate(col) for col in zip(*parts, strict=True))
        if old:
            order = np.lexsort((ts, tid))  # stable: cold before hot at an equal key
            tid, ts, v, q = tid[order], ts[order], v[order], q[order]
            last = np.r_[(tid[1:] != tid[:-1]) | (ts[1:] != ts[:-1]), True]
            tid, ts, v, q = tid[last], ts[last], v[last], q[last]
        name = f"samples-{month}-{_now_us()}.parquet"
        rows = coldstore.write_segment(self._cold_path(name), tid, ts, v, q)
        with self.engine.begin() as c:
            c.execute(delete(t).where(t.c.month == month))
            c.execute(
                insert(t).values(
                    month=month,
                    path=name,
                    rows=rows,
                    ts_min=int(ts.min()),
                    ts_max=int(ts.max()),
                    created_at=_now_us(),
                )
            )
            c.execute(delete(s).where(s.c.ts >= m0, s.c.ts < m1))
        if old and old[0]["path"] != name:
            try:
                os.remove(self._cold_path(old[0]["path"]))
            except FileNotFoundError:
                pass
        return True

    # -- checks --------------------------------------------------------------------------
    def integrity_check(self) -> list[str]:
        """Problems found (empty when sound), never raised: SQLite ``PRAGMA integrity_check``
        (or that it cannot run); for PostgreSQL duplicate keys, NULL keys and the primary-key
        index; each cold file readable and holding the row count recorded for its month."""
        problems = list(self._bulk.integrity_check())
        try:
            segments = self._segments(None, None)
        except Exception as exc:  # noqa: BLE001 - report, do not raise
            return [*problems, f"cold segment list unreadable: {exc}"]
        for seg in segments:
            try:
                import pyarrow.parquet as pq

                if pq.ParquetFile(self._cold_path(seg["path"])).metadata.num_rows != seg["rows"]:
                    problems.append(f"cold segment {seg['month']}: row count differs")
            except Exception as exc:  # noqa: BLE001 - report, do not raise
                problems.append(f"cold segment {seg['month']}: {exc}")
        return problems

    # -- model registry and experiment log -----------------------------------------------
    def record_model_version(
        self, name: str, version: str, rulebase_text: str | None = None, created_at=None
    ) -> int:
        """Store a model version (its rule-base text); returns its id. Re-recording the same
        (name, version) replaces the text."""
        t = schema.model_versions
        at = to_us(created_at) if created_at is not None else _now_us()
        with self.engine.begin() as c:
            row = c.execute(
                select(t.c.id).where(t.c.name == name, t.c.version == str(version))
            ).first()
            if row is not None:
                c.execute(update(t).where(t.c.id == row[0]).values(rulebase_text=rulebase_text))
                return int(row[0])
            res = c.execute(
                insert(t).values(
                    name=name, version=str(version), rulebase_text=rulebase_text, created_at=at
                )
            )
            return int(res.inserted_primary_key[0])

    def model_versions(self, name: str | None = None) -> pd.DataFrame:
        t = schema.model_versions
        q = select(t).order_by(t.c.name, t.c.created_at, t.c.id)
        if name is not None:
            q = q.where(t.c.name == name)
        with self.engine.connect() as c:
            frame = pd.DataFrame(c.execute(q).all(), columns=[col.name for col in t.columns])
        frame["created_at"] = _ts_column(frame["created_at"])
        return frame

    def record_experiment(
        self,
        model: str,
        version: str | None,
        inputs: list[str],
        data_from,
        data_to,
        metrics: dict,
        *,
        notes: str | None = None,
        created_at=None,
    ) -> int:
        """Log a training/validation run; returns its id."""
        t = schema.experiments
        with self.engine.begin() as c:
            res = c.execute(
                insert(t).values(
                    model=model,
                    version=None if version is None else str(version),
                    inputs=json.dumps(list(inputs)),
                    data_from=to_us(data_from) if data_from is not None else None,
                    data_to=to_us(data_to) if data_to is not None else None,
                    metrics=json.dumps(metrics, sort_keys=True, default=float),
                    notes=notes,
                    created_at=to_us(created_at) if created_at is not None else _now_us(),
                )
            )
            return int(res.inserted_primary_key[0])

    def experiments(self, model: str | None = None) -> pd.DataFrame:
        """Experiments (oldest first): id, model, version, inputs (list), data_from, data_to,
        metrics (dict), notes, created_at."""
        t = schema.experiments
        q = select(t).order_by(t.c.created_at, t.c.id)
        if model is not None:
            q = q.where(t.c.model == model)
        with self.engine.connect() as c:
            frame = pd.DataFrame(c.execute(q).all(), columns=[col.name for col in t.columns])
        frame["inputs"] = [json.loads(x) for x in frame["inputs"]]
        frame["metrics"] = [json.loads(x) for x in frame["metrics"]]
        for col in ("data_from", "data_to", "created_at"):
            frame[col] = _ts_column(frame[col])
        return frame

    # -- diagnostic events ---------------------------------------------------------------
    def record_event(
        self,
        ts,
        unit: str,
        *,
        fault: str | None = None,
        status: int = 0,
        certainty: float | None = None,
        severity: int | None = None,
        quality: int = GOOD,
        message: str | None = None,
    ) -> int:
        """Store one diagnosis (NE 107 ``status``, fault ``certainty``); returns its id."""
        t = schema.diag_events
        with self.engine.begin() as c:
            res = c.execute(
                insert(t).values(
                    ts=to_us(ts),
                    unit=unit,
                    fault=fault,
                    status=int(status),
                    certainty=certainty,
                    severity=severity,
                    quality=int(quality),
                    message=message,
                )
            )
            return int(res.inserted_primary_key[0])

    def events(self, unit: str | None = None, start=None, end=None) -> pd.DataFrame:
        t = schema.diag_events
        q = select(t).order_by(t.c.ts, t.c.id)
        if unit is not None:
            q = q.where(t.c.unit == unit)
        if start is not None:
            q = q.where(t.c.ts >= to_us(start))
        if end is not None:
            q = q.where(t.c.ts < to_us(end))
        with self.engine.connect() as c:
            frame = pd.DataFrame(c.execute(q).all(), columns=[col.name for col in t.columns])
        frame["ts"] = _ts_column(frame["ts"])
        return frame

    # -- tag report ----------------------------------------------------------------------
    def tag_report(self, start=None, end=None, *, flat="30min") -> pd.DataFrame:
        """Per tag: metadata, sampling interval and the data-quality summary over its own
        time span (or [start, end)); what ``diag tags`` shows."""
        tags = self.tags()
        rows = {}
        for name, lo, hi in zip(tags["name"], tags["lo"], tags["hi"], strict=True):
            tag_id = self._tag(name)[0]
            s = to_us(start) if start is not None else np.iinfo(np.int64).min
            e = to_us(end) if end is not None else np.iinfo(np.int64).max
            ts, v, q = self._read_raw(tag_id, s, e)
            dt = int(np.median(np.diff(ts))) if len(ts) > 2 else 1_000_000
            s2 = ts[0] if start is None and len(ts) else s
            e2 = ts[-1] + dt if end is None and len(ts) else e
            if not len(ts) and (start is None or end is None):
                s2, e2 = 0, 1
            row = summarize(
                ts, v, q, s2, e2, max(dt, 1), lo=_num(lo), hi=_num(hi), flat=period_us(flat)
            )
            row["interval_s"] = dt / 1e6 if len(ts) > 2 else np.nan
            rows[name] = row
        report = summary_frame(rows).reset_index()
        report["interval_s"] = [rows[n]["interval_s"] for n in report["tag"]]
        meta = tags.rename(columns={"name": "tag"}).drop(columns=["id"])
        return meta.merge(report, on="tag", how="left")


def _num(x):
    return None if x is None or (isinstance(x, float) and np.isnan(x)) else float(x)


def _ts_column(col: pd.Series) -> pd.Series:
    vals = pd.array(col, dtype="Int64")
    return pd.Series(
        [from_us(v) if v is not pd.NA else pd.NaT for v in vals],
        index=col.index,
        dtype="datetime64[us, UTC]",
    )


def _sqlite_pragmas(dbapi_conn, _record) -> None:
    cur = dbapi_conn.cursor()
    cur.execute("PRAGMA busy_timeout=60000")
    cur.execute("PRAGMA journal_mode=WAL")
    cur.execute("PRAGMA synchronous=FULL")
    cur.close()


def _sorted_unique(ts, value, q):
    """Sort by time and keep the first of equal times (what the database would keep)."""
    if len(ts) > 1 and not np.all(ts[1:] > ts[:-1]):
        order = np.argsort(ts, kind="stable")
        ts, value, q = ts[order], value[order], q[order]
        first = np.r_[True, ts[1:] != ts[:-1]]
        ts, value, q = ts[first], value[first], q[first]
    return ts, value, q


def _iter_tag_arrays(data, quality):
    """Yield (tag, ts µs, value float64, quality int64) per tag from any accepted shape."""
    if isinstance(data, pd.Series):
        if data.name is None:
            raise ValueError("a Series needs its tag as name")
        ts = index_us(data.index)
        value = pd.to_numeric(data, errors="raise").to_numpy(np.float64, na_value=np.nan)
        q = _quality_array(quality, len(ts), data.name)
        yield data.name, ts, value, q
        return
    if not isinstance(data, pd.DataFrame):
        raise TypeError("write_samples takes a DataFrame or a Series")
    cols = set(data.columns)
    if {"tag", "ts", "value"} <= cols:  # long
        ts_all = index_us(data["ts"])
        tag_codes, names = pd.factorize(data["tag"])
        value_all = pd.to_numeric(data["value"]).to_numpy(np.float64, na_value=np.nan)
        if "quality" in cols:
            q_all = data["quality"].to_numpy(np.int64)
        else:
            q_all = np.full(len(data), int(quality), np.int64)
        order = np.argsort(tag_codes, kind="stable")
        bounds = np.searchsorted(tag_codes[order], np.arange(len(names) + 1))
        for i, name in enumerate(names):
            sel = order[bounds[i] : bounds[i + 1]]
            yield name, ts_all[sel], value_all[sel], q_all[sel]
        return
    # wide
    if isinstance(data.index, pd.DatetimeIndex):
        ts = index_us(data.index)
        body = data
    elif "ts" in cols:
        ts = index_us(data["ts"])
        body = data.drop(columns=["ts"])
    else:
        raise ValueError("a wide frame needs a DatetimeIndex or a 'ts' column")
    for name in body.columns:
        value = pd.to_numeric(body[name]).to_numpy(np.float64, na_value=np.nan)
        if isinstance(quality, pd.DataFrame):
            q = quality[name].to_numpy(np.int64)
        else:
            q = np.full(len(value), int(quality), np.int64)
        present = ~np.isnan(value)
        if present.all():
            yield name, ts, value, q
        else:
            yield name, ts[present], value[present], q[present]


def _quality_array(quality, n, name):
    if isinstance(quality, pd.Series):
        return quality.to_numpy(np.int64)
    if isinstance(quality, pd.DataFrame):
        return quality[name].to_numpy(np.int64)
    return np.full(n, int(quality), np.int64)
