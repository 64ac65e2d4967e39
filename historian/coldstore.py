"""Parquet cold store: closed months of samples moved out of the database.

One file per month, ``samples-YYYY-MM-<stamp>.parquet``, columns ``tag_id, ts, value,
quality`` sorted by (tag_id, ts), one row group per tag, so a read of one tag touches one row
group (min/max statistics prune the rest). The database keeps the list of rolled months
(table ``cold_segments``); reads combine the cold file and any hot rows written later for that
month. The writer checks rolled months before inserting, so a hot row at a (tag, ts) the cold
file holds is an overwrite (``policy="update"``): the hot row wins on read and on the next roll.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from .times import to_us

SCHEMA = pa.schema(
    [("tag_id", pa.int32()), ("ts", pa.int64()), ("value", pa.float64()), ("quality", pa.int8())]
)


def month_bounds(month: str) -> tuple[int, int]:
    """'YYYY-MM' → [start, end) in µs UTC."""
    start = pd.Timestamp(f"{month}-01", tz="UTC")
    return to_us(start), to_us(start + pd.offsets.MonthBegin(1))


def month_of(us: int) -> str:
    return pd.Timestamp(int(us), unit="us", tz="UTC").strftime("%Y-%m")


def months_between(start_us: int, end_us: int) -> list[str]:
    """Months that intersect [start, end)."""
    if end_us <= start_us:
        return []
    first = pd.Timestamp(int(start_us), unit="us", tz="UTC").tz_localize(None).to_period("M")
    last = pd.Timestamp(int(end_us) - 1, unit="us", tz="UTC").tz_localize(None).to_period("M")
    return [str(p) for p in pd.period_range(first, last, freq="M")]


def write_segment(path: Path, tag_id, ts, value, quality) -> int:
    """Write one month atomically (temporary file, fsync, rename). Input sorted by (tag, ts)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    table = pa.table(
        {
            "tag_id": pa.array(np.asarray(tag_id, np.int32)),
            "ts": pa.array(np.asarray(ts, np.int64)),
            "value": pa.array(np.asarray(value, np.float64)),
            "quality": pa.array(np.asarray(quality, np.int8)),
        },
        schema=SCHEMA,
    )
    tmp = path.with_name(path.name + ".tmp")
    with pq.ParquetWriter(tmp, SCHEMA, compression="zstd") as writer:
        tids = table.column("tag_id").to_numpy()
        cuts = np.flatnonzero(np.r_[True, tids[1:] != tids[:-1], True])
        for a, b in zip(cuts[:-1], cuts[1:], strict=False):
            writer.write_table(table.slice(int(a), int(b - a)))
    with open(tmp, "rb") as fh:
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    dfd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dfd)
    finally:
        os.close(dfd)
    return table.num_rows


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
    table = pq.read_table(path, filters=filters or None)
    return (
        table.column("tag_id").to_numpy().astype(np.int64),
        table.column("ts").to_numpy().astype(np.int64),
        table.column("value").to_numpy(zero_copy_only=False).astype(np.float64),
        table.column("quality").to_numpy().astype(np.int64),
    )
