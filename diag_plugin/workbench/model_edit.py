"""Create a model's rule-base file and add or remove inputs in place.

Edits go through tomlkit, so comments and expert edits elsewhere in the file
survive. A change of the inputs changes the rule grid, so the trained rules are
cleared (the file says so) and the next ``diag train`` fills them — but the
experts' locked rules are carried to the new grid (:func:`carry_locks`), an edit
that cannot carry one is refused unless ``drop_locks``, and the previous file is
kept as a numbered backup beside it (``NAME.toml.~N~``,
:mod:`diag_plugin.rulebase.backups`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd
import tomlkit

from diag_plugin.fuzzy.partition import UniformPartition
from diag_plugin.regressors import InputSpec, feature
from diag_plugin.rulebase.backups import keep_backup
from diag_plugin.rulebase.document import RuleBase
from diag_plugin.selection.sets import sets_for_data
from diag_plugin.selection.spans import variable_for
from historian.errors import UserError
from historian.taginfo import TagInfo


def new_model(
    path: Path,
    name: str,
    output: str,
    inputs: Sequence[str],
    *,
    frame: pd.DataFrame | None,
    tag_info: Mapping[str, TagInfo | Mapping[str, object]],
    sets: int | None = None,
    method: str = "wm-avg",
    shape: str | None = "trapezoidal",
    period: str = "10s",
    description: str = "",
    notes: list[str] | None = None,
) -> RuleBase:
    """Write a new model file. Without ``sets``, each input gets the sets the data fill
    (:func:`sets_for_data`; 31 without data); where with those the fine grid would answer
    few held-out samples (several inputs), each input's count is searched on held-out data
    (:func:`~diag_plugin.selection.setsearch.choose_sets`) and what was chosen is appended to
    ``notes``. ``shape=None`` (``diag model new`` without ``--shape``) chooses the sets' shape on
    the same held-out data (:func:`~diag_plugin.selection.setsearch.choose_shape`: triangular
    where it errs less, else the paper's trapezoidal; trapezoidal without data), before the
    sets are searched; the default is the paper's trapezoidal sets (the examples reproduce
    the paper with them)."""
    if path.exists():
        raise FileExistsError(f"{path} exists already; edit it or choose another name")
    fixed = sets
    out = variable_for(output, frame=frame, tag_info=tag_info, sets=fixed)
    ins = [variable_for(s, frame=frame, tag_info=tag_info, sets=fixed) for s in inputs]
    if fixed is None and frame is not None:
        cols = [feature(frame, InputSpec.parse(v.spec)) for v in ins]
        auto = sets_for_data(cols, [v.span for v in ins])
        ins = [
            v if v.spec.startswith(("dir(", "hour(", "days(")) else replace(v, sets=auto)
            for v in ins
        ]
        ins = _level_sets(ins, cols, auto, notes)
    if shape is None:
        shape = _chosen_shape(name, out, ins, frame, method, period, notes)
    if fixed is None and frame is not None:
        if len(ins) > 1 and not any(v.spec.startswith(("dir(", "hour(", "days(")) for v in ins):
            capped = {v.spec: v.sets for v in ins if v.sets < auto}
            ins = _searched_sets(name, out, ins, frame, method, shape, period, auto, notes)
            ins = [replace(v, sets=min(v.sets, capped.get(v.spec, v.sets))) for v in ins]
    rb = RuleBase.new(
        name,
        out,
        ins,
        method=method,
        shape=shape,
        description=description,
        period=period,
        path=path,
    )
    rb.save()
    return RuleBase.load(path)


#: the start of ``model new``'s line for an input whose sets its operating levels set
LEVELS_NOTE = "operating levels:"


def _level_sets(ins, cols, auto: int, notes: list[str] | None):
    """``ins`` with an input that dwells at a few operating levels (a stepped command,
    :func:`~diag_plugin.selection.sets.operating_levels`) given the fewest sets that keep
    each level in a set of its own (:func:`~diag_plugin.selection.sets.sets_for_levels`)
    where that is fewer than ``auto`` (what the data fill): more sets would train no more
    rules, only a finer grid of empty cells (the i34-qa2 pass: 31 sets for a valve stepped
    to 3 openings, 3 rules trained). What was chosen and why is appended to ``notes``."""
    from diag_plugin.selection.sets import operating_levels, sets_for_levels

    out = []
    for v, col in zip(ins, cols, strict=True):
        levels = None
        if not v.spec.startswith(("dir(", "hour(", "days(")):
            levels = operating_levels(col, v.span)
        n = auto if levels is None else sets_for_levels(levels, v.span, auto)
        if n < auto:
            if notes is not None:
                shown = ", ".join(f"{x:.4g}" for x in levels[:8]) + (
                    ", …" if len(levels) > 8 else ""
                )
                notes.append(
                    f"{LEVELS_NOTE} {v.spec} gets {n} sets, not the {auto} the data could fill: "
                    f"it dwells at {len(levels)} operating levels ({shown}) and {n} sets keep "
                    "each in a set of its own; more would train no more rules"
                )
            v = replace(v, sets=n)
        out.append(v)
    return out


def _chosen_shape(name, out, ins, frame, method, period, notes) -> str:
    """The sets' shape chosen on the frame's held-out tail
    (:func:`~diag_plugin.selection.setsearch.choose_shape`); the paper's trapezoidal sets
    without data or where no choice can be made."""
    from diag_plugin.selection.scoring import cut_row
    from diag_plugin.selection.setsearch import choose_shape

    if frame is None or len(frame) < 100 or not ins:
        return "trapezoidal"
    probe = RuleBase.new(name, out, ins, method=method, shape="trapezoidal", period=period)
    cols = [feature(frame, InputSpec.parse(v.spec)) for v in ins]
    y = feature(frame, InputSpec.parse(out.spec))
    choice = choose_shape(probe, cols, y, cut_row(frame.index, 0.2))
    if choice is None:
        return "trapezoidal"
    if notes is not None:
        notes.append(choice.note())
    return choice.shape


def _searched_sets(name, out, ins, frame, method, shape, period, auto, notes):
    """``ins`` with each input's sets searched on held-out data where the fine grid is thin
    (:func:`~diag_plugin.selection.setsearch.choose_sets`); unchanged otherwise."""
    from diag_plugin.selection.scoring import cut_row
    from diag_plugin.selection.setsearch import choose_sets

    probe = RuleBase.new(name, out, ins, method=method, shape=shape, period=period)
    if not probe.new_model().capabilities.rule_regions or len(frame) < 100:
        return ins
    cols = [feature(frame, InputSpec.parse(v.spec)) for v in ins]
    y = feature(frame, InputSpec.parse(out.spec))
    choice = choose_sets(probe, cols, y, cut_row(frame.index, 0.2), auto)
    if choice is None:
        return ins
    if notes is not None:
        notes.append(choice.note([v.spec for v in ins]))
    return [replace(v, sets=s) for v, s in zip(ins, choice.sets, strict=True)]


def add_input(
    rb: RuleBase,
    spec: str,
    *,
    frame: pd.DataFrame | None,
    tag_info: Mapping[str, TagInfo | Mapping[str, object]],
    sets: int | None = None,
    replace: str | None = None,
    drop_locks: bool = False,
) -> RuleBase:
    """Add ``spec`` as an input (or let it replace input ``replace``) and save; locked
    rules are carried (:func:`carry_locks`)."""
    specs = [v.spec for v in rb.inputs]
    default_sets = rb.inputs[0].sets if rb.inputs else 31
    known = {s.tags[0]: v.span for v in rb.inputs if (s := InputSpec.parse(v.spec)).fn == ""}
    var = variable_for(
        spec,
        frame=frame,
        tag_info=tag_info,
        sets=sets,
        default_sets=default_sets,
        known_spans=known,
    )
    new = var.spec
    if new in specs:
        raise ValueError(f"{new} is already an input of {rb.name}")
    fields = {
        "spec": var.spec,
        "label": var.label,
        "unit": var.unit,
        "span": [var.span[0], var.span[1]],
        "sets": var.sets,
    }
    doc = rb.doc
    if replace is not None:
        old = str(InputSpec.parse(replace))
        if old not in specs:
            raise ValueError(f"{old} is not an input of {rb.name} (inputs: {', '.join(specs)})")
        i = specs.index(old)
        table = doc["inputs"][i]  # edited in place: its comments stay
        for k, v in fields.items():
            table[k] = v
        same_tag = InputSpec.parse(old).with_lag(0) == InputSpec.parse(new).with_lag(0)
        mapping = [j if (j != i or same_tag) else None for j in range(len(specs))]
        return _restructure(rb, f"input {old} replaced by {new}", mapping, drop_locks)
    table = tomlkit.table()
    table.update(fields)
    doc["inputs"].append(table)
    mapping = [*range(len(specs)), None]
    return _restructure(rb, f"input {new} added", mapping, drop_locks)


def set_input(
    rb: RuleBase,
    spec: str,
    *,
    span: tuple[float, float] | None = None,
    sets: int | None = None,
    drop_locks: bool = False,
) -> RuleBase:
    """Change an input's nominal span and/or set count (the model's resolution) and save."""
    old = str(InputSpec.parse(spec))
    specs = [v.spec for v in rb.inputs]
    if old not in specs:
        raise ValueError(f"{old} is not an input of {rb.name} (inputs: {', '.join(specs)})")
    if span is None and sets is None:
        raise ValueError(f"{rb.path}: {old}: give --span LO HI and/or --sets N")
    table = rb.doc["inputs"][specs.index(old)]  # edited in place: its comments stay
    if span is not None:
        if not span[0] < span[1]:
            raise ValueError(f"{rb.path}: {old}: span needs lo < hi, got {list(span)}")
        table["span"] = [float(span[0]), float(span[1])]
    if sets is not None:
        if sets < 2:
            raise ValueError(f"{rb.path}: {old}: sets must be at least 2, got {sets}")
        table["sets"] = int(sets)
    mapping = list(range(len(specs)))
    return _restructure(rb, f"input {old} resized", mapping, drop_locks)


def remove_input(rb: RuleBase, spec: str, *, drop_locks: bool = False) -> RuleBase:
    old = str(InputSpec.parse(spec))
    specs = [v.spec for v in rb.inputs]
    if old not in specs:
        raise ValueError(f"{old} is not an input of {rb.name} (inputs: {', '.join(specs)})")
    if len(specs) == 1:
        raise ValueError(f"{old} is the only input of {rb.name}; a model needs one")
    i = specs.index(old)
    del rb.doc["inputs"][i]
    mapping = [j for j in range(len(specs)) if j != i]
    return _restructure(rb, f"input {old} removed", mapping, drop_locks)


class LocksNotCarried(UserError, ValueError):
    """A structural edit would lose locked rules; ``problems`` says which and why."""

    def __init__(self, path, problems: list[str]):
        self.problems = problems
        super().__init__(
            f"{path}: {len(problems)} locked rule(s) cannot be carried to the new rule grid:\n"
            + "\n".join(f"  {p}" for p in problems)
            + "\nnothing changed; --drop-locks makes the edit anyway (the file is kept as a "
            "numbered backup)"
        )


@dataclass
class Carried:
    """Locked rules of the old file placed on the new grid, and those that could not be."""

    rules: list
    problems: list[str]


def carry_locks(old: RuleBase, new_inputs: Sequence, mapping: Sequence[int | None]) -> Carried:
    """The old file's locked rules on the grid of ``new_inputs``.

    ``mapping[j]`` is the old input that new input ``j`` continues (the same tag values, maybe
    another span, set count or lag), or None for a new input. A lock goes to the new set
    whose centre is nearest to its old set's centre (in engineering units) — it cannot be
    carried when that centre lies outside the new span. Over a new input it holds for every
    set. Old inputs no longer there are dropped from the premises; locks that then meet in
    one cell must agree on their conclusion, or none of them can be carried."""
    locked = [r for r in old.rules if getattr(r, "lock", False) and hasattr(r, "premise")]
    if not locked:
        return Carried([], [])
    old_parts = [_partition(v, old.shape) for v in old.inputs]
    new_parts = [_partition(v, old.shape) for v in new_inputs]
    cells: dict[tuple[int, ...], list] = {}
    problems = []
    for r in locked:
        axes, why = [], None
        for j, m in enumerate(mapping):
            if m is None:
                axes.append(range(new_parts[j].n))
                continue
            c = float(old_parts[m].centers[r.premise[m]])
            part = new_parts[j]
            tol = 1e-9 * part.span
            if not part.lo - tol <= c <= part.hi + tol:
                why = (
                    f"{old.inputs[m].set_label(r.premise[m])} of {old.inputs[m].spec} "
                    f"(centre {c:g}) is outside the new span {part.lo:g}..{part.hi:g}"
                )
                break
            axes.append([int(part.nearest(np.array([c]))[0])])
        if why:
            problems.append(f"{old.path}:{r.line}: {_premise(old, r)}: {why}")
            continue
        for p in _product(axes):
            cells.setdefault(p, []).append(r)
    out = []
    for p, rs in sorted(cells.items()):
        thens = {("nan" if math.isnan(r.then) else round(r.then, 12)) for r in rs}
        if len(thens) > 1:
            where = ", ".join(f"{old.path}:{r.line} ({_premise(old, r)})" for r in rs)
            problems.append(f"{where}: meet in one cell of the new grid with different values")
            continue
        first = rs[0]
        out.append(replace(first, premise=p, line=0, comments=list(first.comments)))
    return Carried(out, sorted(set(problems)))


def _partition(v, shape: str) -> UniformPartition:
    return UniformPartition(v.span[0], v.span[1], v.sets, shape)


def _product(axes):
    import itertools

    return [tuple(p) for p in itertools.product(*axes)]


def _premise(rb: RuleBase, r) -> str:
    return " ".join(v.set_label(i) for v, i in zip(rb.inputs, r.premise, strict=True))


def _restructure(rb: RuleBase, what: str, mapping: list[int | None], drop_locks: bool):
    """Save an edit of the inputs: rules cleared but the locks carried, the old file kept as
    a numbered backup; refused (nothing written) when a lock cannot be carried."""
    old = RuleBase.load(rb.path)
    rb.clear_rules(f"{what}: rules cleared, run diag train")
    fresh = RuleBase(rb.dumps(), rb.path)  # validates before anything is written
    carried = carry_locks(old, fresh.inputs, mapping)
    if carried.problems and not drop_locks:
        raise LocksNotCarried(rb.path, carried.problems)
    backup = keep_backup(rb.path)
    kept = f", {len(carried.rules)} locked rule(s) carried" if carried.rules else ""
    lost = f", {len(carried.problems)} lock(s) dropped (--drop-locks)" if carried.problems else ""
    fresh.set_training(
        {
            "status": f"{what}: rules cleared{kept}{lost}; previous file {backup.name}; "
            "run diag train"
        }
    )
    fresh.rules = carried.rules
    fresh._dirty_rules = True
    fresh.save()
    return RuleBase.load(rb.path)
