"""The levels a declared run condition's tag takes over the build window (issue 34, item 5;
acceptance pass 10, docs/explanation/acceptance-pasteuriser.md): a run feedback's two (0/1),
or a mode's more — an HTST pasteuriser's idle 0, production 1, CIP rinse 2 / caustic 3 /
acid 4 — found by the one rule a discrete state is found by
(:func:`historian.discrete.discrete_levels`, up to :data:`~historian.discrete.MAX_MODE_LEVELS`
levels). ``--running MODE=1`` runs where ``MODE`` is at 1 and is stopped at every other level
(:class:`~diag_plugin.diagnose.running.RunCondition`); an analog tag is no run condition."""

from __future__ import annotations

import numpy as np

from diag_plugin.diagnose.running import RunCondition
from diag_plugin.unitbuild.loops import Running
from historian.discrete import MAX_MODE_LEVELS, discrete_levels
from historian.errors import UserError


def mode_levels(x: np.ndarray) -> tuple[float, ...] | None:
    """The levels of the run tag's finite values ``x`` where it is a state of more than two
    (a mode): a discrete state by :func:`~historian.discrete.discrete_levels` (up to
    :data:`~historian.discrete.MAX_MODE_LEVELS` levels holding
    :data:`~historian.discrete.DISCRETE_SHARE` of the values), its levels those and every
    other value held on two samples running (a filter's filter-to-waste, 1 % of a window,
    beside its commonest two; not where a grid averaged a switch). None for a two-valued
    tag, a constant or an analog one."""
    found = discrete_levels(x, most=MAX_MODE_LEVELS)
    if found is None:
        return None
    held = set(found) | {float(v) for v in x[1:][x[1:] == x[:-1]]}
    return tuple(sorted(held)) if 2 < len(held) <= MAX_MODE_LEVELS else None


def listed(levels: tuple[float, ...] | np.ndarray) -> str:
    """``0, 1, 2, 3 or 4``."""
    vals = [f"{float(v):g}" for v in levels]
    return vals[0] if len(vals) == 1 else ", ".join(vals[:-1]) + f" or {vals[-1]}"


def mode_condition(tag: str, run: float, levels: tuple[float, ...], x: np.ndarray) -> RunCondition:
    """The run condition of a mode ``tag`` running at ``run`` (one of its ``levels``; ``x``
    its finite values over the window, for the share it ran on): stopped at every other
    level, ``stop`` the nearest of them (the lower on a tie), named in the why where the tag
    holds no other."""
    others = np.asarray([v for v in levels if v != run], float)
    stop = float(others[np.argmin(np.abs(others - run))])
    rc = RunCondition(tag, float(run), stop, None, tuple(float(v) for v in levels))
    share = float(np.mean(rc.runs(x))) if x.size else 0.0
    return RunCondition(tag, rc.run, stop, share, rc.levels)


def not_a_state(values: np.ndarray) -> str:
    """Why a run tag of these window values is refused, and what to give instead."""
    if values.size == 1:
        return (
            f"holds one value over the window ({values[0]:g}): it never stopped there; build "
            "on a window where it stops, or leave the run condition out"
        )
    seen = ", ".join(f"{v:g}" for v in values[:5]) + (" …" if values.size > 5 else "")
    return (
        f"is not a state over the window ({values.size} value(s): {seen or 'none'}); it must "
        f"be a state, e.g. a run feedback 0/1 or a mode of up to {MAX_MODE_LEVELS} values "
        "each held for a while (TAG=VALUE runs at one of them)"
    )


def give_a_value(tag: str, levels: tuple[float, ...]) -> str:
    """What a mode declared without the value it runs at is told."""
    return (
        f"takes {len(levels)} values over the window ({listed(levels)}); give the one it "
        f"runs at, e.g. {tag}={levels[1]:g} (stopped at every other)"
    )


def mode_run(rc: Running, x: np.ndarray) -> RunCondition | None:
    """The unit's run condition where its tag is a mode of more than two values over the
    window (``x``: its finite values; :mod:`~diag_plugin.unitbuild.runlevels`): running at
    the declared ``VALUE``, one of them, stopped at every other; None for any other tag."""
    levels = mode_levels(x)
    if levels is None:
        return None
    head = f"{rc.where}: run condition {rc.tag} (running)"
    if rc.value is None:
        raise UserError(f"{head} {give_a_value(rc.tag, levels)}")
    if rc.value not in levels:
        raise UserError(f"{head} is {listed(levels)} over the window, never {rc.value:g}")
    return mode_condition(rc.tag, rc.value, levels, x)


def two_valued_run(rc: Running, x: np.ndarray) -> RunCondition:
    """The unit's run condition of a two-valued tag (``x``: its finite values over the
    window): running at ``VALUE`` (default: the higher), stopped at the other; any other tag
    refused saying what a run condition is."""
    head = f"{rc.where}: run condition {rc.tag} (running)"
    values = np.unique(x)
    if values.size != 2:
        raise UserError(f"{head} {not_a_state(values)}")
    lo, hi = float(values[0]), float(values[1])
    run = hi if rc.value is None else rc.value
    if run not in (lo, hi):
        raise UserError(f"{head} is {lo:g} or {hi:g} over the window, never {run:g}")
    stop = lo if run == hi else hi
    return RunCondition(rc.tag, run, stop, float(np.mean(x == run)))


def unit_run(rc: Running, x: np.ndarray) -> RunCondition:
    """The unit's declared run condition checked against its tag's finite values ``x`` over
    the window: a mode's (:func:`mode_run`), else a two-valued tag's (:func:`two_valued_run`)."""
    return mode_run(rc, x) or two_valued_run(rc, x)
