"""Months rolled to the Parquet cold store, on the database side: rolling a closed month
into its file (:mod:`historian.coldstore` writes and reads the files), the list of rolled
months, the key check that keeps writes into them idempotent, and the check of the files.
Mixed into :class:`historian.store.Historian`."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd
from sqlalchemy import delete, insert, select

from . import coldstore, schema
from .times import now_us, to_us


class ColdMonths:
    """Needs ``self.engine``, ``self._bulk`` (hot reads), ``self.cold_dir`` and
    ``self.tags()``."""

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

    def _read_cold(self, tag_id: int, start: int, end: int) -> list[tuple[np.ndarray, ...]]:
        """(ts, value, quality) of one tag in [start, end) from each rolled month it meets."""
        parts = []
        for seg in self._segments(start, end):
            m0, m1 = coldstore.month_bounds(seg["month"])
            _, ts, v, q = coldstore.read_segment(
                self._cold_path(seg["path"]), tag_id, max(start, m0), min(end, m1)
            )
            parts.append((ts, v, q))
        return parts

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
        name = f"samples-{month}-{now_us()}.parquet"
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
                    created_at=now_us(),
                )
            )
            c.execute(delete(s).where(s.c.ts >= m0, s.c.ts < m1))
        if old and old[0]["path"] != name:
            try:
                os.remove(self._cold_path(old[0]["path"]))
            except FileNotFoundError:
                pass
        return True

    def _cold_problems(self) -> list[str]:
        """What is wrong with the rolled months: each file readable and holding the row count
        recorded for its month (reported, never raised)."""
        problems = []
        try:
            segments = self._segments(None, None)
        except Exception as exc:  # noqa: BLE001 - report, do not raise
            return [f"cold segment list unreadable: {exc}"]
        for seg in segments:
            try:
                import pyarrow.parquet as pq

                if pq.ParquetFile(self._cold_path(seg["path"])).metadata.num_rows != seg["rows"]:
                    problems.append(f"cold segment {seg['month']}: row count differs")
            except Exception as exc:  # noqa: BLE001 - report, do not raise
                problems.append(f"cold segment {seg['month']}: {exc}")
        return problems
