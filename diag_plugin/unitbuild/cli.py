"""``diag unit build``: a unit from a window of the plant's history you declare fault-free.

Only argparse is imported at start-up; the command imports what it needs when it runs.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
from pathlib import Path

from diag_plugin.cliargs import add_json
from diag_plugin.diagnose.cli import load_unit, parse_time, unit_actions, unit_frames
from diag_plugin.learn.cli import add_far
from diag_plugin.learn.far import check_far
from diag_plugin.training.dask_connect import add_dask_args, check_timeout
from historian.errors import UserError


def add_commands(sub: argparse._SubParsersAction) -> None:
    usub = unit_actions(sub)
    p = usub.add_parser(
        "build",
        help="build a unit from a fault-free window: tests, inputs, models and thresholds",
    )
    p.add_argument("name")
    p.add_argument("--from", dest="start", required=True, metavar="T0",
                   help="start of the fault-free window to build from, e.g. 2026-03-01 or "
                   "2026-03-01T06:00 (ISO 8601; naive times are UTC)")  # fmt: skip
    p.add_argument("--to", dest="end", required=True, metavar="T1",
                   help="end of that window (exclusive), the same form as --from")  # fmt: skip
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "--tags", nargs="+", metavar="TAG", help="the tags to test (default: all that vary)"
    )
    g.add_argument(
        "--tags-from", metavar="FILE", help="the tags to test, one per line (# comments)"
    )
    add_far(p, "(default 0.001)")
    p.add_argument(
        "--max-inputs",
        type=int,
        default=3,
        metavar="N",
        help="inputs per test (3; a short window's at most 2; a "
        "controller output's or a flow balance's linear test up to 6)",
    )
    p.add_argument(
        "--loop",
        action="append",
        default=[],
        metavar="PV=SP:OUT",
        help="a control loop: the measurement it holds, its set-point (a tag, or a fixed "
        "number: TI9=120.4:TV9) and its output (repeatable; docs/how-to/unit-loops.md)",
    )
    p.add_argument(
        "--loops-from",
        metavar="TAGS_CSV",
        help="loops declared in a tags CSV's 'loop' and 'role' (pv|sp|out|sensor|actuator) "
        "columns; a fixed set-point in a 'set_point' column of the pv row; hand valves by "
        "the role 'manual', measured disturbances by the role 'disturbance' (rows without "
        "a loop); a piece of equipment by an 'equipment' column naming the piece of each of "
        "its tags, its run tag the piece's row of role 'running'",
    )
    p.add_argument(
        "--manual",
        action="append",
        default=[],
        metavar="TAG",
        help="a hand valve (an operator's setting): an input, never tested; outside the span "
        "the window learned it in, the tests reading it are unknown (CHECK_FUNCTION) until "
        "diag unit accept learns the new position (repeatable; docs/how-to/unit-loops.md)",
    )
    p.add_argument(
        "--disturbance",
        action="append",
        default=[],
        metavar="TAG",
        help="a measured disturbance (the weather, an upstream flow, an influent): it drives "
        "the process and nothing in it sets it; an input, never tested (repeatable; "
        "docs/how-to/unit-loops.md)",
    )
    p.add_argument(
        "--state",
        action="append",
        default=[],
        metavar="TAG",
        help="a discrete state of more levels than the build finds by itself (a batch "
        "recipe's phase or step number): a mode of the plant, never tested nor named, an "
        "input; its values the unit held go into [states] (repeatable; in a tags CSV: the "
        "role 'state'; docs/how-to/unit-loops.md)",
    )
    p.add_argument(
        "--running",
        action="append",
        default=[],
        metavar="TAG[=VALUE]",
        help="the run condition: a two-valued state (a run feedback, an occupied mode); the "
        "unit runs where TAG is at its higher value (or at VALUE: also one of a mode's many, "
        "MODE=1 of idle 0, production 1, CIP 2-4), learns only from those "
        "rows and judges nothing elsewhere (CHECK_FUNCTION, not running; ISA-18.2's "
        "state-based alarming; docs/how-to/unit-loops.md). In a tags CSV: the role 'running'. "
        "'[NAME:]TAG[=VALUE]:TAG1,TAG2,…': a piece of equipment's run condition (repeatable): "
        "while it is stopped the tests of TAG1, TAG2, … are off, the rest judged",
    )
    p.add_argument(
        "--period",
        help="grid period of the unit, e.g. 10s, 1min (default: from the data, the longest "
        "typical spacing of the tags; a faster tag is averaged over each period)",
    )
    p.add_argument("--force", action="store_true", help="overwrite an existing unit and models")
    add_dask_args(p, "the per-test work (inputs, training, threshold residuals)")
    add_json(p)
    p.set_defaults(func=cmd_unit_build)
    p = usub.add_parser(
        "accept",
        help="learn an operator-confirmed fault-free period (a new operating point) into the "
        "unit: models merged, thresholds re-learned, the old version kept (unit rollback)",
    )
    p.add_argument("name", help="the unit (as in diag unit show)")
    p.add_argument(
        "--from",
        dest="start",
        required=True,
        metavar="T0",
        help="start of the fault-free period the operator confirmed, e.g. 2026-03-01T06:00 "
        "(ISO 8601; naive times are UTC)",
    )
    p.add_argument(
        "--to",
        dest="end",
        required=True,
        metavar="T1",
        help="end of that period (exclusive), the same form as --from",
    )
    add_far(p, "(default: the unit's own)")
    add_json(p)
    p.set_defaults(func=cmd_unit_accept)
    p = usub.add_parser("rollback", help="undo the last `diag unit accept` of a unit")
    p.add_argument("name")
    add_json(p)
    p.set_defaults(func=cmd_unit_rollback)


def _printed_json(args, doc: dict) -> bool:
    """With ``--json``: ``doc`` printed as the command's whole answer (True)."""
    if args.json:
        print(json.dumps(doc, indent=2))
    return args.json


def _tags_from(path: str) -> list[str]:
    try:
        lines = Path(path).read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise UserError(f"--tags-from {path}: cannot read: {exc}") from None
    tags = [ln.split("#", 1)[0].strip() for ln in lines]
    tags = [t for t in tags if t]
    if not tags:
        raise UserError(f"--tags-from {path}: lists no tag (one per line)")
    return tags


def _build(args, tags, loops, manual, disturbances, t0, t1, workers, running=None,
           equipment=(), states=()):  # fmt: skip
    """The build, its progress drawn on a terminal's standard error."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

    from diag_plugin.unitbuild.build import build_from_historian

    err = Console(stderr=True)
    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        console=err,
        transient=True,
        disable=args.json or not err.is_terminal,
    ) as bar:
        tasks: dict[str, int] = {}

        def progress(stage: str, done: int, total: int) -> None:
            if stage not in tasks:
                tasks[stage] = bar.add_task(stage, total=total)
            bar.update(tasks[stage], completed=done)

        return build_from_historian(
            args.db,
            args.name,
            t0,
            t1,
            folder=args.rulebases,
            tags=tags,
            far=args.far,
            max_inputs=args.max_inputs,
            force=args.force,
            progress=progress,
            loops=loops,
            period=args.period,
            workers=workers,
            manual=manual,
            disturbances=disturbances,
            running=running,
            equipment=equipment,
            states=states,
        )


def cmd_unit_build(args) -> int:
    from diag_plugin.unitbuild.loops import (
        Disturbance,
        Manual,
        declared_in_tags_csv,
        parse_loop,
        parse_running,
    )

    tags = args.tags or (_tags_from(args.tags_from) if args.tags_from else None)
    loops = [parse_loop(x) for x in args.loop]
    manual = [Manual(t.strip(), f"--manual {t}") for t in args.manual]
    driven = [Disturbance(t.strip(), f"--disturbance {t}") for t in args.disturbance]
    running = [parse_running(x) for x in args.running]
    states = [t.strip() for t in args.state]
    equipment = [r for r in running if r.tags]
    running = [r for r in running if not r.tags]
    if args.loops_from:  # the checks diag import --tags makes of the same file
        declared = declared_in_tags_csv(args.loops_from)
        manual += declared.manual
        driven += declared.disturbances
        running += declared.running
        equipment += declared.equipment
        states += declared.states
        loops += declared.loops
    if len(running) > 1:
        raise UserError(
            f"{running[1].where}: a second run condition ({running[1].tag}; the first "
            f"{running[0].tag}, {running[0].where}): a unit has one"
        )
    if args.max_inputs < 1:
        raise UserError(f"--max-inputs {args.max_inputs}: at least 1")
    check_timeout(args.dask_timeout)
    t0, t1 = parse_time(args.start), parse_time(args.end)
    with contextlib.ExitStack() as stack:
        workers = None
        if args.dask:  # reached and checked before any work
            from diag_plugin.unitbuild.parallel import DaskPool

            workers = stack.enter_context(DaskPool.connect(args.dask, args.dask_timeout))
        res = _build(args, tags, loops, manual, driven, t0, t1, workers,
                     running[0] if running else None, equipment, states)  # fmt: skip
    if _printed_json(args, res.as_dict()):
        return 0
    print(
        f"wrote {res.path}: {len(res.tests)} tests from {res.window[0]} … {res.window[1]} "
        f"(period {res.period}), thresholds to {res.far:g} false alarms per hour"
        + (" (the default)" if args.far is None else "")
    )
    for ch in res.tests:
        errs = " → ".join(
            f"{x:.2f}"
            for x in [ch.baseline_rmse_pct, *(s.rmse_pct for s in ch.steps)]
            if math.isfinite(x)
        )
        loop = f" (its control loop, {ch.method}; actuator {ch.actuator})" if ch.tracks else ""
        if ch.statistic == "spread":
            loop = f" (the spread of its loop's error: stiction of {ch.actuator})"
        if not ch.tracks and ch.why:
            loop = f" ({ch.why})"
        print(f"  {ch.test}: {test_line(ch)}{loop}; held-out error {errs} % of span")
    hand = {m.tag for m in res.manual}
    for tag in hand:
        print(f"  {tag}: {res.skipped[tag]}")
    for tag, why in res.skipped.items():
        if tag not in hand:
            print(f"  not tested: {tag}: {why}")
    from diag_plugin.learn.thresholds import WIDE_SAID
    from diag_plugin.unitbuild.build import CHOSEN_SAID, NARROW_OUTPUTS_SAID, NARROW_SAID

    # a test that never alarms, the inputs learned over a narrow span, the tested tags whose
    # own test goes unknown outside it, the set-points whose readers do: each said, not counted
    said = (WIDE_SAID, NARROW_SAID, NARROW_OUTPUTS_SAID, CHOSEN_SAID)
    wide = [n for n in res.notes if any(k in n for k in said)]
    for n in wide:
        print(f"  ⚠ {n}")
    for line in note_lines([n for n in res.notes if n not in wide]):
        print(line)
    print("  time: " + ", ".join(f"{k} {v:.1f} s" for k, v in res.seconds.items()))
    print(f"next: diag unit show {args.name}; diag diagnose {args.name} --from … --to …")
    return 0


def test_line(ch) -> str:
    """What a built test compares, in words where a formula would mislead: a level test
    (no inputs) is the tag against its window mean, a joint test the group's common
    direction."""
    if ch.method == "joint":
        from diag_plugin.regressors import InputSpec

        tags = [ch.tag, *(InputSpec.parse(s).tags[0] for s in ch.inputs)]
        return f"{', '.join(tags)} jointly (their common direction)"
    if not ch.inputs and not ch.tracks:
        return f"{ch.tag} against its window mean"
    return f"{ch.tag} = f({', '.join(ch.inputs)})"


def cmd_unit_accept(args) -> int:
    from diag_plugin.unitbuild.accept import accept

    unit = load_unit(args, args.name)
    t0, t1 = parse_time(args.start), parse_time(args.end)
    if args.far is not None:
        check_far(args.far)
    res = accept(unit, lambda a, b: unit_frames(args, unit, a, b), t0, t1, far=args.far)
    if _printed_json(args, res.as_dict()):
        return 0
    print(
        f"unit {res.unit}: learned {res.window[0]} … {res.window[1]} (old version kept in "
        f"{res.backup}; diag unit rollback {res.unit} puts it back)"
    )
    nan = (float("nan"), float("nan"))

    def band(lo: float, hi: float) -> str:
        return f"{lo:+.3f} … {hi:+.3f}" if lo == lo else f"high {hi:+.3f}"  # NaN: none

    for k, (before, after) in res.rules.items():
        print(
            f"  {k}: {res.samples.get(k, 0):,} samples merged; rules {before} → {after}; "
            f"thresholds {band(*res.before.get(k, nan))} → {band(*res.limits.get(k, nan))}"
            + _kept(res.kept.get(k, {}))
        )
    if "combined" in res.kept:
        print("  combined test: high" + _kept(res.kept["combined"]).removeprefix(";"))
    print("  windows learned: " + "; ".join(f"{a} … {b}" for a, b in res.windows))
    for how in res.envelope:  # a start's envelope re-learned (diagnose/envelope.py)
        print(f"  {how}")
    for k, x in res.widened().items():
        print(
            f"  ⚠ {k}: its band is {x:.1f}× as wide: it now passes what it flagged before — "
            "its inputs do not tell the accepted period from the windows it learned, so both "
            f"share one band; diag unit rollback {res.unit} undoes the accept"
        )
    for line in note_lines(res.warnings):
        print(line)
    return 0


def note_lines(notes: list[str], shown: int = 4) -> list[str]:
    """The lines ``unit build`` and ``unit accept`` print of their notes: the first
    ``shown``, then how many more there are (``--json`` lists them all). Until 2026-11-30
    the accept dropped the rest without a word (the AHU's pass, acceptance-ahu.md)."""
    lines = [f"  note: {n}" for n in notes[:shown]]
    if len(notes) > shown:
        lines.append(
            f"  … {len(notes) - shown} more notes of the same kind (--json lists them all)"
        )
    return lines


def _kept(note: dict) -> str:
    """What an accept kept of a test's band before it (``AcceptResult.kept``), said."""
    said = [
        f"{side} re-learned {note[key][0]:+.3f}, kept {note[key][1]:+.3f}"
        for side, key in (("low", "kept_low"), ("high", "kept_high"))
        if key in note
    ]
    if "kept_levels" in note:
        said.append("level scales " + " ".join(f"{x:.3g}" for x in note["kept_levels"][1]))
    return f"; kept: not narrowed ({'; '.join(said)})" if said else ""


def cmd_unit_rollback(args) -> int:
    from diag_plugin.diagnose.unitfile import unit_path
    from diag_plugin.unitbuild.accept import rollback

    path = unit_path(args.name, args.rulebases)
    if not path.exists():
        raise UserError(f"unit {args.name}: no file {path}")
    got = rollback(path)
    if _printed_json(args, got):
        return 0
    acc = got.get("accepted") or ["?", "?"]
    print(
        f"unit {args.name}: restored the version before accepting {acc[0]} … {acc[1]} "
        f"({len(got['files'])} files; {got['left']} older backup(s) left)"
        + (f"; the files it replaced are kept in {got['replaced']}" if got["replaced"] else "")
    )
    return 0
