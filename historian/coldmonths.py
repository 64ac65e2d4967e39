"""Months rolled to the Parquet cold store, on the database side: rolling a closed month
into its file, or merging an import's samples of a closed month straight into it
(:mod:`historian.coldstore` writes and reads the files), the list of rolled months and where
their folder is, the key check that keeps writes into them idempotent, and the check of the
files. Mixed into :class:`historian.store.Historian`."""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import coldstore
from .lazy import LazyModule
from .times import now_us, to_us

sa = LazyModule("sqlalchemy")
schema = LazyModule("historian.schema")

#: times a month is re-read when rows arrived in it while it was being rolled
ROLL_ATTEMPTS = 3
#: key of the cold folder in the ``settings`` table
COLD_DIR_KEY = "cold_dir"

#: the columns of ``cold_segments`` (:data:`historian.schema.cold_segments`), in its order
SEGMENT_COLUMNS = ("month", "path", "rows", "ts_min", "ts_max", "created_at")

Progress = Callable[[int, int], None]


class MonthChanged(RuntimeError):
    """Rows of a month were written while it was being rolled (nothing was changed)."""


@dataclass
class MonthMerge:
    """What :meth:`ColdMonths.import_month` found: given samples at a (tag, ts) not stored
    before (``added``), stored with another value or quality (``changed``: conflicts), the
    earliest of those as ``(ts, tag id, stored value, stored quality, value, quality)``, and
    whether a new file was written."""

    added: int = 0
    changed: int = 0
    first: tuple[int, int, float, int, float, int] | None = None
    wrote: bool = False

    def count(self, tag_id: int, stored, new) -> None:
        s_ts, s_v, s_q = stored
        ts, v, q = new
        if not len(s_ts):
            self.added += len(ts)
            return
        pos = np.minimum(np.searchsorted(s_ts, ts), len(s_ts) - 1)
        hit = s_ts[pos] == ts
        sv = s_v[pos]
        same = ((sv == v) | (np.isnan(sv) & np.isnan(v))) & (s_q[pos] == q)
        differ = np.flatnonzero(hit & ~same)
        self.added += int(np.count_nonzero(~hit))
        self.changed += len(differ)
        if len(differ) and (self.first is None or ts[differ[0]] < self.first[0]):
            k, i = int(differ[0]), int(pos[differ[0]])
            self.first = (int(ts[k]), tag_id, float(s_v[i]), int(s_q[i]), float(v[k]), int(q[k]))


class ColdMonths:
    """Needs ``self.engine``, ``self._meta`` (None: metadata read through the engine),
    ``self._writing()``, ``self._bulk`` (hot reads), ``self.cold_dir``,
    ``self._default_cold_dir`` and ``self.tags()``."""

    def _cold_path(self, name: str) -> Path:
        if self.cold_dir is None:
            raise RuntimeError(
                "this database has rolled months but no cold folder is known: "
                "open it with cold_dir=..."
            )
        return self.cold_dir / name

    # -- where the cold folder is ------------------------------------------------------------
    def _recorded_cold_dir(self) -> Path | None:
        if self._meta is not None:
            found = self._meta.rows("SELECT value FROM settings WHERE key = ?", (COLD_DIR_KEY,))
            v = found[0][0] if found else None
        else:
            t = schema.settings
            with self.engine.connect() as c:
                v = c.execute(sa.select(t.c.value).where(t.c.key == COLD_DIR_KEY)).scalar()
        return Path(v) if v else None

    def _record_cold_dir(self) -> None:
        """Remember the cold folder in the database (unless it is SQLite's default beside the
        file), so a later ``Historian(url)`` and every ``diag`` command find the months."""
        here = self.cold_dir.resolve()
        recorded = self._recorded_cold_dir()
        if recorded is not None and recorded.resolve() == here:
            return
        if recorded is not None and self._segments(None, None):
            raise ValueError(
                f"this database keeps its rolled months in {recorded}, not {self.cold_dir}: "
                "open it without cold_dir (or with that folder)"
            )
        t = schema.settings
        with self._writing() as c:
            c.execute(sa.delete(t).where(t.c.key == COLD_DIR_KEY))
            if self._default_cold_dir is None or self._default_cold_dir.resolve() != here:
                c.execute(sa.insert(t).values(key=COLD_DIR_KEY, value=str(here)))

    # -- the list of rolled months and their files -------------------------------------------
    def _segments(self, start: int | None, end: int | None) -> list[dict]:
        if self._meta is not None:
            found = self._meta.rows(
                f"SELECT {', '.join(SEGMENT_COLUMNS)} FROM cold_segments ORDER BY month"
            )
            rows = [dict(zip(SEGMENT_COLUMNS, r, strict=True)) for r in found]
        else:
            t = schema.cold_segments
            with self.engine.connect() as c:
                rows = c.execute(sa.select(t).order_by(t.c.month)).mappings().all()
        if start is None:
            return [dict(r) for r in rows]
        out = []
        for r in rows:
            m0, m1 = coldstore.month_bounds(r["month"])
            if m0 < end and m1 > start:
                out.append(dict(r))
        return out

    def _segment_index(self, seg: dict) -> coldstore.SegmentIndex:
        """The row-group index of a segment's file, read once per file (files are never
        rewritten in place: a re-roll writes a new name; size and mtime guard the rest)."""
        path = self._cold_path(seg["path"])
        st = os.stat(path)
        key = (seg["path"], st.st_size, st.st_mtime_ns)
        cache = self.__dict__.setdefault("_cold_index_cache", {})
        index = cache.get(key)
        if index is None:
            index = coldstore.SegmentIndex.open(path)
            cache[key] = index
        return index

    def _read_cold(
        self, tag_id: int, start: int, end: int, segments: list[dict] | None = None
    ) -> list[tuple[np.ndarray, ...]]:
        """(ts, value, quality) of one tag in [start, end) from the rolled months it meets, as
        consecutive pieces in time order, none empty (:meth:`SegmentIndex.read_pieces`;
        ``segments``: the list of rolled months when the caller has it already)."""
        parts = []
        for seg in self._segments(None, None) if segments is None else segments:
            m0, m1 = coldstore.month_bounds(seg["month"])
            if m0 >= end or m1 <= start:
                continue
            index = self._segment_index(seg)
            cache = self.__dict__.setdefault("_row_group_cache", coldstore.RowGroupCache())
            parts += index.read_pieces(tag_id, max(start, m0), min(end, m1), cache)
        return parts

    def _cold_bounds(self, tag_id: int, segments: list[dict]) -> tuple[int | None, int | None]:
        """First and last time of a tag in the cold files: from the row-group statistics,
        reading the tag's times only where they cannot say."""
        first = last = None
        for seg in segments:
            b = self._segment_index(seg).bounds(tag_id)
            if b is None:
                m0, m1 = coldstore.month_bounds(seg["month"])
                ts = self._segment_index(seg).read(tag_id, m0, m1)[0]
                b = (int(ts[0]), int(ts[-1])) if len(ts) else (0, -1)
            if b[1] < b[0]:
                continue
            first = b[0] if first is None else min(first, b[0])
            last = b[1] if last is None else max(last, b[1])
        return first, last

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
            index = self._segment_index(seg)
            lo, hi = int(ts[rows].min()), int(ts[rows].max()) + 1
            for tid in np.unique(tag_id[rows]):
                c_ts, c_v, c_q = index.read(int(tid), lo, hi)
                if not len(c_ts):
                    continue
                mine = rows[tag_id[rows] == tid]
                pos = np.minimum(np.searchsorted(c_ts, ts[mine]), len(c_ts) - 1)
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

    # -- rolling -----------------------------------------------------------------------------
    def months_to_roll(self, before=None) -> list[str]:
        """The closed months (ending at or before ``before``, default: the start of the
        current UTC month) that still hold rows in the database."""
        limit = to_us(before if before is not None else coldstore.month_start())
        s = schema.samples
        ids = [int(i) for i in self.tags()["id"]]
        months = []
        with self.engine.connect() as c:  # index seeks per tag (a scan without the tag)
            lows = [
                c.execute(sa.select(sa.func.min(s.c.ts)).where(s.c.tag_id == i)).scalar()
                for i in ids
            ]
            lo = min((x for x in lows if x is not None), default=None)
            if lo is None:
                return []
            for month in coldstore.months_between(lo, limit):
                m0, m1 = coldstore.month_bounds(month)
                if m1 > limit:
                    break
                held = sa.select(s.c.ts).where(s.c.tag_id.in_(ids), s.c.ts >= m0, s.c.ts < m1)
                if c.execute(held.limit(1)).first() is not None:  # rolled months hold none
                    months.append(month)
        return months

    def roll_months(self, before=None, *, progress: Progress | None = None) -> list[str]:
        """Move every closed month (ending at or before ``before``, default: the start of the
        current UTC month) from the database to the Parquet cold store. Returns the months
        rolled. Reads see the same data before and after. ``progress(done, total)`` is called
        after each tag of each month.

        The space the rows took stays in a SQLite file (as free pages, reused by later
        writes) and in PostgreSQL's table (dead rows) until :meth:`vacuum`."""
        if self.cold_dir is None:
            raise RuntimeError(
                "rolling months needs a folder for the Parquet files: Historian(url, cold_dir=...)"
            )
        months = self.months_to_roll(before)
        if not months:
            return []
        self._record_cold_dir()
        ids = sorted(int(i) for i in self.tags()["id"])
        total = len(months) * len(ids)
        rolled = []
        for i, month in enumerate(months):

            def step(j: int, i=i) -> None:
                if progress is not None:
                    progress(i * len(ids) + j, total)

            for attempt in range(ROLL_ATTEMPTS):
                try:
                    if self._roll_month(month, ids, step):
                        rolled.append(month)
                    break
                except MonthChanged:
                    if attempt == ROLL_ATTEMPTS - 1:
                        raise RuntimeError(
                            f"rows of {month} kept arriving while it was being rolled "
                            f"({ROLL_ATTEMPTS} tries); nothing of it was moved: roll again later"
                        ) from None
        if progress is not None:
            progress(total, total)
        return rolled

    def _roll_month(self, month: str, ids: list[int], step: Callable[[int], None]) -> bool:
        """Write the month's file tag by tag (the hot rows merged into the month's earlier file,
        the hot row winning at an equal (tag, ts)), then in one transaction record it and
        delete the rows it holds. If the delete meets more rows than were read, a writer added
        some meanwhile: the transaction is undone and :class:`MonthChanged` raised."""
        return self._write_month(month, ids, step).wrote

    def import_month(
        self, month: str, rows: dict[int, tuple[np.ndarray, ...]], policy: str = "ignore"
    ) -> MonthMerge:
        """Store samples of a closed month straight into its cold file (``diag import``):
        ``rows`` maps a tag id to its (ts, value, quality), sorted by time, one row per time.
        The month's file is written anew from what the month holds (its earlier file and any
        rows of it in the database, the database's winning, as a roll merges them) and the
        given rows: at a (tag, ts) already stored, the stored sample stays (``"ignore"``) or
        the given one replaces it (``"update"``). Then, in one transaction, the file is
        recorded and the month's database rows deleted; a kill leaves the old file and record
        or the new ones (the other file is an orphan, :meth:`cold_orphans`). Nothing is
        written when nothing would change. Retried when a writer changed the month meanwhile.
        Returns the counts (:class:`MonthMerge`)."""
        if policy not in ("ignore", "update"):
            raise ValueError(f"policy must be 'ignore' or 'update', not {policy!r}")
        m0, m1 = coldstore.month_bounds(month)
        if m1 > to_us(coldstore.month_start()):
            raise ValueError(f"{month} is not a closed month")
        if self.cold_dir is None:
            raise RuntimeError(
                "storing a closed month needs a cold folder: Historian(url, cold_dir=...)"
            )
        self._record_cold_dir()
        ids = sorted({int(i) for i in self.tags()["id"]} | {int(i) for i in rows})
        for attempt in range(ROLL_ATTEMPTS):
            try:
                return self._write_month(month, ids, None, rows, policy)
            except MonthChanged:
                if attempt == ROLL_ATTEMPTS - 1:
                    raise RuntimeError(
                        f"rows of {month} kept arriving while the import wrote it "
                        f"({ROLL_ATTEMPTS} tries); nothing of it was stored: import again"
                    ) from None
        raise AssertionError("unreachable")

    def _write_month(
        self,
        month: str,
        ids: list[int],
        step: Callable[[int], None] | None,
        extra: dict[int, tuple[np.ndarray, ...]] | None = None,
        policy: str = "ignore",
    ) -> MonthMerge:
        """Write the month's file tag by tag: its earlier file, its database rows (winning at
        an equal (tag, ts)) and the ``extra`` rows (winning with ``"update"``, else losing);
        then in one transaction record the file and delete the database rows it holds. If the
        delete meets more rows than were read, or the month's record changed, another writer
        wrote meanwhile: the transaction is undone and :class:`MonthChanged` raised."""
        s, t = schema.samples, schema.cold_segments
        m0, m1 = coldstore.month_bounds(month)
        extra = extra or {}
        old = self._segments(m0, m1)
        old_index = self._segment_index(old[0]) if old else None
        name = f"samples-{month}-{now_us()}.parquet"
        hot = 0
        out = MonthMerge()
        with coldstore.SegmentWriter(self._cold_path(name)) as w:
            for j, tid in enumerate(ids):
                ts, v, q = self._bulk.read(tid, m0, m1)
                hot += len(ts)
                if old_index is not None:
                    ts, v, q = _merge(old_index.read(tid, m0, m1), (ts, v, q))
                new = extra.get(tid)
                if new is not None and len(new[0]):
                    out.count(tid, (ts, v, q), new)
                    pair = ((ts, v, q), new) if policy == "update" else (new, (ts, v, q))
                    ts, v, q = _merge(*pair)
                w.write(tid, ts, v, q)
                if step is not None:
                    step(j + 1)
        changes = out.added + (out.changed if policy == "update" else 0)
        if hot == 0 and changes == 0:  # nothing in the database, nothing new: no new file
            self._cold_path(name).unlink(missing_ok=True)
            return out
        try:
            with self._writing() as c:
                gone = c.execute(
                    sa.delete(s).where(s.c.tag_id.in_(ids), s.c.ts >= m0, s.c.ts < m1)
                ).rowcount
                if gone != hot:
                    raise MonthChanged(month)
                mine = sa.delete(t).where(t.c.month == month)
                if old:  # the record this file was merged from, still there
                    if c.execute(mine.where(t.c.path == old[0]["path"])).rowcount != 1:
                        raise MonthChanged(month)
                elif c.execute(sa.select(t.c.path).where(t.c.month == month)).first():
                    raise MonthChanged(month)
                c.execute(
                    sa.insert(t).values(
                        month=month,
                        path=name,
                        rows=w.rows,
                        ts_min=w.ts_min,
                        ts_max=w.ts_max,
                        created_at=now_us(),
                    )
                )
        except sa.exc.IntegrityError:  # PostgreSQL: another writer recorded the month meanwhile
            self._cold_path(name).unlink(missing_ok=True)
            raise MonthChanged(month) from None
        except BaseException:
            self._cold_path(name).unlink(missing_ok=True)
            raise
        if old and old[0]["path"] != name:
            self._cold_path(old[0]["path"]).unlink(missing_ok=True)
        out.wrote = True
        return out

    def _cold_problems(self, progress: Progress | None = None) -> list[str]:
        """What is wrong with the rolled months: each file readable and holding the row count
        recorded for its month (reported, never raised)."""
        problems = []
        try:
            segments = self._segments(None, None)
        except Exception as exc:  # noqa: BLE001 - report, do not raise
            return [f"cold segment list unreadable: {exc}"]
        for i, seg in enumerate(segments):
            try:
                index = coldstore.SegmentIndex.open(self._cold_path(seg["path"]))
                m0, m1 = coldstore.month_bounds(seg["month"])
                if index.metadata.num_rows != seg["rows"]:
                    problems.append(f"cold segment {seg['month']}: row count differs")
                elif _outside(index, m0, m1):
                    problems.append(f"cold segment {seg['month']}: rows outside the month")
            except Exception as exc:  # noqa: BLE001 - report, do not raise
                problems.append(f"cold segment {seg['month']}: {exc}")
            if progress is not None:
                progress(i + 1, len(segments))
        return problems

    def cold_orphans(self) -> list[Path]:
        """Files in the cold folder that no rolled month lists: left by a roll or an import
        interrupted between writing a month's file and recording it, or between recording
        it and removing the file it replaced (nothing reads them: the month's recorded file
        and its database rows are its data, so they can be deleted)."""
        if self.cold_dir is None or not self.cold_dir.is_dir():
            return []
        listed = {seg["path"] for seg in self._segments(None, None)}
        return sorted(
            p
            for p in self.cold_dir.glob("samples-*.parquet*")
            if p.name not in listed and p.name.endswith((".parquet", ".parquet.tmp"))
        )


def _outside(index: coldstore.SegmentIndex, m0: int, m1: int) -> bool:
    """Whether the file's statistics show times outside [m0, m1)."""
    known = index.ts_lo != np.iinfo(np.int64).min
    return bool(known.any() and (index.ts_lo[known].min() < m0 or index.ts_hi[known].max() >= m1))


def _merge(cold, hot):
    """One tag's cold rows and hot rows, sorted by time; the hot row wins at an equal time
    (it is a late sample or an update)."""
    if not len(cold[0]):
        return hot
    if not len(hot[0]):
        return cold
    ts, v, q = (np.concatenate(pair) for pair in zip(cold, hot, strict=True))
    order = np.argsort(ts, kind="stable")  # stable: cold before hot at an equal time
    ts, v, q = ts[order], v[order], q[order]
    last = np.r_[ts[1:] != ts[:-1], True]
    return ts[last], v[last], q[last]
