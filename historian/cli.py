"""``diag import`` and ``diag tags``."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from historian.errors import UserError
from historian.jsonable import to_jsonable

PROGRESS_MIN_BYTES = 5_000_000


def add_commands(subparsers) -> None:
    p = subparsers.add_parser(
        "import",
        help="import a wide CSV or Parquet file (time column + one column per tag)",
        description="Import samples: a time column plus one column per tag. The time column "
        "is --time-column, else one named ts/time/timestamp/datetime/date, else the first if "
        "it holds date-times; plain-number times need --time-unit (and --start for a "
        "relative time). Bad rows are reported as file:line and skipped; re-importing the "
        "same file adds nothing; values that differ from stored ones are reported and kept "
        "unless --replace.",
    )
    p.add_argument("file", help="CSV or Parquet file")
    p.add_argument("--time-column", help="name of the time column")
    p.add_argument("--tz", default="UTC", help="time zone of naive times (default UTC)")
    p.add_argument(
        "--time-unit",
        choices=["s", "ms", "us", "µs", "ns", "min", "h"],
        help="the time column holds plain numbers of this unit (after --start, else after "
        "1970-01-01 UTC)",
    )
    p.add_argument(
        "--time-format",
        metavar="FORMAT",
        help="strftime format of the times, e.g. '%%d.%%m.%%Y %%H:%%M:%%S' (default ISO 8601; "
        "day.month dates are read when the file shows the order)",
    )
    p.add_argument(
        "--sep", help="CSV separator, e.g. ';' (default: detected from the first lines, else ,)"
    )
    p.add_argument(
        "--decimal",
        choices=[".", ","],
        help="decimal mark (default: detected; a comma only with another separator)",
    )
    p.add_argument(
        "--rename",
        action="append",
        default=[],
        metavar="COLUMN=TAG",
        help="store a column under another tag name (repeatable)",
    )
    p.add_argument("--json", action="store_true", help="print the import report as JSON")
    p.add_argument(
        "--start",
        metavar="TIME",
        help="origin of a plain-number time column, e.g. 2001-11-17T00:00:00Z (naive: --tz)",
    )
    p.add_argument("--tags", dest="tags_csv", help="tags CSV: name, unit, lo, hi, description")
    p.add_argument("--strict", action="store_true", help="refuse the file if any row is bad")
    p.add_argument(
        "--replace",
        "--update",
        dest="replace",
        action="store_true",
        help="overwrite stored samples whose value or quality differs (--update: the old name)",
    )
    p.add_argument(
        "--duplicates",
        choices=["error", "first", "last", "mean"],
        default="error",
        help="a time repeated within the file: refuse the file naming the rows (error, the "
        "default), or keep each tag's first or last sample there, or the mean of its usable "
        "ones",
    )
    p.add_argument(
        "--hot",
        action="store_true",
        help="store every sample in the database's samples table (default: the samples of "
        "closed months go to their Parquet month files in the cold folder, as 'diag "
        "historian roll' keeps them; the current month always to the table)",
    )
    p.add_argument(
        "--cold-dir",
        metavar="DIR",
        help="folder of the Parquet month files (SQLite default: <db file>.cold; PostgreSQL: "
        "the one recorded by an earlier roll or import, else none: every sample to the table)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_import)

    t = subparsers.add_parser(
        "tags", help="list tags with ranges, coverage and data quality", description=None
    )
    t.add_argument("--json", action="store_true", help="print JSON instead of a table")
    t.add_argument("--start", help="summarise from this time (default: each tag's first)")
    t.add_argument("--end", help="summarise up to this time (default: each tag's last)")
    t.add_argument(
        "--tags",
        dest="tags_csv",
        help="tags CSV whose 'role' column declares states (state, phase, step, running): "
        "such a tag holding one value for hours is a state, not flat-lined",
    )
    t.set_defaults(func=cmd_tags)

    h = subparsers.add_parser(
        "historian",
        help="roll closed months to the Parquet cold store, check the store, reclaim space",
        description="Upkeep of the historian: 'roll' moves closed months to Parquet files "
        "(reads stay the same), 'check' checks the database and the files, 'vacuum' gives "
        "the room of rolled months back to the disk.",
    )
    hs = h.add_subparsers(dest="historian_command", metavar="ACTION", required=True)
    r = hs.add_parser(
        "roll",
        help="move closed months from the database to the Parquet cold store",
        description="Move every closed month (before --before, default the current UTC "
        "month) to one Parquet file per month in the cold folder. Reads and training see the "
        "same data after. The database file keeps the room as free pages until "
        "'diag historian vacuum' (or --vacuum).",
    )
    r.add_argument(
        "--before",
        metavar="MONTH",
        help="roll the months before this one, YYYY-MM (default: the current UTC month)",
    )
    r.add_argument(
        "--cold-dir",
        metavar="DIR",
        help="folder of the Parquet files (SQLite default: <db file>.cold; PostgreSQL needs "
        "it the first time; the database remembers it)",
    )
    r.add_argument("--vacuum", action="store_true", help="vacuum after rolling")
    r.add_argument("--json", action="store_true", help="print the result as JSON")
    r.add_argument("--no-progress", action="store_true", help="no progress bar")
    r.set_defaults(func=cmd_roll)
    c = hs.add_parser(
        "check",
        help="check the database and every rolled month's file (exit 1 on a problem)",
        description="SQLite: PRAGMA integrity_check; PostgreSQL: duplicate and NULL keys, "
        "the primary-key index. Each rolled month: its file readable, holding the rows "
        "recorded for it and no time outside the month. Files no month lists (left by an "
        "interrupted roll) are named. Exit status 1 when a problem is found.",
    )
    c.add_argument("--json", action="store_true", help="print the result as JSON")
    c.add_argument("--no-progress", action="store_true", help="no progress bar")
    c.set_defaults(func=cmd_check)
    v = hs.add_parser(
        "vacuum",
        help="give the room of deleted (rolled) rows back: SQLite VACUUM, PostgreSQL "
        "VACUUM ANALYZE",
        description="SQLite: VACUUM rebuilds the file without its free pages (it needs as "
        "much free disk as the database while it runs, and blocks writers). PostgreSQL: "
        "VACUUM (ANALYZE) of the historian's tables makes the room reusable and renews the "
        "planner's statistics; --full rewrites the tables and gives the room back to the "
        "disk, locking each table while it runs.",
    )
    v.add_argument("--full", action="store_true", help="PostgreSQL: VACUUM (FULL, ANALYZE)")
    v.add_argument("--json", action="store_true", help="print the result as JSON")
    v.set_defaults(func=cmd_vacuum)


def _open(args, **kw):
    from .store import Historian

    try:
        return Historian.open(args.db, **kw)
    except ValueError as exc:
        raise UserError(str(exc)) from None


def cmd_import(args) -> int:
    from rich.console import Console
    from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn, TimeRemainingColumn

    from .importer import ImportRefused, import_file

    path = Path(args.file)
    if not path.exists():
        raise UserError(f"{path}: no such file")
    if not path.is_file():
        raise UserError(f"{path}: not a file")
    err = Console(stderr=True)
    show = not args.no_progress and path.stat().st_size >= PROGRESS_MIN_BYTES
    columns = [TextColumn(f"importing {path.name}"), BarColumn(), TimeRemainingColumn()]
    if path.suffix.lower() not in (".parquet", ".pq"):
        columns.insert(2, DownloadColumn())
    if args.tags_csv is None:  # tag metadata written beside the data (diag simulate does)
        side = Path(str(path) + ".tags.csv")
        if side.exists():
            args.tags_csv = str(side)
            print(f"tag metadata from {side}", file=sys.stderr)
    if args.tags_csv is not None:  # its loops and roles checked as unit build --loops-from
        from .tagroles import check_tags_csv_declarations

        try:
            check_tags_csv_declarations(args.tags_csv)
        except (ValueError, OSError) as exc:
            raise UserError(str(exc)) from None
    opened = _open(args, cold_dir=args.cold_dir) if args.cold_dir else _open(args)
    with opened as h, Progress(*columns, console=err, disable=not show, transient=True) as bar:
        task = bar.add_task("import", total=None)

        def progress(done, total):
            bar.update(task, completed=done, total=total)

        try:
            report = import_file(
                h,
                path,
                time_column=args.time_column,
                tz=args.tz,
                time_unit="us" if args.time_unit == "µs" else args.time_unit,
                start=args.start,
                tags_csv=args.tags_csv,
                strict=args.strict,
                policy="update" if args.replace else "ignore",
                sep={"tab": "\t", "\\t": "\t"}.get(args.sep, args.sep),
                decimal=args.decimal,
                time_format=args.time_format,
                rename=_renames(args.rename),
                duplicates=args.duplicates,
                progress=progress,
                hot=args.hot,
            )
        except ImportRefused as exc:
            for msg in exc.messages[:20]:
                print(msg, file=sys.stderr)
            more = exc.n_bad - min(20, len(exc.messages))
            if more > 0:
                print(f"... and {more} more", file=sys.stderr)
            msg = f"{path}: {exc.n_bad} bad row(s) or cell(s); nothing imported (--strict)"
            raise UserError(msg) from None
        except (ValueError, FileNotFoundError) as exc:
            raise UserError(str(exc)) from None
    if args.json:
        print(json.dumps(_report_json(report), indent=2, default=str))
        return 0
    for note in report.notes:
        print(f"{path}: {note}", file=sys.stderr)
    for msg in report.bad[:20]:
        print(msg, file=sys.stderr)
    if report.n_bad > 20:
        print(f"... and {report.n_bad - 20} more", file=sys.stderr)
    for msg in report.cells[:20]:
        print(msg, file=sys.stderr)
    if report.n_bad_cells > 20:
        print(f"... and {report.n_bad_cells - 20} more bad cells", file=sys.stderr)
    if report.bad_cells:
        per_tag = ", ".join(f"{t} {n}" for t, n in report.bad_cells.items())
        print(f"{path}: stored as Bad samples: {per_tag}", file=sys.stderr)
    repeats = report.repeat_message()
    if repeats:
        print(f"{path}: {repeats}", file=sys.stderr)
    conflicts = report.conflict_message()
    if conflicts:
        print(f"{path}: {conflicts}", file=sys.stderr)
    span = f"{report.first} .. {report.last}" if report.first is not None else "no data"
    counts = f"{report.new} new samples, {report.already} already stored"
    if report.repeats:
        counts = f"{report.repeats} rows at a repeated time merged ({report.duplicates}); " + counts
    if report.conflicts:
        counts += f", {report.conflicts} " + ("replaced" if report.replace else "conflicting")
    print(
        f"{path}: {report.rows} rows, {len(report.tags)} tags, {span}; {counts}"
        + (f"; {report.n_bad} bad rows skipped" if report.n_bad else "")
        + (f"; {report.n_bad_cells} bad cells stored as Bad" if report.n_bad_cells else "")
    )
    where = report.stored_where()
    if where:
        print(f"{path}: {where}")
    return 0


def _renames(pairs: list[str]) -> dict[str, str]:
    out = {}
    for text in pairs:
        old, eq, new = text.partition("=")
        if not eq or not old or not new:
            raise UserError(f"--rename {text!r}: write COLUMN=TAG")
        out[old] = new
    return out


def _report_json(r) -> dict:
    return {
        "file": r.file,
        "rows": r.rows,
        "tags": r.tags,
        "first": to_jsonable(r.first),
        "last": to_jsonable(r.last),
        "samples": r.samples,
        "new": r.new,
        "already": r.already,
        "conflicts": r.conflicts,
        "first_conflict": r.first_conflict.describe() if r.first_conflict else None,
        "repeated_times": r.repeats,
        "first_repeat": r.repeat_example,
        "duplicates": r.duplicates,
        "bad_rows": r.n_bad,
        "bad_row_messages": r.bad,
        "bad_cells": r.bad_cells,
        "bad_cell_messages": r.cells,
        "notes": r.notes,
        "cold_months": r.cold_months,
        "cold_dir": r.cold_dir,
        "stored": r.stored_where(),
    }


def cmd_tags(args) -> int:
    states: set[str] = set()
    if getattr(args, "tags_csv", None):
        from historian.importer import read_state_tags

        try:
            states = read_state_tags(args.tags_csv)
        except FileNotFoundError:
            raise UserError(f"--tags {args.tags_csv}: no such file") from None
        except ValueError as e:
            raise UserError(str(e)) from None
    if args.start is None and args.end is None and _stored_tags(args.db) == 0:
        records: list[dict] = []  # an empty historian: nothing to summarise (no pandas)
    else:
        with _open(args) as h:
            records = h.tag_report(args.start, args.end, states=states).to_dict("records")
    records.sort(key=lambda r: natural_key(r["tag"]))
    if args.json:
        rows = [{k: to_jsonable(v) for k, v in r.items()} for r in records]
        print(json.dumps(rows, indent=2))
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"tags in {args.db}")
    for col in ("tag", "unit", "range", "samples", "first", "last", "interval", "coverage"):
        table.add_column(col, justify="right" if col in ("samples", "coverage") else "left")
    for col in ("bad", "gaps", "flat", "out of range"):
        table.add_column(col, justify="right", no_wrap=col == "flat")
    for r in records:
        lo, hi = to_jsonable(r["lo"]), to_jsonable(r["hi"])
        rng = "" if lo is None and hi is None else f"{_fmt(lo)} .. {_fmt(hi)}"
        table.add_row(
            r["tag"],
            to_jsonable(r["unit"]) or "",  # no unit: None, or NaN in a column of strings
            rng,
            f"{r['samples']:,}",
            _when(r["first"]),
            _when(r["last"]),
            _interval(to_jsonable(r["interval_s"])),
            f"{100 * r['coverage']:.1f} %",
            f"{r['bad']:,}",
            f"{r['gaps']} ({r['gap_s'] / 3600:.1f} h)" if r["gaps"] else "0",
            _flat(r),
            f"{r['out_of_range']:,}",
        )
    console = Console()
    if not console.is_terminal:
        console = Console(width=160)
    console.print(table)
    return 0


def _flat(r: dict) -> str:
    """The flat column: the flat-lined runs, or a discrete state's longest hold (a filter
    filtering for 30 h holds 0: a state, not a frozen sensor)."""
    if to_jsonable(r.get("state")) is not None:
        return f"holds {r['held']:g} for {r['held_s'] / 3600:.1f} h (a state)"
    return f"{r['flat']} ({r['flat_s'] / 3600:.1f} h)" if r["flat"] else "0"


def natural_key(name: str) -> tuple:
    """Sort key of a tag name with its digit runs read as numbers: XMEAS2 before XMEAS10
    (``diag tags`` listed classic TEP's XMEAS1, XMEAS10, XMEAS11, …, XMEAS2)."""
    import re

    return tuple(
        (0, int(part), "") if part.isdigit() else (1, 0, part.casefold())
        for part in re.split(r"(\d+)", name)
    )


def _stored_tags(url: str) -> int | None:
    """How many tags the SQLite historian at ``url`` holds, read with the standard library
    (``diag tags`` on an empty historian then imports neither pandas nor SQLAlchemy). None
    where this cannot tell: another database, a URL with options, a file not made yet (the
    historian makes it) or not readable as a historian."""
    import sqlite3
    from urllib.parse import quote

    prefix = "sqlite:///"
    if not url.startswith(prefix) or "?" in url:
        return None
    path = Path(url[len(prefix) :])
    if not path.is_file():
        return None
    try:
        con = sqlite3.connect(f"file:{quote(str(path))}?mode=ro", uri=True)
        try:
            return int(con.execute("SELECT count(*) FROM tags").fetchone()[0])
        finally:
            con.close()
    except sqlite3.Error:
        return None


def _fmt(x):
    return "" if x is None else f"{x:g}"


def _interval(seconds: float | None) -> str:
    """A tag's typical sampling interval as a person reads it: ``1 s``, ``1.01 s`` (a
    jittered 1 s export: the median spacing, not ``1.01409 s``), ``3 min``, ``1 h``."""
    if seconds is None:
        return ""
    for size, unit in ((3600, "h"), (60, "min")):
        if seconds >= size and seconds % size == 0:
            return f"{seconds / size:g} {unit}"
    return f"{seconds:.3g} s"


def _when(t):
    return "" if to_jsonable(t) is None else t.strftime("%Y-%m-%d %H:%M:%S")


# -- diag historian roll | check | vacuum ------------------------------------------------------


def _mb(n) -> str:
    return "?" if n is None else f"{n / 1e6:,.1f} MB"


def _bar(args, what: str):
    """A rich progress bar on stderr when it is a terminal (and not --no-progress)."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

    err = Console(stderr=True)
    off = getattr(args, "no_progress", False) or args.json or not err.is_terminal
    return Progress(TextColumn(what), BarColumn(), MofNCompleteColumn(), console=err, disable=off)


def _month_limit(text: str | None):
    """--before MONTH as the start of that month (UTC); refused when not YYYY-MM or after
    the current month (only closed months are rolled)."""
    import re

    import pandas as pd

    from .coldstore import month_start

    now = month_start()
    if text is None:
        return now
    if not re.fullmatch(r"\d{4}-\d{2}", text.strip()):
        raise UserError(f"--before {text!r}: not a month like 2024-03")
    try:
        limit = pd.Timestamp(f"{text.strip()}-01", tz="UTC")
    except ValueError:
        raise UserError(f"--before {text!r}: not a month like 2024-03") from None
    if limit > now:
        raise UserError(
            f"--before {text}: after the current month {now:%Y-%m}; only closed months are "
            "rolled (the default rolls all of them)"
        )
    return limit


def cmd_roll(args) -> int:
    import time

    limit = _month_limit(args.before)
    kw = {"cold_dir": args.cold_dir} if args.cold_dir else {}
    started = time.perf_counter()
    with _open(args, **kw) as h:
        if h.cold_dir is None:
            raise UserError(
                "a PostgreSQL historian keeps rolled months in Parquet files: give their folder "
                "with --cold-dir DIR the first time (the database remembers it)"
            )
        with _bar(args, "rolling months") as bar:
            task = bar.add_task("roll", total=None)
            try:
                rolled = h.roll_months(
                    limit,
                    progress=lambda done, total: bar.update(task, completed=done, total=total),
                )
            except ValueError as exc:  # the database keeps its months in another folder
                raise UserError(str(exc)) from None
        seconds = time.perf_counter() - started
        store = h.storage()
        vacuum = None
        if args.vacuum and rolled:
            vacuum = _vacuum(h, args, full=False)
    doc = {
        "rolled": rolled,
        "before": f"{limit:%Y-%m}",
        "seconds": round(seconds, 3),
        **store,
        "vacuum": vacuum,
    }
    if args.json:
        print(json.dumps(doc, indent=2))
        return 0
    if not rolled:
        done = store["cold_months"]
        tail = f" (rolled already: {done[0]} .. {done[-1]})" if done else ""
        print(f"no month before {limit:%Y-%m} left in the database to roll{tail}")
        return 0
    span = rolled[0] if len(rolled) == 1 else f"{rolled[0]} .. {rolled[-1]}"
    print(
        f"rolled {len(rolled)} month(s) ({span}) to {store['cold_dir']} in {seconds:.1f} s; "
        f"cold store: {len(store['cold_months'])} months, {store['cold_rows']:,} rows, "
        f"{_mb(store['cold_bytes'])}"
    )
    if vacuum is not None:
        _print_vacuum(vacuum)
    elif store["free_bytes"]:
        print(
            f"the database file ({_mb(store['db_bytes'])}) holds {_mb(store['free_bytes'])} of "
            "free pages: 'diag historian vacuum' gives them back to the disk"
        )
    elif store["backend"] == "postgresql":
        print("'diag historian vacuum' makes the room of the moved rows reusable")
    return 0


def cmd_check(args) -> int:
    with _open(args) as h:
        with _bar(args, "checking rolled months") as bar:
            task = bar.add_task("check", total=None)
            problems = h.integrity_check(
                progress=lambda done, total: bar.update(task, completed=done, total=total)
            )
        store = h.storage()
        orphans = [str(p) for p in h.cold_orphans()]
    doc = {"ok": not problems, "problems": problems, "orphan_files": orphans, **store}
    if args.json:
        print(json.dumps(doc, indent=2))
    else:
        for p in problems:
            print(f"{args.db}: {p}")
        for p in orphans:
            print(
                f"{p}: listed by no rolled month (left by an interrupted roll or import; "
                "nothing reads it — the month's recorded file and rows are the data — so it "
                "can be deleted)"
            )
        months = store["cold_months"]
        print(
            f"{'problems found' if problems else 'sound'}: {store['backend']} database "
            f"({_mb(store['db_bytes'])})"
            + (
                f", {len(months)} rolled months ({store['cold_rows']:,} rows, "
                f"{_mb(store['cold_bytes'])} in {store['cold_dir']})"
                if months
                else ", no rolled months"
            )
        )
    return 1 if problems else 0


def _vacuum(h, args, *, full: bool) -> dict:
    import time

    from rich.console import Console

    err = Console(stderr=True)
    what = (
        "VACUUM"
        if h.backend == "sqlite"
        else ("VACUUM (FULL, ANALYZE)" if full else "VACUUM (ANALYZE)")
    )
    started = time.perf_counter()
    if err.is_terminal and not args.json:
        with err.status(f"{what} of {h.backend} database ..."):
            out = h.vacuum(full=full)
    else:
        out = h.vacuum(full=full)
    return {**out, "statement": what, "seconds": round(time.perf_counter() - started, 3)}


def _print_vacuum(v: dict) -> None:
    freed = v["before_bytes"] - v["after_bytes"]
    print(
        f"{v['statement']}: {_mb(v['before_bytes'])} -> {_mb(v['after_bytes'])}"
        + (f" ({_mb(freed)} given back to the disk)" if freed > 0 else "")
        + f" in {v['seconds']:.1f} s"
    )


def cmd_vacuum(args) -> int:
    with _open(args) as h:
        v = _vacuum(h, args, full=args.full)
    if args.json:
        print(json.dumps(v, indent=2))
    else:
        _print_vacuum(v)
    return 0
