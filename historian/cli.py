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
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_import)

    t = subparsers.add_parser(
        "tags", help="list tags with ranges, coverage and data quality", description=None
    )
    t.add_argument("--json", action="store_true", help="print JSON instead of a table")
    t.add_argument("--start", help="summarise from this time (default: each tag's first)")
    t.add_argument("--end", help="summarise up to this time (default: each tag's last)")
    t.set_defaults(func=cmd_tags)


def _open(args):
    from .store import Historian

    try:
        return Historian.open(args.db)
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
    with _open(args) as h, Progress(*columns, console=err, disable=not show, transient=True) as bar:
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
                progress=progress,
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
    conflicts = report.conflict_message()
    if conflicts:
        print(f"{path}: {conflicts}", file=sys.stderr)
    span = f"{report.first} .. {report.last}" if report.first is not None else "no data"
    counts = f"{report.new} new samples, {report.already} already stored"
    if report.conflicts:
        counts += f", {report.conflicts} " + ("replaced" if report.replace else "conflicting")
    print(
        f"{path}: {report.rows} rows, {len(report.tags)} tags, {span}; {counts}"
        + (f"; {report.n_bad} bad rows skipped" if report.n_bad else "")
        + (f"; {report.n_bad_cells} bad cells stored as Bad" if report.n_bad_cells else "")
    )
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
        "bad_rows": r.n_bad,
        "bad_row_messages": r.bad,
        "bad_cells": r.bad_cells,
        "bad_cell_messages": r.cells,
        "notes": r.notes,
    }


def cmd_tags(args) -> int:
    with _open(args) as h:
        report = h.tag_report(args.start, args.end)
    if args.json:
        rows = [{k: to_jsonable(v) for k, v in r.items()} for r in report.to_dict("records")]
        print(json.dumps(rows, indent=2))
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"tags in {args.db}")
    for col in ("tag", "unit", "range", "samples", "first", "last", "interval", "coverage"):
        table.add_column(col, justify="right" if col in ("samples", "coverage") else "left")
    for col in ("bad", "gaps", "flat", "out of range"):
        table.add_column(col, justify="right")
    for r in report.to_dict("records"):
        lo, hi = to_jsonable(r["lo"]), to_jsonable(r["hi"])
        rng = "" if lo is None and hi is None else f"{_fmt(lo)} .. {_fmt(hi)}"
        table.add_row(
            r["tag"],
            r["unit"] or "",
            rng,
            f"{r['samples']:,}",
            _when(r["first"]),
            _when(r["last"]),
            "" if to_jsonable(r["interval_s"]) is None else f"{r['interval_s']:g} s",
            f"{100 * r['coverage']:.1f} %",
            f"{r['bad']:,}",
            f"{r['gaps']} ({r['gap_s'] / 3600:.1f} h)" if r["gaps"] else "0",
            f"{r['flat']} ({r['flat_s'] / 3600:.1f} h)" if r["flat"] else "0",
            f"{r['out_of_range']:,}",
        )
    console = Console()
    if not console.is_terminal:
        console = Console(width=160)
    console.print(table)
    return 0


def _fmt(x):
    return "" if x is None else f"{x:g}"


def _when(t):
    return "" if to_jsonable(t) is None else t.strftime("%Y-%m-%d %H:%M:%S")
