"""``diag simulate``: write simulated actuator data to CSV or Parquet."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

FAULT_HELP = (
    "fault NAME:STRENGTH[@ONSET][/abrupt|/incipient[=DURATION]], repeatable; "
    "e.g. f17:0.5@2026-03-01T10:00 or f2:1@2026-03-01/incipient=1d (ONSET in UTC); "
    "with CSV output the fault truth goes to FILE.faults.json"
)


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Register ``simulate`` on the ``diag`` sub-command parser."""
    p = sub.add_parser(
        "simulate",
        help="simulate the DAMADICS servomotor-valve assembly",
        description="Simulate the servomotor-valve assembly (DAMADICS actuator, faults "
        "f1-f19) and write the measured tags CV, P1, P2, T1, X, F, P0, Pch.",
    )
    p.add_argument("--days", type=float, required=True, help="length of the run, days")
    p.add_argument("--out", required=True, metavar="FILE", help="output .csv or .parquet")
    p.add_argument("--fault", action="append", default=[], metavar="SPEC", help=FAULT_HELP)
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--period", type=float, default=10.0, help="sample period, s (default 10)")
    p.add_argument("--start", default="2026-01-01", help="time of the first sample (UTC)")
    p.add_argument(
        "--min-flow",
        type=float,
        metavar="T/H",
        help="lowest flow set-point, t/h (default 4): lower runs the plant at low load too",
    )
    p.add_argument("--json", action="store_true", help="print what was written as JSON")
    p.set_defaults(func=cmd_simulate)


def write_tags_csv(path: Path, columns) -> None:
    """Tag metadata beside the data (name, unit, lo, hi, description): ``diag import``
    picks it up, so the historian knows units and nominal ranges."""
    from diag_plugin.simulate.valve import TAGS

    rows = ["name,unit,lo,hi,description"]
    for c in columns:
        m = TAGS.get(c)
        if m:
            desc = m.description.replace('"', "'")
            rows.append(f'{c},{m.unit},{m.lo:g},{m.hi:g},"{desc}"')
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")


def cmd_simulate(args: argparse.Namespace) -> int:
    """Run the simulation described by ``args`` and write the file; returns 0."""
    import pandas as pd

    from historian.errors import UserError

    from .faults import parse_fault
    from .process import ProcessParams
    from .valve import ValveParams, simulate_valve

    out = Path(args.out)
    suffix = out.suffix.lower()
    if suffix not in (".csv", ".parquet"):
        raise UserError(f"--out {args.out}: use a .csv or .parquet file name")
    try:
        faults = [parse_fault(text) for text in args.fault]
    except ValueError as exc:
        raise UserError(f"--fault: {exc}") from None
    if not args.days > 0:
        raise UserError(f"--days {args.days}: must be positive")
    try:
        start = pd.Timestamp(args.start)
    except (ValueError, TypeError):
        raise UserError(f"--start {args.start!r}: not an ISO 8601 time") from None
    params = None
    if args.min_flow is not None:
        hi = ProcessParams().sp_hi_th
        if not 0 <= args.min_flow < hi:
            raise UserError(f"--min-flow {args.min_flow}: must be at least 0 and below {hi:g} t/h")
        params = ValveParams(process=ProcessParams(sp_lo_th=args.min_flow))
    t0 = time.perf_counter()
    try:
        df = simulate_valve(
            args.days,
            period_s=args.period,
            start=start,
            seed=args.seed,
            faults=faults,
            params=params,
        )
    except ValueError as exc:
        raise UserError(str(exc)) from None
    out.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".csv":
        fmt = "%Y-%m-%dT%H:%M:%S" if float(args.period).is_integer() else "%Y-%m-%dT%H:%M:%S.%f"
        frame = df.reset_index()
        frame["ts"] = df.index.strftime(fmt) + "+00:00"
        frame.to_csv(out, index=False, float_format="%.6g")
        if faults:  # the fault truth beside the data
            side = out.with_name(out.name + ".faults.json")
            side.write_text(json.dumps(df.attrs["faults"], indent=1) + "\n")
    else:
        df.to_parquet(out)  # pandas keeps df.attrs (the fault truth) in the file metadata
    write_tags_csv(out.with_name(out.name + ".tags.csv"), df.columns)
    secs = time.perf_counter() - t0
    if args.json:
        doc = {
            "file": str(out),
            "samples": len(df),
            "tags": list(df.columns),
            "first": df.index[0].isoformat(),
            "last": df.index[-1].isoformat(),
            "period_s": args.period,
            "faults": [str(f) for f in args.fault],
            "seconds": round(secs, 2),
        }
        print(json.dumps(doc, indent=2))
        return 0
    print(
        f"wrote {len(df)} samples ({args.days:g} days at {args.period:g} s, "
        f"{len(faults)} fault(s)) to {out} in {secs:.1f} s",
        file=sys.stderr,
    )
    return 0
