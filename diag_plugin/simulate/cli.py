"""``diag simulate``: write simulated plant data to CSV or Parquet.

``--plant valve`` (the default) is the DAMADICS servomotor–valve assembly; ``chemplant`` the
chemical plant with recycle (:mod:`diag_plugin.simulate.chemplant`, 44 tags, one fault at a
time: ``--fault NAME[@HOURS][:SIZE]``); ``tank`` and ``heatex`` the two small plants of
:mod:`diag_plugin.simulate.smallplants` (fault-free).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from diag_plugin.cliargs import add_json

FAULT_HELP = (
    "fault NAME:STRENGTH[@ONSET][/abrupt|/incipient[=DURATION]], repeatable; "
    "e.g. f17:0.5@2026-03-01T10:00 or f2:1@2026-03-01/incipient=1d (ONSET in UTC); "
    "with CSV output the fault truth goes to FILE.faults.json. --plant chemplant: one fault "
    "NAME[@HOURS][:SIZE], HOURS after the start (default a third into the run), SIZE in the "
    "fault's unit (default its own), e.g. ti104_bias@24:1.5"
)
PLANTS = ("valve", "chemplant", "tank", "heatex")


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Register ``simulate`` on the ``diag`` sub-command parser."""
    p = sub.add_parser(
        "simulate",
        help="simulate a plant (the DAMADICS servomotor-valve assembly by default)",
        description="Simulate the servomotor-valve assembly (DAMADICS actuator, faults "
        "f1-f19) and write the measured tags CV, P1, P2, T1, X, F, P0, Pch; or, with --plant, "
        "the chemical plant with recycle (44 tags, 15 fault types) or a small plant.",
    )
    p.add_argument(
        "--plant",
        choices=PLANTS,
        default="valve",
        help="which plant (default valve); chemplant: reactor, cooler, flash drum, recycle",
    )
    p.add_argument("--days", type=float, required=True, help="length of the run, days")
    p.add_argument("--out", required=True, metavar="FILE", help="output .csv or .parquet")
    p.add_argument("--fault", action="append", default=[], metavar="SPEC", help=FAULT_HELP)
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument(
        "--period",
        type=float,
        help="sample period, s (default 10; chemplant 180, each sample the period's mean)",
    )
    p.add_argument("--start", default="2026-01-01", help="time of the first sample (UTC)")
    p.add_argument(
        "--min-flow",
        type=float,
        metavar="T/H",
        help="lowest flow set-point, t/h (default 4): lower runs the plant at low load too",
    )
    add_json(p, "print what was written as JSON")
    p.set_defaults(func=cmd_simulate)


def write_tags_csv(path: Path, columns, meta: dict | None = None) -> None:
    """Tag metadata beside the data (name, unit, lo, hi, description): ``diag import``
    picks it up, so the historian knows units and nominal ranges. ``meta`` maps a tag to
    (unit, lo, hi, description, ...); default the valve's tags."""
    if meta is None:
        from diag_plugin.simulate.valve import TAGS

        meta = {k: (m.unit, m.lo, m.hi, m.description) for k, m in TAGS.items()}
    rows = ["name,unit,lo,hi,description"]
    for c in columns:
        m = meta.get(c)
        if m:
            unit, lo, hi, description = m[:4]
            desc = description.replace('"', "'")
            rows.append(f'{c},{unit},{lo:g},{hi:g},"{desc}"')
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")


def parse_chem_fault(text: str) -> tuple[str, float | None, float | None]:
    """``NAME[@HOURS][:SIZE]`` (either order) → (name, onset in s or None, size or None)."""
    import re

    from .chemplant import FAULTS

    m = re.fullmatch(r"([A-Za-z0-9_]+)((?:[@:][^@:]+){0,2})", text.strip())
    if not m:
        raise ValueError(f"{text!r}: use NAME[@HOURS][:SIZE], e.g. ti104_bias@24:1.5")
    name, rest = m.group(1), m.group(2)
    if name not in FAULTS:
        raise ValueError(f"{text!r}: unknown fault {name!r}; known: {', '.join(FAULTS)}")
    onset = size = None
    for sep, value in re.findall(r"([@:])([^@:]+)", rest):
        try:
            number = float(value)
        except ValueError:
            raise ValueError(f"{text!r}: {value!r} is not a number") from None
        if sep == "@":
            if onset is not None or not number >= 0:
                raise ValueError(f"{text!r}: give one onset, hours ≥ 0")
            onset = number * 3600.0
        else:
            if size is not None:
                raise ValueError(f"{text!r}: give one size")
            size = number
    return name, onset, size


def _simulate_plant(args: argparse.Namespace, start):
    """The frame of a non-valve plant at ``args.period`` (means), its tag metadata, truth."""
    from historian.errors import UserError

    from . import chemplant, smallplants

    period = 180.0 if args.period is None else args.period
    if args.min_flow is not None:
        raise UserError("--min-flow: only for --plant valve")
    if not float(period).is_integer() or period < 1:
        raise UserError(f"--period {period:g}: --plant {args.plant} takes whole seconds ≥ 1")
    if args.days * 86400 < 2 * period:
        raise UserError(f"--days {args.days:g}: shorter than two periods of {period:g} s")
    truth = []
    if args.plant == "chemplant":
        if len(args.fault) > 1:
            raise UserError("--fault: --plant chemplant takes one fault per run")
        name = onset = size = None
        if args.fault:
            try:
                name, onset, size = parse_chem_fault(args.fault[0])
            except ValueError as exc:
                raise UserError(f"--fault {exc}") from None
        try:
            run = chemplant.simulate_chemplant(
                args.days, args.seed, fault=name, onset_s=onset, size=size, start=start
            )
        except ValueError as exc:
            raise UserError(str(exc)) from None
        meta = chemplant.CHEMPLANT_TAGS
        if run.attrs["fault"]:
            truth = [run.attrs["fault"]]
    else:
        if args.fault:
            raise UserError(f"--fault: --plant {args.plant} has no faults")
        sim = smallplants.simulate_tank if args.plant == "tank" else (
            smallplants.simulate_heat_exchanger)  # fmt: skip
        run = sim(args.days, seed=args.seed, start=start)
        meta = smallplants.PLANTS[args.plant]
    df = chemplant.sample(run, period, "mean")
    df.attrs["faults"] = truth
    return df, meta, period


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
    if not args.days > 0:
        raise UserError(f"--days {args.days}: must be positive")
    try:
        start = pd.Timestamp(args.start)
    except (ValueError, TypeError):
        raise UserError(f"--start {args.start!r}: not an ISO 8601 time") from None
    if args.plant != "valve":
        t0 = time.perf_counter()
        df, meta, args.period = _simulate_plant(args, start)
        faults = df.attrs["faults"]
        return _write(args, out, df, faults, meta, t0)
    if args.period is None:
        args.period = 10.0
    try:
        faults = [parse_fault(text) for text in args.fault]
    except ValueError as exc:
        raise UserError(f"--fault: {exc}") from None
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
    return _write(args, out, df, faults, None, t0)


def _write(args, out: Path, df, faults, meta, t0: float) -> int:
    """Write ``df`` (and its fault truth, its tags' metadata) to ``out``; report; 0."""
    suffix = out.suffix.lower()
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
    write_tags_csv(out.with_name(out.name + ".tags.csv"), df.columns, meta)
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
