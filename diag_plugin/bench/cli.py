"""``diag benchmark``: the DAMADICS faults against a unit, or a unit built on a simulated
plant scored beside PCA and DPCA.

Only argparse is imported at start-up; the command imports what it needs when it runs.
"""

from __future__ import annotations

import argparse
import json
import sys

from diag_plugin.cliargs import add_json
from diag_plugin.diagnose.cli import load_unit
from diag_plugin.learn.far import check_far
from historian.errors import UserError


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "benchmark",
        help="DAMADICS faults f1–f19 against a unit, scored with the benchmark indexes; or "
        "(--plant chemplant) a unit built from the plant's history beside PCA and DPCA",
    )
    p.add_argument("--unit", default="valve_unit", help="unit to score (default the example)")
    p.add_argument(
        "--quick",
        action="store_true",
        help="DAMADICS: one strength per fault (38 scenarios); --plant: 2 training seeds × 6 "
        "days, one seed, three faults",
    )
    p.add_argument(
        "--seed",
        type=int,
        action="append",
        dest="seeds",
        help="simulator seed(s) (--plant chemplant without --match-far: the faulty runs' "
        "seeds, default 9101–9103)",
    )
    p.add_argument(
        "--plant",
        choices=["chemplant", "tep", "tep-studio", "skab"],
        help="build a unit on this plant and score it beside PCA and DPCA: the simulated "
        "chemical plant, or (always at matched false alarms) the public Tennessee Eastman "
        "data (tep: the classic set; tep-studio: simulated runs) or SKAB",
    )
    p.add_argument(
        "--match-far",
        nargs="?",
        const="0.001,0.005,0.01,0.02,0.05",
        metavar="RATES",
        help="--plant: set every method's limit to the same false-alarm rate on fault-free "
        "calibration runs, at each of these comma-separated rates (default "
        "0.001,0.005,0.01,0.02,0.05); --page FILE writes the result page",
    )
    p.add_argument(
        "--far-per",
        choices=["sample", "hour"],
        default="sample",
        help="--match-far: the rates are shares of samples (default) or alarm episodes per hour",
    )
    p.add_argument("--page", metavar="FILE",
                   help="write the result page (provenance: command, date, commit, seeds): "
                   "only when given, e.g. docs/results/damadics.md or, with --plant and "
                   "--match-far, docs/results/PLANT.md")  # fmt: skip
    p.add_argument("--data", metavar="DIR",
                   help="--plant tep/tep-studio/skab: where the data are (default: the "
                   "environment variable or cache the docs name)")  # fmt: skip
    p.add_argument(
        "--period",
        type=int,  # no default here: the matched mode must see whether it was given
        help="--plant chemplant without --match-far: sample period, whole s (default 180, e.g. 1)",
    )
    p.add_argument("--free-seed", type=int, action="append", dest="free_seeds",
                   help="--plant chemplant without --match-far: fault-free scoring seed(s) "
                   "(default 9151–9153)")  # fmt: skip
    p.add_argument("--train-seed", type=int, action="append", dest="train_seeds",
                   help="--plant chemplant without --match-far: fault-free training seed(s) "
                   "(default 1–3)")  # fmt: skip
    p.add_argument(
        "--train-days",
        type=float,
        help="--plant chemplant without --match-far: days per training seed",
    )
    p.add_argument("--fault", action="append", dest="faults", metavar="NAME[:SIZE]",
                   help="--plant: a fault to score, repeatable (default all the plant's: chemplant "
                   "15, tep 21, tep-studio 20; SKAB is scored on all its runs)")  # fmt: skip
    p.add_argument(
        "--far",
        type=float,
        help="--plant chemplant without --match-far: budget, alarms per hour (unit build's)",
    )
    p.add_argument("--out", metavar="DIR", help="--plant: keep the built unit in DIR")
    add_json(p)
    p.set_defaults(func=cmd_benchmark)


def _fmt(v, spec: str = ".3f") -> str:
    if v is None:
        return "—"
    if isinstance(v, bool):
        return "yes" if v else "no"
    return format(v, spec)


def cmd_benchmark(args) -> int:
    from rich.console import Console
    from rich.progress import Progress
    from rich.table import Table

    from diag_plugin.bench.damadics import SeedClash, run_benchmark

    if args.plant and (args.match_far or args.plant != "chemplant"):
        return cmd_matched_benchmark(args)
    if args.plant:
        return cmd_plant_benchmark(args)
    unit = load_unit(args, args.unit)
    if not unit.has_thresholds:
        raise UserError(f"unit {unit.name} has no thresholds: run diag unit learn first")
    seeds = tuple(args.seeds or (11,))
    if args.page:
        from diag_plugin.bench.pages import commit

        started = commit()  # the code that runs, not what the tree holds when it ends
    con = Console(stderr=True)
    with Progress(console=con, transient=True, disable=args.json or not con.is_terminal) as pr:
        n = (38 if args.quick else 76) * len(seeds)
        task = pr.add_task("scenarios", total=n)
        pr.update(task, description="PCA / DPCA: fit and match to the unit's false alarms")
        try:
            out = run_benchmark(
                unit,
                quick=args.quick,
                seeds=seeds,
                progress=lambda sc: pr.update(task, advance=1, description=f"{sc.fault} {sc.mode}"),
            )
        except SeedClash as exc:  # only that: any other ValueError is a bug, not the user's
            raise UserError(str(exc)) from None
    if args.page:
        from diag_plugin.bench.pages import render_damadics, write

        out["page"] = str(write(render_damadics(out, _command(), started), args.page))
    if args.json:
        print(json.dumps(out, indent=2, allow_nan=False))
        return 0
    t = Table(title=f"DAMADICS benchmark, unit {unit.name} (times in s after the onset)")
    cols = ("fault", "mode", "strength", "detected", "t_dt", "r_fd", "r_td", "unknown")
    for c in cols + ("isolated", "t_it", "r_ti", "r_mi", "dacc"):
        t.add_column(c, justify="right")
    for r in out["scenarios"]:
        t.add_row(
            r["fault"],
            r["mode"],
            f"{r['strength']:g}",
            _fmt(r["detected"]),
            _fmt(r["detection_time_s"], ".0f"),
            _fmt(r["false_detection_rate"]),
            _fmt(r["true_detection_rate"]),
            _fmt(r["unknown_rate"], ".2f"),
            _fmt(r["isolated"]) + ("" if r["unit_fault"] is None else f" ({r['unit_fault']})"),
            _fmt(r["isolation_time_s"], ".0f"),
            _fmt(r["true_isolation_rate"]),
            _fmt(r["mismatch_isolation_rate"]),
            _fmt(r["diagnosis_accuracy"], ".2f"),
        )
    Console(width=None if con.is_terminal else 150).print(t)
    s = out["summary"]
    print(
        f"detected {s['scenarios_detected']}/{s['scenarios']} scenarios; faults detected: "
        f"{', '.join(s['faults_detected']) or '—'}; missed: {', '.join(s['faults_missed']) or '—'}"
    )
    print(
        f"of the {s['literature_detectable']} faults the literature detects: "
        f"{s['literature_detectable_detected']} ({s['literature_detectable_share']:.0%}); "
        f"false detection rate mean {s['mean_false_detection_rate']:.4f}, "
        f"max {s['max_false_detection_rate']:.4f} (unknown before the onsets "
        f"{s['mean_unknown_rate_before']:.1%})"
    )
    print(
        f"isolated {s['scenarios_isolated']}/{s['scenarios_with_isolation']} scenarios with a "
        f"matrix column: {', '.join(s['faults_isolated']) or '—'}"
    )
    for line in baseline_lines(out):
        print(line)
    if args.page:
        print(f"page: {out['page']}")
    return 0


def baseline_lines(out: dict) -> list[str]:
    """The DAMADICS run's PCA and DPCA beside the unit, at its false-alarm rate on the
    calibration runs, as lines of text (none without baselines)."""
    b = out.get("baselines")
    if not b:
        return []
    cal, n = b["calibration"], b["calibration"]["samples"]
    lines = [
        f"at the unit's false-alarm rate on the fault-free calibration runs (seeds "
        f"{', '.join(map(str, cal['seeds']))}: unit {cal['unit']['alarms']} of {n} samples, "
        + ", ".join(f"{m} {cal[m]['alarms']}" for m in b["summary"])
        + "):"
    ]
    for m, s in b["summary"].items():
        lines.append(
            f"  {m}: detected {s['scenarios_detected']}/{s['scenarios']} scenarios; faults "
            f"detected: {', '.join(s['faults_detected']) or '—'}; false detection rate mean "
            f"{s['mean_false_detection_rate']:.4f}, max {s['max_false_detection_rate']:.4f}"
        )
    return lines


def _command() -> str:
    """The command line as the user typed it, from ``benchmark`` on (for a page's provenance)."""
    argv = sys.argv[1:]
    return "diag " + " ".join(argv[argv.index("benchmark") :] if "benchmark" in argv else argv)


def _dur(s: float | None) -> str:
    if s is None:
        return "—"
    return f"{s / 3600:.1f} h" if s >= 3600 else f"{s / 60:.0f} min" if s >= 60 else f"{s:.0f} s"


#: the options only the budget-limit benchmark (``--plant chemplant`` without ``--match-far``)
#: reads, by their ``args`` attribute: the matched mode fixes its own runs and sets every
#: method's limit from the target rate, so it refuses them rather than ignore them
BUDGET_ONLY = {
    "seeds": "--seed",
    "period": "--period",
    "free_seeds": "--free-seed",
    "train_seeds": "--train-seed",
    "train_days": "--train-days",
    "far": "--far",
}


def refuse_budget_options(args) -> None:
    """Raise :class:`UserError` naming the first budget-only option given to the matched mode."""
    for attr, flag in BUDGET_ONLY.items():
        if getattr(args, attr, None) is not None:
            mode = "--match-far" if args.plant == "chemplant" else f"--plant {args.plant}"
            why = (
                "its limits come from the --match-far rates, not a budget"
                if attr == "far"
                else "it scores the plant's own fixed runs"
            )
            raise UserError(
                f"{flag}: only for --plant chemplant without --match-far; {mode} benchmarks "
                f"at matched false-alarm rates and {why}"
            )


def cmd_matched_benchmark(args) -> int:
    """``diag benchmark --plant P --match-far``: the unit, PCA and DPCA at matched false-alarm
    rates (:func:`~diag_plugin.bench.publicbench.run_matched_benchmark`); the result page
    written only when ``--page`` names it. The budget-only options are refused
    (:func:`refuse_budget_options`) before anything is loaded."""
    refuse_budget_options(args)
    from rich.console import Console
    from rich.progress import Progress

    from diag_plugin.bench import publicplants as pp
    from diag_plugin.bench.publicbench import chemplant_plant, run_matched_benchmark, write_page

    try:
        targets = [float(x) for x in (args.match_far or "0.001,0.005,0.01,0.02,0.05").split(",")]
    except ValueError:
        raise UserError(f"--match-far {args.match_far}: comma-separated rates") from None
    if any(not t > 0 for t in targets) or (args.far_per == "sample" and max(targets) >= 1):
        raise UserError(f"--match-far {args.match_far}: rates must be > 0 (and < 1 per sample)")
    con = Console(stderr=True)
    try:
        if args.plant == "chemplant":
            plant = chemplant_plant(quick=args.quick, faults=args.faults)
        elif args.plant == "tep":
            plant = pp.load_braatz(args.data, faults=args.faults)
        elif args.plant == "tep-studio":
            plant = pp.load_tep_studio(args.data, faults=args.faults)
        else:
            if args.faults:
                raise UserError("--fault: SKAB is scored on all its scoring runs")
            plant = pp.load_skab(args.data)
    except (pp.DataMissing, KeyError, ValueError) as exc:
        raise UserError(str(exc)) from None
    with Progress(console=con, transient=True, disable=args.json or not con.is_terminal) as pr:
        task = pr.add_task("build", total=None)

        def tick(stage: str, done: int, total: int) -> None:
            pr.update(task, description=stage, completed=done, total=total)

        out = run_matched_benchmark(
            plant, targets=targets, per=args.far_per, work=args.out, progress=tick
        )
    command = _command()
    page = args.page  # only --page writes a page; --json (or nothing) leaves docs/ alone
    if page:
        out["page"] = str(write_page(out, page, command))
    if args.json:
        print(json.dumps(out, indent=2, default=float))
        return 0
    print(f"{out['title']}: " + ("" if "unit" in out["methods"] else
          f"unit not built ({out['unit']['note']}); "))  # fmt: skip
    for p in out["curve"]["points"]:
        parts = []
        for m in out["methods"]:
            x = p["methods"][m]
            fa = "—" if x["free_share"] is None else f"{x['free_share']:.2%}"
            n = x["named_runs"]
            parts.append(f"{m} {x['mean_detection']:.0%} (top 3 {x['in_top']}/{n}, first "
                         f"{x['named_first']}/{n}, episodes right {x['episodes_right']}/"
                         f"{x['episodes_named']}, false alarms {fa})")  # fmt: skip
        print(f"at {p['target']:g} {out['per']}: " + "; ".join(parts))
    if page:
        print(f"page: {out['page']}")
    return 0


def cmd_plant_benchmark(args) -> int:
    """``diag benchmark --plant chemplant``: build a unit on fault-free runs, score it beside
    PCA and DPCA held to the same budget (:func:`~diag_plugin.bench.plant.run_plant_benchmark`).
    The output says first that its figures are at the unit's budget, not at matched
    false-alarm rates (:func:`~diag_plugin.bench.plant.budget_note`); it writes no page."""
    from rich.console import Console
    from rich.progress import Progress
    from rich.table import Table

    from diag_plugin.bench.plant import run_plant_benchmark

    if args.page:
        raise UserError(
            "--page: --plant chemplant without --match-far writes no page (its figures are at "
            "the unit's budget, not at matched false-alarm rates); the result pages are made "
            "with --match-far"
        )
    period = 180 if args.period is None else args.period
    if period < 1:
        raise UserError(f"--period {period}: a whole number of seconds ≥ 1")
    if args.far is not None:
        check_far(args.far)
    con = Console(stderr=True)
    with Progress(console=con, transient=True, disable=args.json or not con.is_terminal) as pr:
        task = pr.add_task("simulate", total=None)

        def tick(stage: str, done: int, total: int) -> None:
            pr.update(task, description=stage, completed=done, total=total)

        try:
            out = run_plant_benchmark(
                args.plant,
                period_s=period,
                quick=args.quick,
                fault_seeds=args.seeds,
                free_seeds=args.free_seeds,
                train_seeds=args.train_seeds,
                train_days=args.train_days,
                faults=args.faults,
                far=args.far,
                folder=args.out,
                progress=tick,
            )
        except ValueError as exc:
            raise UserError(str(exc)) from None
    if args.json:
        print(json.dumps(out, indent=2, allow_nan=False))
        return 0
    print(out["note"])
    methods = out["methods"]
    tr, sc = out["training"], out["scoring"]
    t = Table(
        title=f"{out['plant']} at {out['period_s']} s: unit built on seeds "
        f"{', '.join(map(str, tr['seeds']))} × {tr['days']:g} days ({tr['tests']} tests) beside "
        f"PCA and DPCA, budget {out['far_per_hour']:g} alarms/h; faults from day "
        f"{sc['onset_days']:g} of {sc['days']:g}-day runs, seeds "
        f"{', '.join(map(str, sc['fault_seeds']))}"
    )
    t.add_column("fault")
    t.add_column("kind")
    t.add_column("tag")
    for m in methods:
        t.add_column(f"{m} detected", justify="right")
        t.add_column(f"{m} delay", justify="right")
        t.add_column(f"{m} top 3", justify="right")
    for r in out["faults"]:
        cells = [r["fault"], r["kind"], ", ".join(r["tags"])]
        for m in methods:
            x = r[m]
            cells += [f"{x['detection_rate']:.0%}", _dur(x["delay_s"]),
                      f"{x['in_top3']}/{x['runs']}"]  # fmt: skip
        t.add_row(*cells)
    cells = ["fault-free: samples, alarms/h", f"seeds {', '.join(map(str, sc['free_seeds']))}", ""]
    for m in methods:
        fa = out["fault_free"][m]
        cells += [f"{fa['share']:.2%}", f"{fa['per_hour']:.3g}/h", ""]
    t.add_row(*cells, end_section=True)
    Console(width=None if con.is_terminal else 200).print(t)
    s = out["summary"]
    print(
        "mean detection rate on the faults either the unit or PCA detects (≥ "
        f"{s['detected_threshold']:.0%}): "
        + ", ".join(f"{m} {s[m]['mean_detection_rate_either'] or 0:.0%}" for m in methods)
    )
    print(
        "faulted tag in the top three, sensor and actuator runs detected (≥ "
        f"{s['detected_threshold']:.0%}): "
        + ", ".join(f"{m} {s[m]['sensor_actuator_named_of_detected']}" for m in methods)
        + "; of all runs: "
        + ", ".join(f"{m} {s[m]['sensor_actuator_in_top3']}" for m in methods)
    )
    print("unit misses: " + (", ".join(s["unit"]["faults_missed"]) or "—"))
    g = s["goal"]
    print(
        f"goal (issue 25): detection above PCA {_fmt(g['detection_above_pca'])}, false alarms "
        f"no higher {_fmt(g['false_alarms_no_higher'])}, top three ≥ 80 % of the detected "
        f"{_fmt(g['top3_80pct'])} → {'holds' if g['holds'] else 'does not hold'}"
    )
    sec = out["seconds"]
    print(
        f"build {sec['build']:.0f} s, PCA fit {sec['fit PCA']:.0f} s, scoring: unit "
        f"{sec['score unit']:.1f} s, PCA {sec['score PCA']:.1f} s, DPCA {sec['score DPCA']:.1f} s"
        f" (simulation {sec['simulate training'] + sec['simulate scoring runs']:.0f} s)"
    )
    return 0
