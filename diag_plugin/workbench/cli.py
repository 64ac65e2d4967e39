"""Workbench commands: ``diag model``, ``diag compare``, ``diag explain``, ``diag report``."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from diag_plugin.cliargs import add_json, table_console
from diag_plugin.models.registry import METHODS
from historian.errors import UserError

if TYPE_CHECKING:  # the commands import pandas, rich and the models when they run
    from diag_plugin.rulebase.document import RuleBase


def add_commands(sub: argparse._SubParsersAction) -> None:
    model = sub.add_parser("model", help="create a model or change its inputs")
    msub = model.add_subparsers(dest="model_command", metavar="ACTION", required=True)
    p = msub.add_parser("new", help="write rulebases/NAME.toml for a new model")
    p.add_argument("name")
    p.add_argument("--output", required=True, metavar="TAG", help="output tag or spec, e.g. F")
    p.add_argument("--input", action="append", required=True, metavar="SPEC", dest="inputs")
    p.add_argument(
        "--sets", type=int, help="sets per input (default: what the data fill, at most 31)"
    )
    p.add_argument(
        "--method",
        default="wm-avg",
        choices=list(METHODS),
        help="identification method: "
        + "; ".join(f"{m.name} ({m.summary})" for m in METHODS.values()),
    )
    p.add_argument(
        "--shape",
        choices=["trapezoidal", "triangular"],
        help="shape of the fuzzy sets (default: chosen on the data's held-out tail — "
        "triangular where it errs less, else the paper's trapezoidal)",
    )
    p.add_argument(
        "--period",
        help="grid period of the model, e.g. 1s, 10s, 3min (default: from the data, the "
        "longest typical spacing of its tags' samples)",
    )
    p.add_argument(
        "--from",
        dest="start",
        help="start of the data the period, spans, sets and shape are chosen on (default: all "
        "data; give a fault-free stretch; diag train takes its own --from/--to)",
    )
    p.add_argument("--to", dest="end", help="end of that data")
    p.add_argument("--description", default="")
    p.set_defaults(func=cmd_model_new)
    p = msub.add_parser("add-input", help="add an input (or replace one with --replace)")
    p.add_argument("name")
    p.add_argument("spec")
    p.add_argument("--replace", metavar="SPEC", help="input the new one replaces")
    p.add_argument("--sets", type=int)
    _edit_flags(p)
    p.set_defaults(func=cmd_add_input)
    p = msub.add_parser("set-input", help="change an input's span or sets (resolution)")
    p.add_argument("name")
    p.add_argument("spec")
    p.add_argument("--span", type=float, nargs=2, metavar=("LO", "HI"))
    p.add_argument("--sets", type=int)
    _edit_flags(p)
    p.set_defaults(func=cmd_set_input)
    p = msub.add_parser("remove-input", help="remove an input")
    p.add_argument("name")
    p.add_argument("spec")
    _edit_flags(p)
    p.set_defaults(func=cmd_remove_input)

    for name, fn, helptext in (
        ("compare", cmd_compare, "model against measurements: where it fails"),
        ("explain", cmd_explain, "rank candidate missing effects"),
        ("report", cmd_report, "self-contained HTML report"),
    ):
        p = sub.add_parser(name, help=helptext)
        p.add_argument("name")
        p.add_argument("--from", dest="start", help="start time (default: all data)")
        p.add_argument("--to", dest="end", help="end time")
        p.add_argument(
            "--no-baseline",
            action="store_true",
            help="skip scikit-learn's HistGradientBoosting on the same rows beside the "
            "held-out error",
        )
        if name == "compare":
            p.add_argument("--report", metavar="FILE.html")
            add_json(p)
        elif name == "explain":
            p.add_argument("--top", type=int, default=10)
            p.add_argument(
                "--max-lag",
                type=int,
                help="longest dead time screened, in samples (default: 10 minutes of samples)",
            )
            add_json(p)
        else:
            p.add_argument("--out", required=True, metavar="FILE.html")
            add_json(p, "print what was written as JSON")
        p.set_defaults(func=fn)


def _edit_flags(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--drop-locks",
        action="store_true",
        help="make the edit even when locked rules cannot be carried to the new grid",
    )
    add_json(p, "print the result as JSON")


def _load(args) -> RuleBase:
    from diag_plugin.rulebase.cli import load

    return load(args.name, args.rulebases)


def _data(args, tags: list[str] | None, period: str):
    from historian.access import open_data

    try:
        return open_data(args.db, tags, args_start(args), args_end(args), period)
    except (KeyError, ValueError) as exc:
        raise UserError(str(exc)) from None


def args_start(args):
    import pandas as pd

    return pd.Timestamp(args.start, tz="UTC") if getattr(args, "start", None) else None


def args_end(args):
    import pandas as pd

    return pd.Timestamp(args.end, tz="UTC") if getattr(args, "end", None) else None


def cmd_model_new(args) -> int:
    import numpy as np

    from diag_plugin.regressors import needed_tags
    from diag_plugin.workbench.model_edit import new_model

    path = Path(args.rulebases) / f"{args.name}.toml"
    Path(args.rulebases).mkdir(parents=True, exist_ok=True)
    out = args.output if "[" in args.output else f"{args.output}[k]"
    tags = needed_tags(_specs([out, *args.inputs]))
    period, notes = _period(args, tags)
    frame, info = _data(args, tags, period)
    try:
        rb = new_model(
            path,
            args.name,
            out,
            args.inputs,
            frame=frame,
            tag_info=info,
            sets=args.sets,
            method=args.method,
            shape=args.shape,
            period=period,
            description=args.description,
            notes=(chosen := []),
        )
    except (FileExistsError, ValueError) as exc:
        raise UserError(str(exc)) from None
    print(f"wrote {path}: {rb.output.spec} = f({', '.join(v.spec for v in rb.inputs)})")
    for line in notes:
        print(line)
    from diag_plugin.selection.setsearch import SHAPE_NOTE
    from diag_plugin.workbench.model_edit import LEVELS_NOTE

    searched = [line for line in chosen if not line.startswith((SHAPE_NOTE, LEVELS_NOTE))]
    for line in chosen:  # the shape and the sets per input chosen on held-out data
        sets_line = not line.startswith(SHAPE_NOTE)
        print(line + (" (give --sets to choose)" if sets_line else " (give --shape)"))
    X = _inputs(frame, rb)
    at_levels = {v.spec for v in rb.inputs if any(f"{LEVELS_NOTE} {v.spec} " in c for c in chosen)}
    filling = [v for v in rb.inputs if v.spec not in at_levels]
    if args.sets is None and not searched and filling and rb.new_model().capabilities.rule_regions:
        sets = sorted({v.sets for v in filling})
        filled = int(np.isfinite(X).all(axis=1).sum()) if X is not None else len(frame)
        print(
            f"sets per input: {', '.join(map(str, sets))}, what {filled:,} samples "
            "can fill (give --sets to choose)"
        )
    for line in _sliver_notes(X, rb):
        print(line)
    for line in _heldout_notes(X, frame, rb, chosen):
        print(line)
    print(f"next: diag train {args.name}")
    return 0


def _heldout_notes(X, frame, rb: RuleBase, chosen: list[str]) -> list[str]:
    """A warning line per input the held-out tail (the last 20 %, as ``diag train`` holds
    out) sees at one operating point (:mod:`~diag_plugin.training.heldout`), saying that
    what was chosen on it (``chosen``: the shape, the sets) was chosen at that point."""
    import numpy as np

    from diag_plugin.selection.scoring import cut_row
    from diag_plugin.training.heldout import narrow_inputs, narrow_note

    if X is None or frame is None or len(frame) != len(X):
        return []
    held = np.arange(len(X)) >= cut_row(frame.index, 0.2)
    narrow = narrow_inputs([v.spec for v in rb.inputs], X, held)
    also = " (the shape and set counts above were chosen on it too)" if chosen else ""
    return [narrow_note(n) + also for n in narrow]


#: an input whose data use less than this share of its span is named by ``model new``
SLIVER = 0.25


def _sliver_notes(X, rb: RuleBase) -> list[str]:
    """A line per input of ``rb`` whose data use under :data:`SLIVER` of its span (a valve's
    0–100 % from the tags file, the data at 39–43 %): few of its sets hold data, so the
    model is a coarse staircase there whatever the set count; with the command that fits
    the span to the data (``diag compare``'s span use, :func:`~.compare.span_use`). ``X``:
    the inputs' values (:func:`_inputs`)."""
    import numpy as np

    from diag_plugin.workbench.compare import span_use

    if X is None or not len(X):
        return []
    lines = []
    for v, u in zip(rb.inputs, span_use(rb, X), strict=True):
        used = u["used_fraction"]
        if v.spec.startswith(("dir(", "hour(", "days(")) or not used < SLIVER:
            continue
        lo, hi = u["used"]
        held = min(v.sets, int(np.floor(used * (v.sets - 1))) + 2)
        lines.append(
            f"{v.spec}: the data use {lo:.4g} … {hi:.4g}, {used:.0%} of its span "
            f"{v.span[0]:g} … {v.span[1]:g}: about {held} of its {v.sets} sets hold data, "
            f"a coarse model there; diag model set-input {rb.name} '{v.spec}' --span "
            f"{lo:.4g} {hi:.4g} fits the sets to the data (diag explain scores it)"
        )
    return lines


def _inputs(frame, rb: RuleBase):
    """The values of ``rb``'s inputs on ``frame``'s grid (samples × inputs; None without
    inputs or data): what ``model new`` counts and checks its sets on — the grid points
    where every input holds a value are the samples its sets are chosen on
    (``sets_for_data``), not the empty points of the gaps between runs."""
    import numpy as np

    from diag_plugin.regressors import InputSpec, feature

    if frame is None or not len(frame) or not rb.inputs:
        return None
    return np.column_stack([feature(frame, InputSpec.parse(v.spec)) for v in rb.inputs])


def _specs(specs: list[str]) -> list[str]:
    """The specs, each checked: a bad one is a usage error showing where it goes wrong."""
    from diag_plugin.regressors import SpecError, parse_specs

    try:
        parse_specs(specs)
    except SpecError as exc:
        raise UserError(str(exc)) from None
    return specs


def _period(args, tags: list[str]) -> tuple[str, list[str]]:
    """The model's grid period (``--period`` or from the data) and lines saying how each
    tag is sampled and aligned on it."""
    from historian.access import tag_sampling
    from historian.sampling import format_period, hold_us, model_period, nice_period_us
    from historian.times import period_us

    try:
        sampling = tag_sampling(args.db, tags, args_start(args), args_end(args))
    except KeyError as exc:
        raise UserError(str(exc).strip("'\"")) from None
    if args.period:
        try:
            p = period_us(args.period)
        except ValueError:
            raise UserError(
                f"--period {args.period!r} is not a duration like 10s or 3min"
            ) from None
        said = f"period {format_period(p)} (--period)"
    else:
        try:
            p = model_period(list(sampling.values()))
        except ValueError as exc:
            raise UserError(str(exc)) from None
        said = f"period {format_period(p)} from the data (the longest typical spacing)"
    lines = [f"{said}: " + "; ".join(f"{t} {s.describe()}" for t, s in sampling.items())]
    half = format_period(p // 2) if p > 1 else "0"
    faster = [t for t, s in sampling.items() if 0 < s.median_us < 0.75 * p]
    held = {t: hold_us(s, p) for t, s in sampling.items() if hold_us(s, p)}
    if faster:
        lines.append(
            f"  {', '.join(faster)}: averaged over each period (samples within {half} of a "
            "grid point)"
        )
    for t, us in held.items():
        lines.append(
            f"  {t}: sampled slower than the grid or irregularly: its last value stands for "
            f"up to {format_period(nice_period_us(us))}, then a gap"
        )
    return format_period(p), lines


def cmd_add_input(args) -> int:
    from diag_plugin.regressors import needed_tags
    from diag_plugin.workbench.model_edit import add_input

    rb = _load(args)
    frame, info = _data(args, needed_tags(_specs([args.spec])) or None, rb.period)
    try:
        rb = add_input(
            rb,
            args.spec,
            frame=frame,
            tag_info=info,
            sets=args.sets,
            replace=args.replace,
            drop_locks=args.drop_locks,
        )
    except (ValueError, KeyError) as exc:
        raise UserError(str(exc).strip("'\"")) from None
    return _changed(rb, args.json)


def cmd_set_input(args) -> int:
    from diag_plugin.workbench.model_edit import set_input

    rb = _load(args)
    try:
        rb = set_input(rb, args.spec, span=args.span, sets=args.sets, drop_locks=args.drop_locks)
    except (ValueError, KeyError) as exc:
        raise UserError(str(exc).strip("'\"")) from None
    return _changed(rb, args.json)


def cmd_remove_input(args) -> int:
    from diag_plugin.workbench.model_edit import remove_input

    try:
        rb = remove_input(_load(args), args.spec, drop_locks=args.drop_locks)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    return _changed(rb, args.json)


def _changed(rb: RuleBase, as_json: bool = False) -> int:
    status = str(rb.training.get("status", ""))
    if as_json:
        doc = {
            "model": rb.name,
            "file": str(rb.path),
            "output": rb.output.spec,
            "inputs": [v.spec for v in rb.inputs],
            "locked_rules": sum(1 for r in rb.rules if getattr(r, "lock", False)),
            "status": status,
        }
        print(json.dumps(doc, indent=2))
        return 0
    print(f"{rb.path}: {rb.output.spec} = f({', '.join(v.spec for v in rb.inputs)})")
    print(status or "rules cleared")
    print(f"next: diag train {rb.name}")
    return 0


def _model_frame(args, rb: RuleBase):
    if not rb.rules:
        raise UserError(f"{rb.name} has no rules yet: run diag train {rb.name}")
    return _data(args, None, rb.period)


def cmd_compare(args) -> int:
    from rich.markup import escape
    from rich.table import Table

    from diag_plugin.metrics import coverage_note, levels_note
    from diag_plugin.training.baseline import describe
    from diag_plugin.workbench.compare import compare, scope_note

    rb = _load(args)
    frame, info = _model_frame(args, rb)
    try:
        c = compare(rb, frame, baseline=not args.no_baseline)
    except (KeyError, ValueError) as exc:
        raise UserError(str(exc)) from None
    if args.report:
        from diag_plugin.workbench.report import write_report

        write_report(args.report, rb, c, None, _experiments(args, rb), frame)
    if args.json:
        print(json.dumps(c.as_dict(), indent=2, allow_nan=False, default=str))
        return 0
    con = table_console()
    m = c.metrics
    con.print(
        f"{rb.name}: {rb.output.spec} = f({', '.join(v.spec for v in rb.inputs)}) on "
        f"{len(c.y):,} samples {c.index[0]:%Y-%m-%d} … {c.index[-1]:%Y-%m-%d}"
        if len(c.y)
        else f"{rb.name}: no samples",
        markup=False,
    )
    con.print(
        f"RMSE {m['rmse_pct']:.2f} %  MAE {m['mae_pct']:.2f} %  bias {m['bias_pct']:+.2f} %  "
        f"max {m['max_abs_pct']:.1f} % of span; coverage {m['coverage']:.1%}"
    )
    con.print(scope_note(c.scope), markup=False, soft_wrap=True)
    if line := describe(c.baseline):
        con.print(line + " — beside diag train's held-out RMSE", markup=False, soft_wrap=True)
    if note := levels_note(m):
        con.print(note, markup=False)
    if note := coverage_note(m):
        con.print(note, markup=False)
    for u in c.inputs:
        con.print(
            f"{u['input']}: uses {u['used'][0]:.4g} … {u['used'][1]:.4g}, "
            f"{u['used_fraction']:.0%} of its span {u['span'][0]:g} … {u['span'][1]:g}"
            + ("  (explain tries a narrower span)" if u["used_fraction"] < 0.7 else ""),
            markup=False,
        )
    d = c.as_dict()
    if len(c.regions):  # methods without rule cells (ts-fcm, narmax2) have no such map
        t = Table(title="worst operating regions (rule cells)")
        for col in [v.spec for v in rb.inputs] + ["count", "mean %", "RMSE %"]:
            t.add_column(escape(col), justify="right")
        for r in d["worst_regions"]:
            t.add_row(
                *[str(r[v.spec]) for v in rb.inputs],
                str(r["count"]),
                f"{r['mean_pct']:+.2f}",
                f"{r['rmse_pct']:.2f}",
            )
        con.print(t)
    t = Table(title="worst time windows")
    for col in ("start", "end", "RMSE %", "mean %"):
        t.add_column(col)
    for r in d["worst_periods"]:
        t.add_row(r["start"][:16], r["end"][:16], f"{r['rmse_pct']:.2f}", f"{r['mean_pct']:+.2f}")
    con.print(t)
    if d["tags"]:
        t = Table(title="residual against the other tags of the plant")
        for col in ("tag", "explains % of residual variance", "correlation", "driven by output"):
            t.add_column(col)
        for r in d["tags"]:
            t.add_row(
                r["tag"],
                f"{r['explained_pct']:.1f}",
                f"{r['corr']:+.2f}",
                "likely"
                if r.get("likely_consequence")
                else "cannot tell"
                if r.get("consequence_unjudged")
                else "",
            )
        con.print(t)
        con.print(
            "each tag alone, in-sample, over its deciles; diag explain ranks by the held-out "
            "error of the model retrained with the tag, tags driven by the output last",
            markup=False,
            soft_wrap=True,
        )
    con.print(f"next: diag explain {rb.name}")
    return 0


def screened_name(s: dict) -> str:
    """A screened-out candidate as ``explain`` lists it: the input, what it would replace
    (a dead time: ``LEVEL[k-2] for LEVEL[k]``; the same input added for dynamics would
    otherwise print twice with nothing to tell them apart) and its screening error."""
    instead = f" for {s['replaces']}" if s.get("replaces") else ""
    return f"{s['input']}{instead} ({s['screen_rmse_pct']:.2f})"


def cmd_explain(args) -> int:
    from rich.markup import escape
    from rich.table import Table

    from diag_plugin.training.baseline import describe
    from diag_plugin.workbench.explain import explain

    rb = _load(args)
    frame, info = _data(args, None, rb.period)
    try:
        e = explain(
            rb,
            frame,
            tag_info=info,
            max_lag=args.max_lag,
            top=args.top,
            baseline=not args.no_baseline,
        )
    except (KeyError, ValueError) as exc:
        raise UserError(str(exc)) from None
    if args.json:
        print(json.dumps(e.as_dict(), indent=2))
        return 0
    con = table_console()
    con.print(
        f"[bold]{escape(rb.name)}[/]: held-out error {e.baseline_rmse_pct:.2f} % of span, "
        f"coverage {e.baseline_coverage:.0%} (validation from {e.validation_from:%Y-%m-%d %H:%M}; "
        "every candidate scored on these samples, its nearest rule standing in where it has "
        "none)"
    )
    if line := describe(e.baseline):
        con.print(line, markup=False, soft_wrap=True)
    from diag_plugin.training.heldout import narrow_note

    for n in e.heldout_narrow:  # as train and compare say it of their held-out blocks
        con.print(narrow_note(n), markup=False, soft_wrap=True)
    t = Table(title="candidate missing effects, best first")
    t.add_column("#", justify="right")
    t.add_column("effect")
    t.add_column("error %", justify="right")
    t.add_column("own coverage", justify="right")
    t.add_column("next command", no_wrap=True)  # whole, to be copied
    for i, c in enumerate(e.candidates, 1):
        effect = c.effect + "".join(f"\n  ⚠ {n}" for n in c.notes)
        err = "n/a" if not math.isfinite(c.rmse_pct_if_added) else f"{c.rmse_pct_if_added:.2f}"
        t.add_row(str(i), escape(effect), err, f"{c.coverage:.0%}", escape(c.command))
    con.print(t)
    if e.screened:
        shown = ", ".join(screened_name(s) for s in e.screened[:8])
        more = f" and {len(e.screened) - 8} more" if len(e.screened) > 8 else ""
        con.print(
            f"screened out, not retrained ({len(e.screened)}; their screening error in "
            f"brackets, the model's held-out prediction corrected by the mean out-of-fold "
            f"residual of the candidate's cells — not a promise): {shown}{more}",
            markup=False,
            soft_wrap=True,
        )
    if any(c.consequence for c in e.candidates):
        con.print(
            "candidates marked 'likely a consequence' follow the output: they are ranked after "
            "every cause that cuts the error, whatever their own error. diag compare's table "
            "of the residual against the tags orders by the in-sample share each tag alone "
            "explains; explain orders by the held-out error of the retrained model",
            markup=False,
            soft_wrap=True,
        )
    for note in e.notes:
        con.print(note, markup=False, soft_wrap=True)
    return 0


def _experiments(args, rb):
    from historian.access import experiments

    try:
        return experiments(args.db, rb.name)
    except Exception:  # noqa: BLE001 - the report shows what it has
        return None


def cmd_report(args) -> int:
    from diag_plugin.workbench.compare import compare
    from diag_plugin.workbench.explain import explain
    from diag_plugin.workbench.report import write_report

    rb = _load(args)
    frame, info = _model_frame(args, rb)
    c = compare(rb, frame, baseline=not args.no_baseline)
    e = explain(rb, frame, tag_info=info, baseline=not args.no_baseline)
    write_report(args.out, rb, c, e, _experiments(args, rb), frame)
    if args.json:
        doc = {"model": rb.name, "report": args.out, "metrics": c.metrics}
        # the held-out RMSE card: the model trained before validation_from, scored after
        # it, as explain's JSON gives it
        ed = e.as_dict(top=0)
        doc.update({k: ed[k] for k in ("heldout_rmse_pct", "validation_from")})
        from diag_plugin.training.baseline import KEY, OLD_KEY

        # the page's HistGradientBoosting card: on the rows of heldout_rmse_pct
        if (hgb := e.baseline if e.baseline is not None else c.baseline) is not None:
            doc[KEY] = hgb
        if c.baseline is not None:  # as before issue 34: compare's, on train's block
            doc[OLD_KEY] = c.baseline
        print(json.dumps(doc, default=str))
        return 0
    print(f"wrote {args.out}", file=sys.stderr)
    return 0
