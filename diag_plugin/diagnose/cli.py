"""``diag unit new|check|show|learn`` and ``diag diagnose``: units on historian data.

Only argparse is imported at start-up; each command imports what it needs when it runs.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from historian.errors import UserError


def add_commands(sub: argparse._SubParsersAction) -> None:
    unit = sub.add_parser("unit", help="create, check, show a unit or learn its thresholds")
    usub = unit.add_subparsers(dest="unit_command", metavar="ACTION", required=True)
    p = usub.add_parser("new", help="write rulebases/NAME.unit.toml naming the unit's models")
    p.add_argument("name")
    p.add_argument(
        "--model",
        action="append",
        required=True,
        metavar="TEST=RULEBASE",
        help="a test and the model whose residual it is, e.g. r1=valve_r1 (repeat)",
    )
    p.add_argument("--matrix", metavar="FILE", help="diagnostic matrix file (else detect only)")
    p.add_argument("--outputs", metavar="PREFIX", help="prefix of the published tags")
    p.add_argument("--description", default="")
    p.add_argument("--force", action="store_true", help="overwrite an existing unit file")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_unit_new)
    p = usub.add_parser("check", help="check a unit file, its models and matrix (file:line)")
    p.add_argument("file")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_unit_check)
    p = usub.add_parser("show", help="tests, thresholds, matrix and its isolability")
    p.add_argument("name")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_unit_show)
    p = usub.add_parser("learn", help="learn thresholds from a window you declare fault-free")
    p.add_argument("name")
    p.add_argument("--from", dest="start", required=True, metavar="T0")
    p.add_argument("--to", dest="end", required=True, metavar="T1")
    p.add_argument(
        "--far",
        type=float,
        default=None,
        metavar="PER_HOUR",
        help="false-alarm budget: alarms per hour of operation of the unit, all tests together "
        "(default 0.001, about one in six weeks)",
    )
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
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_unit_learn)
    p = usub.add_parser(
        "build",
        help="build a unit from a fault-free window: tests, inputs, models and thresholds",
    )
    p.add_argument("name")
    p.add_argument("--from", dest="start", required=True, metavar="T0")
    p.add_argument("--to", dest="end", required=True, metavar="T1")
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "--tags", nargs="+", metavar="TAG", help="the tags to test (default: all that vary)"
    )
    g.add_argument(
        "--tags-from", metavar="FILE", help="the tags to test, one per line (# comments)"
    )
    p.add_argument(
        "--far",
        type=float,
        default=None,
        metavar="PER_HOUR",
        help="false-alarm budget: alarms per hour of operation of the unit, all tests together "
        "(default 0.001)",
    )
    p.add_argument("--max-inputs", type=int, default=3, metavar="N", help="inputs per model (3)")
    p.add_argument("--force", action="store_true", help="overwrite an existing unit and models")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_unit_build)

    p = sub.add_parser("diagnose", help="replay historian data through a unit")
    p.add_argument("name")
    p.add_argument("--from", dest="start", metavar="T0")
    p.add_argument("--to", dest="end", metavar="T1")
    p.add_argument("--csv", metavar="FILE", help="one row per sample (ts, status, r_*, s_*, c_*)")
    p.add_argument("--chunk", default="7D", help="data read per step (default 7D)")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_diagnose)

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
        help="simulator seed(s) (--plant: the faulty runs' seeds, default 9101–9103)",
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
        "0.001,0.005,0.01,0.02,0.05), and write the result page",
    )
    p.add_argument(
        "--far-per",
        choices=["sample", "hour"],
        default="sample",
        help="--match-far: the rates are shares of samples (default) or alarm episodes per hour",
    )
    p.add_argument("--page", metavar="FILE",
                   help="--match-far: the result page (default docs/results/PLANT.md)")  # fmt: skip
    p.add_argument("--data", metavar="DIR",
                   help="--plant tep/tep-studio/skab: where the data are (default: the "
                   "environment variable or cache the docs name)")  # fmt: skip
    p.add_argument(
        "--period", type=int, default=180, help="--plant: sample period in s (default 180; 1)"
    )
    p.add_argument("--free-seed", type=int, action="append", dest="free_seeds",
                   help="--plant: fault-free scoring seed(s) (default 9151–9153)")  # fmt: skip
    p.add_argument("--train-seed", type=int, action="append", dest="train_seeds",
                   help="--plant: fault-free training seed(s) (default 1–3)")  # fmt: skip
    p.add_argument("--train-days", type=float, help="--plant: days per training seed")
    p.add_argument("--fault", action="append", dest="faults", metavar="NAME[:SIZE]",
                   help="--plant: a fault to score (default all 15)")  # fmt: skip
    p.add_argument("--far", type=float, help="--plant: budget, alarms per hour (unit build's)")
    p.add_argument("--out", metavar="DIR", help="--plant: keep the built unit in DIR")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_benchmark)


def _load_unit(args, name: str):
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.diagnose.unitfile import SUFFIX, UnitError, unit_path

    path = unit_path(name, args.rulebases)
    if not path.exists():
        from diag_plugin.examples.shipped import find_shipped

        path = find_shipped(name, SUFFIX) or path
    if not path.exists():
        raise UserError(f"no unit file {path} (make one with `diag unit new`)")
    try:
        return Unit.load(path, args.rulebases)
    except UnitError as exc:
        raise UserError("unit file has problems:\n" + "\n".join(exc.problems)) from None


def _ts(text: str | None):
    import pandas as pd

    if text is None:
        return None
    try:
        t = pd.Timestamp(text)
    except ValueError:
        raise UserError(
            f"{text!r} is not a time (use e.g. 2026-01-01 or 2026-01-01T06:00)"
        ) from None
    return t.tz_localize("UTC") if t.tzinfo is None else t.tz_convert("UTC")


def cmd_unit_new(args) -> int:
    from diag_plugin.diagnose.unitfile import SUFFIX, new_unit_text
    from diag_plugin.rulebase.document import resolve

    folder = Path(args.rulebases)
    path = folder / f"{args.name}{SUFFIX}"
    if path.exists() and not args.force:
        raise UserError(f"{path} exists (use --force to overwrite)")
    tests: dict[str, str] = {}
    for item in args.model:
        test, sep, model = item.partition("=")
        if not sep or not test or not model:
            raise UserError(f"--model {item!r}: write TEST=RULEBASE, e.g. r1=valve_r1")
        if test in tests:
            raise UserError(f"--model {item!r}: test {test!r} given twice")
        mpath = resolve(model, folder)
        if not mpath.exists():
            raise UserError(f"--model {item!r}: no model file {mpath}")
        tests[test] = os.path.relpath(mpath.resolve(), folder.resolve())
    matrix = None
    if args.matrix:
        mp = Path(args.matrix)
        if not mp.exists() and (folder / mp).exists():
            mp = folder / mp
        if not mp.exists():
            raise UserError(f"--matrix {args.matrix}: no such file")
        matrix = os.path.relpath(mp.resolve(), folder.resolve())
    text = new_unit_text(
        args.name, tests, matrix=matrix, description=args.description, outputs=args.outputs
    )
    folder.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    problems = _problems(path, args.rulebases)
    if args.json:
        print(json.dumps({"unit": str(path), "tests": tests, "problems": problems}, indent=2))
    else:
        print(f"wrote {path}: {len(tests)} tests" + (f", matrix {matrix}" if matrix else ""))
        for p in problems:
            print(p, file=sys.stderr)
        print(f"next: diag unit learn {args.name} --from T0 --to T1 (a fault-free window)")
    if problems:
        raise UserError("the new unit has problems (above)")
    return 0


def _problems(path: Path, folder: str) -> list[str]:
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.diagnose.unitfile import UnitError

    try:
        Unit.load(path, folder)
    except UnitError as exc:
        return exc.problems
    return []


def cmd_unit_check(args) -> int:
    from diag_plugin.diagnose.unitfile import unit_path

    path = unit_path(args.file, args.rulebases)
    problems = _problems(path, args.rulebases)
    if args.json:
        print(json.dumps({"file": str(path), "ok": not problems, "problems": problems}, indent=2))
    elif problems:
        print("\n".join(problems), file=sys.stderr)
    else:
        print(f"{path}: ok")
    return 2 if problems else 0


def unit_summary(unit) -> dict:
    """What ``diag unit show`` prints: tests, thresholds, evaluation, matrix analysis."""
    f = unit.file
    tests = []
    for t in f.tests:
        m = unit.models[t.name]
        lim = t.limits
        tests.append(
            {
                "test": t.name,
                "model": t.model,
                "output": m.output,
                "inputs": m.inputs,
                "low": None if lim is None else lim[0],
                "high": None if lim is None else lim[1],
                "levels": list(t.levels) if t.levels else [1.0],
                "spread": t.spread,
                "learned": f.learned.get(t.name, {}),
            }
        )
    out = {
        "unit": unit.name,
        "file": str(f.path),
        "description": f.description,
        "outputs": f.outputs,
        "period": unit.period,
        "tags": unit.tags,
        "evaluation": f.evaluation,
        "thresholds": f.thresholds,
        "tests": tests,
        "build": getattr(f, "build", {}) or {},
        "matrix": None,
        "combined": _combined_summary(unit),
    }
    if unit.matrix is not None:
        mx = unit.matrix
        out["matrix"] = {
            "file": str(f.matrix_path),
            "tests": mx.tests,
            "faults": mx.faults,
            "rows": {t: list(mx.entries[i]) for i, t in enumerate(mx.tests)},
            "isolability_groups": mx.isolability_groups(),
            "undetectable": mx.undetectable,
            "diagnosis_accuracy": mx.diagnosis_accuracy(),
            "mean_diagnosis_accuracy": mx.mean_diagnosis_accuracy(),
            "fault_status": {k: v.name for k, v in f.fault_status.items()},
            "derived": unit.derived,
        }
    return out


def _combined_summary(unit) -> dict | None:
    """The unit-level test and isolation to tags, as ``unit show`` prints them."""
    ev = unit.ev
    if not ev["combined"] and ev["isolation"] != "tags":
        return None
    c = unit.file.combined
    return {
        "enabled": bool(ev["combined"]),
        "isolation": ev["isolation"],
        "learned": c is not None,
        "high": None if c is None else c.high,
        "shrinkage": None if c is None else c.shrinkage,
        "notes": {} if c is None else dict(c.notes),
        "gains": {} if c is None else c.gains,
    }


def cmd_unit_show(args) -> int:
    unit = _load_unit(args, args.name)
    s = unit_summary(unit)
    if args.json:
        print(json.dumps(s, indent=2, default=str))
        return 0
    from rich.console import Console
    from rich.table import Table

    con = Console()
    con.print(f"unit {s['unit']} ({s['file']}): {s['description']}", markup=False)
    ev = s["evaluation"]
    con.print(
        f"period {s['period']}; low-pass {ev['lowpass'] or 'off'} (order {ev['order']}); "
        f"{ev['symptoms']} symptoms, on/off delay {ev['on_delay']}/{ev['off_delay']} samples"
        + ("; latched" if ev["latch"] else "")
        + ("" if ev.get("hold_isolation", True) else "; isolated afresh each sample"),
        markup=False,
    )
    t = Table(title="tests (residuals in % of span)")
    for c in ("test", "model", "output = f(inputs)", "low", "high", "false alarms/h", "unknown"):
        t.add_column(c)
    for r in s["tests"]:
        n = r["learned"]
        t.add_row(
            r["test"],
            r["model"],
            f"{r['output']} = f({', '.join(r['inputs'])})",
            "—" if r["low"] is None else f"{r['low']:.3g}",
            "—" if r["high"] is None else f"{r['high']:.3g}",
            "—" if "far" not in n else f"{n['far']:.2g} ({n.get('method', '?')})",
            "—" if "unknown" not in n else f"{n['unknown']:.1%}",
        )
    con.print(t)
    th = s["thresholds"]
    if th.get("from"):
        how = (
            f"budget {th['far']:g} false alarms per hour of operation"
            if "far" in th
            else f"quantile {th.get('quantile')} × margin {th.get('margin')}"
        )
        con.print(
            f"thresholds learned from {th['from']} … {th['to']} ({how}, {th.get('samples')} "
            "samples"
            + (f", residuals cross-fitted over {th['blocks']} blocks" if th.get("blocks") else "")
            + ")",
            markup=False,
        )
    else:
        con.print(f"no thresholds learned yet: diag unit learn {s['unit']} --from … --to …")
    _print_learned(con, s["tests"])
    _print_combined(con, s)
    _print_build(con, s["build"])
    mx = s["matrix"]
    if mx is None:
        con.print("no matrix: this unit only detects (status OFF_SPEC on a symptom)")
        return 0
    title = (
        "diagnostic matrix derived from the models (a column per tag)"
        if mx.get("derived")
        else f"diagnostic matrix {mx['file']}"
    )
    t = Table(title=title)
    t.add_column("test")
    for f in mx["faults"]:
        t.add_column(f, justify="center")
    for test in mx["tests"]:
        t.add_row(test, *mx["rows"][test])
    con.print(t)
    groups = [g for g in mx["isolability_groups"] if len(g) > 1]
    con.print(
        "isolable: every detectable fault"
        if not groups
        else "not isolable from each other: " + "; ".join("{" + ", ".join(g) + "}" for g in groups),
        markup=False,
    )
    if mx["undetectable"]:
        con.print(f"undetectable: {', '.join(mx['undetectable'])}", markup=False)
    con.print(f"theoretical diagnosis accuracy (DAMADICS): {mx['mean_diagnosis_accuracy']:.2f}")
    return 0


def _print_learned(con, tests: list[dict]) -> None:
    """Per test: why its thresholds are what they are (the budget's support, the unknown share
    and why, the level scales)."""
    from diag_plugin.diagnose.learning import WHY, hours

    for r in tests:
        n = r["learned"]
        if not n:
            continue
        parts = [
            f"expected {n['far']:.2g} false alarms/h"
            + ("" if n.get("supported") else f", extrapolated ({n.get('method')} fit)"),
            f"≈ {n.get('independent', 0):,} independent values over {hours(n.get('hours', 0))}",
        ]
        if not n.get("supported"):
            parts.append(f"a window of {hours(n.get('hours_needed', 0))} would support it")
        why = [f"{WHY[k[8:]]} {v:.1%}" for k, v in n.items() if k.startswith("unknown_")]
        if why:
            parts.append("unknown: " + "; ".join(why))
        if len(r["levels"]) > 1:
            parts.append(
                "coarser rule levels scaled ×" + ", ×".join(f"{x:.2g}" for x in r["levels"][1:])
            )
        if r["spread"]:
            parts.append("residual in units of its model's local spread")
        con.print(f"{r['test']}: " + "; ".join(parts), markup=False)


def _print_combined(con, s: dict) -> None:
    """The combined test's threshold and what it rests on, and the isolation to tags."""
    c = s.get("combined")
    if c is None:
        return
    if c["enabled"]:
        n = c["notes"]
        if c["high"] is None:
            con.print(
                f"combined test: no threshold yet: diag unit learn {s['unit']} --from … --to …",
                markup=False,
            )
        else:
            con.print(
                f"combined test (T² of the scaled residuals, covariance shrunk "
                f"{c['shrinkage']:.2g}): threshold {c['high']:.4g}; expected {n.get('far', 0):.2g} "
                f"false alarms/h"
                + ("" if n.get("supported") else f", extrapolated ({n.get('method')} fit)"),
                markup=False,
            )
    if c["isolation"] == "tags":
        con.print(
            "isolation to tags: "
            + (
                "the expert matrix names faults; alarms also rank the tags"
                if s["matrix"] is not None and not s["matrix"].get("derived")
                else "a matrix derived from the models; alarms rank the tags by contribution"
            ),
            markup=False,
        )


def _print_build(con, build: dict) -> None:
    """How ``diag unit build`` chose each test's inputs: the held-out error (% of span)
    before any input and after each, and the held-out coverage."""
    if not build:
        return
    con.print(
        f"built by diag unit build from {build.get('from')} … {build.get('to')}: inputs "
        "chosen one at a time on held-out error (each time block of the window held out in "
        "turn); a tag a controller holds is tested against its set-point",
        markup=False,
    )
    for test, row in (build.get("tests") or {}).items():
        errs = list(row.get("rmse_pct", []))
        cov = list(row.get("coverage", []))
        steps = [f"{errs[0]:.2f} % with no input" if errs else "?"]
        for i, inp in enumerate(row.get("inputs", [])):
            e = f"{errs[i + 1]:.2f} %" if i + 1 < len(errs) else "?"
            c = f", coverage {cov[i]:.0%}" if i < len(cov) else ""
            steps.append(f"+ {inp} → {e}{c}")
        same = row.get("same_as")
        loop = ""
        if row.get("tracks"):
            out = f" (output {row['actuator']})" if row.get("actuator") else ""
            loop = (
                f"held at {row['tracks']} by its controller{out}, tested as the loop holds it "
                f"({row.get('method')}): "
            )
        con.print(
            f"  {test} ({row.get('tag')}): "
            + loop
            + "; ".join(steps)
            + (f"; never from {', '.join(same)} (the same measurement)" if same else ""),
            markup=False,
        )
    for tag, why in (build.get("skipped") or {}).items():
        con.print(f"  not tested: {tag}: {why}", markup=False)


def _frames(args, unit, start, end, chunk="7D"):
    """Consecutive aligned pieces of the unit's tags from the historian."""
    import pandas as pd

    from historian.store import Historian

    h = Historian.open(args.db)
    try:
        known = set(h.tags()["name"])
        missing = [t for t in unit.tags if t not in known]
        if missing:
            raise UserError(f"unit {unit.name}: tag(s) {', '.join(missing)} not in the historian")
        a, b = h.time_range(unit.tags)
        if a is None:
            raise UserError(f"no samples of {', '.join(unit.tags)} in the historian")
        t0 = start if start is not None else a
        t1 = end if end is not None else b + pd.Timedelta(unit.period)
        if t1 <= t0:
            raise UserError(f"--to {t1} is not after --from {t0}")
        for frame in h.iter_windows(unit.tags, t0, t1, unit.period, chunk=chunk):
            frame.attrs = {}  # the quality summary is not read here; pandas would copy it
            yield frame  # into every derived frame
    finally:
        h.close()


def _prefetch(items):
    """Yield from ``items`` while a thread already reads the next one (the historian read
    releases the GIL, so reading and evaluating overlap)."""
    from concurrent.futures import ThreadPoolExecutor

    it = iter(items)
    with ThreadPoolExecutor(1) as ex:
        nxt = ex.submit(next, it, None)
        while True:
            item = nxt.result()
            if item is None:
                return
            nxt = ex.submit(next, it, None)
            yield item


def cmd_unit_learn(args) -> int:
    from diag_plugin.diagnose.learning import (
        DEFAULT_BLOCKS,
        DEFAULT_FAR,
        WHY,
        LearnError,
        learn_thresholds,
    )
    from diag_plugin.diagnose.unitfile import UnitFile

    unit = _load_unit(args, args.name)
    far = DEFAULT_FAR if args.far is None else args.far
    blocks = DEFAULT_BLOCKS if args.blocks is None else args.blocks
    if not far > 0:
        raise UserError(f"--far {far:g}: the budget must be a positive rate per hour")
    t0, t1 = _ts(args.start), _ts(args.end)
    frames = list(_frames(args, unit, t0, t1))
    cross = {"auto": None, "yes": True, "no": False}[args.cross_fit]
    try:
        got = learn_thresholds(unit, frames, far=far, blocks=blocks, cross_fit=cross)
    except LearnError as exc:
        raise UserError(f"unit {unit.name}: cannot learn thresholds:\n" + "\n".join(
            "  " + p for p in exc.problems
        )) from None  # fmt: skip
    uf = UnitFile.load(unit.file.path)
    uf.set_learned(got)
    uf.save()
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
    c = got.combined
    if c is not None and c.high is not None:
        print(
            f"  combined test (T²): {c.high:.4g}; expected {c.notes['far']:.2g} false alarms/h "
            f"({c.notes['method']}; its share of the budget, the tests the rest)"
        )
    for w in got.warnings:
        print(f"  note: {w}")
    return 0


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


def cmd_unit_build(args) -> int:
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

    from diag_plugin.diagnose.unitbuild import build_from_historian

    tags = args.tags or (_tags_from(args.tags_from) if args.tags_from else None)
    if args.max_inputs < 1:
        raise UserError(f"--max-inputs {args.max_inputs}: at least 1")
    t0, t1 = _ts(args.start), _ts(args.end)
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

        res = build_from_historian(
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
        )
    if args.json:
        print(json.dumps(res.as_dict(), indent=2))
        return 0
    print(
        f"wrote {res.path}: {len(res.tests)} tests from {res.window[0]} … {res.window[1]} "
        f"(period {res.period}), thresholds to {res.far:g} false alarms per hour"
        + (" (the default)" if args.far is None else "")
    )
    for ch in res.tests:
        errs = " → ".join(
            f"{x:.2f}" for x in [ch.baseline_rmse_pct, *(s.rmse_pct for s in ch.steps)]
        )
        loop = f" (its control loop, {ch.method}; actuator {ch.actuator})" if ch.tracks else ""
        print(
            f"  {ch.test}: {ch.tag} = f({', '.join(ch.inputs)}){loop}; held-out error {errs} % "
            "of span"
        )
    for tag, why in res.skipped.items():
        print(f"  not tested: {tag}: {why}")
    for n in res.notes[:4]:
        print(f"  note: {n}")
    if len(res.notes) > 4:
        print(f"  … {len(res.notes) - 4} more notes of the same kind (--json lists them all)")
    print("  time: " + ", ".join(f"{k} {v:.1f} s" for k, v in res.seconds.items()))
    print(f"next: diag unit show {args.name}; diag diagnose {args.name} --from … --to …")
    return 0


def cmd_diagnose(args) -> int:
    import pandas as pd

    from diag_plugin.diagnose.unit import concat

    unit = _load_unit(args, args.name)
    try:
        chunk = pd.Timedelta(args.chunk)
    except ValueError:
        raise UserError(f"--chunk {args.chunk!r} is not a duration like 7D") from None
    frames = _prefetch(_frames(args, unit, _ts(args.start), _ts(args.end), chunk))
    parts = [unit.evaluate(f) for f in frames]
    parts = [p for p in parts if len(p)]
    if not parts:
        raise UserError("no data in the window")
    d = concat(parts)
    if args.csv:
        write_csv(d, args.csv)
    iv = d.intervals()
    summary = {
        "unit": unit.name,
        "from": d.status.index[0].isoformat(),
        "samples": len(d),
        "message": d.message,
        "status_share": {
            _name(k): round(float(v), 6) for k, v in d.status.value_counts(normalize=True).items()
        },
        "detected_share": _share(d.detected),
        "intervals": [
            {**r, "from": r["from"].isoformat(), "to": r["to"].isoformat()}
            for r in iv.to_dict("records")
        ],
    }
    if args.json:
        print(json.dumps(summary, indent=2))
        return 0
    _print_timeline(unit, d, iv, args.csv)
    return 0


def _name(s: int) -> str:
    from diag_plugin.diagnose.status import NE107

    return NE107(int(s)).name


def _share(s) -> float | None:
    import numpy as np

    v = s.to_numpy()
    k = np.isfinite(v)
    return None if not k.any() else round(float(v[k].mean()), 6)


def write_csv(d, path: str) -> None:
    """One row per sample: ts, status (NE 107), r_<test>, s_<test>, c_<fault>, detected
    (1/0, empty when unknown), quality, faults; with a combined test or isolation to tags also
    T2 (the combined statistic), s_T2 (its symptom) and top1, share1, … top3, share3 (the
    tags that explain an alarm, their share of T²)."""
    frame = d.to_frame()
    frame["detected"] = frame["detected"].map(lambda v: "" if v != v else str(int(v)))
    frame.to_csv(path, float_format="%.6g", date_format="%Y-%m-%dT%H:%M:%S%z")


def _print_timeline(unit, d, iv, csv) -> None:
    from rich.console import Console
    from rich.table import Table

    con = Console()
    con.print(
        f"unit {unit.name}: {len(d):,} samples {d.status.index[0]:%Y-%m-%d %H:%M} … "
        f"{d.status.index[-1]:%Y-%m-%d %H:%M}",
        markup=False,
    )
    if d.message:
        con.print(d.message, markup=False)
    t = Table(title="timeline")
    for c in ("from", "to", "status", "faults", "tests with symptoms", "samples"):
        t.add_column(c)
    shown = iv if len(iv) <= 60 else iv[iv["status"] != "NORMAL"].head(60)
    for r in shown.to_dict("records"):
        t.add_row(
            f"{r['from']:%Y-%m-%d %H:%M:%S}",
            f"{r['to']:%Y-%m-%d %H:%M:%S}",
            r["status"],
            r["faults"].replace("|", ", ") or "—",
            r["tests"] or "—",
            f"{r['samples']:,}",
        )
    con.print(t)
    if len(shown) < len(iv):
        con.print(f"({len(iv) - len(shown)} more intervals; --json or --csv for all)")
    if csv:
        con.print(f"wrote {csv}")


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

    from diag_plugin.diagnose.benchmark import run_benchmark

    if args.plant and (args.match_far or args.plant != "chemplant"):
        return cmd_matched_benchmark(args)
    if args.plant:
        return cmd_plant_benchmark(args)
    unit = _load_unit(args, args.unit)
    if not unit.has_thresholds:
        raise UserError(f"unit {unit.name} has no thresholds: run diag unit learn first")
    seeds = tuple(args.seeds or (11,))
    con = Console(stderr=True)
    with Progress(console=con, transient=True, disable=args.json or not con.is_terminal) as pr:
        n = (38 if args.quick else 76) * len(seeds)
        task = pr.add_task("scenarios", total=n)
        out = run_benchmark(
            unit,
            quick=args.quick,
            seeds=seeds,
            progress=lambda sc: pr.update(task, advance=1, description=f"{sc.fault} {sc.mode}"),
        )
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
    return 0


def _dur(s: float | None) -> str:
    if s is None:
        return "—"
    return f"{s / 3600:.1f} h" if s >= 3600 else f"{s / 60:.0f} min" if s >= 60 else f"{s:.0f} s"


def cmd_matched_benchmark(args) -> int:
    """``diag benchmark --plant P --match-far``: the unit, PCA and DPCA at matched false-alarm
    rates (:func:`~diag_plugin.diagnose.publicbench.run_matched_benchmark`), the result page
    written."""
    from rich.console import Console
    from rich.progress import Progress

    from diag_plugin.diagnose import publicplants as pp
    from diag_plugin.diagnose.publicbench import chemplant_plant, run_matched_benchmark, write_page

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
    argv = sys.argv[1:]
    command = "diag " + " ".join(argv[argv.index("benchmark") :] if "benchmark" in argv else argv)
    page = args.page or (f"docs/results/{plant.name}.md" if Path("docs/results").is_dir() else None)
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
            parts.append(f"{m} {x['mean_detection']:.0%} (top 3 {x['in_top']}/"
                         f"{x['named_runs']}, false alarms {fa})")  # fmt: skip
        print(f"at {p['target']:g} {out['per']}: " + "; ".join(parts))
    if page:
        print(f"page: {out['page']}")
    return 0


def cmd_plant_benchmark(args) -> int:
    """``diag benchmark --plant chemplant``: build a unit on fault-free runs, score it beside
    PCA and DPCA held to the same budget (:func:`~diag_plugin.diagnose.plantbench.
    run_plant_benchmark`)."""
    from rich.console import Console
    from rich.progress import Progress
    from rich.table import Table

    from diag_plugin.diagnose.plantbench import run_plant_benchmark

    if args.period < 1:
        raise UserError(f"--period {args.period}: a whole number of seconds ≥ 1")
    if args.far is not None and not args.far > 0:
        raise UserError(f"--far {args.far:g}: the budget must be a positive rate per hour")
    con = Console(stderr=True)
    with Progress(console=con, transient=True, disable=args.json or not con.is_terminal) as pr:
        task = pr.add_task("simulate", total=None)

        def tick(stage: str, done: int, total: int) -> None:
            pr.update(task, description=stage, completed=done, total=total)

        try:
            out = run_plant_benchmark(
                args.plant,
                period_s=args.period,
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
