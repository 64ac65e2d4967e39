"""``diag rules check|show|export-fcl``: the plant expert's tools for rule-base files."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from diag_plugin.cliargs import add_json
from historian.errors import UserError

if TYPE_CHECKING:  # the commands import rich and the rule base when they run
    from diag_plugin.rulebase.document import RuleBase


def add_commands(sub: argparse._SubParsersAction) -> None:
    rules = sub.add_parser("rules", help="check, show and export rule-base files")
    rsub = rules.add_subparsers(dest="rules_command", metavar="ACTION", required=True)

    p = rsub.add_parser(
        "check",
        help="validate rule-base, unit and matrix files; prints file:line: problem",
    )
    p.add_argument("files", nargs="+", metavar="FILE")
    add_json(p, "print the problems as JSON")
    p.set_defaults(func=cmd_check)

    p = rsub.add_parser("show", help="print the rules of a model (a grid, or --list)")
    p.add_argument("name", metavar="NAME", help="model name in the rule-base folder, or a file")
    p.add_argument(
        "--list",
        action="store_true",
        help="one rule per line with each premise set's centre in engineering units (the "
        "default when a grid would not fit the terminal)",
    )
    add_json(p, "print the rules as JSON")
    p.add_argument(
        "--level",
        type=int,
        default=0,
        metavar="L",
        help="a coarser level behind the fine grid (derived from the fine rules; 0 = the rules)",
    )
    p.set_defaults(func=cmd_show)

    p = rsub.add_parser("export-fcl", help="write the model as IEC 61131-7 FCL")
    p.add_argument("name", metavar="NAME")
    p.add_argument("--out", "-o", help="output file (default: stdout)")
    p.set_defaults(func=cmd_export_fcl)


def load(name: str, folder: str) -> RuleBase:
    from diag_plugin.rulebase.document import RuleBase, RuleBaseError, resolve

    path = resolve(name, folder)
    if not path.exists():
        from diag_plugin.rulebase.folder import find_shipped

        path = find_shipped(name) or path
    if not path.exists():
        raise UserError(f"no model {name!r}: {path} does not exist (diag model new …)")
    try:
        return RuleBase.load(path)
    except RuleBaseError as exc:
        raise UserError(f"{path} has problems:\n" + "\n".join(exc.problems)) from None


def cmd_check(args: argparse.Namespace) -> int:
    """Check each file by its kind (a unit file, a matrix file, else a rule base); exit 2
    when any has problems, like every command given bad input."""
    import json

    from diag_plugin.rulebase.document import resolve

    report = {}
    for f in args.files:
        path = resolve(f, args.rulebases)
        if not path.exists() and (Path(args.rulebases) / f).exists():
            path = Path(args.rulebases) / f
        kind, problems = file_problems(path, args.rulebases)
        report[str(path)] = {"kind": kind, "problems": problems}
        if args.json:
            continue
        for p in problems:
            print(p)
        if not problems:
            print(f"{f}: ok ({kind})")
    if args.json:
        print(json.dumps(report, indent=2))
    return 2 if any(r["problems"] for r in report.values()) else 0


def file_problems(path: Path, folder: str) -> tuple[str, list[str]]:
    """The kind of a file (``unit``, ``matrix``, ``rule base``) and its problems."""
    from diag_plugin.rulebase.folder import MATRIX_SUFFIX, UNIT_SUFFIX

    if not path.exists():
        return "missing", [f"{path}: no such file"]
    head = path.read_text(encoding="utf-8", errors="replace")
    if path.name.endswith(UNIT_SUFFIX) or head.lstrip().startswith("[unit]") or "\n[unit]" in head:
        from diag_plugin.diagnose.unit import Unit
        from diag_plugin.diagnose.unitfile import UnitError

        try:
            Unit.load(path, folder)
        except UnitError as exc:
            return "unit", exc.problems
        return "unit", []
    if path.name.endswith(MATRIX_SUFFIX) or "\n[matrix]" in "\n" + head:
        from diag_plugin.diagnose.matrix import MatrixError, load_matrix

        try:
            load_matrix(path)
        except MatrixError as exc:
            return "matrix", list(getattr(exc, "problems", None) or [str(exc)])
        return "matrix", []
    from diag_plugin.rulebase.document import check

    return "rule base", check(path)


def cmd_show(args: argparse.Namespace) -> int:
    from rich import box
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    rb = load(args.name, args.rulebases)
    con = Console()
    if args.level:
        return show_level(rb, args.level, con)
    if args.json:
        import json

        print(json.dumps(rules_json(rb), indent=2))
        return 0
    if hasattr(rb.codec, "rule_table"):  # a method with its own kind of rules
        columns, rows = rb.codec.rule_table(rb)
        con.print(
            f"[bold]{escape(rb.name)}[/]: "
            + escape(f"{rb.output.spec} = f({', '.join(v.spec for v in rb.inputs)}), ")
            + f"method {rb.method}, {len(rb.rules)} rules"
        )
        t = Table()
        for col in columns:
            t.add_column(escape(col), justify="right")
        for row in rows:
            t.add_row(*(escape(c) for c in row))
        con.print(t)
        return 0
    n_live = sum(not math.isnan(r.then) for r in rb.rules)
    con.print(
        f"[bold]{escape(rb.name)}[/]: "
        + escape(f"{rb.output.spec} = f({', '.join(v.spec for v in rb.inputs)}), ")
        + f"method {rb.method}, {len(rb.rules)} rules ({n_live} live), "
        f"locked {sum(r.lock for r in rb.rules)}"
    )
    if rb.description:
        con.print(rb.description, markup=False)
    unit = f" [{rb.output.unit}]" if rb.output.unit else ""
    if len(rb.inputs) == 1:
        v = rb.inputs[0]
        t = Table(title=escape(f"{rb.output.spec}{unit} per set of {v.spec}"))
        for col in ("set", "centre", "then", "n", "sd", "lock"):
            t.add_column(col, justify="right")
        by = {r.premise[0]: r for r in rb.rules}
        step = (v.span[1] - v.span[0]) / (v.sets - 1)
        for i in range(v.sets):
            r = by.get(i)
            cells = (
                ["·", "", "", ""]
                if r is None
                else [_fmt(r.then), str(r.n), _fmt(r.sd), "🔒" if r.lock else ""]
            )
            t.add_row(v.set_label(i), f"{v.span[0] + i * step:g}", *cells)
        con.print(t)
    elif len(rb.inputs) == 2 and not args.list and _grid_fits(rb, con.width):
        a, b = rb.inputs
        title = (
            f"{rb.output.spec}{unit}: rows {a.spec}, columns {b.spec}"
            + (f" [{b.unit}]" if b.unit else "")
            + " at the set centres"
        )
        t = Table(
            title=escape(title + " (· = no rule, * = locked)"),
            box=box.SIMPLE_HEAD,
            padding=(0, 0, 0, 1),
            pad_edge=False,
        )
        t.add_column("", justify="right", style="bold")
        cols = sorted({r.premise[1] for r in rb.rules}) or [0]
        cols = list(range(min(cols), max(cols) + 1))
        for j in cols:
            t.add_column(_centre(b, j), justify="right")
        by = {r.premise: r for r in rb.rules}
        rows = sorted({r.premise[0] for r in rb.rules}) or [0]
        for i in range(min(rows), max(rows) + 1):
            row = []
            for j in cols:
                r = by.get((i, j))
                row.append("·" if r is None else f"{r.then:.3g}" + ("*" if r.lock else ""))
            t.add_row(f"{a.set_label(i)} {_centre(a, i)}", *row)
        con.print(t)
    else:
        if len(rb.inputs) == 2 and not args.list:
            con.print("(the grid is wider than the terminal: one rule per line)")
        t = Table(
            title=escape(
                f"{len(rb.rules)} rules: premise sets at their centres → {rb.output.spec}"
            ),
            box=box.SIMPLE_HEAD,
            padding=(0, 1, 0, 0),
        )
        for v in rb.inputs:
            t.add_column(escape(v.spec + (f" [{v.unit}]" if v.unit else "")), justify="right")
        for col in (f"then{unit}", "n", "sd", "lock"):
            t.add_column(escape(col), justify="right")
        for r in rb.rules:
            labels = [
                f"{v.set_label(i)} {_centre(v, i)}"
                for v, i in zip(rb.inputs, r.premise, strict=True)
            ]
            t.add_row(*labels, _fmt(r.then), str(r.n), _fmt(r.sd), "🔒" if r.lock else "")
        con.print(t)
    levels = _levels(rb)
    if levels > 1:
        con.print(
            f"coarser levels 1…{levels - 1} behind this grid are derived from these rules "
            f"(answer where a fine cell has none): diag rules show {rb.name} --level 1",
            markup=False,
        )
    return 0


def _levels(rb: RuleBase) -> int:
    """Levels of a Wang–Mendel file's model (1 = the fine grid alone; 0 for other methods)."""
    if rb.method not in ("wm-avg", "wm") or not rb.rules:
        return 0
    return rb.to_model().n_levels_


def show_level(rb: RuleBase, level: int, con) -> int:
    """Print the rules of a coarser level: each coarse set names the fine sets it groups and
    their centre; the rules are derived from the fine ones (``n``-weighted means), read-only."""
    from rich.markup import escape
    from rich.table import Table

    if rb.method not in ("wm-avg", "wm"):
        raise UserError(f"{rb.name}: method {rb.method} has no rule levels")
    model = rb.to_model()
    if not 0 <= level < model.n_levels_:
        raise UserError(f"{rb.name}: --level {level}: the model has levels 0…{model.n_levels_ - 1}")
    rules = model.level_rules(level)
    cells = model.level_cells(level)
    blocks = model.level_blocks_[level]
    centres = model.level_centers(level)

    def label(k: int, i: int) -> str:
        v = rb.inputs[k]
        a = i * int(blocks[k])
        b = min(a + int(blocks[k]), v.sets) - 1
        return v.set_label(a) if a == b else f"{v.set_label(a)}-{b:0{v.width}d}"

    con.print(
        f"[bold]{escape(rb.name)}[/] level {level} of {model.n_levels_ - 1}: "
        + escape(
            ", ".join(
                f"{v.spec} {int(n)} sets of {int(b)}"
                for v, n, b in zip(rb.inputs, model.level_nsets(level), blocks, strict=True)
            )
        )
        + f"; {rules.keys.size} rules, derived from the {model.n_rules_} fine rules "
        "(edit those: this level follows)"
    )
    unit = f" [{rb.output.unit}]" if rb.output.unit else ""
    t = Table(title=escape(f"{rb.output.spec}{unit}"))
    for v in rb.inputs:
        t.add_column(escape(f"{v.spec} sets"))
        t.add_column("centre", justify="right")
    for col in ("then", "n", "sd"):
        t.add_column(col, justify="right")
    for j in range(rules.keys.size):
        row = []
        for k in range(len(rb.inputs)):
            i = int(cells[j, k])
            row += [label(k, i), f"{centres[k][i]:.4g}"]
        t.add_row(*row, _fmt(rules.conclusions[j]), str(rules.count[j]), _fmt(rules.sd[j]))
    con.print(t)
    return 0


def _centre(v, i: int) -> str:
    """Set ``i``'s centre in engineering units, short: ``53.3``, ``2.1e+03``."""
    return f"{v.span[0] + i * (v.span[1] - v.span[0]) / (v.sets - 1):.4g}"


def _grid_fits(rb, width: int) -> bool:
    """A two-input grid fits when its columns (about 6 characters each) do."""
    cols = {r.premise[1] for r in rb.rules} or {0}
    return 8 + 6 * (max(cols) - min(cols) + 1) <= width


def rules_json(rb) -> dict:
    """The model's rules with each premise set's label and centre in engineering units."""
    return {
        "model": rb.name,
        "output": {"spec": rb.output.spec, "unit": rb.output.unit, "span": list(rb.output.span)},
        "inputs": [
            {"spec": v.spec, "unit": v.unit, "span": list(v.span), "sets": v.sets}
            for v in rb.inputs
        ],
        "rules": [
            {
                "if": [
                    {"set": v.set_label(i), "centre": float(_centre(v, i))}
                    for v, i in zip(rb.inputs, r.premise, strict=True)
                ],
                "then": None if math.isnan(r.then) else r.then,
                "n": r.n,
                "sd": None if math.isnan(r.sd) else r.sd,
                "lock": r.lock,
            }
            for r in rb.rules
            if hasattr(r, "premise")
        ],
    }


def cmd_export_fcl(args: argparse.Namespace) -> int:
    from diag_plugin.rulebase.fcl import to_fcl

    rb = load(args.name, args.rulebases)
    if not getattr(rb.codec, "fcl", True):
        raise UserError(f"{rb.name}: method {rb.method} has no IEC 61131-7 FCL form")
    text = to_fcl(rb)
    if args.out:
        Path(args.out).write_text(text, encoding="utf-8")
        print(f"wrote {args.out}", file=sys.stderr)
    else:
        sys.stdout.write(text)
    return 0


def _fmt(v: float) -> str:
    return "nan" if math.isnan(v) else f"{v:.4g}"
