"""``diag unit new|check|show`` and ``diag diagnose``: units on historian data.

Only argparse is imported at start-up; each command imports what it needs when it runs.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
from pathlib import Path

from diag_plugin.cliargs import add_json, table_console
from historian.errors import UserError

#: values (samples × tags) ``diag diagnose`` reads per piece by default, when that is more
#: than 7 days: 200,000 rows of a 46-tag unit at 180 s in 5 pieces instead of 60 (the read
#: 2.7 → 1.8 CPU s, the replay 2.0 → 1.4 s; one piece of all rows was no faster)
CHUNK_VALUES = 2_000_000


def add_commands(sub: argparse._SubParsersAction) -> None:
    usub = unit_actions(sub)
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
    add_json(p)
    p.set_defaults(func=cmd_unit_new)
    for action, arg, text, func in (
        ("check", "file", "check a unit file, its models and matrix (file:line)", cmd_unit_check),
        ("show", "name", "tests, thresholds, matrix and its isolability", cmd_unit_show),
    ):
        p = usub.add_parser(action, help=text)
        p.add_argument(arg)
        add_json(p)
        p.set_defaults(func=func)

    p = sub.add_parser("diagnose", help="replay historian data through a unit")
    p.add_argument("name")
    p.add_argument("--from", dest="start", metavar="T0")
    p.add_argument("--to", dest="end", metavar="T1")
    p.add_argument("--csv", metavar="FILE", help="one row per sample (ts, status, r_*, s_*, c_*)")
    p.add_argument(
        "--chunk",
        default=None,
        help="data read per step (default: 7 days, or more at a short period or few tags: "
        f"{CHUNK_VALUES:,} samples over the unit's tags, about {CHUNK_VALUES * 8 >> 20} MB)",
    )
    add_json(p)
    p.set_defaults(func=cmd_diagnose)


def unit_actions(sub: argparse._SubParsersAction) -> argparse._SubParsersAction:
    """The actions of ``diag unit``, made here if not yet there: this package adds ``new``,
    ``check`` and ``show``; :mod:`diag_plugin.learn.cli` and :mod:`diag_plugin.unitbuild.cli`
    add ``learn`` and ``build``."""
    if "unit" not in sub.choices:
        unit = sub.add_parser("unit", help="create, check, show a unit or learn its thresholds")
        unit.add_subparsers(dest="unit_command", metavar="ACTION", required=True)
    actions = sub.choices["unit"]._actions
    return next(a for a in actions if isinstance(a, argparse._SubParsersAction))


def load_unit(args, name: str, cached: bool = False):
    """The unit ``name`` of ``args.rulebases``; ``cached``: its tests' models through the
    cache of models read before (:mod:`~diag_plugin.diagnose.modelcache`, ``diag diagnose``;
    ``$DIAG_MODEL_CACHE=off`` turns it off)."""
    from diag_plugin.diagnose.modelcache import ModelCache
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.diagnose.unitfile import UnitError

    path = unit_file_of(args, name)
    try:
        return Unit.load(path, args.rulebases, store=ModelCache.default() if cached else None)
    except UnitError as exc:
        raise UserError("unit file has problems:\n" + "\n".join(exc.problems)) from None


def unit_file_of(args, name: str) -> Path:
    """The file of the unit ``name``: in ``args.rulebases``, else shipped with the plug-in."""
    from diag_plugin.rulebase.folder import UNIT_SUFFIX, unit_path

    path = unit_path(name, args.rulebases)
    if not path.exists():
        from diag_plugin.rulebase.folder import find_shipped

        path = find_shipped(name, UNIT_SUFFIX) or path
    if not path.exists():
        raise UserError(f"no unit file {path} (make one with `diag unit new`)")
    return path


def parse_time(text: str | None):
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
    from diag_plugin.diagnose.unitfile import new_unit_text
    from diag_plugin.rulebase.document import resolve
    from diag_plugin.rulebase.folder import UNIT_SUFFIX

    folder = Path(args.rulebases)
    path = folder / f"{args.name}{UNIT_SUFFIX}"
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
    from diag_plugin.diagnose.equipment import output_tag, owner
    from diag_plugin.diagnose.leadin import LEAD_CAP, lead_in, lead_in_parts

    f = unit.file
    pieces = getattr(f, "equipment", None) or []
    tests = []
    for t in f.tests:
        m = unit.models[t.name]
        lim = t.limits
        # a piece's test: its unknown share counts the rows where the piece was stopped
        piece = owner(pieces, output_tag(m.output))
        stopped = (
            None
            if piece is None or piece.rc.share is None
            else {
                "piece": piece.name,
                "tag": piece.rc.tag,
                "stop": piece.rc.stop,
                "share": 1.0 - piece.rc.share,
            }
        )
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
                "statistic": t.statistic,
                "actuator": t.actuator,
                "set_point": t.set_point,
                "residual_unit": residual_unit(t.spread, f.evaluation.get("scale", "span")),
                "learned": f.learned.get(t.name, {}),
                "stopped": stopped,
            }
        )
    out = {
        "unit": unit.name,
        "file": str(f.path),
        "description": f.description,
        "outputs": f.outputs,
        "period": unit.period,
        "tags": unit.tags,
        "evaluation": unit.ev,  # delays in seconds resolved to samples at the period
        "thresholds": f.thresholds,
        "tests": tests,
        "build": getattr(f, "build", {}) or {},
        "matrix": None,
        "combined": _combined_summary(unit),
        "lead_in": {**lead_in_parts(unit), "samples": lead_in(unit), "cap": LEAD_CAP},
        # the pieces of equipment (``[equipment]``) and the tests off while each is stopped
        "equipment": [
            {"name": e.name, **e.as_table(), "tests": [unit.tests[j] for j in cols]}
            for e, cols in zip(unit.equipment, unit.equipment_tests, strict=True)
        ],
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


def residual_unit(spread: bool, scale: str = "span") -> str:
    """What a test's residual and thresholds are measured in (issue 37): % of the output's
    span (eq. 6) or of its maximum, and for a ``spread = true`` test that divided by the
    answering rules' spread relative to the model's typical one — % of span at the model's
    typical spread, not % of span."""
    base = "% of max" if scale == "max" else "% of span"
    return f"{base} ÷ local spread (× typical)" if spread else base


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
    unit = load_unit(args, args.name)
    s = unit_summary(unit)
    if args.json:
        print(json.dumps(s, indent=2, default=str))
        return 0
    from rich.table import Table

    con = table_console()
    con.print(f"unit {s['unit']} ({s['file']}): {s['description']}", markup=False)
    ev = s["evaluation"]
    con.print(
        f"period {s['period']}; low-pass {ev['lowpass'] or 'off'} (order {ev['order']}); "
        f"{ev['symptoms']} symptoms, on/off delay {ev['on_delay']}/{ev['off_delay']} samples"
        + (
            f" ({ev['on_delay_s']:g}/{ev['off_delay_s']:g} s; the unit's own off-delay too)"
            if ev.get("off_delay_s")
            else ""
        )
        + (f"; deadband {ev['deadband']:.0%} of the threshold" if ev.get("deadband") else "")
        + (
            f"; a test swung there and back within 2 x {ev['oscillation_window_s']:g} s stays"
            f" on until a side is quiet for {ev['oscillation_window_s']:g} s"
            if ev.get("oscillation_window_s")
            else ""
        )
        + ("; latched" if ev["latch"] else "")
        + ("" if ev.get("hold_isolation", True) else "; isolated afresh each sample"),
        markup=False,
    )
    t = Table(title="tests (low and high in the residual's unit, per test)")
    cols = ("test", "model", "output = f(inputs)", "low", "high", "unit", "false alarms/h")
    # a piece of equipment's tests: the share its piece was stopped, off (not unknown)
    off = any("off" in r["learned"] for r in s["tests"])
    for c in (*cols, "unknown", *(["off (piece stopped)"] if off else [])):
        t.add_column(c)
    for r in s["tests"]:
        n = r["learned"]
        t.add_row(
            r["test"],
            r["model"],
            f"{r['output']} = f({', '.join(r['inputs'])})",
            "—" if r["low"] is None else f"{r['low']:.3g}",
            "—" if r["high"] is None else f"{r['high']:.3g}",
            r["residual_unit"],
            "—" if "far" not in n else f"{n['far']:.2g} ({n.get('method', '?')})",
            "—" if "unknown" not in n else f"{n['unknown']:.1%}",
            *([] if not off else ["—" if "off" not in n else f"{n['off']:.1%}"]),
        )
    con.print(t)
    for e in s["equipment"]:
        con.print(
            f"equipment {e['name']}: runs while {e['tag']} = {e['run']:g}"
            + (f" ({e['share']:.1%} of the build window)" if e.get("share") is not None else "")
            + f"; tests {', '.join(e['tests']) or 'none'} off while it is stopped or settling "
            "after a start (counted as off, not unknown)",
            markup=False,
        )
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
    lead = s["lead_in"]
    why = ", ".join(f"{k} {lead[k]}" for k in ("lags", "spread", "filter", "delays") if lead[k])
    con.print(
        f"diag diagnose --from T0 first reads {lead['samples']:,} samples before T0 "
        f"({why or 'none needed'}; at most {lead['cap']})",
        markup=False,
    )
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
    from diag_plugin.diagnose.unitfile import WHY, hours

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
        st = r.get("stopped")
        if why and st and st["share"] > 0 and "off" not in n:  # learned before "off" was kept
            why.append(
                f"{st['piece']} stopped ({st['tag']} = {st['stop']:g}) on {st['share']:.1%} "
                "of the window, counted as missing: its tests learn and judge only while it runs"
            )
        if why:
            parts.append("unknown: " + "; ".join(why))
        if "off" in n:
            parts.append(
                f"off: {n.get('off_equipment', 'its piece of equipment')} stopped "
                f"{n['off']:.1%} (its tests off, not unknown)"
            )
        if len(r["levels"]) > 1:
            parts.append(
                "coarser rule levels scaled ×" + ", ×".join(f"{x:.2g}" for x in r["levels"][1:])
            )
        if r["spread"]:
            parts.append(
                "residual and thresholds in % of span divided by the local spread relative "
                "to the model's typical spread (not % of span)"
            )
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
    for reason in build.get("plan") or []:
        con.print(f"  window: {reason}", markup=False)
    for test, row in (build.get("tests") or {}).items():
        errs = list(row.get("rmse_pct", []))
        cov = list(row.get("coverage", []))
        steps = [f"{errs[0]:.2f} % with no input" if errs else "?"]
        for i, inp in enumerate(row.get("inputs", [])):
            e = f"{errs[i + 1]:.2f} %" if i + 1 < len(errs) else "?"
            c = f", coverage {cov[i]:.0%}" if i < len(cov) else ""
            steps.append(f"+ {inp} → {e}{c}")
        if row.get("method") == "joint":  # a group's common direction: no inputs chosen
            steps = [f"{errs[0]:.2f} % of span the group's first tag alone"] if errs else []
        same = row.get("same_as")
        loop = ""
        if row.get("tracks"):
            out = f" (output {row['actuator']})" if row.get("actuator") else ""
            loop = (
                f"held at {row['tracks']} by its controller{out}, tested as the loop holds it "
                f"({row.get('method')}): "
            )
        if row.get("why") and not row.get("tracks"):
            loop = f"{row.get('method', 'wm-avg')} ({row['why']}): "
        con.print(
            f"  {test} ({row.get('tag')}): "
            + loop
            + "; ".join(steps)
            + (f"; never from {', '.join(same)} (the same measurement)" if same else ""),
            markup=False,
        )
    for tag, why in (build.get("skipped") or {}).items():
        con.print(f"  not tested: {tag}: {why}", markup=False)


def unit_frames(args, unit, start, end, chunk="7D", lead: int = 0, bounds=None):
    """Consecutive aligned pieces of the unit's tags from the historian; with ``lead`` and a
    ``start``, from ``lead`` samples before it where the historian has them (the rows before
    ``start`` are the caller's to drop, :func:`~diag_plugin.diagnose.leadin.since`). The
    window's end is noted in ``bounds["end"]`` when given (a dict)."""
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
        judged = max(t0, a)  # the first time judged (not the lead-in before it)
        if start is not None and lead > 0:  # not before the record: there it starts cold
            t0 = min(t0, max(a, t0 - lead * pd.Timedelta(unit.period)))
        if bounds is not None:
            bounds["end"] = t1
        # no quality summary: diagnose does not read it (it cost a quarter of the read's CPU,
        # 50 tags × 200,000 rows: 3.9 → 3.0 s), and in attrs pandas would copy it into every
        # derived frame
        pieces = (
            f
            for a, b in ramped(t0, t1, unit.period, chunk)
            for f in h.iter_windows(unit.tags, a, b, unit.period, chunk=chunk, summary=False)
        )
        pieces = lead_from_data(pieces, start) if start is not None and lead > 0 else pieces
        for k, f in enumerate(pieces):
            yield f
            if k == 0 and bounds is not None:  # after the first piece: not on its way
                bounds["coarser"] = coarser_data(h, unit, judged, t1)
    finally:
        h.close()


#: the unit's periods of the window's start over which :func:`coarser_data` measures how
#: often the data come (a bounded read: 7 tags × 2,000 rows at most)
SAMPLING_PERIODS = 2000


def coarser_data(h, unit, t0, t1) -> str:
    """A warning when the unit's tags come at a coarser period than the unit's (``""``
    otherwise): the typical (median) spacing of the regularly sampled tags, measured over the
    first :data:`SAMPLING_PERIODS` of the unit's periods from ``t0``, above
    :data:`~historian.sampling.HOLD_WHEN` × the period. The window's reader holds each sample
    over the grid points up to the next (:func:`historian.sampling.hold_us`), so the unit
    replays steps, not the process; data at a finer period are averaged onto its grid, as at
    the build (nothing to say)."""
    import numpy as np
    import pandas as pd

    from historian.sampling import HOLD_WHEN, format_period, nice_period_us
    from historian.times import period_us

    p = period_us(unit.period)
    end = min(t1, t0 + pd.Timedelta(SAMPLING_PERIODS * p, "us"))
    got = [s for s in h.sampling(unit.tags, t0, end).values() if s.regular]
    if not got:
        return ""
    typical = float(np.median([s.median_us for s in got]))
    if typical <= HOLD_WHEN * p:
        return ""
    data = format_period(nice_period_us(typical))
    slow = [s.tag for s in got if s.median_us > HOLD_WHEN * p]
    shown = ", ".join(slow[:4]) + (f" and {len(slow) - 4} more" if len(slow) > 4 else "")
    return (
        f"the data come every {data} ({shown}, from {t0}), the unit {unit.name} every "
        f"{unit.period}: each sample is held over ~{round(typical / p)} of the unit's periods, "
        "so its lags, filter and delays read steps, not the process (its tests judged at "
        f"a rate they did not learn); build a unit at the data's rate (diag unit build NAME "
        f"--period {data} …) or give the data every {unit.period}"
    )


def lead_from_data(pieces, start):
    """``pieces`` from the lead-in's first row holding a sample on: the leading rows before
    ``start`` without any sample are dropped (the lead-in began in a gap of the historian:
    nothing was recorded there, so the unit starts cold at the first sample, as a replay of
    the same rows through the Python API does; replayed, those empty rows had left the spread
    test's window and the filter otherwise, the line's off-grid replay, 2026-12-03)."""
    import numpy as np

    trimming = True
    for f in pieces:
        if trimming:
            keep = np.flatnonzero(f.notna().to_numpy().any(axis=1) | (f.index >= start))
            if not keep.size:
                continue
            f = f.iloc[keep[0] :]
            trimming = False
        yield f


#: the first and the last piece of a long window are this fraction of a piece (:func:`ramped`)
RAMP = 8


def ramped(t0, t1, period: str, chunk) -> list:
    """The parts of [t0, t1) read piece by piece: where it is at least two pieces of ``chunk``
    long, its first and last ``chunk / RAMP`` (whole periods) apart. The replay waits for
    the first piece's read, and the last's replay (and CSV) follows all reads: a smaller
    piece at either end is less time with one core idle (200,000 rows of the bench's unit,
    5 pieces: ~0.3 s of an idle ~2.1 s run); the pieces between are as many as before, the
    rows the same (the grid of ``t0``, each edge one of its points)."""
    from historian.sampling import snap_up
    from historian.times import from_us, period_us, to_us

    p = period_us(period)
    g0, e = snap_up(to_us(t0), p), to_us(t1)
    step = max(1, period_us(chunk) // p)  # rows per piece, as Historian.iter_windows
    rows = max(0, -(-(e - g0) // p))
    small = step // RAMP
    if small < 1 or rows < 2 * step:
        return [(t0, t1)]
    a, b = from_us(g0 + small * p), from_us(g0 + (rows - small) * p)
    return [(t0, a), (a, b), (b, t1)]


def default_chunk(period: str, tags: int):
    """The default piece of ``diag diagnose``: 7 days, or :data:`CHUNK_VALUES` samples over
    ``tags`` tags when that is longer (fewer, larger reads and replays; the state is carried
    between pieces, and the JSON and CSV were the same bytes as with 7-day pieces:
    tests/test_diagnose_output.py)."""
    import pandas as pd

    week = pd.Timedelta("7D")
    return max(week, pd.Timedelta(period) * (CHUNK_VALUES // max(1, tags)))


def cmd_diagnose(args) -> int:
    if args.csv and not Path(args.csv).parent.is_dir():
        # refused before the replay, whose result would be lost at the write (as it was)
        raise UserError(f"--csv {args.csv}: no folder {Path(args.csv).parent}")
    if args.csv and Path(args.csv).is_dir():
        raise UserError(f"--csv {args.csv}: a folder; name the file to write")
    with contextlib.ExitStack() as stack:
        with _start_up():  # the imports and the unit's objects: no collections, then frozen
            from diag_plugin.diagnose.pertest import cores
            from diag_plugin.diagnose.readahead import ReadAhead, numba_ready
            from diag_plugin.diagnose.readplan import Plan, plan_file, remember, remembered
            from historian.store import Historian  # noqa: F401 - here, not in the reading thread

            # what the last run of this unit file read, read again from now on, before the
            # unit's modules are imported and the unit is loaded (readplan: a guess, checked
            # against the loaded unit below)
            kept = plan_file(unit_file_of(args, args.name))
            guess, early, early_bounds = remembered(kept), None, {}
            if guess is not None:
                with contextlib.suppress(UserError):  # said below, after the unit's load
                    pieces = _pieces(args, guess, early_bounds)
                    early = stack.enter_context(ReadAhead(pieces, READ_AHEAD))
            unit = load_unit(args, args.name, cached=True)
            unit.workers = cores()  # a piece's tests on every core (pertest: the same bits)
            chunk = _chunk(args, unit)
            start = parse_time(args.start)
            plan = Plan.of(unit)
            if early is not None and plan == guess:
                frames, bounds = early, early_bounds
            else:  # none kept, or the unit reads otherwise now: read what it reads
                if early is not None:
                    early.close()
                bounds = {}  # the window unit_frames read (its end where --to is not given)
                # the history before --from its lags, filter and delays need (lead_in),
                # evaluated, not shown; the first piece read from here on, while the rest of
                # the start-up runs
                frames = stack.enter_context(ReadAhead(_pieces(args, plan, bounds), READ_AHEAD))
                remember(kept, plan)
            # scipy.linalg and scipy.special: what the first piece's replay imports, here with
            # the collector off (scipy.stats imported both with the unit's modules before):
            # numba's first dispatch imports scipy.linalg (its BLAS check), the combined
            # test's χ² levels scipy.special; after the freeze they made one full collection
            # (tests/test_diagnose_output.py); then numba's registries, which the first
            # piece's replay loaded (issue 34: ~0.2 CPU s moved beside the first read)
            import scipy.linalg  # noqa: F401
            import scipy.special  # noqa: F401

            numba_ready()
        return _diagnose(args, unit, frames, start, bounds, chunk)


#: pieces read ahead of the replay (:class:`~diag_plugin.diagnose.readahead.ReadAhead`):
#: three, so that the read goes on beside the whole start-up once it starts before the
#: unit's load (~46 tags × 41,680 rows, 15 MB a piece)
READ_AHEAD = 3


def _pieces(args, plan, bounds: dict):
    """:func:`unit_frames` of a unit's :class:`~diag_plugin.diagnose.readplan.Plan` (its
    tags, period and lead-in) over ``--from`` … ``--to`` in pieces of ``--chunk``."""
    start, end = parse_time(args.start), parse_time(args.end)
    return unit_frames(args, plan, start, end, _chunk(args, plan), plan.lead, bounds)


def _chunk(args, unit):
    """``--chunk``, or :func:`default_chunk` of the unit (or its plan)."""
    import pandas as pd

    if args.chunk is None:
        return default_chunk(unit.period, len(unit.tags))
    try:
        return pd.Timedelta(args.chunk)
    except ValueError:
        raise UserError(f"--chunk {args.chunk!r} is not a duration like 7D") from None


def _diagnose(args, unit, frames, start, bounds: dict, chunk) -> int:
    """:func:`cmd_diagnose` once started: each piece of ``frames`` replayed, its summary
    kept (and its CSV rows written), then the JSON or the timeline."""
    from diag_plugin.diagnose.leadin import since
    from diag_plugin.diagnose.unit import concat

    # the CSV written piece by piece in a thread of its own while the next pieces are replayed
    # (CsvPieces); the pieces kept whole and joined only where it cannot write the file
    stream = CsvPieces(args.csv) if args.csv and CsvPieces.can_write(args.csv) else None
    full: list | None = [] if args.csv and stream is None else None
    try:
        with _one_blas_thread():  # the combined test's small inverses: no thread per core
            # each piece is cut to what the summary reads as soon as it is made: the pieces'
            # residuals and certainties were all held until the end (1,000,000 rows of the
            # bench's 45 tests: peak RSS 2.9 → 1.9 GB without a CSV, most of the rest the
            # database file's pages read through SQLite's memory map; 16.2 → 13.4 CPU s)
            parts = []
            for f in frames:
                p = since(unit.evaluate(f), start)
                if not len(p):
                    continue
                parts.append(_summary_part(p))
                if full is not None:
                    full.append(p)
                if stream is not None:
                    stream.add(p)
                del p
        if not parts:
            raise UserError("no data in the window")
        if bounds.get("coarser"):
            print(f"⚠ {bounds['coarser']}", file=sys.stderr)
        if stream is not None and not stream.close():
            full = _replayed(args, start, bounds["end"], chunk)  # pieces unlike each other
        if full is not None:
            write_csv(concat(full), args.csv)
    finally:
        if stream is not None:
            stream.abort()
    del full
    d = concat(parts)
    iv = d.intervals()
    if args.json:
        from diag_plugin.diagnose.summaryjson import summary_text

        summary = {
            "unit": unit.name,
            "from": d.status.index[0].isoformat(),
            "samples": len(d),
            "message": d.message,
            "status_share": {
                _name(k): round(float(v), 6)
                for k, v in d.status.value_counts(normalize=True).items()
            },
            "detected_share": _share(d.detected),
        }
        if d.equipment is not None:  # a stopped piece's samples: off, counted on their own
            summary["equipment_off"] = equipment_off(d)
        print(summary_text(summary, "intervals", iv))  # the intervals by column (issue 34)
        return 0
    _print_timeline(unit, d, iv, args.csv)
    return 0


def equipment_off(d) -> dict[str, dict[str, float]]:
    """Per piece of equipment (``Diagnosis.equipment``) the samples its tests were off: it
    stopped, and settling after its starts — neither unknown nor CHECK_FUNCTION (the unit
    judged by its other tests there)."""
    from diag_plugin.diagnose.equipment import SETTLING, STOPPED

    n = max(len(d.equipment), 1)
    out = {}
    for name in d.equipment.columns:
        x = d.equipment[name].to_numpy()
        stopped, settling = int((x == STOPPED).sum()), int((x == SETTLING).sum())
        out[str(name)] = {
            "stopped": stopped,
            "stopped_share": round(stopped / n, 6),
            "settling": settling,
            "settling_share": round(settling / n, 6),
        }
    return out


def _replayed(args, start, end, chunk) -> list:
    """The whole pieces of the window replayed once more by the unit loaded afresh: for a CSV
    :class:`CsvPieces` could not write piece by piece (its pieces' columns differ in kind),
    which the pieces' concatenation gives (never seen in a replay: each piece has the unit's
    columns, of the same kinds)."""
    from diag_plugin.diagnose.leadin import lead_in, since
    from diag_plugin.diagnose.pertest import cores

    unit = load_unit(args, args.name, cached=True)
    unit.workers = cores()
    with _one_blas_thread():
        frames = unit_frames(args, unit, start, end, chunk, lead_in(unit))
        return [p for f in frames if len(p := since(unit.evaluate(f), start))]


@contextlib.contextmanager
def _start_up():
    """No garbage collection while ``diag diagnose`` imports its libraries and loads the
    unit, and what they made moved out of the collector's sight after (:func:`gc.freeze`):
    they live as long as the process. The collector traversed them again in every full
    collection: 0.3–0.5 CPU s of each run (4 full and ~50 middle collections during the
    imports, the unit's load and numba's first dispatch, issue 34), nothing of which
    was garbage to free, and the interpreter's exit ~0.3 s more. Collections of the objects
    made later run as before. (A process that calls the command and lives on, a test run,
    keeps what was frozen, cyclic garbage of the start-up too: a command's process ends.)"""
    import gc

    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        if enabled:
            gc.enable()


def _summary_part(d):
    """A piece's diagnosis with what the summary and the timeline read (status, faults, why,
    symptoms, the combined test, detected): without a CSV the residuals, certainties and
    tags are not joined over the pieces (3 frames of 200,000 × 45 floats, issue 34), and of
    the symptoms only their signs, one byte each (:meth:`~diag_plugin.diagnose.unit.
    Diagnosis.intervals` reads whether a test has one: not 0, not unknown; unknown is 0 here):
    the join of 200,000 × 45 floats was ~0.1 CPU s and 72 MB."""
    import dataclasses

    import numpy as np
    import pandas as pd

    x = d.symptoms.to_numpy()
    signs = (x > 0).view(np.int8) - (x < 0).view(np.int8)
    return dataclasses.replace(
        d,
        residuals=d.residuals.iloc[:, :0],
        symptoms=pd.DataFrame(signs, index=d.symptoms.index, columns=d.symptoms.columns),
        certainties=d.certainties.iloc[:, :0],
        top=None,
        _contributions=None,
    )


def _one_blas_thread():
    """BLAS held to one thread while a replay runs (a 45 × 45 inverse took 17 ms with a
    thread per core on the loaded 2-core machine); a no-op without threadpoolctl."""
    import contextlib

    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover
        return contextlib.nullcontext()
    return threadpool_limits(1)


def _name(s: int) -> str:
    from diag_plugin.status import NE107

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
    write_frame_csv(csv_frame(d), path)


#: how :func:`write_csv` writes numbers and times (``DataFrame.to_csv``'s arguments)
CSV_FLOAT, CSV_DATE = "%.6g", "%Y-%m-%dT%H:%M:%S%z"


def csv_frame(d):
    """The frame :func:`write_csv` writes of the diagnosis ``d``: :meth:`~diag_plugin.
    diagnose.unit.Diagnosis.to_frame`, ``detected`` as text (1, 0, empty when unknown)."""
    import numpy as np
    import pandas as pd

    frame = d.to_frame()
    # each distinct value's text once ("" unknown), not a call per sample
    codes, uniq = pd.factorize(frame["detected"].to_numpy())  # NaN: -1, the last text
    text = np.array([*(str(int(v)) for v in uniq.tolist()), ""], dtype=object)
    frame["detected"] = pd.Series(text[codes], index=frame.index, dtype="str")
    return frame


def write_frame_csv(frame, path: str) -> None:
    """``frame.to_csv(path, float_format=CSV_FLOAT, date_format=CSV_DATE)``, the same bytes,
    in one compiled pass a block of rows (:mod:`~diag_plugin.diagnose.csvfast`, issue 34:
    pandas formats each float through two Python calls; 1,000,000 rows × ~150 columns took
    ~46 CPU s through ``%`` and the :mod:`csv` writer). Float64 columns are formatted there;
    integer and text columns and the times are tables of their distinct texts. A frame with
    another kind of column or index is written by pandas itself."""
    got = csv_arrays(frame)
    if got is None:
        frame.to_csv(path, float_format=CSV_FLOAT, date_format=CSV_DATE)
        return
    from diag_plugin.diagnose.csvfast import write_rows

    with open(path, "wb") as fh:
        fh.write(csv_head(frame))
        write_rows(fh, *got[:4], os.linesep, CSV_ROWS)


def csv_head(frame) -> bytes:
    """The header line :func:`write_frame_csv` writes of ``frame``."""
    return frame.iloc[:0].to_csv(float_format=CSV_FLOAT, date_format=CSV_DATE).encode("utf-8")


def csv_arrays(frame, spare=None):
    """What :func:`~diag_plugin.diagnose.csvfast.write_rows` writes of ``frame``: the float64
    columns (rows × columns, a column contiguous), the codes of the times and the other
    columns into a :class:`~diag_plugin.diagnose.csvfast.TextTable`, the order of the columns,
    the table, and each column's kind (``f`` float, ``i`` integer, ``t`` text); None where
    pandas writes the frame (another kind of column or index). ``spare``, a list, keeps the
    floats' array for the next call of the same shape (a new one is a page fault per 4 kB:
    ~half the cost of a piece's 47 MB of floats)."""
    from diag_plugin.diagnose.csvfast import G6, TextTable

    index = _csv_times(frame.index)
    cols = [col for _, col in frame.items()]  # each column once (~20 µs a Series)
    if index is None or CSV_FLOAT != G6 or not all(map(_csv_known, cols)):
        return None
    import numpy as np

    kinds = [_csv_kind(col.dtype) for col in cols]
    n, nf = len(frame), kinds.count("f")
    if spare and spare[0].shape == (n, nf):
        floats = spare[0]
    else:
        floats = np.empty((nf, n)).T  # a column's rows together: copied as they are
        if spare is not None:
            spare[:] = [floats]
    codes = np.empty((len(kinds) - nf + 1, n), np.int64).T
    table = TextTable()
    codes[:, 0] = table.add_times(index)
    order = [(1, 0)]
    count = [0, 1]  # float and text columns so far
    for col, kind in zip(cols, kinds, strict=True):
        k = 0 if kind == "f" else 1
        order.append((k, count[k]))
        count[k] += 1
        if k == 0:
            floats[:, order[-1][1]] = col.to_numpy()
        else:
            codes[:, order[-1][1]] = table.add(*_csv_codes(col))
    return floats, codes, order, table, kinds


def _csv_kind(dt) -> str:
    import numpy as np

    if dt == np.float64:
        return "f"
    return "i" if isinstance(dt, np.dtype) and dt.kind in "iu" else "t"


class CsvPieces:
    """:func:`write_csv` of the concatenated pieces of a replay, written piece by piece in a
    thread of its own while the next pieces are replayed (issue 34: the CSV of 1,000,000
    rows was ~9 CPU s on one core after the replay). Each piece's rows are the bytes the
    concatenation's would be where every piece has the same columns of the same kinds (the
    formats are value by value); the one column that may come and go, ``why`` (the last,
    there when some sample has one), is written from the first piece with one on: the rows
    before it then get its empty field (their ends noted while written). Written to
    ``FILE.part`` beside ``FILE``, moved to it when complete; :meth:`close` says False where
    the pieces differ otherwise (then the caller writes the CSV of the pieces joined). The
    pieces are not kept: at most two wait for the writer."""

    def __init__(self, path: str) -> None:
        from concurrent.futures import ThreadPoolExecutor

        self.path = path
        self.part = f"{path}.part"
        self.fh = None
        self.spec: list | None = None  # per column but why: (name, kind) of the first piece
        #: None: no why yet; False: a piece without a why series (so none); True: written
        self.why: bool | None = None
        self.ends: list = []  # while no why is written: each piece's row ends in the file
        self.head = b""
        self.failed = False
        self.spare: list = []  # the floats' array of the last piece, for the next
        self.buffer: list = []  # the bytes' buffer of the last piece, for the next
        self.pool = ThreadPoolExecutor(1, thread_name_prefix="diag-csv")
        self.jobs: list = []

    @staticmethod
    def can_write(path: str) -> bool:
        """A regular file or none yet (not a device, a pipe, …: written as before)."""
        p = Path(path)
        return (p.is_file() or not p.exists()) and p.parent.is_dir()

    def add(self, d) -> None:
        """Write ``d``'s rows next (in the writing thread); waits while two pieces are not
        written yet (at most those held besides the one replayed)."""
        if len(self.jobs) >= 2:
            self.jobs.pop(0).result()
        self.jobs.append(self.pool.submit(self._write, d))

    def close(self) -> bool:
        """The pieces written (a writing error raised here): True where the CSV is complete
        at the path, False where the caller must write it."""
        for job in self.jobs:
            job.result()
        self.pool.shutdown()
        if self.failed or self.fh is None:
            return False
        self.fh.close()
        if Path(self.path).exists():
            import shutil

            shutil.copymode(self.path, self.part)
        os.replace(self.part, self.path)
        self.fh = None
        return True

    def abort(self) -> None:
        """Stop and remove the partial file (nothing where :meth:`close` moved it)."""
        for job in self.jobs:
            job.cancel()
        self.pool.shutdown()
        if self.fh is not None:
            self.fh.close()
            self.fh = None
            Path(self.part).unlink(missing_ok=True)

    def _write(self, d) -> None:
        if self.failed:
            return
        import numpy as np

        from diag_plugin.diagnose.csvfast import write_rows

        frame = csv_frame(d)
        said = "why" in frame.columns  # some sample of this piece has a why
        if d.why is None:  # then the concatenation has no why column at all
            self.failed = self.failed or self.why is True
            self.why = self.why or False
        elif said:
            self.failed = self.failed or self.why is False
        elif self.why:  # written: this piece's are all empty
            frame["why"] = d.why.rename("why")
        last = "why" not in frame.columns or frame.columns[-1] == "why"  # its field is added last
        got = None if self.failed or not last else csv_arrays(frame, self.spare)
        if got is None:
            self.failed = True
            return
        spec = [(c, k) for c, k in zip(frame.columns, got[4], strict=True) if c != "why"]
        if self.spec is not None and spec != self.spec:
            self.failed = True
            return
        if self.fh is None:  # the first piece
            self.spec = spec
            self.fh = open(self.part, "wb")  # noqa: SIM115 - closed by close or abort
            self.head = csv_head(frame)
            self.fh.write(self.head)
        elif said and not self.why:
            self._add_why(csv_head(frame))
        if said:
            self.why = True
        rows = None if self.why else np.empty(len(frame), np.int64)
        at = self.fh.tell() - len(self.head)
        write_rows(self.fh, *got[:4], os.linesep, CSV_ROWS, rows, self.buffer)
        if rows is not None:
            self.ends.append(rows + at)

    def _add_why(self, head: bytes) -> None:
        """The rows written so far get the empty ``why`` field at their end, the header its
        name."""
        import numpy as np

        self.fh.flush()
        with open(self.part, "rb") as fh:
            fh.seek(len(self.head))
            rows = np.frombuffer(fh.read(), np.uint8)
        ends = np.concatenate(self.ends)
        self.fh.seek(0)
        self.fh.truncate()
        self.fh.write(head)
        self.fh.write(np.insert(rows, ends, ord(",")).data)
        self.head, self.ends, self.why = head, [], True


def _csv_codes(col):
    """An integer or text column (:func:`_csv_known`) as codes into its distinct texts (as
    ``to_csv`` writes them) and whether some are missing (code −1: empty)."""
    import numpy as np
    import pandas as pd

    dt = col.dtype
    if isinstance(dt, np.dtype) and dt.kind in "iu":
        codes, uniq = pd.factorize(col.to_numpy())
        return codes, list(map(str, uniq.tolist())), False
    codes, uniq = pd.factorize(col.to_numpy(dtype=object, na_value=None))
    return codes, list(uniq), bool((codes < 0).any())


#: rows :func:`write_frame_csv` formats at a time
CSV_ROWS = 16_384


def _csv_known(col) -> bool:
    """Whether :func:`write_frame_csv` writes this column itself: float64, integers, or
    strings (a string dtype, or objects that are all strings or missing)."""
    import numpy as np
    import pandas as pd

    dt = col.dtype
    if dt == np.float64 or (isinstance(dt, np.dtype) and dt.kind in "iu"):
        return True
    if isinstance(dt, pd.StringDtype):
        return True
    if isinstance(dt, np.dtype) and dt.kind == "O":
        return all(x is None or type(x) is str for x in col.to_numpy(na_value=None).tolist())
    return False


def _csv_times(index):
    """The index as ``CSV_DATE`` text (a numpy array of str, or of 24-byte strings): UTC times
    on whole seconds without strftime (:func:`~diag_plugin.diagnose.csvfast.utc_texts`), any
    other DatetimeIndex with it; None for another index."""
    import numpy as np
    import pandas as pd

    if not isinstance(index, pd.DatetimeIndex):
        return None
    per_s = {"s": 1, "ms": 1_000, "us": 1_000_000, "ns": 1_000_000_000}.get(index.unit)
    if str(index.tz) == "UTC" and per_s and not (index.asi8 % per_s).any():
        from diag_plugin.diagnose.csvfast import utc_texts

        fast = utc_texts(index.asi8 // per_s)  # fixed-width bytes
        if fast is not None:
            return fast
        text = np.datetime_as_string(index.tz_localize(None).to_numpy(), unit="s")
        return np.char.add(text, "+0000")
    return np.array(index.strftime(CSV_DATE).tolist(), dtype=str)


def _print_timeline(unit, d, iv, csv) -> None:
    from rich.table import Table

    con = table_console()
    con.print(
        f"unit {unit.name}: {len(d):,} samples {d.status.index[0]:%Y-%m-%d %H:%M} … "
        f"{d.status.index[-1]:%Y-%m-%d %H:%M}",
        markup=False,
    )
    if d.message:
        con.print(d.message, markup=False)
    t = Table(title="timeline (faults; for CHECK_FUNCTION the input outside what it learned)")
    for c in ("from", "to", "status", "faults", "tests with symptoms", "samples"):
        t.add_column(c)
    shown = iv if len(iv) <= 60 else iv[iv["status"] != "NORMAL"].head(60)
    for r in shown.to_dict("records"):
        t.add_row(
            f"{r['from']:%Y-%m-%d %H:%M:%S}",
            f"{r['to']:%Y-%m-%d %H:%M:%S}",
            r["status"],
            r["faults"].replace("|", ", ") or r.get("why") or "—",
            r["tests"] or "—",
            f"{r['samples']:,}",
        )
    con.print(t)
    if len(shown) < len(iv):
        con.print(f"({len(iv) - len(shown)} more intervals; --json or --csv for all)")
    if d.equipment is not None:
        for name, o in equipment_off(d).items():
            con.print(
                f"off: {name} stopped on {o['stopped']:,} samples ({o['stopped_share']:.1%}), "
                f"settling after its starts on {o['settling']:,} ({o['settling_share']:.1%}): "
                "its tests off there, not unknown (the unit judged by its other tests)",
                markup=False,
            )
    if csv:
        con.print(f"wrote {csv}")
