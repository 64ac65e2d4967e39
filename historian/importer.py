"""Import of wide CSV and Parquet files: a time column plus one column per tag.

The time column is ``--time-column`` if given, else the first column named ``ts``, ``time``,
``timestamp`` or ``datetime`` (any case), else the first column. Times with an offset are
converted to UTC; naive times are in ``tz`` (default UTC; ambiguous or non-existent local
times are bad rows); a numeric time column is seconds since the epoch.

Empty cells (and NA/NaN) mean "no sample". A row whose time cannot be parsed or that holds a
non-numeric value is *bad*: it is reported as ``file:line: what is wrong`` (CSV: the physical
line, header = line 1; Parquet: the 1-based row number) and skipped, or with ``strict=True``
the whole import is refused before anything is written. Stored samples are never modified
(``policy="ignore"``), so a re-import adds nothing.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from .quality import GOOD
from .store import Historian

TIME_NAMES = ("ts", "time", "timestamp", "datetime")
MAX_MESSAGES = 1000


class ImportRefused(Exception):
    """Strict import found bad rows; nothing was written. ``messages`` lists them."""

    def __init__(self, messages: list[str], n_bad: int):
        self.messages = messages
        self.n_bad = n_bad
        super().__init__(f"{n_bad} bad row(s); nothing imported:\n" + "\n".join(messages[:20]))


@dataclass
class ImportReport:
    file: str
    rows: int = 0  # data rows read (blank lines not counted)
    n_bad: int = 0
    bad: list[str] = field(default_factory=list)  # first MAX_MESSAGES 'file:line: ...'
    samples: int = 0  # samples offered to the store
    written: int = 0  # newly stored (the rest were already there)
    tags: list[str] = field(default_factory=list)
    first: pd.Timestamp | None = None
    last: pd.Timestamp | None = None

    def _bad(self, msg: str) -> None:
        self.n_bad += 1
        if len(self.bad) < MAX_MESSAGES:
            self.bad.append(msg)


def pick_time_column(columns, time_column: str | None = None) -> str:
    cols = [str(c) for c in columns]
    if not cols:
        raise ValueError("the file has no columns")
    if time_column is not None:
        if time_column not in cols:
            raise ValueError(f"no column {time_column!r}; columns are {', '.join(cols)}")
        return time_column
    for c in cols:
        if c.strip().lower() in TIME_NAMES:
            return c
    return cols[0]


def parse_times(raw: pd.Series, tz: str = "UTC") -> pd.Series:
    """Times → tz-aware UTC (NaT where unparseable)."""
    if pd.api.types.is_datetime64_any_dtype(raw.dtype):
        t = raw
    elif pd.api.types.is_numeric_dtype(raw.dtype):
        return pd.to_datetime(raw, unit="s", utc=True, errors="coerce")
    else:
        text = raw.astype("string").str.strip()
        num = pd.to_numeric(text, errors="coerce")
        if num.notna().sum() == text.notna().sum() and text.notna().any():
            return pd.to_datetime(num, unit="s", utc=True, errors="coerce")
        try:
            t = pd.to_datetime(text, errors="coerce", format="ISO8601")
        except (ValueError, TypeError):
            t = pd.to_datetime(text, errors="coerce", utc=True)
        if t.isna().sum() > text.isna().sum() and not pd.api.types.is_datetime64_any_dtype(t):
            t = pd.to_datetime(text, errors="coerce", utc=True)
        if t.dtype == object:  # mixed offsets
            t = pd.to_datetime(text, errors="coerce", utc=True)
    if getattr(t.dt, "tz", None) is None:
        t = t.dt.tz_localize(tz, ambiguous="NaT", nonexistent="NaT")
    return t.dt.tz_convert("UTC")


def _clean_chunk(
    chunk: pd.DataFrame, tcol: str, tz: str, line_of: Callable[[int], str], report: ImportReport
) -> pd.DataFrame:
    """Parse one chunk; report bad rows; return the good rows as a wide frame on UTC time."""
    values = chunk.drop(columns=[tcol])
    raw_t = chunk[tcol]
    blank = raw_t.isna().to_numpy() & values.isna().all(axis=1).to_numpy()
    t = parse_times(raw_t, tz)
    bad_time = t.isna().to_numpy() & ~blank
    reason: dict[int, str] = {}
    for i in np.flatnonzero(bad_time):
        rv = raw_t.iloc[i]
        why = "missing time" if pd.isna(rv) else f"unparseable time {str(rv)!r}"
        if not pd.isna(rv) and tz != "UTC":
            why += f" (or ambiguous/non-existent in {tz})"
        reason[i] = why
    numeric = {}
    for name in values.columns:
        col = values[name]
        if pd.api.types.is_numeric_dtype(col.dtype) and not pd.api.types.is_bool_dtype(col.dtype):
            numeric[name] = col.to_numpy(np.float64, na_value=np.nan)
            continue
        num = pd.to_numeric(col.astype("string").str.strip(), errors="coerce")
        wrong = (num.isna() & col.notna()).to_numpy()
        for i in np.flatnonzero(wrong):
            reason.setdefault(i, f"non-numeric value {str(col.iloc[i])!r} in column {name!r}")
        numeric[name] = num.to_numpy(np.float64, na_value=np.nan)
    ok = ~blank
    for i in sorted(reason):
        report._bad(f"{line_of(i)}: {reason[i]}")
        ok[i] = False
    report.rows += int(np.count_nonzero(~blank))
    frame = pd.DataFrame(numeric, index=pd.DatetimeIndex(t, name="ts"))[ok]
    return frame


def _csv_chunks(path: Path, tcol: str, chunk_rows: int, advance) -> Iterator:
    with open(path, "rb") as fh:
        reader = pd.read_csv(
            fh,
            chunksize=chunk_rows,
            dtype={tcol: str},
            skip_blank_lines=False,
            skipinitialspace=True,
        )
        base = 0
        for chunk in reader:
            n = len(chunk)
            start = base

            def line_of(i, start=start):
                return f"{path}:{start + i + 2}"

            yield chunk, line_of
            base += n
            advance(fh.tell())


def _parquet_chunks(path: Path, chunk_rows: int, advance) -> Iterator:
    import pyarrow.parquet as pq

    pf = pq.ParquetFile(path)
    base = 0
    for batch in pf.iter_batches(batch_size=chunk_rows):
        chunk = batch.to_pandas(ignore_metadata=True)  # a DatetimeIndex stays a column
        start = base

        def line_of(i, start=start):
            return f"{path}:{start + i + 1}"

        yield chunk, line_of
        base += len(chunk)
        advance(base)


def _is_parquet(path: Path) -> bool:
    if path.suffix.lower() in (".parquet", ".pq"):
        return True
    with open(path, "rb") as fh:
        return fh.read(4) == b"PAR1"


def file_columns(path: Path) -> list[str]:
    if _is_parquet(path):
        import pyarrow.parquet as pq

        return list(pq.ParquetFile(path).schema_arrow.names)
    return [str(c) for c in pd.read_csv(path, nrows=0, skipinitialspace=True).columns]


def load_tags_csv(h: Historian, path: str | Path) -> list[str]:
    """Tag metadata from a CSV with columns name (or tag), unit, lo (or min), hi (or max),
    description, source; returns the tag names. A bad number raises ValueError file:line."""
    path = Path(path)
    frame = pd.read_csv(path, dtype=str, keep_default_na=False, skipinitialspace=True)
    cols = {c.strip().lower(): c for c in frame.columns}

    def col(*names):
        for n in names:
            if n in cols:
                return cols[n]
        return None

    c_name = col("name", "tag")
    if c_name is None:
        raise ValueError(f"{path}:1: a tags CSV needs a 'name' (or 'tag') column")
    c_unit, c_desc, c_src = col("unit"), col("description"), col("source")
    c_lo, c_hi = col("lo", "min", "range_lo"), col("hi", "max", "range_hi")
    names = []
    for i, row in enumerate(frame.to_dict("records")):
        line = f"{path}:{i + 2}"
        name = row[c_name].strip()
        if not name:
            continue

        def num(c, row=row, line=line):
            if c is None or not row[c].strip():
                return None
            try:
                return float(row[c])
            except ValueError:
                raise ValueError(f"{line}: {c} {row[c]!r} is not a number") from None

        lo, hi = num(c_lo), num(c_hi)
        if lo is not None and hi is not None and lo >= hi:
            raise ValueError(f"{line}: range lo {lo} must be below hi {hi}")
        h.ensure_tag(
            name,
            unit=(row[c_unit].strip() or None) if c_unit else None,
            lo=lo,
            hi=hi,
            description=(row[c_desc].strip() or None) if c_desc else None,
            source=(row[c_src].strip() or None) if c_src else None,
        )
        names.append(name)
    return names


def import_file(
    h: Historian,
    path: str | Path,
    *,
    time_column: str | None = None,
    tz: str = "UTC",
    tags_csv: str | Path | None = None,
    strict: bool = False,
    policy: str = "ignore",
    chunk_rows: int = 200_000,
    progress: Callable[[int, int], None] | None = None,
) -> ImportReport:
    """Import a wide CSV or Parquet file into ``h``; see the module docstring.

    ``progress(done, total)`` is called after each chunk (bytes for CSV, rows for Parquet).
    Raises :class:`ImportRefused` in strict mode when any row is bad (nothing written).
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    parquet = _is_parquet(path)
    tcol = pick_time_column(file_columns(path), time_column)
    if parquet:
        import pyarrow.parquet as pq

        total = pq.ParquetFile(path).metadata.num_rows
    else:
        total = os.path.getsize(path)

    def chunks(advance):
        if parquet:
            return _parquet_chunks(path, chunk_rows, advance)
        return _csv_chunks(path, tcol, chunk_rows, advance)

    def noop(_done):
        pass

    if strict:  # validate the whole file first: refuse before writing anything
        check = ImportReport(str(path))
        for chunk, line_of in chunks(noop):
            _clean_chunk(chunk, tcol, tz, line_of, check)
        if check.n_bad:
            raise ImportRefused(check.bad, check.n_bad)
    if tags_csv is not None:
        load_tags_csv(h, tags_csv)
    report = ImportReport(str(path))
    known = set(h.tags()["name"])
    tags_seen: list[str] = []

    def advance(done):
        if progress is not None:
            progress(done, total)

    for chunk, line_of in chunks(advance):
        frame = _clean_chunk(chunk, tcol, tz, line_of, report)
        for name in frame.columns:
            if name not in known:
                h.ensure_tag(str(name), source=path.name)
                known.add(name)
            if name not in tags_seen:
                tags_seen.append(str(name))
        if len(frame):
            report.samples += int(frame.notna().to_numpy().sum())
            report.written += h.write_samples(frame, quality=GOOD, policy=policy)
            lo, hi = frame.index.min(), frame.index.max()
            report.first = lo if report.first is None else min(report.first, lo)
            report.last = hi if report.last is None else max(report.last, hi)
    report.tags = tags_seen
    return report
