"""The build's side of a piece of equipment's run condition (:mod:`diag_plugin.diagnose.equipment`):
the declarations checked against the window, the ``[equipment]`` tables, and the tests
grouped by the piece whose rows they learn from."""

from __future__ import annotations

from collections.abc import Callable, Container, Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd
import tomlkit

from diag_plugin.diagnose.equipment import Equipment, output_tag, owner
from diag_plugin.diagnose.running import RunCondition
from diag_plugin.regressors import InputSpec, feature
from diag_plugin.unitbuild.loops import Loop, Running
from diag_plugin.unitbuild.runlevels import (
    give_a_value,
    listed,
    mode_condition,
    mode_levels,
    not_a_state,
)
from historian.errors import UserError


def equipment_conditions(
    frame: pd.DataFrame, declared: Sequence[Running], unit_run: str | None = None
) -> tuple[list[Equipment], list[str]]:
    """Each declared piece (``--running [NAME:]TAG[=VALUE]:TAG1,…``) checked against the
    window: its run tag and tags in the data, a tag in one piece only, the run tag two-valued
    (or one-valued with the ``VALUE`` it runs at: a piece that ran throughout the window), or
    a mode of more values with the ``VALUE`` it runs at (:func:`piece_run`).
    Returns the pieces and the plan's notes. ``unit_run``: the unit's own run tag (no piece's)."""
    out: list[Equipment] = []
    notes: list[str] = []
    seen: dict[str, str] = {}
    for d in declared:
        name, where = d.name or d.tag, d.where
        missing = [t for t in (d.tag, *d.tags) if t not in frame.columns]
        if missing:
            raise UserError(f"{d.where_of(missing[0])}: {', '.join(missing)} not in the data")
        if d.tag == unit_run:
            raise UserError(f"{where}: {d.tag} is the unit's run condition already")
        if name in {e.name for e in out}:
            raise UserError(f"{where}: a second piece of equipment named {name}")
        for t in d.tags:
            if t in seen:
                raise UserError(f"{d.where_of(t)}: {t} belongs to {seen[t]} already")
            seen[t] = name
        x = frame[d.tag].to_numpy(float)
        rc = piece_run(d, name, x[np.isfinite(x)])
        out.append(Equipment(name, rc, tuple(d.tags)))
        notes.append(
            f"{name}: runs while {d.tag} = {rc.run:g} ({rc.share:.1%} of the window's samples); "
            f"the tests of {', '.join(d.tags)} learned from those only, off while it is stopped"
        )
    return out, notes


def piece_run(d: Running, name: str, x: np.ndarray) -> RunCondition:
    """A piece's run condition from its run tag's finite values ``x`` over the window: a mode
    of more than two values (:func:`~diag_plugin.unitbuild.runlevels.mode_levels`: a filter's
    0 filtering, 1 backwash, 2 filter-to-waste; a pasteuriser's idle 0, production 1, CIP
    2-4) runs at the ``VALUE`` given, any of them, stopped at every other; a two-valued tag at
    its higher value or ``VALUE``; one value with ``VALUE``, a piece that ran throughout."""
    where = d.where
    levels = mode_levels(x)
    if levels is not None:
        if d.value is None:
            raise UserError(f"{where}: run condition {d.tag} of {name} "
                            f"{give_a_value(d.tag, levels)}")  # fmt: skip
        if d.value not in levels:
            raise UserError(f"{where}: run condition {d.tag} of {name} is {listed(levels)} "
                            f"over the window, never {d.value:g}")  # fmt: skip
        return mode_condition(d.tag, d.value, levels, x)
    values = np.unique(x)
    shown = ", ".join(f"{v:g}" for v in values[:5]) + (" …" if values.size > 5 else "")
    if values.size > 2 and (d.value is None or d.value not in (values[0], values[-1])):
        # no state (an analog tag, a grid's means of switches): at one end of its values
        # only, stopped nearer the next one (RunCondition.runs), as before modes
        raise UserError(f"{where}: run condition {d.tag} of {name} {not_a_state(values)}")
    if values.size == 0 or (values.size == 1 and d.value is None):
        raise UserError(
            f"{where}: run condition {d.tag} of {name} is not two-valued over the window "
            f"({values.size} value(s): {shown or 'none'}); a piece that ran throughout: "
            f"{d.tag}=VALUE"
        )
    run = float(values.max()) if d.value is None else d.value
    if values.size == 2 and run not in values:
        raise UserError(
            f"{where}: run condition {d.tag} of {name} is {values[0]:g} or {values[1]:g} "
            f"over the window, never {run:g}"
        )
    others = values[values != run]
    near = others[np.argmin(np.abs(others - run))] if others.size else None
    stop = float(near) if near is not None else (0.0 if run != 0 else 1.0)
    return RunCondition(d.tag, run, stop, float(np.mean(x == run)))


def stretches(on: np.ndarray) -> list[int]:
    """Lengths of the runs of consecutive True in ``on``."""
    edges = np.diff(np.concatenate(([0], on.astype(np.int8), [0])))
    return (np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)).tolist()


def ran(runs: Sequence[int], n: int) -> str:
    """'ran on 1509 of the window's 86400 samples (1.7%) in 2 run(s), the longest 910'."""
    k = sum(runs)
    longest = f", the longest {max(runs)}" if runs else ""
    return (
        f"ran on {k} of the window's {n} samples ({k / max(n, 1):.1%}) in {len(runs)} run(s)"
        + longest
    )


def short_run_hints(
    equipment: Sequence[Equipment], frame: pd.DataFrame, problems: Sequence[str],
    output_of: Callable[[str], str | None],
) -> list[str]:  # fmt: skip
    """For a build whose thresholds could not be learned: a line per declared piece whose
    tests are among ``problems`` (``test NAME: …``; ``output_of(NAME)`` its output,
    ``TAG[k]``), saying how little it ran. A piece's tests learn from its running rows only,
    each start's first samples left out and their inputs' history refilled after it: short
    runs leave none."""
    failed = {p.split(":", 1)[0].removeprefix("test ").strip() for p in problems}
    out = []
    for e in equipment:
        tests = sorted(t for t in failed if output_tag(output_of(t) or "") in e.tags)
        if not tests:
            continue
        runs = stretches(frame[e.rc.tag].to_numpy(float) == e.rc.run)
        out.append(
            f"{e.name} {ran(runs, len(frame))}: its tests ({', '.join(tests)}) learn from its "
            f"running rows only, each start's first samples left out and their inputs' "
            f"history filled again after it; build on a window where {e.name} runs longer, "
            "or leave it undeclared"
        )
    return out


def foreign_tags(
    e: Equipment, equipment: Sequence[Equipment], loops: Sequence[Loop] = (),
    candidates: Container[str] | None = None,
) -> dict[str, list[str]]:  # fmt: skip
    """Per other piece the tags that belong to it (among ``candidates``, the window's
    candidate inputs, when given) ``e``'s tests never read (issue 34, items 4-5): a
    sibling's measurement is at best a proxy for a common cause (the header, the room, the
    load, which are unit-wide tags), means nothing while the sibling is stopped, and makes
    ``e``'s tests fire on the sibling's faults (the compressors' ``C2_TD = f(C2_TAC, C1_TD,
    DRY_PDP)``, acceptance-compressors.md). A declared loop of ``e``'s tags keeps its
    set-point and output wherever they belong (the loop's relation is the user's). The
    sibling's run tag stays a candidate: it says whether the sibling runs, which is true
    while it is stopped, never at fault, and is what shares a load between the pieces (a
    chiller's load halves when the other starts: on the twin chillers, both declared,
    chiller A's sensor bias was found on 9-15 % of its samples with the sibling's run tag
    left out too, 54-61 % with it read; 97-99 % when A's tests read B's power; 99 % with
    the load A carries, :func:`share_inputs`, offered besides). Tests of no piece read any
    tag: a header is what the pieces feed."""
    partners = {t for lp in loops if {lp.pv, lp.out} & set(e.tags) for t in (lp.sp, lp.out)}
    out: dict[str, list[str]] = {}
    for other in equipment:
        if other.name == e.name:
            continue
        tags = [t for t in other.tags if t not in partners and t not in e.tags]
        tags = [t for t in tags if candidates is None or t in candidates]
        if tags:
            out[other.name] = tags
    return out


def share_inputs(
    e: Equipment, equipment: Sequence[Equipment], unit_wide: Sequence[str]
) -> list[InputSpec]:
    """The unit-wide loads shared by ``e`` and the other pieces that run, candidate inputs of
    ``e``'s tests (issue 34, item 4): ``share(X,R1,…)`` = ``X / (1 + n)`` per unit-wide tag
    ``X`` in ``unit_wide`` (the declared disturbances: the load, the plant's draw), ``n`` how
    many of the other pieces run (``R1, …`` their run tags; ``e`` itself runs wherever its
    tests judge). Two chillers sharing a building's load each cool half of it while both run,
    all of it alone: the load a chiller carries is ``share(LOAD,B_RUN)``, read without reading
    the sibling's measurements (its power, which :func:`foreign_tags` keeps out, and which a
    fault of the sibling's moves). Only run tags that run at 1 and stop at 0 are counted (a
    mode's levels, a filter's ``STATE=0`` running, are not): none, no share."""
    runs = tuple(
        o.rc.tag for o in equipment
        if o.name != e.name and not o.rc.levels and (o.rc.run, o.rc.stop) == (1.0, 0.0)
    )  # fmt: skip
    if not runs:
        return []
    return [InputSpec("share", (x, *runs)) for x in unit_wide if x not in runs]


#: units of a temperature: a unit-wide tag in one (the room's) is no load the pieces share
TEMPERATURE_UNITS = frozenset({"degc", "°c", "c", "k", "degf", "°f", "f", "degk"})


def shared_loads(tags: Sequence[str], info: Mapping[str, Any]) -> list[str]:
    """The declared disturbances a share is offered of (:func:`share_inputs`): all but those
    whose unit is a temperature's (the room's temperature is no load the pieces share; on the
    compressed-air station ``share(T_AMB,…)`` was chosen as a proxy of how many run)."""
    unit = {t: str(getattr(info.get(t), "unit", "") or "").strip().lower() for t in tags}
    return [t for t in tags if unit[t] not in TEMPERATURE_UNITS]


def share_note(e: Equipment, shares: Sequence[InputSpec]) -> str:
    """The build's note, once per piece, naming the shared loads :func:`share_inputs` offered
    its tests."""
    runs = ", ".join(shares[0].tags[1:])
    return (
        f"{e.name}: its tests may read {', '.join(s.base for s in shares)}: the load over the "
        f"pieces running, {e.name} and those of {runs} at 1 (what {e.name} carries where the "
        "pieces share a load, read without the other pieces' measurements)"
    )


def own_inputs_note(e: Equipment, left: dict[str, list[str]]) -> str:
    """The build's note, once per piece, naming the candidate inputs :func:`foreign_tags`
    left out of its tests and why."""
    shown = "; ".join(f"{name}'s {', '.join(tags)}" for name, tags in left.items())
    return (
        f"{e.name}: its tests read its own tags, the unit-wide ones and whether the other "
        f"pieces run, not {shown} (another piece's measurement means nothing while it is "
        f"stopped and would make {e.name}'s tests fire on its faults; a common cause, the "
        "load, a header, the room, is a unit-wide tag)"
    )


def with_shares(frame: pd.DataFrame, shares: Sequence[InputSpec]) -> pd.DataFrame:
    """``frame`` with a column per shared load (:func:`share_inputs`) under its spec's base
    (``share(LOAD,B_RUN)``): a piece's candidate input, read as its spec
    (``_Context.spec_of``)."""
    if not shares:
        return frame
    return frame.assign(**{s.base: feature(frame, s) for s in shares})


def equipment_table(equipment: Sequence[Equipment]) -> tomlkit.items.Table:
    """The unit file's ``[equipment]`` tables (:mod:`diag_plugin.diagnose.equipment`)."""
    t = tomlkit.table(is_super_table=True)
    for e in equipment:
        row = tomlkit.table()
        row.comment("written by `diag unit build --running`: its tests judged while it runs")
        for k, v in e.as_table().items():
            row[k] = v
        t[e.name] = row
    return t


def map_by_equipment(
    fn: Callable[..., Any],
    items: Sequence[Any],
    tag_of: Callable[[Any], str | None],
    args_for: Callable[[Equipment | None], tuple],
    equipment: Sequence[Equipment],
    mapper: Callable[..., list[Any]],
) -> list[Any]:
    """``mapper(fn, group, args_for(piece))`` per group of ``items`` by the piece their tag
    (``tag_of``; None: no piece) belongs to, the results in ``items``' order: a piece's tests
    chosen and trained on the rows where it runs."""
    groups: dict[int, list[int]] = {}
    owners: list[Equipment | None] = [None]
    for i, it in enumerate(items):
        tag = tag_of(it)
        e = owner(equipment, tag) if tag is not None else None
        if e not in owners:
            owners.append(e)
        groups.setdefault(owners.index(e), []).append(i)
    out: list[Any] = [None] * len(items)
    for k, idx in groups.items():
        got = mapper(fn, [items[i] for i in idx], args_for(owners[k]))
        for i, g in zip(idx, got, strict=True):
            out[i] = g
    return out
