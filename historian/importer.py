"""Import of wide CSV and Parquet files: a time column plus one column per tag.

Import refuses to guess. The time column is ``time_column`` if given, else the first column
named ``ts``, ``time``, ``timestamp``, ``datetime`` or ``date`` (any case), else the only
Parquet column of timestamp type, else the first column if its values are date-times (text
such as ``2026-01-01 00:00:10`` or ISO 8601, at least half of the first 100 non-empty
values). Otherwise :class:`FileRefused` names the file, the columns found and
``--time-column``.

Date-time text with an offset is converted to UTC; naive times are in ``tz`` (default UTC;
the hour repeated when the clock goes back is read in the rows' order where they run through
it in order; otherwise its times, and times the clock skips, are bad rows saying so). A time
column of plain numbers is refused unless ``time_unit`` says what they count (``s``, ``ms``,
``us``, ``min``, ``h``): they are then that many units after ``start`` (a time; naive means
``tz``), or after 1970-01-01 UTC (Unix time) when no ``start`` is given. A relative time
column (e.g. DAMADICS: seconds from 0) needs its origin as ``start``.

Separator and decimal mark are ``sep`` and ``decimal`` (``--sep``, ``--decimal``); when not
given they are detected from the first lines where that is unambiguous (a header split by
``;`` only, cells such as ``12,5`` and none such as ``12.5``), and :attr:`ImportReport.notes`
says what was detected. Date-times are ISO 8601 unless ``time_format`` (``--time-format``, a
``strftime`` format such as ``%d.%m.%Y %H:%M:%S``) says otherwise; day.month and month/day
dates are read only when their order shows in the file (a first field above 12) and the notes
say so, otherwise the import asks for ``--time-format``. Times must fall between 1970 and a
year from now: epoch milliseconds read as seconds (year 58869) are refused with the unit that
fits.

Empty cells mean "no sample". A row whose time is missing or cannot be parsed is *bad*: it is
reported as ``file:line: what is wrong`` (CSV: the physical line, header = line 1; Parquet:
the 1-based row number) and skipped. A *cell* that holds no usable number — text such as
``Bad`` or ``#N/A``, ``NaN``, ``inf``, a number beyond the 32-bit float range historians and
OPC UA Float store (|x| > 3.4e38), or one outside the tag's declared range [lo, hi] by the
failure margins of NAMUR NE 43 (below lo − 2.5 % or above hi + 6.25 % of the span) — is stored
as a *Bad-quality* sample at its time (its number kept where it has one) and counted per tag
with its ``file:line``; the rest of the row is kept. With ``strict=True`` any bad row or
cell refuses the whole import before anything is written.

An import that stores no sample at all is refused (:class:`FileRefused`) and leaves no tag
behind. Tag names are the column names; a name a model cannot refer to (empty, blank at an
end, a double quote, a square bracket or a control character in it) is refused with the
rename that fixes it (``rename``, ``--rename OLD=NEW``); any other name works in input specs,
in double quotes when it holds spaces or brackets (``"Flow (t/h)"[k]``).

A file that cannot be imported at all (missing, empty, blank, header only, no tag column, not
UTF-8 text or binary, not readable Parquet) raises :class:`FileRefused` before anything is
written, naming the file (``file:line`` where a line is meaningful).

A sample whose (tag, ts) is already stored (in the database or in a month rolled to the
cold store) with the same value and quality is "already stored" and silently skipped. One
stored with a *different* value or quality is a *conflict*: counted in
:attr:`ImportReport.conflicts`, the earliest one kept in :attr:`ImportReport.first_conflict`;
the stored value is kept (``policy="ignore"``) or overwritten (``policy="update"``, the CLI's
``--replace``). A time that repeats within the file is compared the same way with the row
stored first. See :func:`stored_conflicts`.

Samples of closed months (before the current UTC month) go straight into the cold store's
Parquet month files (:meth:`Historian.import_month`: merged with the month's earlier file and
its rows in the table, under the same policy and counts), so a training over imported history
reads columnar data (issue 37); the current month goes to the samples table. ``hot=True``
(``--hot``) keeps everything in the table; a historian without a cold folder (PostgreSQL
unless one is recorded or given) does too, and the report says so.
"""

from __future__ import annotations

import codecs
import os
import re
import shlex
import warnings
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from . import coldstore
from .errors import UserError
from .quality import BAD, GOOD, NAMES
from .store import Historian
from .taginfo import tag_name_problem
from .times import from_us, index_us, to_us

TIME_NAMES = ("ts", "time", "timestamp", "datetime", "date")
#: what ``duplicates`` (``--duplicates``) may say about a time repeated within a file
DUPLICATES = ("error", "first", "last", "mean")
KEPT = {
    "first": "each tag's first sample",
    "last": "each tag's last sample",
    "mean": "the mean of each tag's usable samples",
}
#: µs per unit of a plain-number time column
TIME_UNITS = {
    "s": 1_000_000,
    "ms": 1_000,
    "us": 1,
    "µs": 1,
    "ns": 1e-3,
    "min": 60_000_000,
    "h": 3_600_000_000,
}
#: the largest magnitude a 32-bit float historian (and OPC UA Float) stores
FLOAT32_MAX = 3.4028235e38
#: NAMUR NE 43 failure signals: below 3.6 mA / above 21 mA of a 4-20 mA span
NE43_LOW, NE43_HIGH = 0.025, 0.0625
#: plausible times: 1970-01-02 up to this long after now
FUTURE_LIMIT = pd.Timedelta(days=366)
SEPARATORS = (",", ";", "\t", "|")
MAX_MESSAGES = 1000
#: rows read to recognise the time column and its kind
SAMPLE_ROWS = 100


#: an import's first write joins this many pieces of the file where its samples land at
#: the end of the samples' ``(tag_id, ts)`` key (:func:`_appends`): SQLite appends
#: there for half the CPU of an insert inside the key, where every later piece's rows go
#: (benchmarks/bench_insert_order.py: 0.31 against 0.62 µs a sample), so the larger piece
#: holds the write lock no longer than a later one
FIRST_PIECE_FACTOR = 2
#: samples of closed months an import holds in memory before writing their month files
#: (a file in time order writes each month once, when it leaves the month; past this, the
#: months held are written and merged again with what comes later)
COLD_HELD_SAMPLES = 20_000_000


class ImportRefused(UserError):
    """Strict import found bad rows; nothing was written. ``messages`` lists them."""

    def __init__(self, messages: list[str], n_bad: int):
        self.messages = messages
        self.n_bad = n_bad
        super().__init__(
            f"{n_bad} bad row(s) or cell(s); nothing imported:\n" + "\n".join(messages[:20])
        )


class FileRefused(UserError, ValueError):
    """The file cannot be imported as given (missing, empty, header only, unreadable, no
    recognisable time column, plain-number times without a unit); the message names the file
    and what to do. Nothing was written."""


@dataclass
class Conflict:
    """A file sample at a stored (tag, ts) with a different value or quality."""

    tag: str
    ts: pd.Timestamp
    stored: float
    stored_quality: int
    value: float
    quality: int
    where: str  # file:line of the row

    def describe(self) -> str:
        """``P1 at 2026-01-01T00:01:00Z (f.csv:3): stored 501.2, file 499.0``."""
        show_q = self.stored_quality != self.quality
        return (
            f"{self.tag} at {_iso(self.ts)} ({self.where}): "
            f"stored {_num(self.stored, self.stored_quality if show_q else None)}, "
            f"file {_num(self.value, self.quality if show_q else None)}"
        )


@dataclass
class ImportReport:
    file: str
    rows: int = 0  # data rows read (blank lines not counted)
    n_bad: int = 0
    bad: list[str] = field(default_factory=list)  # first MAX_MESSAGES 'file:line: ...'
    samples: int = 0  # samples offered to the store
    written: int = 0  # rows the store added (replace: added or changed)
    tags: list[str] = field(default_factory=list)
    first: pd.Timestamp | None = None
    last: pd.Timestamp | None = None
    conflicts: int = 0  # samples at a stored (tag, ts) with another value or quality
    first_conflict: Conflict | None = None  # the earliest
    replace: bool = False  # conflicts overwrote the stored values
    bad_cells: dict[str, int] = field(default_factory=dict)  # per tag: stored as Bad
    cells: list[str] = field(default_factory=list)  # first MAX_MESSAGES 'file:line: TAG: ...'
    notes: list[str] = field(default_factory=list)  # what was detected (separator, ...)
    repeats: int = 0  # rows whose time repeats an earlier row's in the file
    repeat_example: str | None = None  # the first, 'file:line repeats file:line (time)'
    duplicates: str = "error"  # what was kept at a repeated time
    cold_months: list[str] = field(default_factory=list)  # closed months written to Parquet
    cold_dir: str | None = None  # where they went (None: every sample went to the table)
    no_cold_folder: bool = False  # closed months went to the table: no cold folder known

    def stored_where(self) -> str | None:
        """The sentence saying where closed months went (None: nothing to say)."""
        if self.cold_months:
            m = self.cold_months
            which = m[0] if len(m) == 1 else f"{m[0]} .. {m[-1]}"
            return (
                f"closed months {which} stored as Parquet month files in {self.cold_dir} "
                "(--hot: keep them in the database's table)"
            )
        if self.no_cold_folder:
            return (
                "closed months stored in the samples table: this historian has no cold "
                "folder (--cold-dir DIR stores them as Parquet month files)"
            )
        return None

    def _bad(self, msg: str) -> None:
        self.n_bad += 1
        if len(self.bad) < MAX_MESSAGES:
            self.bad.append(msg)

    def _bad_cell(self, tag: str, msg: str) -> None:
        self.bad_cells[tag] = self.bad_cells.get(tag, 0) + 1
        if len(self.cells) < MAX_MESSAGES:
            self.cells.append(msg)

    @property
    def n_bad_cells(self) -> int:
        return sum(self.bad_cells.values())

    @property
    def new(self) -> int:
        """Samples at a (tag, ts) not stored before."""
        return max(0, self.written - self.conflicts) if self.replace else self.written

    @property
    def already(self) -> int:
        """Samples stored before with the same value and quality."""
        return self.samples - self.new - self.conflicts

    def repeat_message(self) -> str | None:
        """The sentence telling the user about times repeated in the file (None: none)."""
        if not self.repeats:
            return None
        noun = "1 row repeats" if self.repeats == 1 else f"{self.repeats} rows repeat"
        return (
            f"{noun} a time of an earlier row of the file (first: {self.repeat_example}); "
            f"kept {KEPT[self.duplicates]} at each repeated time (--duplicates "
            f"{self.duplicates})"
        )

    def conflict_message(self) -> str | None:
        """The sentence telling the user about conflicts (None when there were none)."""
        if not self.conflicts or self.first_conflict is None:
            return None
        n = self.conflicts
        noun = "1 sample" if n == 1 else f"{n} samples"
        first = self.first_conflict.describe()
        if self.replace:
            return (
                f"{noun} conflicted with stored values (first: {first}); "
                "replaced them with the file's (--replace)"
            )
        verb = "conflicts" if n == 1 else "conflict"
        return (
            f"{noun} {verb} with stored values (first: {first}); "
            "kept the stored ones — use --replace to overwrite"
        )


def _iso(t: pd.Timestamp) -> str:
    text = t.tz_convert("UTC").strftime("%Y-%m-%dT%H:%M:%S")
    if t.microsecond:
        text += f".{t.microsecond:06d}".rstrip("0")
    return text + "Z"


def _num(v: float, q: int | None = None) -> str:
    text = "no value" if np.isnan(v) else repr(float(v))
    return text if q is None else f"{text} ({NAMES.get(int(q), q)})"


def _plain_numbers(raw: pd.Series) -> bool:
    """Every non-empty value is a plain number (a numeric column, or text of numbers)."""
    if pd.api.types.is_bool_dtype(raw.dtype) or pd.api.types.is_datetime64_any_dtype(raw.dtype):
        return False
    if pd.api.types.is_numeric_dtype(raw.dtype):
        return bool(raw.notna().any())
    text = _texts(raw)
    return bool(len(text)) and bool(pd.to_numeric(text, errors="coerce").notna().all())


def _texts(raw: pd.Series) -> pd.Series:
    text = raw.dropna().astype("string").str.strip()
    return text[text != ""]


def _holds_datetimes(raw: pd.Series) -> bool:
    """At least half of the first non-empty values are date-times (never plain numbers)."""
    if pd.api.types.is_datetime64_any_dtype(raw.dtype):
        return True
    if pd.api.types.is_numeric_dtype(raw.dtype) or pd.api.types.is_bool_dtype(raw.dtype):
        return False
    text = _texts(raw).iloc[:SAMPLE_ROWS]
    if not len(text):
        return False
    dated = parse_times(text).notna() | text.str.match(_DAY_MONTH.pattern)
    return 2 * int(dated.sum()) >= len(text)


def _no_time_column(where: str, cols: list[str]) -> str:
    sep = next((c for c in (";", "\t", "|") if len(cols) == 1 and c in cols[0]), None)
    hint = f" (one column: is {sep!r} the separator? import reads commas)" if sep else ""
    return (
        f"{where}: no time column among the columns {', '.join(cols)}{hint}: none is named "
        f"{', '.join(TIME_NAMES[:-1])} or {TIME_NAMES[-1]} (any case), and the first, "
        f"{cols[0]!r}, does not hold date-times such as 2026-01-01 00:00:10; name the time "
        "column with --time-column NAME (a column of plain numbers also needs --time-unit, "
        "e.g. --time-unit s)"
    )


def pick_time_column(
    columns, time_column: str | None = None, sample: pd.DataFrame | None = None, where="file"
) -> str:
    """The time column (see the module docstring); ``sample``: the first rows of the file,
    to recognise a first column of date-times or a timestamp-typed column. Raises
    :class:`FileRefused` when there is none (``where`` names the file)."""
    cols = [str(c) for c in columns]
    if not cols:
        raise FileRefused(f"{where}: the file has no columns")
    if time_column is not None:
        if time_column not in cols:
            raise FileRefused(
                f"{where}: no column {time_column!r} (--time-column); the columns are "
                + ", ".join(cols)
            )
        return time_column
    for c in cols:
        if c.strip().lower() in TIME_NAMES:
            return c
    if sample is not None:
        typed = [c for c in cols if pd.api.types.is_datetime64_any_dtype(sample[c].dtype)]
        if len(typed) == 1:
            return typed[0]
        if _holds_datetimes(sample[cols[0]]):
            return cols[0]
    raise FileRefused(_no_time_column(where, cols))


def check_time_kind(
    where: str, tcol: str, raw: pd.Series, time_unit: str | None, start, tz: str = "UTC"
) -> int | None:
    """Refuse plain-number times without a unit, a unit for date-times, ``start`` without
    a unit; return the origin of a plain-number time column in µs (None for date-times)."""
    flag = shlex.quote(tcol)
    if time_unit is None:
        if start is not None:
            raise FileRefused(
                f"{where}: --start is the origin of plain-number times; it needs --time-unit"
            )
        if _plain_numbers(raw):
            shown = ", ".join(_texts(raw).iloc[:3].tolist())
            raise FileRefused(
                f"{where}: the time column {tcol!r} holds plain numbers ({shown}, ...), not "
                "date-times, and import does not guess what they count. Say it: "
                f"--time-column {flag} --time-unit s --start 2001-11-17T00:00:00Z reads "
                "them as seconds after that time (give the time of 0: a relative time needs "
                "its origin); --time-unit s without --start reads seconds since 1970-01-01 "
                f"UTC (Unix time). Units: {', '.join(TIME_UNITS)}"
            )
        return None
    if time_unit not in TIME_UNITS:
        raise FileRefused(f"--time-unit {time_unit!r}: use one of {', '.join(TIME_UNITS)}")
    if not _plain_numbers(raw) and len(_texts(raw)):
        example = _texts(raw).iloc[0]
        raise FileRefused(
            f"{where}: --time-unit {time_unit} is for a time column of plain numbers, but "
            f"{tcol!r} holds date-times (e.g. {str(example)!r}); leave --time-unit and "
            "--start out"
        )
    if start is None:
        return 0
    try:
        origin = pd.Timestamp(start)
        if origin.tzinfo is None:
            origin = origin.tz_localize(tz)
    except Exception:  # noqa: BLE001 - unparseable, or ambiguous/non-existent in tz
        raise FileRefused(
            f"--start {start!r}: not a time in {tz} (e.g. 2001-11-17T00:00:00Z)"
        ) from None
    return int(index_us(pd.DatetimeIndex([origin]))[0])


def parse_times(
    raw: pd.Series,
    tz: str = "UTC",
    unit: str | None = None,
    origin_us: int = 0,
    time_format: str | None = None,
) -> pd.Series:
    """Times → tz-aware UTC (NaT where unparseable). Without ``unit`` plain numbers are not
    times (NaT); with it every value must be a number of ``unit`` after ``origin_us``.
    ``time_format``: a ``strftime`` format the text follows (default ISO 8601)."""
    if unit is not None:
        return _numeric_times(raw, unit, origin_us)
    if pd.api.types.is_datetime64_any_dtype(raw.dtype):
        t = raw
    elif pd.api.types.is_numeric_dtype(raw.dtype):
        return pd.Series(pd.NaT, index=raw.index, dtype="datetime64[us, UTC]")
    elif time_format is not None:
        text = _strip(raw)
        t = pd.to_datetime(text, errors="coerce", format=time_format, utc="%z" in time_format)
    else:
        text = _strip(raw)
        # a plain number is no time, though ISO 8601 reads 2026 or 20260101 as dates: the
        # only numbers it reads are that short, so only short cells are tested (fast)
        short = text.str.len() <= 10
        if short.any():
            number = pd.to_numeric(text[short], errors="coerce").notna()
            text = text.mask(number.reindex(text.index, fill_value=False))
        try:
            with warnings.catch_warnings():
                # pandas 2.x warns (FutureWarning) of times with mixed offsets, which it
                # returns as objects: they are read again with utc=True below
                warnings.simplefilter("ignore", FutureWarning)
                t = pd.to_datetime(text, errors="coerce", format="ISO8601")
        except (ValueError, TypeError):
            t = pd.to_datetime(text, errors="coerce", utc=True)
        if t.isna().sum() > text.isna().sum() and not pd.api.types.is_datetime64_any_dtype(t):
            t = pd.to_datetime(text, errors="coerce", utc=True)
        if t.dtype == object:  # mixed offsets
            t = pd.to_datetime(text, errors="coerce", utc=True)
    if getattr(t.dt, "tz", None) is None:
        t = _localize(t, tz)
    return t.dt.tz_convert("UTC")


def _localize(t: pd.Series, tz: str) -> pd.Series:
    """Naive times read as local times in ``tz``. The hour repeated when the clock goes back
    is settled by the rows' order where they run through it in order (pandas'
    ``ambiguous="infer"``: the times going back mark the second pass); otherwise, and for a
    time the clock skips, NaT (reported by :func:`_time_reason`)."""
    strict = t.dt.tz_localize(tz, ambiguous="NaT", nonexistent="NaT")
    unsure = strict.isna() & t.notna()
    if not unsure.any():
        return strict
    try:
        inferred = t.dt.tz_localize(tz, ambiguous="infer", nonexistent="NaT")
    except ValueError:  # out of order through the repeated hour, or only one pass of it
        return strict
    run = inferred[unsure].dropna()
    if not run.is_monotonic_increasing:  # the order settles it only where time then runs on
        return strict
    return inferred


#: a time written with its UTC offset: ``…Z``, ``…+01:00``, ``…-0500``
_OFFSET = r"(?:Z|[+-]\d\d:?\d\d)\s*$"


def _is_time(text: object) -> bool:
    """``text`` reads as a date-time on its own (a naive one pandas could not place among
    times with a UTC offset)."""
    try:
        return pd.Timestamp(str(text).strip()) is not pd.NaT
    except (ValueError, TypeError):
        return False


def _time_reason(text: object, tz: str) -> str:
    """Why a time in local time ``tz`` was not read: ambiguous, skipped by the clock, or not
    a time at all."""
    try:
        naive = pd.Timestamp(str(text).strip())
    except (ValueError, TypeError):
        return f"unparseable time {str(text)!r}"
    if naive is pd.NaT or naive.tzinfo is not None:
        return f"unparseable time {str(text)!r}"
    try:
        naive.tz_localize(tz)
    except ValueError as exc:
        if "nonexistent" in str(exc):
            return (
                f"time {str(text)!r} does not exist in {tz} (the hour the clock skips "
                "forward); write times with their UTC offset"
            )
        return (
            f"time {str(text)!r} is ambiguous in {tz} (the hour repeated when the clock goes "
            "back, and the rows do not run through it in order); write times with their "
            "UTC offset"
        )
    return f"unparseable time {str(text)!r}"


def _strip(raw: pd.Series) -> pd.Series:
    """Text without surrounding blanks (a column of str as it is; anything else as text)."""
    if raw.dtype == object and pd.api.types.infer_dtype(raw, skipna=True) in ("string", "empty"):
        return raw.str.strip()
    return raw.astype("string").str.strip()


def _numeric_times(raw: pd.Series, unit: str, origin_us: int) -> pd.Series:
    if pd.api.types.is_numeric_dtype(raw.dtype) and not pd.api.types.is_bool_dtype(raw.dtype):
        x = raw.to_numpy(np.float64, na_value=np.nan)
    else:
        num = pd.to_numeric(raw.astype("string").str.strip(), errors="coerce")
        x = num.to_numpy(np.float64, na_value=np.nan)
    after = np.rint(x * TIME_UNITS[unit]) if unit != "ns" else np.rint(x / 1000.0)
    ok = np.isfinite(after) & (np.abs(after) < 4e18)
    out = np.full(len(x), np.datetime64("NaT"), "datetime64[us]")
    out[ok] = (after[ok].astype(np.int64) + origin_us).view("datetime64[us]")
    return pd.Series(pd.DatetimeIndex(out).tz_localize("UTC"), index=raw.index)


@dataclass
class Dialect:
    """How a file writes its rows: the CSV separator, the decimal mark, the date-time format
    (None: ISO 8601), and the tags' declared ranges used to judge values."""

    sep: str = ","
    decimal: str = "."
    time_format: str | None = None
    ranges: dict[str, tuple[float | None, float | None]] = field(default_factory=dict)


def _clean_chunk(
    chunk: pd.DataFrame,
    tcol: str,
    tz: str,
    line_of: Callable[[int], str],
    report: ImportReport,
    unit: str | None = None,
    origin_us: int = 0,
    dialect: Dialect | None = None,
) -> tuple[pd.DataFrame, pd.DataFrame, np.ndarray]:
    """Parse one chunk: report bad rows (no usable time: skipped) and bad cells (stored as
    Bad samples); return the rows with a time as a wide frame of values on UTC time, the
    frame of their quality codes (NaN value and GOOD: no sample) and the rows' positions in
    the chunk (for ``line_of``)."""
    dialect = dialect or Dialect()
    values = chunk.drop(columns=[tcol])
    raw_t = chunk[tcol]
    blank = raw_t.isna().to_numpy() & values.isna().all(axis=1).to_numpy()
    t = parse_times(raw_t, tz, unit, origin_us, dialect.time_format)
    bad_time = t.isna().to_numpy() & ~blank
    reason: dict[int, str] = {}
    offset = None  # per row: its time written with a UTC offset (only where a time is bad)
    for i in np.flatnonzero(bad_time):
        rv = raw_t.iloc[i]
        why = "missing time" if pd.isna(rv) else f"unparseable time {str(rv)!r}"
        if not pd.isna(rv) and unit is not None:
            why += f" (--time-unit {unit}: expected a number)"
        elif not pd.isna(rv) and dialect.time_format:
            why += f" (--time-format {dialect.time_format})"
        elif not pd.isna(rv):
            if offset is None:
                offset = _texts(raw_t).str.contains(_OFFSET, na=False).to_numpy()
            if offset.any() and not offset[i] and _is_time(rv):
                why = (
                    f"time {str(rv)!r} has no UTC offset, among times that have one (in "
                    "which zone is it?); write every time with its offset"
                )
            elif tz != "UTC":
                why = _time_reason(rv, tz)
        reason[i] = why
    implausible = ~blank & ~t.isna().to_numpy()  # every row with a time, judged below
    if implausible.any():
        lo, hi = _plausible_times()
        ok_t = pd.DatetimeIndex(t[implausible])
        out_of = (ok_t < lo) | (ok_t > hi)
        for i, when in zip(np.flatnonzero(implausible)[out_of], ok_t[out_of], strict=True):
            reason[i] = f"time {when} is before 1970 or more than a year ahead"
    ok = ~blank
    for i in sorted(reason):
        report._bad(f"{line_of(i)}: {reason[i]}")
        ok[i] = False
    report.rows += int(np.count_nonzero(~blank))
    rows = np.flatnonzero(ok)
    every = len(rows) == len(ok)  # no row dropped: the columns as they are, not copies
    # filled column by column into one block each (Fortran order: a column is contiguous),
    # which the frames take as they are
    numeric = np.empty((len(rows), values.shape[1]), np.float64, order="F")
    quality = np.empty((len(rows), values.shape[1]), np.int8, order="F")
    for j, name in enumerate(values.columns):
        v, bad, why = _cell_values(values[name], dialect, str(name))
        if not every:
            v, bad = v[rows], bad[rows]
        for k in np.flatnonzero(bad):
            i = int(rows[k])
            report._bad_cell(str(name), f"{line_of(i)}: {name}: {why[i]}; stored as a Bad sample")
        numeric[:, j] = v
        quality[:, j] = np.where(bad, BAD, GOOD)
    index = pd.DatetimeIndex(t.iloc[rows], name="ts")
    return (
        pd.DataFrame(numeric, index=index, columns=values.columns, copy=False),
        pd.DataFrame(quality, index=index, columns=values.columns, copy=False),
        rows,
    )


def _plausible_times() -> tuple[pd.Timestamp, pd.Timestamp]:
    return pd.Timestamp("1970-01-02", tz="UTC"), pd.Timestamp.now(tz="UTC") + FUTURE_LIMIT


def _cell_values(
    col: pd.Series, dialect: Dialect, name: str
) -> tuple[np.ndarray, np.ndarray, dict[int, str]]:
    """One column's numbers (NaN: no number), the mask of bad cells (something there, but no
    usable number) and, per bad cell's position, why it is bad."""
    if pd.api.types.is_numeric_dtype(col.dtype) and not pd.api.types.is_bool_dtype(col.dtype):
        v = col.to_numpy(np.float64, na_value=np.nan)
        present = ~np.isnan(v)
        text = None
    else:
        text = col.astype("string").str.strip()
        present = (text.notna() & (text != "")).to_numpy()
        if dialect.decimal != ".":  # a '.' is then no decimal mark: not a number
            text = text.mask(text.str.contains(".", regex=False))
            text = text.str.replace(dialect.decimal, ".", regex=False)
        v = pd.to_numeric(text, errors="coerce").to_numpy(np.float64, na_value=np.nan)
        v[~present] = np.nan
    why: dict[int, str] = {}  # only bad cells: a column of good ones builds nothing
    bad = np.zeros(len(v), bool)
    nan = present & np.isnan(v)
    if nan.any():
        bad |= nan
        shown = col.astype("string").to_numpy(dtype=object, na_value="")
        why |= {int(i): f"no number in {str(shown[i]).strip()!r}" for i in np.flatnonzero(nan)}
    inf = present & np.isinf(v)
    bad |= inf
    why |= dict.fromkeys(np.flatnonzero(inf).tolist(), "not finite (inf)")
    huge = present & np.isfinite(v) & (np.abs(v) > FLOAT32_MAX)
    bad |= huge
    why |= {
        int(i): f"{v[i]:g} is beyond the float range a historian stores"
        for i in np.flatnonzero(huge)
    }
    lo, hi = dialect.ranges.get(name, (None, None))
    if lo is not None and hi is not None and hi > lo:
        span = hi - lo
        out = (
            present
            & np.isfinite(v)
            & ~huge
            & ((v < lo - NE43_LOW * span) | (v > hi + NE43_HIGH * span))
        )
        bad |= out
        why |= {
            int(i): f"{v[i]:g} is outside the tag's range {lo:g}..{hi:g} beyond the NE 43 "
            "failure margins"
            for i in np.flatnonzero(out)
        }
    return v, bad, why


def _csv_chunks(
    path: Path, tcol: str, chunk_rows: int, advance, dialect: Dialect, numbers: bool = False
) -> Iterator:
    """The CSV file's rows in chunks of ``chunk_rows``, each with the line of its first row.

    The time column comes as text, as written (an error quotes it). Each column's type is
    inferred from the whole chunk, the time column's too unless the file's times are plain
    numbers (``numbers``, from the sample): pandas (3.1) parses a column it infers to be
    text faster than one it is told to keep as text (1 M rows × 20 tags: 1.00 against
    1.49 s CPU). A chunk whose times all read as numbers, booleans or blanks is read
    again, with the rest of the file, with the time column kept as text (the rows already
    read skipped; at most once a file)."""
    options = dict(
        chunksize=chunk_rows,
        sep=dialect.sep,
        decimal=dialect.decimal,
        keep_default_na=False,
        na_values=[""],
        skip_blank_lines=False,
        skipinitialspace=True,
        encoding="utf-8-sig",
        # each chunk's column types inferred from the whole chunk: a column with a text
        # cell is text throughout the chunk (its cells judged one by one), never a mix of
        # numbers and text pieces (pandas' DtypeWarning)
        low_memory=False,
    )
    fields = _ShortRows(path, dialect.sep)
    try:
        yield from _csv_readers(path, tcol, advance, options, numbers, fields)
    finally:
        fields.close()


def _csv_readers(path: Path, tcol: str, advance, options: dict, numbers: bool, fields):
    """:func:`_csv_chunks`' loop: a reader, and a second from where a chunk of times that
    read as numbers stopped the first."""
    base, as_text = 0, numbers
    while True:
        skipped = base  # rows read before this reader: skipped, and counted in the index
        with open(path, "rb") as fh:
            reader = pd.read_csv(
                fh,
                dtype={tcol: str} if as_text else None,
                skiprows=(lambda i, done=skipped: 0 < i <= done) if skipped else None,
                **options,
            )
            for chunk in reader:
                if not as_text and not _all_text(chunk[tcol]):
                    as_text = True  # times that look like numbers: read again as text
                    break
                fields.check(chunk, base + 2)
                if skipped:
                    chunk.index += skipped
                yield chunk, base + 2  # the header is line 1
                base += len(chunk)
                advance(fh.tell())
            else:
                return


class ShortRow(pd.errors.ParserError):
    """A CSV row with fewer fields than the header (pandas reads the missing cells as
    blanks), in pandas' words for a row with more (:func:`_parse_error`)."""


class _ShortRows:
    """Rows of a CSV file with fewer fields than its header, which pandas reads without a
    word (the missing cells as blanks; a row with more is its ParserError).

    Only the rows whose last cell pandas read as blank and whose other cells are not all
    blank (a blank line is skipped, as documented) are suspects, so a file whose last
    column is full costs one ``isna`` a chunk. For a chunk with suspects, the chunk's lines
    are read again as bytes (forward only, from a handle of its own) and their fields
    counted: separators per line (numpy), the csv module's count for a line with a quote.
    Rows are lines (as the import's ``file:line`` messages take them); a line whose quotes
    do not close (a quoted cell over two lines) ends the check for the rest of the file."""

    def __init__(self, path: Path, sep: str):
        self.path, self.sep = path, sep
        self.fh = None
        self.line = 1  # the line ``self.buf`` starts at
        self.buf = b""
        self.off = len(sep) != 1  # a separator of more characters: not counted

    def check(self, chunk: pd.DataFrame, first: int) -> None:
        """Raise :class:`ShortRow` at the first row of ``chunk`` (its first row at line
        ``first``) with fewer fields than the header."""
        if self.off or not len(chunk):
            return
        last = chunk.iloc[:, -1].isna().to_numpy()
        if not last.any():
            return
        want = chunk.shape[1]
        counts = self._counts(first, first + len(chunk), want)
        if counts is None:
            return
        rows = np.flatnonzero(last & (counts[: len(last)] < want))
        if not len(rows):
            return
        rows = rows[chunk.iloc[rows].notna().any(axis=1).to_numpy()]  # not a blank line
        if len(rows):
            i = int(rows[0])
            raise ShortRow(f"Expected {want} fields in line {first + i}, saw {int(counts[i])}")

    def _lines(self, n: int, keep: bool = True) -> bytes:
        """The next ``n`` lines' bytes (fewer at the end of the file); skipped (``keep``
        false): ``b""`` unless they hold a quote (for :meth:`_odd_quotes`)."""
        if self.fh is None:
            self.fh = open(self.path, "rb")  # noqa: SIM115 - closed with the generator
        parts, have, quoted, block = [], 0, False, self.buf
        while True:
            c = block.count(b"\n")
            quoted = quoted or b'"' in block
            if have + c >= n:  # the n-th newline in this block
                pos = int(np.flatnonzero(np.frombuffer(block, np.uint8) == 10)[n - have - 1]) + 1
                parts.append(block[:pos])
                self.buf = block[pos:]
                break
            parts.append(block)
            have += c
            block = self.fh.read(1 << 22)
            if not block:
                self.buf = b""
                break
        self.line += n
        return b"".join(parts) if keep or quoted else b""

    def _counts(self, a: int, b: int, want: int) -> np.ndarray | None:
        """Fields per line of lines ``a`` … ``b - 1`` (lines ``b - a`` long, ``want`` for each
        when every line has them: the chunk's separators counted first, a row with more
        being pandas' error); None once the check is off (or for lines already passed:
        never asked, the chunks come in file order)."""
        if self.line > a:
            return None
        while self.line < a:  # skip the lines of chunks without suspects
            if self._odd_quotes(self._lines(min(a - self.line, 200_000), keep=False)):
                return None
        raw = self._lines(b - a)
        n = b - a
        quoted = b'"' in raw
        if not quoted and raw.count(self.sep.encode()) == n * (want - 1):
            return np.full(n, want)  # no line short (none longer)
        if quoted and self._odd_quotes(raw):
            return None
        arr = np.frombuffer(raw, np.uint8)
        ends = np.flatnonzero(arr == 10)
        if not len(arr) or arr[-1] != 10:
            ends = np.append(ends, len(arr))
        starts = np.r_[0, ends[:-1] + 1]
        seps = np.flatnonzero(arr == ord(self.sep))
        counts = 1 + np.searchsorted(seps, ends) - np.searchsorted(seps, starts)
        if quoted:  # a separator inside quotes is no separator
            import csv

            quotes = np.flatnonzero(arr == ord('"'))
            has = np.searchsorted(quotes, ends) > np.searchsorted(quotes, starts)
            for k in np.flatnonzero(has):
                text = raw[starts[k] : ends[k]].decode("utf-8", "replace").rstrip("\r")
                counts[k] = len(next(csv.reader([text], delimiter=self.sep), []))
        return np.r_[counts, np.full(max(0, n - len(counts)), want)][:n]

    def _odd_quotes(self, raw: bytes) -> bool:
        """A line of ``raw`` with an odd number of quotes: a quoted cell runs over lines,
        rows are no longer lines, and the check is off from here on."""
        if b'"' not in raw:
            return False
        arr = np.frombuffer(raw, np.uint8)
        cum = np.cumsum(arr == ord('"'))
        at_ends = cum[arr == 10]
        per_line = np.diff(np.r_[0, at_ends, cum[-1]])  # the last: after the last newline
        self.off = bool(np.any(per_line % 2))
        return self.off

    def close(self) -> None:
        if self.fh is not None:
            self.fh.close()


def _all_text(col: pd.Series) -> bool:
    """The column holds text only (pandas' string type, or Python strings): not numbers,
    booleans (``True`` with a blank reads as a Python bool) or only blanks."""
    if isinstance(col.dtype, pd.StringDtype):
        return True
    return col.dtype == object and pd.api.types.infer_dtype(col, skipna=True) == "string"


def _parquet_chunks(path: Path, chunk_rows: int, advance) -> Iterator:
    import pyarrow.parquet as pq

    pf = pq.ParquetFile(path)
    base = 0
    for batch in pf.iter_batches(batch_size=chunk_rows):
        chunk = batch.to_pandas(ignore_metadata=True)  # a DatetimeIndex stays a column
        yield chunk, base + 1  # 1-based row numbers
        base += len(chunk)
        advance(base)


def _is_parquet(path: Path) -> bool:
    if path.suffix.lower() in (".parquet", ".pq"):
        return True
    with open(path, "rb") as fh:
        return fh.read(4) == b"PAR1"


def _spreadsheet(path: Path) -> str | None:
    """What kind of spreadsheet workbook the file is, from its first bytes (None: not one):
    Office Open XML and OpenDocument are ZIP archives, Excel 97-2003 an OLE2 file."""
    with open(path, "rb") as fh:
        head = fh.read(8)
    if head.startswith(b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1"):
        return "an Excel 97-2003 workbook (.xls)"
    if not head.startswith(b"PK\x03\x04"):
        return None
    import zipfile

    try:
        with zipfile.ZipFile(path) as z:
            names = z.namelist()
            mime = z.read("mimetype").decode("ascii", "replace") if "mimetype" in names else ""
    except (zipfile.BadZipFile, OSError, KeyError):
        return "a ZIP archive"
    if any(n.startswith("xl/") for n in names):
        return "an Excel workbook (.xlsx)"
    if "opendocument.spreadsheet" in mime:
        return "an OpenDocument spreadsheet (.ods)"
    return "a ZIP archive"


def _check_text(path: Path, block_size: int = 1 << 20) -> None:
    """Refuse a CSV that is not UTF-8 text (a NUL byte, an invalid byte) at ``file:line``,
    or holds only blank lines. Reads the whole file once, before anything is written; a
    block of ASCII is UTF-8 as it is (no decoding), and lines are counted only to name
    one."""
    decoder = codecs.getincrementaldecoder("utf-8")()
    done, text = 0, False
    with open(path, "rb") as fh:
        while block := fh.read(block_size):
            nul = block.find(b"\0")
            if nul >= 0:
                at = _line_at(path, done + nul)
                raise FileRefused(f"{path}:{at}: binary data (a NUL byte), not a CSV text file")
            held = len(decoder.getstate()[0])
            if held or not block.isascii():
                try:
                    decoder.decode(block)
                except UnicodeDecodeError as exc:
                    pos = min(max(0, exc.start - held), len(block) - 1)
                    raise FileRefused(
                        f"{path}:{_line_at(path, done + pos)}: not UTF-8 text (byte "
                        f"0x{block[pos : pos + 1].hex()}); save the file as UTF-8 (CSV UTF-8)"
                    ) from None
            text = text or not block.isspace()
            done += len(block)
    try:
        decoder.decode(b"", final=True)
    except UnicodeDecodeError:
        at = _line_at(path, done)
        raise FileRefused(f"{path}:{at}: not UTF-8 text (cut off at the end)") from None
    if not text:
        raise FileRefused(f"{path}: no header line (the file holds only blank lines)")


def _line_at(path: Path, offset: int, block_size: int = 1 << 20) -> int:
    """The line (1-based) of the file's byte at ``offset``."""
    line = 1
    with open(path, "rb") as fh:
        while offset > 0 and (block := fh.read(min(block_size, offset))):
            line += block.count(b"\n")
            offset -= len(block)
    return line


def inspect_file(
    path: Path, sep: str | None = None, decimal: str | None = None
) -> tuple[bool, list[str], pd.DataFrame, Dialect, list[str]]:
    """(is Parquet, column names, the first :data:`SAMPLE_ROWS` data rows as text, the CSV
    dialect, notes on what was detected). Raises :class:`FileRefused`, naming the file, for
    a missing, empty, blank, header-only or unreadable file."""
    if not path.exists():
        raise FileRefused(f"{path}: no such file")
    if not path.is_file():
        raise FileRefused(f"{path}: not a file")
    dialect, notes = Dialect(), []
    try:
        if path.stat().st_size == 0:
            raise FileRefused(
                f"{path}: empty file (0 bytes); expected a header line (a time column, then "
                "one column per tag) and data rows"
            )
        parquet = _is_parquet(path)
        kind = None if parquet else _spreadsheet(path)
        if kind:
            raise FileRefused(
                f"{path}: {kind}, not a CSV text file; import reads CSV and Parquet: in the "
                "spreadsheet program save the sheet as 'CSV UTF-8 (comma delimited)' (Excel) "
                "or 'Text CSV' with UTF-8 (LibreOffice), one time column and one column per "
                "tag, and import that file"
            )
        if parquet:
            sample, columns, rows = _parquet_sample(path)
        else:
            _check_text(path)
            dialect, notes = sniff_csv(path, sep, decimal)
            try:
                sample = pd.read_csv(
                    path,
                    nrows=SAMPLE_ROWS,
                    dtype=str,
                    sep=dialect.sep,
                    keep_default_na=False,
                    na_values=[""],
                    skipinitialspace=True,
                    encoding="utf-8-sig",
                )
            except (pd.errors.ParserError, pd.errors.EmptyDataError, ValueError) as exc:
                raise FileRefused(_parse_error(path, exc)) from None
            check_header_once(path, dialect.sep)
            columns = [str(c) for c in sample.columns]
            rows = len(sample.dropna(how="all"))
    except OSError as exc:
        raise FileRefused(f"{path}: cannot read it: {exc.strerror or exc}") from None
    if not rows:
        raise FileRefused(f"{path}: no data rows, only a header ({', '.join(columns)})")
    return parquet, columns, sample, dialect, notes


def check_header_once(path: Path, sep: str = ",") -> None:
    """Refuses a CSV header naming a column twice (pandas would read the second as
    ``NAME.1``, a tag nobody wrote, or a tags CSV's second ``role`` unread), ``file:1``, the
    name and the columns' positions."""
    import csv

    with open(path, encoding="utf-8-sig", newline="") as fh:
        header = next((row for row in csv.reader(fh, delimiter=sep) if row), [])
    names = [c.strip() for c in header]
    seen: dict[str, list[int]] = {}
    for i, n in enumerate(names, 1):
        seen.setdefault(n, []).append(i)
    twice = {n: at for n, at in seen.items() if len(at) > 1}
    if twice:
        raise FileRefused(
            f"{path}:1: the header names "
            + "; ".join(
                f"column {n!r} {len(at)} times (columns {', '.join(map(str, at))})"
                for n, at in twice.items()
            )
            + ": name each column once"
        )


#: lines read to detect a CSV file's separator and decimal mark
SNIFF_LINES = 50
_COMMA_NUMBER = re.compile(r"^[+-]?\d+,\d+(?:[eE][+-]?\d+)?$")
_DOT_NUMBER = re.compile(r"^[+-]?\d*\.\d+(?:[eE][+-]?\d+)?$")


def sniff_csv(
    path: Path, sep: str | None = None, decimal: str | None = None
) -> tuple[Dialect, list[str]]:
    """The separator and decimal mark of a CSV file: as given, else detected from its first
    lines where unambiguous (every line splits into the header's number of fields by exactly
    one of ``, ; tab |``; cells like ``12,5`` and none like ``12.5`` mean a decimal comma).
    Returns the dialect and a note per detected choice. Raises :class:`FileRefused` when the
    decimal mark cannot be told and matters."""
    import csv

    with open(path, encoding="utf-8-sig", newline="") as fh:
        lines = [ln for _, ln in zip(range(SNIFF_LINES), fh, strict=False) if ln.strip()]
    notes = []
    if sep is None:
        fits = []
        for c in SEPARATORS:
            counts = [len(row) for row in csv.reader(lines, delimiter=c)]
            if counts and counts[0] >= 2 and all(n == counts[0] for n in counts):
                fits.append(c)
        sep = "," if not fits or "," in fits else fits[0]
        if sep != ",":
            notes.append(f"separator {_sep_name(sep)} (detected; --sep to choose)")
    if decimal is None:
        decimal = "."
        if sep != ",":
            cells = [c.strip() for row in csv.reader(lines[1:], delimiter=sep) for c in row[1:]]
            comma = sum(bool(_COMMA_NUMBER.match(c)) for c in cells)
            dot = sum(bool(_DOT_NUMBER.match(c)) for c in cells)
            if comma and dot:
                raise FileRefused(
                    f"{path}: numbers written both as 12,5 and as 12.5 in the first lines; say "
                    "which is the decimal mark: --decimal , or --decimal ."
                )
            if comma:
                decimal = ","
                notes.append("decimal comma (detected; --decimal to choose)")
    elif sep == decimal:
        raise FileRefused(f"{path}: --sep and --decimal are both {sep!r}")
    return Dialect(sep=sep, decimal=decimal), notes


def _sep_name(sep: str) -> str:
    return {"\t": "tab", ";": "';'", "|": "'|'", ",": "','"}[sep]


_DAY_MONTH = re.compile(r"^\s*(\d{1,2})([./-])(\d{1,2})\2(\d{4})(?:[ T](.*))?$")
_CLOCK = re.compile(r"^(\d{1,2}):(\d{2})(?::(\d{2})(\.\d+)?)?$")


def detect_time_format(texts: pd.Series, where: str) -> tuple[str | None, str | None]:
    """The format of date-times written day.month.year or month/day/year, read only when the
    file shows the order (a first field above 12: day first; a second one: month first), and
    a note saying so; ``(None, None)`` for anything else (ISO 8601 is read as it is). Raises
    :class:`FileRefused` when the order cannot be told."""
    first = [m for t in texts if (m := _DAY_MONTH.match(str(t)))]
    if not first or len(first) < len(texts) // 2:
        return None, None
    a = max(int(m[1]) for m in first)
    b = max(int(m[3]) for m in first)
    sep = first[0][2]
    example = first[0].string.strip()
    clock = ""
    if first[0][5]:
        m = _CLOCK.match(first[0][5].strip())
        if not m:
            return None, None
        clock = " %H:%M" + (":%S" if m[3] else "") + (".%f" if m[4] else "")
    day_first, month_first = f"%d{sep}%m{sep}%Y{clock}", f"%m{sep}%d{sep}%Y{clock}"
    if a > 12 and b > 12:
        raise FileRefused(f"{where}: dates such as {example!r} fit no day/month order")
    if a <= 12 and b <= 12:
        raise FileRefused(
            f"{where}: dates such as {example!r} can be read day first or month first and "
            f"import does not guess: give --time-format, e.g. --time-format '{day_first}' "
            f"(day first) or '{month_first}'"
        )
    fmt = day_first if a > 12 else month_first
    order = "day.month.year" if a > 12 else "month/day/year"
    return fmt, f"times read as {order} ({fmt!r}, detected; --time-format to choose)"


def _parquet_sample(path: Path):
    import pyarrow.parquet as pq

    try:
        pf = pq.ParquetFile(path)
        columns = list(pf.schema_arrow.names)
        if pf.metadata.num_rows == 0:
            return pd.DataFrame(columns=columns), columns, 0
        batch = next(pf.iter_batches(batch_size=SAMPLE_ROWS))
    except Exception as exc:  # noqa: BLE001 - pyarrow's errors: say the file is unreadable
        raise FileRefused(f"{path}: not a readable Parquet file ({_first_line(exc)})") from None
    return batch.to_pandas(ignore_metadata=True), columns, pf.metadata.num_rows


def _first_line(exc: Exception) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def file_columns(path: Path) -> list[str]:
    return inspect_file(Path(path))[1]


def load_tags_csv(h: Historian, path: str | Path) -> list[str]:
    """Tag metadata from a tags CSV (:func:`read_tags_csv`) into ``h``; returns the names."""
    rows = read_tags_csv(path)
    for m in rows:
        h.ensure_tag(**m)
    return [m["name"] for m in rows]


def stored_conflicts(
    h: Historian, frame: pd.DataFrame, quality: int | pd.DataFrame = GOOD
) -> tuple[int, tuple[int, int, int, float, int] | None]:
    """Samples of the wide ``frame`` (a DatetimeIndex without repeats, one column per
    existing tag; a cell is a sample when it holds a number or its quality is Bad) whose
    (tag, ts) ``h`` holds with a different value or quality, in the database or in a month
    rolled to the cold store. ``quality``: one code, or a frame of codes like ``frame``.

    Returns ``(count, first)``; ``first`` is ``(ts µs, column, row, stored value, stored
    quality)`` of the earliest conflict, or None. Reads, per tag, the stored samples over the
    frame's span and compares them with numpy (no per-row queries); two NaN values are the
    same value."""
    count, first = 0, None
    ts_all = index_us(frame.index)
    for j, name in enumerate(frame.columns):
        value = frame[name].to_numpy(np.float64, na_value=np.nan)
        q = (
            quality[name].to_numpy(np.int64)
            if isinstance(quality, pd.DataFrame)
            else np.full(len(value), int(quality), np.int64)
        )
        rows = np.flatnonzero(~np.isnan(value) | (q == BAD))
        if not len(rows):
            continue
        ts = ts_all[rows]
        stored = h.read_samples(
            str(name), from_us(int(ts.min())), from_us(int(ts.max()) + 1), with_quality=True
        )
        if stored.empty:
            continue
        s_ts = index_us(stored.index)
        s_v = stored["value"].to_numpy(np.float64)
        s_q = stored["quality"].to_numpy(np.int64)
        pos = np.minimum(np.searchsorted(s_ts, ts), len(s_ts) - 1)
        v, sv = value[rows], s_v[pos]
        same = ((sv == v) | (np.isnan(sv) & np.isnan(v))) & (s_q[pos] == q[rows])
        hits = np.flatnonzero((s_ts[pos] == ts) & ~same)
        if not len(hits):
            continue
        count += len(hits)
        k = hits[np.argmin(ts[hits])]
        if first is None or ts[k] < first[0]:
            first = (int(ts[k]), j, int(rows[k]), float(s_v[pos[k]]), int(s_q[pos[k]]))
    return count, first


def check_tz(tz: str) -> None:
    """Refuse a time zone that is not one (:class:`FileRefused`, nothing written) before the
    file is read. A file whose times carry their offsets localises no naive time, so a
    misspelt ``--tz`` was accepted there without a word (and on a file of naive times
    refused by a message that did not name the option: ``No time zone found with key
    Europe/Berln``)."""
    try:
        pd.Timestamp("2026-01-01").tz_localize(tz)
    except Exception:  # noqa: BLE001 - unknown key, or not a string
        raise FileRefused(
            f"--tz {tz!r}: not a time zone (an IANA name such as Europe/Berlin, or UTC)"
        ) from None


def import_file(
    h: Historian,
    path: str | Path,
    *,
    time_column: str | None = None,
    tz: str = "UTC",
    time_unit: str | None = None,
    start=None,
    tags_csv: str | Path | None = None,
    strict: bool = False,
    policy: str = "ignore",
    sep: str | None = None,
    decimal: str | None = None,
    time_format: str | None = None,
    rename: dict[str, str] | None = None,
    duplicates: str = "error",
    chunk_rows: int = 200_000,
    progress: Callable[[int, int], None] | None = None,
    hot: bool = False,
) -> ImportReport:
    """Import a wide CSV or Parquet file into ``h``; see the module docstring.

    ``time_unit``/``start``: a time column of plain numbers counts ``time_unit`` after
    ``start`` (default 1970-01-01 UTC). ``sep``/``decimal``: the CSV separator and decimal
    mark (default: detected where unambiguous); ``time_format``: a ``strftime`` format of
    the date-times (default ISO 8601); ``rename``: column → tag name. ``policy``:
    ``"ignore"`` keeps stored values at a conflict, ``"update"`` overwrites them; either way
    conflicts are counted in the report. ``duplicates``: what a time repeated within the
    file means (:data:`DUPLICATES`; see :class:`_Repeats`): ``"error"`` refuses the file,
    naming the first repeat and the count; ``"first"``, ``"last"`` keep that sample of each
    tag, ``"mean"`` the mean of each tag's usable samples; the report says how many rows
    repeated a time. ``progress(done, total)`` is called after each
    chunk (bytes for CSV, rows for Parquet). Samples of closed months (before the current
    UTC month) go straight to the cold store's month files when the historian has a cold
    folder (SQLite: always; :func:`_cold_before`), unless ``hot``: then, and for the current
    month, to the database's table. Raises :class:`FileRefused` (nothing written)
    when the file cannot be imported as given or holds no sample, :class:`ImportRefused` in
    strict mode when any row or cell is bad (nothing written).
    """
    if policy not in ("ignore", "update"):
        raise ValueError(f"policy must be 'ignore' or 'update', not {policy!r}")
    if duplicates not in DUPLICATES:
        raise ValueError(f"duplicates must be one of {', '.join(DUPLICATES)}, not {duplicates!r}")
    path = Path(path)
    check_tz(tz)
    parquet, columns, sample, dialect, notes = inspect_file(path, sep, decimal)
    tcol = pick_time_column(columns, time_column, sample, where=str(path))
    if len(columns) < 2:
        raise FileRefused(f"{path}: only the time column {tcol!r}; no tag columns to import")
    names = _tag_names(path, [c for c in columns if c != tcol], rename or {})
    origin = check_time_kind(str(path), tcol, sample[tcol], time_unit, start, tz)
    unit = time_unit if origin is not None else None
    if unit is None and time_format is None and not parquet:
        time_format, note = detect_time_format(_texts(sample[tcol]), str(path))
        notes += [note] if note else []
    dialect.time_format = time_format
    _check_plausible(path, tcol, sample[tcol], tz, unit, origin or 0, time_format)
    numbers = _plain_numbers(sample[tcol])  # times read as text from the first chunk on
    tag_rows = tags_csv_rows(tags_csv) if tags_csv is not None else []
    meta = [m for _, m in tag_rows]
    meta_line: dict[str, int] = {}
    for i, m in tag_rows:
        meta_line.setdefault(m["name"], i)
    dialect.ranges = _ranges(h, names.values(), meta)
    if parquet:
        import pyarrow.parquet as pq

        total = pq.ParquetFile(path).metadata.num_rows
    else:
        total = os.path.getsize(path)

    def chunks(advance):
        if parquet:
            return _parquet_chunks(path, chunk_rows, advance)
        return _csv_chunks(path, tcol, chunk_rows, advance, dialect, numbers)

    def noop(_done):
        pass

    def clean(chunk, line_of, report):
        values, quality, rows = _clean_chunk(
            chunk, tcol, tz, line_of, report, unit, origin or 0, dialect
        )
        return values.rename(columns=names), quality.rename(columns=names), rows

    def pieces(advance, report, repeats):
        """The file's rows as pieces without a repeated time (:class:`_Repeats`), each with
        the line number of every row."""
        for chunk, first in chunks(advance):

            def line_of(i, first=first):
                return f"{path}:{first + i}"

            frame, quality, rows = clean(chunk, line_of, report)
            yield from repeats.take(frame, quality, first + rows)
        yield from repeats.flush()

    if strict:  # validate the whole file first: refuse before writing anything
        check = ImportReport(str(path))
        repeats = _Repeats(path, duplicates)
        with _reading(path, check):
            for _ in pieces(noop, check, repeats):
                pass
        if check.n_bad or check.n_bad_cells:
            n = check.n_bad + check.n_bad_cells
            raise ImportRefused(sorted(check.bad + check.cells, key=_line_number), n)
        if repeats.refused:
            raise FileRefused(repeats.refusal(written=False))
    report = ImportReport(str(path), replace=policy == "update", notes=notes)
    repeats = _Repeats(path, duplicates)
    known = set(h.tags()["name"])
    tags_seen: list[str] = []
    pending_meta = {m["name"]: m for m in meta}

    def advance(done):
        if progress is not None:
            progress(done, total)

    def line_at(n):
        return f"{path}:{n}"

    # one piece is written (a thread: the database releases the GIL) while the next is read
    # and checked; in file order, each write waited for before the next starts
    # the first pieces are written as one where they land at the end of the key (appends)
    hold = FIRST_PIECE_FACTOR if _appends(h, names.values()) else 1
    held: list[tuple] = []
    writing = None
    cold_before = None if hot else _cold_before(h)
    report.cold_dir = None if cold_before is None else str(h.cold_dir)
    cold: dict[str, list[tuple]] = {}  # closed month -> its pieces, until the file is written
    cold_held = [0]  # samples in them

    def write_held() -> None:
        nonlocal writing, hold
        if held:
            if writing is not None:
                writing.result()
            frame, quality, n, lines = _join(held)
            writing = writer.submit(_write, h, frame, quality, n, lines, line_at, policy, report)
        held.clear()
        hold = 1

    def write_cold(months) -> None:
        """Write the held pieces of ``months`` into their month files (in the writer)."""
        nonlocal writing
        for month in sorted(months):
            parts = cold.pop(month)
            cold_held[0] -= sum(p[2] for p in parts)
            if writing is not None:
                writing.result()
            writing = writer.submit(_write_cold_month, h, month, parts, policy, line_at, report)

    def take(frame, quality, n, lines) -> None:
        """A piece to write: its closed months' rows held until the file leaves the month
        (a month's file is written once for a file in time order), the rest written."""
        if cold_before is not None:
            t = index_us(frame.index)
            lo, hi = int(t.min()), int(t.max())
            if lo < cold_before:
                for month in coldstore.months_between(lo, min(hi + 1, cold_before)):
                    m0, m1 = coldstore.month_bounds(month)
                    rows = np.flatnonzero((t >= m0) & (t < m1))
                    part = (frame.iloc[rows], quality.iloc[rows])
                    k = int((part[0].notna().to_numpy() | (part[1].to_numpy() == BAD)).sum())
                    cold.setdefault(month, []).append((*part, k, lines[rows]))
                    cold_held[0] += k
                    n -= k
                late = np.flatnonzero(t >= cold_before)
                frame, quality, lines = frame.iloc[late], quality.iloc[late], lines[late]
            done = [m for m in cold if coldstore.month_bounds(m)[1] <= lo]
            write_cold(list(cold) if cold_held[0] > COLD_HELD_SAMPLES else done)
            if not len(frame):
                return
        held.append((frame, quality, n, lines))
        if len(held) >= hold:
            write_held()

    with _reading(path, report), ThreadPoolExecutor(1, "import-writer") as writer:
        try:
            for frame, quality, lines in pieces(advance, report, repeats):
                if repeats.refused:
                    write_held()  # read before the repeat: written, as every earlier piece
                    write_cold(list(cold))
                    continue  # --duplicates error: the rest of the file is only read, to count
                present = frame.notna().to_numpy() | (quality.to_numpy() == BAD)
                has = present.any(axis=0)
                fresh = [
                    n
                    for j, n in enumerate(frame.columns)
                    if has[j] and (n in pending_meta or n not in known)
                ]
                if writing is not None and fresh:
                    writing.result()  # tag rows go in between sample batches, not beside them
                for j, name in enumerate(frame.columns):
                    if not has[j]:
                        continue
                    if name in pending_meta:
                        h.ensure_tag(**pending_meta.pop(name))
                        known.add(name)
                    if name not in known:
                        h.ensure_tag(str(name), source=path.name)
                        known.add(name)
                    if name not in tags_seen:
                        tags_seen.append(str(name))
                if has.any():
                    n = int(present.sum())
                    report.samples += n
                    lo, hi = frame.index.min(), frame.index.max()
                    take(frame, quality, n, lines)
                    report.first = lo if report.first is None else min(report.first, lo)
                    report.last = hi if report.last is None else max(report.last, hi)
        except Exception:
            write_held()  # the rows read before the file was refused are imported, as before
            write_cold(list(cold))
            raise
        write_held()
        write_cold(list(cold))
        if writing is not None:
            writing.result()
    report.repeats, report.repeat_example = repeats.count, repeats.example
    closed = report.first is not None and report.first < coldstore.month_start()
    if closed and cold_before is None and not hot:
        report.no_cold_folder = True
    report.duplicates = duplicates
    if repeats.refused:
        raise FileRefused(repeats.refusal(written=report.samples > 0))
    for m in pending_meta.values():  # metadata of tags already stored
        if m["name"] in known:
            h.ensure_tag(**m)
    unused = [name for name in pending_meta if name not in known]
    if unused:
        report.notes.append(_unused_tags_note(Path(tags_csv), unused, meta_line))
    report.tags = tags_seen
    if not report.samples:
        first = (report.bad + report.cells)[:3]
        raise FileRefused(
            f"{path}: nothing imported: no row holds a usable time and a value"
            + (" (" + "; ".join(first) + ")" if first else "")
        )
    return report


class _Repeats:
    """Rows whose time repeats an earlier row's, met piece by piece.

    :meth:`take` gets each cleaned chunk with its rows' line numbers and gives it back
    without repeated times, by the policy (:data:`DUPLICATES`). The rows at the chunk's last
    time, when it is the chunk's latest, wait for the next chunk (:meth:`flush` gives the
    last ones), so repeats that follow each other always meet in one piece. A time repeating
    one of an earlier piece (a file not in time order) is found among the times already
    taken (8 bytes per row, only searched where the time ranges overlap): ``"first"`` drops
    it, ``"last"`` and ``"mean"`` refuse (they need the repeats together). ``"error"`` sets
    :attr:`refused` at the first repeat; later pieces are still read (and counted), not
    given back."""

    def __init__(self, path: Path, policy: str):
        self.path, self.policy = path, policy
        self.count = 0
        self.example: str | None = None
        self.example_line = 0
        self.refused = False
        self._seen: list[tuple[int, int, np.ndarray]] = []
        self._carry = None

    def take(self, frame: pd.DataFrame, quality: pd.DataFrame, lines: np.ndarray):
        if self._carry is not None:
            cf, cq, cl = self._carry
            frame, quality = pd.concat([cf, frame]), pd.concat([cq, quality])
            lines = np.r_[cl, lines]
            self._carry = None
        t = index_us(frame.index)
        if not len(t):
            return
        k = len(t)
        if t[-1] == t.max():  # in time order at its end: its last time may go on
            k = len(t) - int(np.argmax(t[::-1] != t[-1])) if (t != t[-1]).any() else 0
            self._carry = frame.iloc[k:], quality.iloc[k:], lines[k:]
        if k:
            yield from self._resolve(frame.iloc[:k], quality.iloc[:k], lines[:k], t[:k])

    def flush(self):
        if self._carry is not None:
            frame, quality, lines = self._carry
            self._carry = None
            yield from self._resolve(frame, quality, lines, index_us(frame.index))

    def refusal(self, written: bool) -> str:
        where = (
            f"the rows before line {self.example_line} were imported (importing again skips them)"
            if written
            else "nothing imported"
        )
        noun = "1 row repeats" if self.count == 1 else f"{self.count} rows repeat"
        return (
            f"{self.path}: {noun} the time of an earlier row (first: {self.example}); import "
            "does not choose between them: say which sample each tag keeps with --duplicates "
            f"first, last or mean; {where}"
        )

    def _note(self, line: int, text: str) -> None:
        if self.example is None or line < self.example_line:
            self.example, self.example_line = text, line

    def _resolve(self, frame, quality, lines, t):
        codes, uniq = pd.factorize(t)
        inner = len(uniq) < len(t)
        outer = np.zeros(len(t), bool)
        lo, hi = int(t.min()), int(t.max())
        for a, b, times in self._seen:
            if a <= hi and b >= lo:
                pos = np.minimum(np.searchsorted(times, t), len(times) - 1)
                outer |= times[pos] == t
        self._seen.append((lo, hi, np.sort(uniq)))
        if not inner and not outer.any():
            yield frame, quality, lines
            return
        first_row = np.unique(codes, return_index=True)[1]
        again = np.ones(len(t), bool)
        again[first_row] = False
        self.count += int(np.count_nonzero(again | outer))
        for i in np.flatnonzero(again)[:1]:
            j = first_row[codes[i]]
            self._note(
                int(lines[i]),
                f"{self.path}:{lines[i]} repeats {self.path}:{lines[j]}, "
                f"{_iso(from_us(int(t[i])))}",
            )
        for i in np.flatnonzero(outer)[:1]:
            self._note(
                int(lines[i]),
                f"{self.path}:{lines[i]} repeats a time met earlier in the file, "
                f"{_iso(from_us(int(t[i])))}",
            )
        if self.policy == "error":
            self.refused = True
            return
        if outer.any() and self.policy != "first":
            i = int(np.flatnonzero(outer)[0])
            raise FileRefused(
                f"{self.path}:{lines[i]}: the time {_iso(from_us(int(t[i])))} repeats one met "
                f"earlier in the file, not next to it; --duplicates {self.policy} takes "
                "repeats that follow each other: sort the file by time, or use --duplicates "
                "first"
            )
        keep = ~outer
        if not keep.all():  # "first": a time already taken from an earlier piece stays
            frame, quality, lines, t = frame[keep], quality[keep], lines[keep], t[keep]
            codes, uniq = pd.factorize(t)
        yield _collapse(frame, quality, lines, codes, uniq, self.policy)


def _collapse(frame, quality, lines, codes, uniq, policy: str):
    """One row per time (``uniq``, in the order first met; ``codes`` maps rows to them):
    per tag its first or last sample (a number or a Bad cell) or the mean of its usable
    ones (quality: Uncertain when one of them is; Bad, with the first Bad cell's number,
    when none is usable)."""
    V = frame.to_numpy(np.float64)
    Q = quality.to_numpy(np.int64)
    n, m = len(uniq), V.shape[1]
    out_v = np.full((n, m), np.nan)
    out_q = np.zeros((n, m), np.int64)
    present = ~np.isnan(V) | (Q == BAD)
    for j in range(m):
        rows = np.flatnonzero(present[:, j])
        if policy == "mean":
            use = rows[Q[rows, j] < BAD]
            g = codes[use]
            total = np.bincount(g, weights=V[use, j], minlength=n)
            count = np.bincount(g, minlength=n)
            worst = np.zeros(n, np.int64)
            np.maximum.at(worst, g, Q[use, j])
            has = count > 0
            out_v[has, j], out_q[has, j] = total[has] / count[has], worst[has]
            rows = rows[~has[codes[rows]]]  # groups with only Bad cells: the first of them
        elif policy == "last":
            rows = rows[::-1]
        g, at = np.unique(codes[rows], return_index=True)
        out_v[g, j], out_q[g, j] = V[rows[at], j], Q[rows[at], j]
    pick = np.unique(codes, return_index=True)[1]
    if policy == "last":
        pick = len(codes) - 1 - np.unique(codes[::-1], return_index=True)[1]
    index = pd.DatetimeIndex(np.asarray(uniq, np.int64).view("datetime64[us]"), name="ts")
    index = index.tz_localize("UTC")
    return (
        pd.DataFrame(out_v, index=index, columns=frame.columns),
        pd.DataFrame(
            out_q.astype(quality.dtypes.iloc[0] if m else np.int8),
            index=index,
            columns=quality.columns,
        ),
        lines[pick],
    )


def _line_number(msg: str) -> int:
    m = re.search(r":(\d+): ", msg)
    return int(m[1]) if m else 0


def _tag_names(path: Path, columns: list[str], rename: dict[str, str]) -> dict[str, str]:
    """Column → tag name after ``rename``; refuses names a spec cannot refer to, and a
    rename of a column the file does not have, saying which rename would fix it."""
    unknown = [c for c in rename if c not in columns]
    if unknown:
        raise FileRefused(
            f"{path}: --rename names no column {', '.join(map(repr, unknown))}; the columns "
            f"are {', '.join(columns)}"
        )
    out = {c: rename.get(c, c) for c in columns}
    bad = [(c, n, why) for c, n in out.items() if (why := tag_name_problem(n))]
    if bad:
        fixes = " ".join(f"--rename {shlex.quote(c + '=' + _clean_name(n))}" for c, n, _ in bad)
        raise FileRefused(
            f"{path}: column name(s) no model could refer to: "
            + "; ".join(f"{n!r} ({why})" for _, n, why in bad)
            + f". Rename them as they are imported, e.g. {fixes}"
        )
    twice = sorted({n for n in out.values() if list(out.values()).count(n) > 1})
    if twice:
        raise FileRefused(f"{path}: two columns would both be tag {', '.join(twice)}")
    return out


def _clean_name(name: str) -> str:
    text = re.sub(r'["\[\]]', "_", "".join(c for c in name if c.isprintable())).strip()
    return text or "TAG"


def _ranges(h: Historian, names, meta: list[dict]) -> dict[str, tuple]:
    """Declared range per tag: the tags CSV first, else what the historian has."""
    out = {}
    stored = h.tags().set_index("name") if len(h.tags()) else None
    for n in names:
        if stored is not None and n in stored.index:
            lo, hi = stored.loc[n, "lo"], stored.loc[n, "hi"]
            out[n] = (None if pd.isna(lo) else float(lo), None if pd.isna(hi) else float(hi))
    for m in meta:
        out[m["name"]] = (m.get("lo"), m.get("hi"))
    return out


def _check_plausible(path, tcol, raw, tz, unit, origin, time_format) -> None:
    """Refuse times outside 1970 .. a year ahead in the file's first rows, before anything
    is written; for plain numbers, name the unit that would fit."""
    t = parse_times(_texts(raw), tz, unit, origin, time_format)
    t = pd.DatetimeIndex(t.dropna())
    if not len(t):
        return
    lo, hi = _plausible_times()
    if t.min() >= lo and t.max() <= hi:
        return
    bad = t.max() if t.max() > hi else t.min()
    text = f"{path}: the time column {tcol!r} reads as {bad} (before 1970 or a year ahead)"
    if unit is not None:
        fits = [u for u in ("s", "ms", "us", "ns") if u != unit and _fits(raw, u, origin)]
        text += (
            f"; with --time-unit {fits[0]} it reads as "
            f"{parse_times(_texts(raw).iloc[:1], tz, fits[0], origin).iloc[0]}"
            if fits
            else "; check --time-unit and --start"
        )
    else:
        text += "; check the time column and --time-format"
    raise FileRefused(text)


def _fits(raw, unit, origin) -> bool:
    t = pd.DatetimeIndex(parse_times(_texts(raw), "UTC", unit, origin).dropna())
    lo, hi = _plausible_times()
    return bool(len(t)) and t.min() >= lo and t.max() <= hi


def read_tags_csv(path: str | Path) -> list[dict]:
    """Tag metadata from a CSV with columns name (or tag), unit, lo (or min), hi (or max),
    description, source, as keyword dicts for :meth:`Historian.ensure_tag`. A bad number
    raises ValueError ``file:line``."""
    return [m for _, m in tags_csv_rows(path)]


def tags_csv_rows(path: str | Path) -> list[tuple[int, dict]]:
    """:func:`read_tags_csv`'s dicts, each with the line of the file it was read from."""
    path = Path(path)
    frame, cols, c_name = read_tags_frame(path)

    def col(*names):
        for n in names:
            if n in cols:
                return cols[n]
        return None

    c_unit, c_desc, c_src = col("unit"), col("description"), col("source")
    c_lo, c_hi = col("lo", "min", "range_lo"), col("hi", "max", "range_hi")
    out = []
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
        out.append(
            (
                i + 2,
                {
                    "name": name,
                    "unit": (row[c_unit].strip() or None) if c_unit else None,
                    "lo": lo,
                    "hi": hi,
                    "description": (row[c_desc].strip() or None) if c_desc else None,
                    "source": (row[c_src].strip() or None) if c_src else None,
                },
            )
        )
    return out


def _unused_tags_note(path: Path, names: list[str], line: dict[str, int]) -> str:
    """The note on tags CSV rows naming a tag neither in the file nor in the historian: not
    stored (a tag is made by its samples), each named with its ``file:line`` (``line``: the
    first line naming each tag, :func:`tags_csv_rows`)."""
    said = [f"{n} ({path}:{line[n]})" if n in line else n for n in names]
    more = f" and {len(said) - 10} more" if len(said) > 10 else ""
    head = ", ".join(said[:10]) + more
    noun = "1 row names a tag" if len(names) == 1 else f"{len(names)} rows name tags"
    return (
        f"tags CSV: {noun} neither in this file nor in the historian, not stored: {head} "
        "(a misspelt name? a tag's metadata is stored when its samples are imported)"
    )


def read_tags_frame(path: Path) -> tuple[pd.DataFrame, dict[str, str], str]:
    """A tags CSV as text cells, its columns by lower-case name and its name (or tag)
    column; an empty file, a header naming a column twice or a file without a name column
    raises :class:`FileRefused` ``file:1`` (one reader for ``diag import --tags`` and
    ``unit build --loops-from``); a file pandas cannot parse raises its own error."""
    try:
        frame = pd.read_csv(path, dtype=str, keep_default_na=False, skipinitialspace=True)
    except pd.errors.EmptyDataError:
        raise FileRefused(f"{path}: empty file; a tags CSV needs a header line") from None
    check_header_once(path)
    cols = {c.strip().lower(): c for c in frame.columns}
    c_name = cols.get("name", cols.get("tag"))
    if c_name is None:
        # a tags CSV written with ';' reads as one column: it would declare nothing
        header = ",".join(map(str, frame.columns))
        sep = next((c for c in (";", "\t", "|") if c in header), None)
        raise FileRefused(
            f"{path}:1: a tags CSV needs a 'name' (or 'tag') column; the header reads "
            f"{header[:80]!r}"
            + (f" (separated by {sep!r}? write it comma-separated)" if sep else "")
        )
    return frame, cols, c_name


def read_state_tags(path: str | Path) -> set[str]:
    """The tags a tags CSV declares discrete states (a ``role`` of
    :data:`~historian.discrete.STATE_ROLES` or :data:`~historian.discrete.RUNNING_ROLE`, as
    ``diag unit build`` reads them; none without a ``role`` column), for ``diag tags --tags``."""
    from .discrete import RUNNING_ROLE, STATE_ROLES

    frame, cols, c_name = read_tags_frame(Path(path))
    if "role" not in cols:
        return set()
    roles = frame[cols["role"]].str.strip().str.lower()
    declared = roles.isin((*STATE_ROLES, RUNNING_ROLE))
    return {n.strip() for n in frame.loc[declared, c_name] if n.strip()}


def _join(pieces: list[tuple]) -> tuple[pd.DataFrame, pd.DataFrame, int, np.ndarray]:
    """Pieces ``(values, quality, samples, lines)`` in file order as one (no time is in
    two: :class:`_Repeats`)."""
    if len(pieces) == 1:
        return pieces[0]
    frames, qualities, ns, lines = zip(*pieces, strict=True)
    return pd.concat(frames), pd.concat(qualities), sum(ns), np.concatenate(lines)


def _appends(h: Historian, names) -> bool:
    """The file's first piece lands at the end of the stored samples' key: a SQLite
    historian where every one of the file's tags that exists has a higher id than any tag
    with a sample stored (a new database, or only new tags: they get the highest ids)."""
    if h.backend != "sqlite":
        return False
    tags = h.tags()
    ids = tags.loc[tags["name"].isin(list(names)), "id"] if len(tags) else []
    return not len(ids) or int(min(ids)) > h.last_sample_tag()


def _write(h, frame, quality, n, rows, line_of, policy, report: ImportReport) -> None:
    """Write one piece of ``n`` samples (no time repeats in it: :class:`_Repeats`; wide,
    in one transaction: :meth:`Historian.write_wide`), counting conflicts with stored
    samples. With ``"ignore"`` the stored values are compared after the write, and only
    when some samples were not new (the write keeps stored values, so what differs then is
    a conflict); with ``"update"`` before it. ``rows``: the line of each row."""
    everything = np.arange(len(frame))
    if policy == "update":
        _count_conflicts(h, frame, quality, everything, rows, line_of, report)
        report.written += h.write_wide(frame, quality, policy=policy)
        return
    written = h.write_wide(frame, quality, policy=policy)
    report.written += written
    if written < n:
        _count_conflicts(h, frame, quality, everything, rows, line_of, report)


def _cold_before(h: Historian) -> int | None:
    """Where the samples an import writes to the database's table begin (µs): the start of
    the current UTC month when the historian has a cold folder (SQLite: ``<db>.cold``
    beside the file; PostgreSQL: one recorded or given), the months before it being
    written to their Parquet files; None when it has none (every sample to the table)."""
    if h.cold_dir is None:
        return None
    return to_us(coldstore.month_start())


def _write_cold_month(h, month: str, parts: list[tuple], policy, line_of, report: ImportReport):
    """Store the pieces of one closed month in its cold file (:meth:`Historian.import_month`)
    and count what was new and what conflicted, as :func:`_write` counts them."""
    frame, quality, _n, lines = _join(parts)
    ts = index_us(frame.index)
    order = np.argsort(ts, kind="stable")
    ts, lines = ts[order], lines[order]
    V = frame.to_numpy(np.float64)[order]
    Q = quality.to_numpy(np.int64)[order]
    names, rows = {}, {}
    for j, name in enumerate(frame.columns):
        keep = ~np.isnan(V[:, j]) | (Q[:, j] == BAD)
        if keep.any():  # (a column without a sample may be no tag yet)
            tid = h._tag(str(name))[0]
            names[tid] = str(name)
            rows[tid] = (ts[keep], V[keep, j], Q[keep, j])
    res = h.import_month(month, rows, policy)
    report.written += res.added + (res.changed if policy == "update" else 0)
    report.conflicts += res.changed
    if res.wrote:
        report.cold_months.append(month)
    if res.first is not None:
        t, tid, stored, stored_q, value, q = res.first
        old = report.first_conflict
        if old is None or from_us(t) < old.ts:
            k = int(np.searchsorted(ts, t))
            report.first_conflict = Conflict(
                tag=names[tid],
                ts=from_us(t),
                stored=stored,
                stored_quality=stored_q,
                value=value,
                quality=q,
                where=line_of(int(lines[k])),
            )


def _count_conflicts(h, part, part_q, now, rows, line_of, report: ImportReport) -> None:
    n, first = stored_conflicts(h, part, part_q)
    if not n:
        return
    report.conflicts += n
    ts, j, row, stored, stored_q = first
    old = report.first_conflict
    if old is None or from_us(ts) < old.ts:
        report.first_conflict = Conflict(
            tag=str(part.columns[j]),
            ts=from_us(ts),
            stored=stored,
            stored_quality=stored_q,
            value=float(part.iat[row, j]),
            quality=int(part_q.iat[row, j]),
            where=line_of(int(rows[now[row]])),
        )


def _parse_error(path: Path, exc: Exception) -> str:
    """pandas' parse error as ``file:line: what``."""
    text = _first_line(exc)
    m = re.search(r"Expected (\d+) fields in line (\d+), saw (\d+)", text)
    if m is None:
        return f"{path}: {text}"
    msg = f"{path}:{m[2]}: {m[3]} fields, but the header has {m[1]}"
    if int(m[3]) < int(m[1]):  # an empty cell is written as an empty field: 'a,,c'
        msg += " (a row short of separators; an empty cell keeps its separator: 1,,3)"
    return msg


class _reading:
    """Turn a parse error met while reading the file into :class:`FileRefused` at
    ``file:line`` (saying whether earlier rows were already stored)."""

    def __init__(self, path: Path, report: ImportReport):
        self.path, self.report = path, report

    def __enter__(self):
        return self

    def __exit__(self, kind, exc, tb):
        if exc is None or not isinstance(exc, (pd.errors.ParserError, UnicodeDecodeError)):
            return False
        msg = _parse_error(self.path, exc)
        if self.report.samples:
            msg += (
                "; the rows before it were imported (fix the line and import again: stored "
                "rows are skipped; --strict checks the whole file before writing)"
            )
        raise FileRefused(msg) from None
