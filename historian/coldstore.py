"""Parquet cold store: closed months of samples moved out of the database.

One file per month, ``samples-YYYY-MM-<stamp>.parquet``, columns ``tag_id, ts, value,
quality`` sorted by (tag_id, ts). Each row group holds one tag and at most
:data:`ROW_GROUP_ROWS` rows, so a read of one tag over a few days decodes little more than
it asks for; the footer's min/max statistics of ``tag_id`` and ``ts`` per row group say
which row groups to decode (:class:`SegmentIndex`) and give each tag's first and last time
without reading a row. Sample times are delta-encoded (a regular 10 s series packs to almost
nothing) and values byte-stream-split (they compress better under zstd): a month file is
about 2.3 times smaller than with Parquet's default encodings and decodes 2.5 times faster.

The database keeps the list of rolled months (table ``cold_segments``); reads combine the
cold file and any hot rows written later for that month. The writer checks rolled months
before inserting, so a hot row at a (tag, ts) the cold file holds is an overwrite
(``policy="update"``): the hot row wins on read and on the next roll. Files written before
this layout (one row group per tag, default encodings) read the same way.
"""

from __future__ import annotations

import functools
import os
import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
import pyarrow as pa

from .times import to_us

if TYPE_CHECKING:  # imported where a file is read or written (a database without cold
    import pyarrow.parquet as pq  # months never is: ~0.01 CPU s of every process, issue 34)

SCHEMA = pa.schema(
    [("tag_id", pa.int32()), ("ts", pa.int64()), ("value", pa.float64()), ("quality", pa.int8())]
)
#: rows per row group (each holds one tag): a 7-day read of 10 s data decodes 1-2 of them
ROW_GROUP_ROWS = 1 << 16
_WRITER_OPTIONS = dict(
    compression="zstd",
    use_dictionary=["tag_id", "quality"],
    column_encoding={"ts": "DELTA_BINARY_PACKED", "value": "BYTE_STREAM_SPLIT"},
)
_DATA = ["ts", "value", "quality"]


@functools.lru_cache(maxsize=1024)
def month_bounds(month: str) -> tuple[int, int]:
    """'YYYY-MM' → [start, end) in µs UTC."""
    start = pd.Timestamp(f"{month}-01", tz="UTC")
    return to_us(start), to_us(start + pd.offsets.MonthBegin(1))


def month_start(ts=None) -> pd.Timestamp:
    """The start of ``ts``'s UTC month (a time, or µs since the epoch; None: now): the first
    time that is not in a closed month."""
    if ts is None:
        ts = pd.Timestamp.now(tz="UTC")
    elif isinstance(ts, (int, np.integer)):
        ts = pd.Timestamp(int(ts), unit="us", tz="UTC")
    else:
        ts = pd.Timestamp(ts)
        ts = ts.tz_localize("UTC") if ts.tzinfo is None else ts.tz_convert("UTC")
    return ts.normalize().replace(day=1)


def month_of(us: int) -> str:
    return pd.Timestamp(int(us), unit="us", tz="UTC").strftime("%Y-%m")


def months_between(start_us: int, end_us: int) -> list[str]:
    """Months that intersect [start, end)."""
    if end_us <= start_us:
        return []
    first = pd.Timestamp(int(start_us), unit="us", tz="UTC").tz_localize(None).to_period("M")
    last = pd.Timestamp(int(end_us) - 1, unit="us", tz="UTC").tz_localize(None).to_period("M")
    return [str(p) for p in pd.period_range(first, last, freq="M")]


class SegmentWriter:
    """Write one month file tag by tag (memory: one tag's rows), atomically: a temporary
    file, fsync, rename on a clean exit; nothing is left behind on an error.

    >>> with SegmentWriter(path) as w:                      # doctest: +SKIP
    ...     w.write(tag_id, ts, value, quality)             # ts sorted, tags ascending
    """

    def __init__(self, path: Path):
        self.path = Path(path)
        self.rows = 0
        self.ts_min: int | None = None
        self.ts_max: int | None = None
        self._tmp = self.path.with_name(self.path.name + ".tmp")
        self._writer: pq.ParquetWriter | None = None

    def __enter__(self) -> SegmentWriter:
        import pyarrow.parquet as pq

        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._writer = pq.ParquetWriter(self._tmp, SCHEMA, **_WRITER_OPTIONS)
        return self

    def write(self, tag_id: int, ts, value, quality) -> None:
        """Append one tag's rows (sorted by time; tags in ascending order)."""
        if not len(ts):
            return
        table = pa.table(
            {
                "tag_id": pa.array(np.full(len(ts), tag_id, np.int32)),
                "ts": pa.array(np.asarray(ts, np.int64)),
                "value": pa.array(np.asarray(value, np.float64)),
                "quality": pa.array(np.asarray(quality, np.int8)),
            },
            schema=SCHEMA,
        )
        self._writer.write_table(table, row_group_size=ROW_GROUP_ROWS)
        self.rows += len(ts)
        lo, hi = int(ts[0]), int(ts[-1])
        self.ts_min = lo if self.ts_min is None else min(self.ts_min, lo)
        self.ts_max = hi if self.ts_max is None else max(self.ts_max, hi)

    def __exit__(self, exc_type, *exc) -> None:
        self._writer.close()
        if exc_type is not None:
            self._tmp.unlink(missing_ok=True)
            return
        with open(self._tmp, "rb") as fh:
            os.fsync(fh.fileno())
        os.replace(self._tmp, self.path)
        dfd = os.open(self.path.parent, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)


def write_segment(path: Path, tag_id, ts, value, quality) -> int:
    """Write one month atomically from arrays sorted by (tag, ts); returns the rows."""
    tag_id = np.asarray(tag_id, np.int64)
    cuts = np.flatnonzero(np.r_[True, tag_id[1:] != tag_id[:-1], True]) if len(tag_id) else []
    with SegmentWriter(path) as w:
        for a, b in zip(cuts[:-1], cuts[1:], strict=False):
            w.write(int(tag_id[a]), ts[a:b], value[a:b], quality[a:b])
    return w.rows


def read_segment(path: Path, tag_id=None, start: int | None = None, end=None):
    """Rows of one file (optionally one tag id or a sequence of them, and [start, end)) as
    numpy arrays, in file order: sorted by (tag_id, ts)."""
    filters = []
    if np.ndim(tag_id) == 1:
        filters.append(("tag_id", "in", [int(t) for t in tag_id]))
    elif tag_id is not None:
        filters.append(("tag_id", "=", int(tag_id)))
    if start is not None:
        filters.append(("ts", ">=", int(start)))
    if end is not None:
        filters.append(("ts", "<", int(end)))
    import pyarrow.parquet as pq

    table = pq.read_table(path, filters=filters or None)
    return (
        table.column("tag_id").to_numpy().astype(np.int64),
        table.column("ts").to_numpy().astype(np.int64),
        table.column("value").to_numpy(zero_copy_only=False).astype(np.float64),
        table.column("quality").to_numpy().astype(np.int64),
    )


_INT64 = np.iinfo(np.int64)


@dataclass(frozen=True)
class SegmentIndex:
    """Per row group of one file: the range of tag ids and of times it holds (from the
    footer's statistics; a row group without them spans everything)."""

    path: Path
    metadata: pq.FileMetaData
    tag_lo: np.ndarray
    tag_hi: np.ndarray
    ts_lo: np.ndarray
    ts_hi: np.ndarray
    #: the quality of every row of the row group when they all have the same one, else -1
    #: (most row groups hold only good samples: then the column is not decoded at all)
    q_all: np.ndarray

    #: (size, mtime) of the file when its footer was read: a file replaced in place is
    #: another file for :class:`RowGroupCache`
    stamp: tuple[int, int] = (0, 0)

    @classmethod
    def open(cls, path: Path) -> SegmentIndex:
        import pyarrow.parquet as pq

        fstat = os.stat(path)
        md = pq.ParquetFile(path).metadata
        names = [md.schema.column(i).name for i in range(md.num_columns)]
        it, its = names.index("tag_id"), names.index("ts")
        iq = names.index("quality")
        n = md.num_row_groups
        tag_lo, tag_hi = np.full(n, _INT64.min), np.full(n, _INT64.max)
        ts_lo, ts_hi = np.full(n, _INT64.min), np.full(n, _INT64.max)
        q_lo, q_hi = np.full(n, _INT64.min), np.full(n, _INT64.max)
        for g in range(n):
            rg = md.row_group(g)
            for col, lo, hi in ((it, tag_lo, tag_hi), (its, ts_lo, ts_hi), (iq, q_lo, q_hi)):
                st = rg.column(col).statistics
                if st is not None and st.has_min_max and st.null_count == 0:
                    lo[g], hi[g] = int(st.min), int(st.max)
        q_all = np.where(q_lo == q_hi, q_lo, -1)
        return cls(
            Path(path), md, tag_lo, tag_hi, ts_lo, ts_hi, q_all, (fstat.st_size, fstat.st_mtime_ns)
        )

    def groups(self, tag_id: int, start: int, end: int) -> np.ndarray:
        """Row groups that may hold rows of ``tag_id`` in [start, end)."""
        hit = (self.tag_lo <= tag_id) & (self.tag_hi >= tag_id)
        hit &= (self.ts_hi >= start) & (self.ts_lo < end)
        return np.flatnonzero(hit)

    def bounds(self, tag_id: int) -> tuple[int, int] | None:
        """First and last time of ``tag_id`` in the file from the statistics alone, or None
        when they cannot say (a row group mixing tags or without statistics)."""
        g = self.groups(tag_id, _INT64.min, _INT64.max)
        if not len(g):
            return (0, -1)  # the tag has no rows here
        if np.any(self.tag_lo[g] != self.tag_hi[g]) or np.any(self.ts_lo[g] == _INT64.min):
            return None
        return int(self.ts_lo[g].min()), int(self.ts_hi[g].max())

    def tail_start(self, tag_id: int, rows: int) -> int:
        """A time from which the file holds at least the last ``rows`` rows of ``tag_id``
        (or all of them), from the statistics: the first time of the last row groups that
        hold that many; the lowest time when they cannot say (groups mixing tags)."""
        g = self.groups(tag_id, _INT64.min, _INT64.max)
        if not len(g) or np.any(self.tag_lo[g] != self.tag_hi[g]):
            return int(_INT64.min)
        sizes = np.array([self.metadata.row_group(int(i)).num_rows for i in g])
        order = np.argsort(self.ts_hi[g])[::-1]  # the newest row groups first
        enough = np.flatnonzero(np.cumsum(sizes[order]) >= rows)
        if not len(enough):
            return int(_INT64.min)
        return int(self.ts_lo[g[order[: enough[0] + 1]]].min())

    def read(self, tag_id: int, start: int, end: int, cache: RowGroupCache | None = None):
        """(ts, value, quality) of one tag in [start, end), decoding only its row groups
        (row groups of one tag through ``cache``: consecutive chunked reads decode each once)."""
        pieces = self.read_pieces(tag_id, start, end, cache)
        if not pieces:
            return np.empty(0, np.int64), np.empty(0, np.float64), np.empty(0, np.int64)
        if len(pieces) == 1:
            return pieces[0]
        return tuple(np.concatenate(col) for col in zip(*pieces, strict=True))

    def read_pieces(
        self, tag_id: int, start: int, end: int, cache: RowGroupCache | None = None
    ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """:meth:`read` as consecutive pieces in time order, none empty, not joined (an
        aligned read puts each piece on the grid where it lies, without copying them into one
        array first: :func:`historian.window.align_pieces`)."""
        g = self.groups(tag_id, start, end)
        if not len(g):
            return []
        if cache is not None and np.all(self.tag_lo[g] == self.tag_hi[g]):
            # row groups inside [start, end) are decoded together (no later read wants
            # them); those at its edges, which the next chunk shares, through the cache
            inside = (self.ts_lo[g] >= start) & (self.ts_hi[g] < end)
            parts, run = [], []
            for i, whole in zip(g, inside, strict=True):
                if whole:
                    run.append(int(i))
                    continue
                if run:
                    parts.append(self._decode(run))
                    run = []
                parts.append(cache.get(self, int(i)))
            if run:
                parts.append(self._decode(run))
        else:
            parts = [self._decode([int(i) for i in g], tag_id)]
        pieces = []
        for ts, value, quality in parts:  # one tag's rows are sorted by time
            a, b = np.searchsorted(ts, [start, end])
            if b > a:
                pieces.append((ts[a:b], value[a:b], quality[a:b]))
        return pieces

    def _decode(self, groups: list[int], tag_id: int | None = None):
        """Rows of row groups as (ts int64, value float64, quality int64); only ``tag_id``'s
        when given and a group mixes tags (files of the earlier layout)."""
        mixed = tag_id is not None and bool(np.any(self.tag_lo[groups] != self.tag_hi[groups]))
        q_all = self.q_all[groups]
        one_q = q_all[0] >= 0 and bool(np.all(q_all == q_all[0]))  # one quality: not decoded
        columns = (["tag_id"] if mixed else []) + (_DATA[:2] if one_q else _DATA)
        import pyarrow.parquet as pq

        pf = pq.ParquetFile(self.path, metadata=self.metadata)
        table = pf.read_row_groups(groups, columns=columns, use_threads=False)
        ts = table.column("ts").to_numpy().astype(np.int64, copy=False)
        value = table.column("value").to_numpy().astype(np.float64, copy=False)
        if one_q:
            quality = np.full(len(ts), q_all[0], np.int64)
        else:
            quality = table.column("quality").to_numpy().astype(np.int64)
        if mixed:
            mine = table.column("tag_id").to_numpy() == tag_id
            ts, value, quality = ts[mine], value[mine], quality[mine]
        return ts, value, quality


class RowGroupCache:
    """The last decoded row groups (least recently used out first, at most ``max_rows``
    rows): a training job reads a month in 7-day chunks, and each chunk would otherwise
    decode again the row group it shares with the one before. Thread-safe."""

    def __init__(self, max_rows: int = 1 << 21):
        self.max_rows = max_rows
        self._rows = 0
        self._items: OrderedDict[tuple, tuple[np.ndarray, ...]] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, index: SegmentIndex, group: int) -> tuple[np.ndarray, ...]:
        key = (index.path, index.stamp, group)
        with self._lock:
            hit = self._items.get(key)
            if hit is not None:
                self._items.move_to_end(key)
                return hit
        arrays = index._decode([group])
        with self._lock:
            if key not in self._items:
                self._items[key] = arrays
                self._rows += len(arrays[0])
            while self._rows > self.max_rows and len(self._items) > 1:
                _, old = self._items.popitem(last=False)
                self._rows -= len(old[0])
        return arrays
