"""``diag unit learn``: a unit's thresholds from a window you declare fault-free.

Only argparse is imported at start-up; the command imports what it needs when it runs.
"""

from __future__ import annotations

import argparse
import json

from diag_plugin.cliargs import add_json
from diag_plugin.diagnose.cli import load_unit, parse_time, unit_actions, unit_frames
from diag_plugin.learn.far import check_far
from historian.errors import UserError


def add_far(p: argparse.ArgumentParser, default: str) -> None:
    """``--far PER_HOUR``, the false-alarm budget (``default``: what the help says of it)."""
    p.add_argument(
        "--far",
        type=float,
        default=None,
        metavar="PER_HOUR",
        help="false-alarm budget: alarms per hour of operation of the unit, all tests together "
        + default,
    )


def add_commands(sub: argparse._SubParsersAction) -> None:
    usub = unit_actions(sub)
    p = usub.add_parser("learn", help="learn thresholds from a window you declare fault-free")
    p.add_argument("name")
    p.add_argument("--from", dest="start", required=True, metavar="T0")
    p.add_argument("--to", dest="end", required=True, metavar="T1")
    add_far(p, "(default 0.001, about one in six weeks)")
    p.add_argument(
        "--blocks",
        type=int,
        default=None,
        metavar="N",
        help="time blocks for cross-fitting the residuals (default 5; 0: the models' own)",
    )
    p.add_argument(
        "--cross-fit",
        choices=("auto", "yes", "no"),
        default="auto",
        help="auto: cross-fit the tests whose models were trained on the window (default)",
    )
    add_json(p)
    p.set_defaults(func=cmd_unit_learn)


def cmd_unit_learn(args) -> int:
    from diag_plugin.diagnose.unitfile import WHY, UnitFile
    from diag_plugin.learn.thresholds import (
        DEFAULT_BLOCKS,
        DEFAULT_FAR,
        LearnError,
        learn_thresholds,
    )

    unit = load_unit(args, args.name)
    far = DEFAULT_FAR if args.far is None else args.far
    blocks = DEFAULT_BLOCKS if args.blocks is None else args.blocks
    check_far(far)
    t0, t1 = parse_time(args.start), parse_time(args.end)
    frames = list(unit_frames(args, unit, t0, t1))
    cross = {"auto": None, "yes": True, "no": False}[args.cross_fit]
    try:
        got = learn_thresholds(unit, frames, far=far, blocks=blocks, cross_fit=cross)
    except LearnError as exc:
        raise UserError(f"unit {unit.name}: cannot learn thresholds:\n" + "\n".join(
            "  " + p for p in exc.problems
        )) from None  # fmt: skip
    uf = UnitFile.load(unit.file.path)
    uf.set_learned(got)
    uf.save(as_read=True)
    notes = got.notes()
    out = {
        "unit": unit.name,
        "file": str(uf.path),
        "window": list(got.window),
        "far": far,
        "blocks": got.blocks,
        "thresholds": {k: {"low": lo, "high": hi} for k, (lo, hi) in got.limits.items()},
        "levels": got.levels,
        "samples": got.samples,
        "independent": got.independent,
        "learned": notes,
        "warnings": got.warnings,
    }
    if got.combined is not None:
        out["combined"] = {"high": got.combined.high, **got.combined.notes}
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    print(
        f"{uf.path}: thresholds from {got.window[0]} … {got.window[1]}, budget {far:g} false "
        f"alarms per hour of operation (unit, all tests; "
        + ("the default, " if args.far is None else "")
        + f"one per {1 / far:,.0f} h)"
    )
    for k, (lo, hi) in got.limits.items():
        b = got.budgets[k]
        lv = got.levels[k]
        print(
            f"  {k}: {lo:+.3f} … {hi:+.3f} % ({b.samples:,} samples, ≈ {b.independent:,} "
            f"independent; {got.sources[k]}); expected {b.rate:.2g} false alarms/h "
            f"({b.method}); unknown {b.unknown:.1%}"
            + (f"; levels ×{', ×'.join(f'{x:.2g}' for x in lv[1:])}" if len(lv) > 1 else "")
            + ("; in units of its model's local spread" if got.spread.get(k) else "")
        )
        why = {w: v for w, v in got.unknown[k].items() if v > 0}
        if why:
            print("      unknown: " + "; ".join(f"{WHY[w]} {v:.1%}" for w, v in why.items()))
        if k in got.off:
            share, piece = got.off[k]
            print(f"      off: {piece} stopped {share:.1%} (its tests off, not unknown)")
    c = got.combined
    if c is not None and c.high is not None:
        print(
            f"  combined test (T²): {c.high:.4g}; expected {c.notes['far']:.2g} false alarms/h "
            f"({c.notes['method']}; its share of the budget, the tests the rest)"
        )
    for w in got.warnings:
        print(f"  note: {w}")
    return 0
