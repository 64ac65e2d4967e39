"""A unit from the plant's history: ``diag unit build``.

From a window the user declares fault-free, :func:`build_unit` makes a unit nobody had to
hand-build:

1. **Tests** (:func:`choose_tests`): every tag that varies in the window — measurements and
   controller outputs — unless the user lists them. Left out, each with its reason: tags
   constant over the window, tags with too few good samples (:data:`MIN_GOOD_SHARE`),
   set-points (a name ending ``.SP`` or a description saying set-point: a set-point is the
   operator's choice, not a consequence of the process, so a model of it detects nothing),
   discrete states (:func:`~historian.discrete.discrete_levels`: a pump's run feedback, a
   filter's 0/1/2 state; candidate inputs).
2. **Inputs** (:func:`select_inputs`): greedy forward selection of up to
   :data:`MAX_INPUTS` inputs with the workbench's own held-out scoring
   (:class:`~diag_plugin.selection.scoring.HeldOutScorer`, what ``diag explain`` ranks
   with): at each step every candidate tag is screened at every dead time by the
   correlation of its lagged values with the current model's residual
   (:func:`~diag_plugin.selection.lags.lag_screen`), the best few are scored by
   time-blocked cross-validation (:class:`~diag_plugin.selection.scoring.BlockScorer`: each
   of :data:`FOLDS` time blocks of the window — ``diag unit learn``'s blocks, cut between
   runs — held out in turn, the model retrained on the others, the held-out errors pooled),
   so a relation must hold in every period of the window, not only in its last fifth; the
   candidate that cuts the error most is kept if it cuts it by more than :data:`MIN_GAIN`.
   The shortest dead time scoring within :data:`~diag_plugin.selection.lags.TOLERANCE` of
   the best is kept. A candidate (or a dead time) whose lower bound of the error from its fine
   rule level alone (:meth:`~diag_plugin.selection.scoring.BlockScorer.bound`) shows it
   cannot be chosen — it cannot beat the best error reached, or cannot cut the current one
   by :data:`MIN_GAIN` — is not finished, and the candidates are finished in the order of
   their bounds (the likeliest winner first): the same choice at a fraction of the fits.
   **A tag a controller holds** (:func:`tracked_set_point`: RMS of tag − set-point at most
   :data:`TRACKS` of the tag's standard deviation) is not modelled from the other tags: its
   test is the loop's own relation (:func:`loop_test`: the tag at its set-point plus the
   loop's steady offset, ``track``), whose residual is the control error — valid at
   set-points the window never saw, where other tags' models of it learned the operators'
   choices of the window.
   Never a candidate: the tag itself at any lag (a model of ``y[k]`` from ``y[k-1]`` follows
   a fault as fast as the fault moves ``y`` and so hides it), nor a tag that is the same
   measurement (:func:`same_measurement`: ``|r| >`` :data:`SAME_CORR` at lag 0, linear or
   rank correlation — a redundant transmitter, a copy, a unit conversion or a monotone
   function of the tag); a controller output is no such copy: a tag it drives may read it
   through the screen, the output's own test never reads that tag
   (:func:`driven_reads_output`).
3. **Models**: each test's model (``wm-avg``; sets per input what the data fill,
   :func:`~diag_plugin.selection.sets.sets_for_data`) is written as an ordinary model
   file and trained like ``diag train`` does (80 % / 20 % time-ordered validation, then all
   of the window), with the window as its provenance.
4. **Thresholds**: :func:`~diag_plugin.learn.thresholds.learn_thresholds` on the same
   window, cross-fitted (the models were trained on it), to the false-alarm budget ``far``,
   saved as ``diag unit learn`` saves them.

The unit file records per test, in ``[build.tests]``, the inputs chosen and the held-out
error (% of the output's span) before any input and after each step, and the held-out
coverage; ``diag unit show`` prints it.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import re
import time
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from dataclasses import replace as dc_replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
import tomlkit

from diag_plugin.diagnose.combos import states_table
from diag_plugin.diagnose.equipment import learnable_for
from diag_plugin.diagnose.fixed import learned_text, tolerance
from diag_plugin.diagnose.manual import MARGIN_SAYS, ManualSpan, learned_span
from diag_plugin.diagnose.running import RunCondition, learnable
from diag_plugin.diagnose.unittags import is_set_point
from diag_plugin.learn.far import check_far
from diag_plugin.learn.thresholds import DEFAULT_BLOCKS, block_of
from diag_plugin.models.linear import INPUT_NOISE, LEARNED_OUTPUT
from diag_plugin.models.spec import Variable
from diag_plugin.regressors import InputSpec
from diag_plugin.rulebase.document import RuleBase
from diag_plugin.selection.features import Features
from diag_plugin.selection.lags import TOLERANCE, LagScreen, default_max_lag
from diag_plugin.selection.scoring import BlockScorer, FrozenRuleBase
from diag_plugin.selection.sets import SETS_RANGE, sets_for_data
from diag_plugin.selection.spans import variable_for
from diag_plugin.unitbuild import short
from diag_plugin.unitbuild.equipment import (
    equipment_conditions,
    equipment_table,
    foreign_tags,
    map_by_equipment,
    own_inputs_note,
    share_inputs,
    share_note,
    shared_loads,
    short_run_hints,
    with_shares,
)
from diag_plugin.unitbuild.loops import (
    Disturbance,
    HeldOut,
    Loop,
    Manual,
    Replay,
    Running,
    checked_declared,
    checked_loops,
    checked_manual,
    parse_running,
    piece_settle_bounds,
    settle_bounds,
    settle_envelopes,
)
from diag_plugin.unitbuild.parallel import DaskPool, default_workers, map_tests, one_blas_thread
from diag_plugin.unitbuild.read import read_sampling, read_window
from diag_plugin.unitbuild.runlevels import listed, unit_run
from historian.discrete import DISCRETE_SHARE, discrete_levels, levels_text
from historian.errors import UserError
from historian.taginfo import TagInfo, tag_infos

if TYPE_CHECKING:
    from diag_plugin.diagnose.unit import TestModel

log = logging.getLogger(__name__)

#: inputs per model at most (greedy forward selection stops earlier when none helps)
MAX_INPUTS = 3
#: inputs of a controller output's test at most (issue 34, item 7): a valve position is set by
#: several process conditions at once (load, feed, the other loops' outputs); chosen as a
#: linear (parity) relation, each input kept only where it cuts the held-out error by
#: :data:`MIN_GAIN`, so the window decides how many it supports
ACTUATOR_MAX_INPUTS = 6
#: a step must cut the held-out error by more than this share to be kept
MIN_GAIN = 0.03
#: candidate tags retrained and scored per step (the rest screened out by correlation)
SCREENED = 5
#: dead times retrained per screened candidate (the best by correlation)
LAGS_RETRAINED = 2
#: relative margin by which a candidate's lower bound of the held-out error must exceed the
#: best error reached for it to be passed over (:meth:`BlockScorer.bound`: the bound and the
#: error sum the same squares in another order; rounding is ~1e-16)
BOUND_MARGIN = 1e-9
#: |r| at lag 0 above which two tags count as the same measurement
SAME_CORR = 0.995
#: a tag is held at a set-point when RMS(tag − set-point) ≤ TRACKS × its standard deviation
#: (the set-point as it stands accounts for at least 3/4 of the tag's variance)
TRACKS = 0.5
#: suffixes of a controller's output beside its set-point's (TIC103.SP, TIC103.OUT)
OUTPUT_NAMES = ("OUT", "OP", "MV", "CO", "OUTPUT")
#: the method of a controlled tag's test (its measurement at its set-point plus the offset)
LOOP_METHOD = "track"
#: a tag needs good samples in this share of the window's grid points to be tested
MIN_GOOD_SHARE = 0.5
#: how ``[build.skipped]`` says a tag is a discrete state
DISCRETE_WHY = "a discrete state"
#: how :func:`choose_tests` begins the reason of a tag constant over the window
CONSTANT_WHY = "constant over the window"
#: how :func:`choose_tests` begins the reason of a tag that holds one value on
#: :data:`~historian.discrete.DISCRETE_SHARE` of the window, its other values no level
#: (:func:`rarely_away`)
RARE_WHY = "holds one value"
#: grid points a window needs (a window under short.SHORT_ROWS is built as a short one, see
#: :mod:`diag_plugin.unitbuild.short`)
MIN_ROWS = short.MIN_ROWS
#: share of the window held out to validate each trained model (time-ordered, as diag train)
HOLDOUT = 0.2
#: time blocks each candidate is scored over, each held out in turn (unit learn's blocks)
FOLDS = DEFAULT_BLOCKS


@dataclass
class Step:
    """One step of the forward selection: the input added and the held-out error after."""

    input: str
    rmse_pct: float
    coverage: float


@dataclass
class TestChoice:
    """What the selection chose for one test (one tag) and why."""

    test: str
    tag: str
    baseline_rmse_pct: float  # the training mean as the prediction
    steps: list[Step] = field(default_factory=list)
    excluded: list[str] = field(default_factory=list)  # same measurement as the tag
    validation_rmse_pct: float = math.nan  # the trained model's, as diag train reports
    method: str = "wm-avg"
    tracks: str | None = None  # the set-point a controlled tag is held at
    actuator: str | None = None  # that loop's controller output
    statistic: str = "level"  # "spread": the running sd of the loop's error (stiction)
    declared: bool = False  # the loop was declared (--loop, a tags CSV), not found
    why: str = ""  # why this method (a short window's choice between a grid and a line)
    sets: int | None = None  # sets per input of a short window's grid
    combined: bool = True  # False: kept out of the combined T² (a blind tag's pair test)
    balance: bool = False  # a manipulated flow's balance test (:mod:`.balance`)

    @property
    def inputs(self) -> list[str]:
        return [s.input for s in self.steps]

    def as_dict(self) -> dict:
        return {
            "test": self.test,
            "tag": self.tag,
            "inputs": self.inputs,
            "rmse_pct": [_r(self.baseline_rmse_pct)] + [_r(s.rmse_pct) for s in self.steps],
            "coverage": [_r(s.coverage) for s in self.steps],
            "excluded": self.excluded,
            "validation_rmse_pct": _r(self.validation_rmse_pct),
            "method": self.method,
            "tracks": self.tracks,
            "actuator": self.actuator,
            "statistic": self.statistic,
            "declared": self.declared,
            "why": self.why,
            "balance": self.balance,
        }


@dataclass
class BuildResult:
    unit: str
    path: Path
    period: str
    window: tuple[str, str]
    tests: list[TestChoice]
    skipped: dict[str, str]
    far: float
    learned: object | None = None
    seconds: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    #: the hand valves (--manual) and the span each was learned in
    manual: list[ManualSpan] = field(default_factory=list)

    def as_dict(self) -> dict:
        lim = getattr(self.learned, "limits", {}) or {}
        return {
            "unit": self.unit,
            "file": str(self.path),
            "period": self.period,
            "window": list(self.window),
            "far": self.far,
            "tests": [{**t.as_dict(), "thresholds": list(lim.get(t.test, ()))} for t in self.tests],
            "skipped": self.skipped,
            "seconds": {k: round(v, 2) for k, v in self.seconds.items()},
            "notes": self.notes,
            "manual": {m.tag: m.as_row() for m in self.manual},
        }


def _r(v: float) -> float | None:
    return round(float(v), 4) if v is not None and math.isfinite(v) else None


def test_name(tag: str, taken: set[str]) -> str:
    """A test name from a tag: letters, digits and ``_`` (``TIC202.OUT`` → ``TIC202_OUT``)."""
    base = re.sub(r"\W+", "_", tag).strip("_") or "t"
    if base[0].isdigit():
        base = "t" + base
    name, k = base, 2
    while name in taken:
        name, k = f"{base}_{k}", k + 1
    taken.add(name)
    return name


def choose_tests(
    frame: pd.DataFrame,
    tag_info: Mapping[str, TagInfo | Mapping[str, object]] | None = None,
    tags: Sequence[str] | None = None,
    set_points: Sequence[str] = (),
    manual: Mapping[str, str] | None = None,
    outputs: Sequence[str] = (),
    states: Sequence[str] = (),
) -> tuple[list[str], dict[str, str]]:
    """The tags to test and the others with the reason each is left out.

    ``tags`` (the user's list) are tested as given, unless constant or without enough data
    (a test of a constant teaches nothing; that is an error the caller reports), or a hand
    valve (``manual``: tag → what the plan says of it, never tested). ``outputs``: the
    declared loops' controller outputs, tested though named or declared a set-point — a
    cascade's inner set-point is the outer controller's output, not an operator's entry
    (issue 34, item 7). ``states``: declared discrete states (``--state``, a recipe's phase
    of more levels than :func:`two_states` finds), left out as a found one is."""
    info = tag_infos(tag_info)
    manual = manual or {}
    chosen, skipped = [], {}
    for t in tags if tags is not None else list(frame.columns):
        v = frame[t].to_numpy(float)
        good = np.isfinite(v)
        if t in manual:
            skipped[t] = manual[t]
        elif good.mean() < MIN_GOOD_SHARE:
            skipped[t] = (
                f"good samples in {good.mean():.0%} of the window's grid points "
                f"(a test needs {MIN_GOOD_SHARE:.0%})"
            )
        elif np.ptp(v[good]) <= tolerance(float(np.abs(v[good]).max())):
            skipped[t] = f"{CONSTANT_WHY} ({float(v[good][0]):g})"
        elif (
            tags is None and (is_set_point(t, info.get(t)) or t in set_points) and t not in outputs
        ):
            skipped[t] = "a set-point (the operator's choice; kept as a candidate input)"
        elif tags is None and t in states:
            skipped[t] = (
                f"{DISCRETE_WHY} (declared; {held_values_text(v[good], ())}: a mode of the "
                "plant, as a recipe's phase; kept as a candidate input, never a tag at fault)"
            )
        elif tags is None and (two := two_states(v[good])) is not None:
            skipped[t] = (
                f"{DISCRETE_WHY} ({held_values_text(v[good], two)}: a mode of the plant, as a "
                "pump's run feedback; kept as a candidate input, never a tag at fault)"
            )
        elif tags is None and (away := rarely_away(v[good])) is not None:
            skipped[t] = away
        else:
            chosen.append(t)
    return chosen, skipped


def rarely_away(v: np.ndarray) -> str | None:
    """What the build says of a tag that holds one value on
    :data:`~historian.discrete.DISCRETE_SHARE` of its good samples, its other values too few
    or too scattered to be a level (no discrete state, :func:`two_states`), else None: the
    window shows too little of it away from that value to learn what it does there. A
    standby compressor that ran 4 of a short window's 400 samples, its current 0 on 396 and
    32.3–34.8 A on 4: a level test against the window's mean alarmed whenever it ran (57 % of
    the fault-free days), a discrete state made every other combination CHECK_FUNCTION
    (acceptance-compressors.md). Not tested, not a state; a candidate input."""
    vals, counts = np.unique(v, return_counts=True)
    if len(vals) < 2:
        return None
    top = int(np.argmax(counts))
    if counts[top] < DISCRETE_SHARE * len(v):
        return None
    away = len(v) - int(counts[top])
    return (
        f"{RARE_WHY} ({vals[top]:g}) on {int(counts[top])} of {len(v)} samples, others on "
        f"{away} ({len(vals) - 1} distinct, no level a state holds): too few to learn what it "
        "does away from it (a standby that barely ran); not tested, kept as a candidate "
        "input; build on a window where it moves more"
    )


def constant_tags(
    frame: pd.DataFrame,
    info: Mapping[str, TagInfo],
    set_points: Sequence[str] = (),
    manual: Sequence[str] = (),
) -> list[ManualSpan]:
    """The tags constant over the window (:func:`choose_tests`' test, with enough good
    samples) that are not a set-point nor a hand valve (their own handling: a loop's held
    set-point, ``[manual]``), each with the value it was held at: the unit's ``[fixed]``
    rows (:mod:`~diag_plugin.diagnose.fixed`)."""
    out = []
    for t in frame.columns:
        if t in manual or t in set_points or is_set_point(t, info.get(t)):
            continue
        v = frame[t].to_numpy(float)
        good = np.isfinite(v)
        if not good.any() or good.mean() < MIN_GOOD_SHARE:
            continue
        x = v[good]
        if np.ptp(x) <= tolerance(float(np.abs(x).max())):
            lo, hi = float(x.min()), float(x.max())
            out.append(ManualSpan(str(t), lo, hi, tolerance(float(np.abs(x).max()))))
    return out


def held_set_points(frame: pd.DataFrame, held: Mapping[str, str]) -> list[ManualSpan]:
    """A ``[fixed]`` row for each declared loop's set-point held over the window (``held``:
    set-point → the loop's measurement, :meth:`_Context.hold_set_point`): its value, and as
    ``margin`` the largest distance of the measurement from it over the window (at least the
    build's test of a constant, :func:`tolerance`). Only where the loop is declared: then
    the unit knows which measurement the set-point holds and how far the plant went from it;
    an undeclared set-point's moves are judged by the tests as before (a tank's 990-sample
    unit followed its level set-point's later moves with no alarm; a row at the build's test
    of a constant made it CHECK_FUNCTION on 68 % of the continuation). The loop's own test
    reads the set-point at any value, but every other test learned the plant only where the
    measurement was held there: read at a set-point an operator has moved beyond the
    measurement's own excursions, they judge an operating point the window never showed (an
    aeration basin's dissolved oxygen held at 2.0 mg/l for 14 days, moved to 1.5: the blower's
    and the other zone's valve tests, reading the oxygen, in alarm on 58-61 % of two
    fault-free days, naming the probe; acceptance pass 11). There the unit says so:
    CHECK_FUNCTION naming the set-point, its value and since when
    (:mod:`~diag_plugin.diagnose.fixed`), until it is back or ``diag unit accept`` learns
    the new point; a move within the measurement's own excursions is judged as before."""
    out = []
    for sp, pv in held.items():
        x = frame[sp].to_numpy(float)
        x = x[np.isfinite(x)]
        if not x.size:
            continue
        lo, hi = float(x.min()), float(x.max())
        y = frame[pv].to_numpy(float) if pv in frame else np.empty(0)
        y = y[np.isfinite(y)]
        reach = float(max(np.max(np.abs(y - lo)), np.max(np.abs(y - hi)))) if y.size else 0.0
        margin = max(float(f"{reach:.10g}"), tolerance(max(abs(lo), abs(hi))))
        out.append(ManualSpan(str(sp), lo, hi, margin))
    return out


def fixed_table(spans: Sequence[ManualSpan]) -> tomlkit.items.Table:
    """The unit file's ``[fixed]`` table (docs/reference/units.md)."""
    return span_table(
        spans,
        "written by `diag unit build`: tags constant over its window, read by no test (a "
        "held set-point: read by its loop's test only); outside [min - margin, max + margin] "
        "for the on-delay the unit is CHECK_FUNCTION naming the tag (margin: the build's test "
        "of a constant, 1e-9 * max(1, |value|); a held set-point's: the farthest its loop's "
        "measurement went from it over the window)",
    )


def unguarded_note(tags: Sequence[str]) -> str:
    """What the build says of the set-points constant over the window that no loop declares:
    no test reads them and no guard watches them (:func:`held_set_points` is a declared
    loop's only), so a later move is judged by the tests of the tags it drives."""
    return (
        f"{len(tags)} set-point(s) held over the window and declared in no loop "
        f"({', '.join(tags)}): no test reads them, so where an operator moves one the tests of "
        "what it drives judge the new point, and the unit does not say it left what it "
        "learned; declare the loop (`--loop PV=SP:OUT`, or a tags CSV's loop/role columns) "
        "and such a move is CHECK_FUNCTION naming the set-point"
    )


def fixed_note(spans: Sequence[ManualSpan]) -> str:
    """What the build's note says of the ``[fixed]`` rows."""
    each = ", ".join(f"{s.tag} = {learned_text(s).removesuffix(' over its window')}"
                     for s in spans)  # fmt: skip
    return (
        f"{len(spans)} tag(s) constant over the window recorded in [fixed] ({each}): read by no "
        "test; where one is outside its value for the on-delay (beyond 1e-9 × max(1, |value|), "
        "the build's test of a constant) the unit is CHECK_FUNCTION naming it, until it is "
        "back for the off-delay; `diag unit accept` of a period where it moved learns it"
    )


def state_combos(
    unit: Any, frame: pd.DataFrame, states: Sequence[str]
) -> tuple[list[str], list[str], float] | None:
    """The unit's ``[states]`` (:mod:`~diag_plugin.diagnose.combos`): its discrete states
    (``[build] states``, those in ``frame``), the combinations ``frame`` held for the dwell
    and the dwell (s): the unit's quiet time (:func:`~diag_plugin.diagnose.settle.quiet_samples`:
    the longest history a test reads + the residual filter's delay + the on-delay) — a
    combination held that long has a sample where every test read only it, its residual
    filtered. None without states."""
    from diag_plugin.diagnose.combos import held_combos
    from diag_plugin.diagnose.settle import quiet_samples

    states = [t for t in states if t in frame.columns]
    if not states:
        return None
    held_s = float(quiet_samples(unit) * unit.period_s)
    return states, held_combos(frame, states, held_s), held_s


def put_states(uf: Any, tags: list[str], seen: list[str], held_s: float) -> None:
    """The unit file ``uf``'s ``[states]`` (:func:`state_combos`' ``tags``, ``seen`` and
    ``held_s``): the table it writes and the one it reads (``uf.states``, what
    :func:`~diag_plugin.diagnose.combos.read_states` reads back), set together."""
    uf.doc["states"] = states_table(tags, seen, held_s)
    uf.states = {"tags": tags, "seen": seen, "held_s": held_s}


def short_combos(
    unit: Any, frame: pd.DataFrame, combos: tuple[list[str], list[str], float], state_s
) -> list[str]:
    """The combinations of the states ``combos`` (:func:`state_combos`) never held for its
    dwell but visited repeatedly (:func:`~diag_plugin.diagnose.combos.visited_combos`), where
    the unit has a state settle (``state_s``, its ``state_settle_max_s``; none: ``[]``): the
    settle opened by the change into one holds its transient, so it is judged, not named
    never learned on every visit (issue 34 item 5, ``i34-cip``)."""
    from diag_plugin.diagnose.combos import visited_combos

    if not state_s or float(state_s) <= 0:
        return []
    tags, _, held_s = combos
    return visited_combos(frame, tags, held_s, unit.ev["on_delay"] * unit.period_s)


def combos_note(
    unit: Any, tags: Sequence[str], seen: Sequence[str], held_s: float, short: Sequence[str] = ()
) -> str:
    """What the build's note says of the ``[states]`` table."""
    from diag_plugin.diagnose.combos import MIN_VISITS
    from diag_plugin.diagnose.settle import quiet_parts

    depth, lag, on = quiet_parts(unit)
    visited = (
        f" ({'; '.join(short)}: each visited {MIN_VISITS} times or more, every visit "
        "shorter, learned because the state settle holds the changes into them)"
        if short else ""
    )  # fmt: skip
    return (
        f"{len(seen)} combination(s) of the discrete states {', '.join(tags)} recorded in "
        f"[states] ({'; '.join(seen) or 'none'}): those the window held for {held_s:g} s or "
        f"longer, the unit's quiet time ({depth} samples of the longest history a test reads "
        f"+ {lag} of the residual filter + {on} of the on-delay){visited}; another combination "
        "held for the on-delay makes the unit CHECK_FUNCTION naming it, until a learned one "
        "held for the off-delay; `diag unit accept` of a period where it ran learns it"
    )


def two_states(v: np.ndarray) -> tuple[float, ...] | None:
    """The levels of a discrete state (:func:`~historian.discrete.discrete_levels`: its two
    commonest values, or three, the third held, holding 99 % of ``v``), else None. Not tested
    by default: a model of an on/off feedback from the current it switches reproduces it
    exactly, its residual is zero and no threshold can be learned; what the state does to the
    process is seen by the tests that read it."""
    return discrete_levels(v)


def held_values_text(v: np.ndarray, levels: tuple[float, ...]) -> str:
    """The values a discrete state held, for the build's note
    (:func:`~historian.discrete.levels_text`: ``0, 1 or 2``)."""
    return levels_text(v, levels)


def same_measurement(
    frame: pd.DataFrame, tags: Sequence[str], workers: int | DaskPool | None = 1
) -> dict[str, list[str]]:
    """For each tag, the others that are the same measurement: ``|r| >`` :data:`SAME_CORR`
    at lag 0 over the window, Pearson's or Spearman's (a redundant transmitter, a copy, a
    unit conversion, a monotone function of it). Neither is ever an input of the other's
    model, unless one is a controller output (:func:`driven_reads_output`). ``workers``:
    processes for the two correlation matrices (:func:`map_tests`; None: every core)."""
    X = frame[list(tags)].astype(float)
    # Pearson for a copy or a linear conversion, Spearman (ranks) for any monotone one
    # (a flow computed from a differential pressure, a level in % from one in m)
    pearson, spearman = map_tests(_abs_corr, [False, True], (X,), workers=workers)
    r = np.fmax(pearson, spearman)
    out = {t: [] for t in tags}
    for i, a in enumerate(tags):
        for j, b in enumerate(tags):
            if i != j and np.isfinite(r[i, j]) and abs(r[i, j]) > SAME_CORR:
                out[a].append(b)
    return out


def driven_reads_output(
    same: Mapping[str, Sequence[str]], outputs: Iterable[str]
) -> dict[str, list[str]]:
    """``same`` (:func:`same_measurement`) with each controller output (``outputs``: a
    declared loop's ``out``, or one found by its name beside a set-point) left readable by
    the tags that pass the screen with it: a cause and its effect, not one measurement.

    A controller output is no transmitter: the controller computes it from its loop's error,
    and the valve it moves sets what flows through it. Where the valve is the only thing
    that moves the flow (a header held at its pressure) the two correlate above
    :data:`SAME_CORR` over any fault-free window — the air through a DO loop's valve at r
    0.9993 (docs/explanation/acceptance-aeration.md) — and the screen, meant for a redundant
    transmitter, a copy or a unit conversion, dropped the one relation a bias of the flow's
    meter breaks (the flow was modelled from the load instead, and the bias was found on
    12.7 % of the samples). So the tag may read the output: its test is the valve's
    characteristic, ``F = f(valve)`` (the seed's Model B, ``F_k = f(U_{k-1})``).

    One way only: the output's own test still never reads what it drives. A valve predicted
    from its own flow follows the flow whatever moved it; its test (:func:`actuator_test`)
    predicts it from the process conditions that drive it, so it still fires when its loop
    closes the valve on a drifting sensor. Two controller outputs that pass the screen
    together stay screened (neither drives the other), and so do two measurements (a
    redundant pair): the screen is unchanged for every pair without exactly one output."""
    outs = set(outputs)
    return {t: [c for c in cs if not (c in outs and t not in outs)] for t, cs in same.items()}


def _abs_corr(ranks: bool, X: pd.DataFrame) -> np.ndarray:
    """``|r|`` between the columns of ``X``: Pearson's, or of their ranks (Spearman's)."""
    return np.abs((X.rank() if ranks else X).corr().to_numpy())


class _Context:
    """Columns, spans and variables of the window, shared by every test's selection."""

    def __init__(
        self,
        frame: pd.DataFrame,
        info: dict[str, TagInfo],
        period: str,
        hand: frozenset[str] = frozenset(),
    ):
        self.frame = frame
        self.info = info
        self.period = period
        #: the declared hand valves: never half of a pair (:func:`_pair_step`)
        self.hand = hand
        self.spans: dict[str, tuple[float, float]] = {}
        self.vars: dict[str, Variable] = {}
        #: declared loops' set-point tags constant over the window (:meth:`hold_set_point`)
        self.fixed_sp: dict[str, Variable] = {}
        #: a derived candidate's column name → its spec's base (a piece's shared load,
        #: ``share(LOAD,B_RUN)``: :func:`~diag_plugin.unitbuild.equipment.with_shares`)
        self.derived: dict[str, InputSpec] = {}
        for t in frame.columns:
            col = frame[t].to_numpy(float)
            if not np.isfinite(col).any() or np.nanmax(col) == np.nanmin(col):
                continue
            v = variable_for(str(InputSpec("", (t,), 0)), frame=frame, tag_info=info)
            self.vars[t] = v
            self.spans[t] = v.span
        self.feats = Features(frame, self.spans)
        self.block = block_of(frame.index, FOLDS, frame.notna().any(axis=1).to_numpy())
        self.max_lag = default_max_lag(frame.index)
        # every candidate centred once: each step of each test screens them in one product
        self.lags = LagScreen({t: self.column(t) for t in self.vars}, self.max_lag)

    def hold_set_point(self, sp: str, pv: str) -> bool:
        """A declared loop's set-point tag that did not move over the window: never a
        candidate input (a constant teaches no other model anything), but its loop's test
        still reads it, so the test follows the operators' next set-point. Its span: the
        tag's metadata range, else the measurement's it sets (the same quantity). False
        where the window holds no value of it."""
        col = self.frame[sp].to_numpy(float)
        if not np.isfinite(col).any():
            return False
        v = variable_for(str(InputSpec("", (sp,), 0)), frame=self.frame, tag_info=self.info)
        has_range = sp in self.info and self.info[sp].span is not None
        self.fixed_sp[sp] = v if has_range else dc_replace(v, span=self.vars[pv].span)
        return True

    def spec_of(self, tag: str, lag: int = 0) -> InputSpec:
        """A candidate's spec: a tag's ``TAG[k-lag]``, a derived candidate's its function's."""
        d = self.derived.get(tag)
        return InputSpec("", (tag,), lag) if d is None else d.with_lag(lag)

    def variable(self, tag: str, lag: int) -> Variable:
        spec = self.spec_of(tag, lag)
        v = self.vars[tag] if tag in self.vars else self.fixed_sp[tag]
        return dc_replace(v, spec=str(spec), label=v.label)

    def column(self, tag: str, lag: int = 0) -> np.ndarray:
        return self.feats.column(InputSpec("", (tag,), lag))

    def spec_variable(self, spec: InputSpec) -> Variable:
        """The variable of any input spec: a tag's as :meth:`variable`, a function's (a
        fixed set-point's ``const(120.4)[k]``) from its values over the window."""
        if not spec.fn:
            return self.variable(spec.tags[0], spec.lag)
        return variable_for(str(spec), frame=self.frame, tag_info=self.info)

    def spec_column(self, spec: InputSpec) -> np.ndarray:
        return self.column(spec.tags[0], spec.lag) if not spec.fn else self.feats.column(spec)


def _rulebase(
    name: str,
    out: Variable,
    ins: Sequence[Variable],
    period: str,
    path=None,
    method: str = "wm-avg",
):
    return RuleBase.new(name, out, list(ins), method=method, period=period, path=path)


def _with_sets(
    ins: Sequence[Variable], cols: Sequence[np.ndarray], cut: int, max_sets: int | None = None
) -> list[Variable]:
    """The inputs with the sets the training rows fill (what ``diag model new`` writes), at
    most ``max_sets`` (a short window's coarser grid)."""
    if not ins:
        return []
    sets = sets_for_data([c[:cut] for c in cols], [v.span for v in ins])
    sets = sets if max_sets is None else min(sets, max_sets)
    return [dc_replace(v, sets=sets) for v in ins]


def select_inputs(
    ctx: _Context,
    tag: str,
    candidates: Sequence[str],
    *,
    test: str,
    max_inputs: int = MAX_INPUTS,
    method: str = "wm-avg",
    max_sets: int | None = None,
) -> TestChoice:
    """Greedy forward selection of ``tag``'s inputs among ``candidates`` (see module doc),
    each variant scored as a ``method`` model (``linear`` in a short window)."""
    out = ctx.vars[tag]
    y = ctx.column(tag)
    rows = len(y)
    chosen: list[tuple[str, int]] = []
    # the file is parsed once; each step's model is a variant of it (its inputs replaced)
    base = FrozenRuleBase(_rulebase(test, out, [], ctx.period, method=method))
    scorer = BlockScorer(base, [], y, ctx.block)
    current = scorer.base_rmse
    choice = TestChoice(test, tag, current)
    resid = scorer.residual([])
    pool = [c for c in candidates if c != tag and c in ctx.vars]
    while len(chosen) < max_inputs and pool:
        # screen: every candidate at every dead time against the current residual
        screened = []
        corrs = ctx.lags.screen(resid, pool)
        for c in pool:
            corr = corrs[c]
            order = np.argsort(-corr, kind="stable")[:LAGS_RETRAINED]
            screened.append((float(corr[order[0]]), c, sorted(int(x) for x in order),
                             int(order[0])))  # fmt: skip
        screened.sort(key=lambda s: -s[0])
        best = None  # (rmse, coverage, tag, lag, the variant's inputs, columns and fits)
        base_cols = [ctx.column(t, lag) for t, lag in chosen]
        # each dead time's lower bound of its error from the fine rule level alone
        # (BlockScorer.bound), for every screened candidate before any is finished
        bounded = []
        for rank, (_, c, lags, _) in enumerate(screened[:SCREENED]):
            variants = []
            for lag in lags:
                cols = [*base_cols, ctx.column(c, lag)]
                pairs = [*chosen, (c, lag)]
                ins = _with_sets([ctx.variable(t, g) for t, g in pairs], cols, rows, max_sets)
                variants.append((lag, ins, cols))
            bounds = [scorer.bound(ins, cols) for _, ins, cols in variants]
            bounded.append((min(b for b, _ in bounds), rank, c, variants, bounds))
        # the candidates in the order of their bounds (the likeliest winner finished first):
        # a dead time that cannot be the candidate's best nor within TOLERANCE of it, and a
        # candidate that cannot beat the best error reached nor cut the current one by
        # MIN_GAIN (the step is kept only then), are never chosen, so their coarse rule levels
        # are not fitted; the winner is the least error, ties to the better screened — the
        # choice of every order (the bounds are lower bounds)
        gain = current * (1 - MIN_GAIN)
        for low_bound, rank, c, variants, bounds in sorted(bounded, key=lambda b: b[:2]):
            reach = math.inf if best is None else best[0]
            reach = gain if gain < reach else reach
            if low_bound > reach * (1 + BOUND_MARGIN):
                continue
            scored = []
            for i in sorted(range(len(variants)), key=lambda i: bounds[i][0]):
                lag, ins, cols = variants[i]
                # a dead time past TOLERANCE of the cut by MIN_GAIN is never the kept one
                # (were it in TOLERANCE of its candidate's best, that best would miss the cut)
                near = min((s[0] for s in scored), default=math.inf)
                near = gain if gain < near else near
                if bounds[i][0] > near * (1 + TOLERANCE) * (1 + BOUND_MARGIN):
                    continue
                rmse, cov = scorer.score(ins, cols, bounds[i][1])
                if math.isfinite(rmse):
                    scored.append((rmse, lag, cov, (ins, cols, scorer.fitted())))
            if not scored:
                continue
            low = min(s[0] for s in scored)
            rmse, lag, cov, kept = min((s for s in scored if s[0] <= low * (1 + TOLERANCE)),
                                       key=lambda s: s[1])  # fmt: skip
            if best is None or (rmse, rank) < (best[0], best[-1]):
                best = (rmse, cov, c, lag, kept, rank)
        if best is None or not best[0] < gain:
            if len(chosen) + 2 > max_inputs or method == short.LINEAR or not _a_flow(ctx, tag):
                break  # a line has no product of two inputs to find; a pair: a flow's
            pair = _pair_step(ctx, scorer, chosen, screened[:SCREENED], current, rows, max_sets)
            if pair is None:
                break
            rmse, cov, picked, kept = pair
        else:
            rmse, cov, c, lag, kept, _ = best
            picked = [(c, lag)]
        ins, cols, fits = kept
        for c, lag in picked:
            chosen.append((c, lag))
            pool.remove(c)
            choice.steps.append(Step(str(ctx.spec_of(c, lag)), rmse, cov))
        current = rmse
        # the winner's block fits as its scoring made them: the next step's base model
        scorer = BlockScorer(FrozenRuleBase(base, ins), cols, y, ctx.block, fitted=fits)
        resid = scorer.residual(cols)
    return choice


def _a_flow(ctx: _Context, tag: str) -> bool:
    """``tag`` a flow by its declared kind (:func:`~diag_plugin.unitbuild.balance.tag_kind`):
    the pair step's product is the valve equation's (an opening times its head)."""
    from diag_plugin.unitbuild.balance import tag_kind

    return tag_kind(tag, ctx.info.get(tag)) == "flow"


def _pair_step(ctx, scorer, chosen, screened, current, rows, max_sets):
    """Where no single candidate cuts the error by :data:`MIN_GAIN`: the best pair of the
    step's screened candidates (each at its best-screened dead time), kept where it cuts the
    error by ``2 × MIN_GAIN`` — two inputs that each alone explain nothing (a tank's level
    and its drain valve, the out-flow their product). At most ``C(SCREENED, 2)`` pair fits,
    each skipped where its lower bound cannot beat the best pair or the cut. A declared hand
    valve is half of no pair (still a single candidate): a model reading the valve's
    opening now would follow the operator's move, and the move's settle and its
    CHECK_FUNCTION outside the learned span (:mod:`~diag_plugin.diagnose.manual`) would no
    longer be seen. Returns ``(rmse, coverage, ((tag, lag), (tag, lag)), (inputs, columns,
    fits))`` or None."""
    from itertools import combinations

    gain = current * (1 - 2 * MIN_GAIN)
    base_cols = [ctx.column(t, lag) for t, lag in chosen]
    best = None
    for (_, a, _, la), (_, b, _, lb) in combinations(screened, 2):
        if a in ctx.hand or b in ctx.hand:
            continue
        pairs = [*chosen, (a, la), (b, lb)]
        cols = [*base_cols, ctx.column(a, la), ctx.column(b, lb)]
        ins = _with_sets([ctx.variable(t, g) for t, g in pairs], cols, rows, max_sets)
        low, prefit = scorer.bound(ins, cols)
        reach = gain if best is None or gain < best[0] else best[0]
        if low > reach * (1 + BOUND_MARGIN):
            continue
        rmse, cov = scorer.score(ins, cols, prefit)
        if math.isfinite(rmse) and rmse < reach:
            best = (rmse, cov, ((a, la), (b, lb)), (ins, cols, scorer.fitted()))
    return best


def _choose(tag: str, *args) -> TestChoice:
    """:func:`_choose_test` (``args`` its arguments after ``tag``) with the candidates' coarse
    rule levels fitted to be scored once
    (:func:`~diag_plugin.fuzzy.wang_mendel.scoring_node_fit`); the chosen models are trained
    afterwards as ever."""
    from diag_plugin.fuzzy.wang_mendel import scoring_node_fit

    with scoring_node_fit():
        return _choose_test(tag, *args)


def _choose_test(
    tag: str,
    names,
    same,
    ctx: _Context,
    sel: _Context,
    plan,
    frame,
    info,
    declared,
    held,
    asks=None,
    cascades=None,
) -> TestChoice:
    """One test's choice (a worker's share of the build, see :mod:`.parallel`); ``declared``
    maps a loop's measurement to its declared :class:`Loop`, ``held`` each controller output
    (declared, or found by its name beside a set-point's) to the tag its loop holds (never
    one of its inputs; None where the loop is not declared): its test is
    :func:`actuator_test`. ``asks`` (:func:`asked_for`): each controller output's own loop's
    set-point, a candidate input of the output's test even where the same-measurement screen
    drops it; ``cascades`` (:func:`cascade_outputs`): an outer controller's output → the
    inner loop's measurement and valve, never its inputs (what it drives)."""
    asks, cascades = asks or {}, cascades or {}
    test = names[tag]
    excl = same.get(tag, [])
    use = sel if tag in sel.vars else ctx
    k = plan.factor if use is sel else 1
    lp = declared.get(tag)
    # a set-point declared for another measurement is that loop's (one controller holds it):
    # a tag whose numbers merely coincide with it (a feed beside a steam set-point the
    # operators enter at the same number) is not held at it
    theirs = {d.sp for d in declared.values() if d.pv != tag}
    sp = (
        lp.sp
        if lp is not None
        else tracked_set_point(tag, frame, [c for c in ctx.vars if c not in theirs], info)
    )
    if lp is not None and lp.fixed is not None:
        # a fixed set-point (not a tag): the loop's error against that number
        ch = loop_test(ctx, tag, InputSpec("const", (), 0, lp.fixed), test=test)
        ch.actuator, ch.declared = lp.out, True
        sp = None
    elif sp is not None and (sp in ctx.vars or sp in ctx.fixed_sp):
        # a loop's response time at the data's own rate: one input, a dozen lags, cheap;
        # on the coarse grid it would be a whole coarse step off, and the residual of a
        # loop that holds its set-point would carry the loop's dynamics
        use, k = ctx, 1
        ch = loop_test(ctx, tag, sp, test=test)
        ch.actuator = (
            lp.out if lp is not None else controller_output(sp, [t for t in ctx.vars if t != tag])
        )
        ch.declared = lp is not None
    else:
        sp = None
        # an output's own set-point (the flow asked for) read though the screen drops it;
        # a cascade's outer output never reads the inner loop it drives
        ask = asks.get(tag)
        down = cascades.get(tag, ())
        cands = [
            c
            for c in use.vars
            if c != tag and (c not in excl or c == ask) and c != held.get(tag) and c not in down
        ]
        cands = short.inputs_for(plan, tag, cands, use.column)
        ch = select_inputs(use, tag, cands, test=test, max_inputs=plan.max_inputs,
                           method=plan.select_method, max_sets=plan.max_sets)  # fmt: skip
        if plan.short and ch.steps:
            _short_method(ctx, ch)
        if tag in held:
            ch = actuator_test(use, ch, cands)
    for st in ch.steps:  # dead times chosen on the coarse grid, on the data's grid
        st.input = short.scale_lag(st.input, k)
    read = {t for i in ch.inputs for t in InputSpec.parse(i).tags}
    ch.excluded = [c for c in excl if c != sp and c not in read]
    return ch


def actuator_test(ctx: _Context, ch: TestChoice, candidates: Sequence[str]) -> TestChoice:
    """A controller output's test from several inputs (issue 34, item 7): the valve position
    predicted from the process conditions that drive it, as a linear (parity) relation of up
    to :data:`ACTUATOR_MAX_INPUTS` inputs chosen by the same forward selection (each kept only
    where it cuts the held-out error by :data:`MIN_GAIN`), kept where its held-out error is
    below that of ``ch``, the test chosen as any tag's (a rule grid of at most
    :data:`MAX_INPUTS` inputs, or a short window's two). A loop compensating a disturbance
    holds its measurement and moves its valve; the valve's test is then the one that fires,
    and the tighter its prediction the smaller the disturbance it sees."""
    lin = select_inputs(ctx, ch.tag, candidates, test=ch.test, max_inputs=ACTUATOR_MAX_INPUTS,
                        method=short.LINEAR)  # fmt: skip
    if len(lin.steps) <= len(ch.steps) or not ch.steps:
        # neither found an input: keep the tag's own (a level test), not an empty linear one
        keep = ch if ch.steps or not lin.steps else lin
    else:
        keep = lin if lin.steps[-1].rmse_pct < ch.steps[-1].rmse_pct else ch
    if keep is lin:
        was = ch.steps[-1].rmse_pct if ch.steps else ch.baseline_rmse_pct
        lin.method = short.LINEAR
        lin.why = (
            f"a controller output: linear test of {len(lin.steps)} inputs, held-out error "
            f"{lin.steps[-1].rmse_pct:.2f} % against {was:.2f} % for {len(ch.steps)} "
            f"input(s) ({ch.method})"
        )
    return keep


def _short_method(ctx: _Context, ch: TestChoice) -> None:
    """A short window's test: a rule grid of :func:`short.short_sets` sets where the data
    fill its cells and it beats the linear test's held-out error by more than
    :data:`MIN_GAIN`, else the linear test (``ch.method``, ``ch.sets``, ``ch.why`` set)."""
    specs = [InputSpec.parse(s) for s in ch.inputs]
    cols = [ctx.column(s.tags[0], s.lag) for s in specs]
    ins = [ctx.variable(s.tags[0], s.lag) for s in specs]
    lin = ch.steps[-1].rmse_pct
    ch.method = short.LINEAR
    sets = short.short_sets(cols, [v.span for v in ins])
    if sets is None:
        ch.why = (
            f"too few samples for a grid of {SETS_RANGE[0]} sets per input "
            f"({short.SHORT_PER_CELL} a cell): linear test, held-out error {lin:.2f} %"
        )
        return
    grid_ins = [dc_replace(v, sets=sets) for v in ins]
    scorer = BlockScorer(
        _rulebase(ch.test, ctx.vars[ch.tag], [], ctx.period), [], ctx.column(ch.tag), ctx.block
    )
    grid, _ = scorer.score(grid_ins, cols)
    if math.isfinite(grid) and grid < lin * (1 - MIN_GAIN):
        ch.method, ch.sets = "wm-avg", sets
        ch.why = (
            f"rule grid of {sets} sets per input: held-out error {grid:.2f} % against "
            f"{lin:.2f} % linear"
        )
    else:
        ch.why = (
            f"linear test: held-out error {lin:.2f} % against {grid:.2f} % for a grid of "
            f"{sets} sets per input"
        )


def tracked_set_point(
    tag: str, frame: pd.DataFrame, candidates: Sequence[str], info: Mapping[str, TagInfo]
) -> str | None:
    """The set-point ``tag`` is held at, if any: the set-point (:func:`is_set_point`) among
    ``candidates`` it follows most closely, provided the RMS of ``tag − set-point`` over the
    window is at most :data:`TRACKS` times ``tag``'s standard deviation (the set-point as it
    stands accounts for at least 3/4 of the tag's variance). A controller holds its measurement
    there, so the measurement moves with the operators' choices and nothing else in the
    window says why. A set-point is held at no other."""
    if is_set_point(tag, info.get(tag)):
        return None
    y = frame[tag].to_numpy(float)
    sd = float(np.nanstd(y))
    best = None
    for c in candidates:
        if c == tag or not is_set_point(c, info.get(c)):
            continue
        rms = float(np.sqrt(np.nanmean((y - frame[c].to_numpy(float)) ** 2)))
        if rms <= TRACKS * sd and (best is None or rms < best[0]):
            best = (rms, c)
    return best[1] if best else None


def asked_for(loops: Sequence[Loop], named: Mapping[str, str]) -> dict[str, str]:
    """Each controller output → its own loop's set-point tag (declared, or found by its name,
    ``named``: output → set-point): the quantity asked for, which a fault-free valve follows
    (a flow loop's valve opens with the flow asked for, at the pressures that drive it). A
    candidate input of the output's test even where :func:`same_measurement` drops it — the
    flow set-point and its valve move together — because under a cascade the loop's own
    measurement agrees with the set-point whatever its bias: the outer loop moves the
    set-point by the bias, and only the valve against the flow asked for shows it (issue 34,
    item 4; docs/how-to/unit-loops.md, "A flow loop under a cascade")."""
    out = dict(named)
    out.update({lp.out: lp.sp for lp in loops if lp.out and lp.fixed is None and lp.sp})
    return out


def cascade_outputs(loops: Sequence[Loop]) -> dict[str, tuple[str, ...]]:
    """A cascade's outer controller outputs (a declared loop's ``out`` that is another
    declared loop's set-point) → the inner loop's measurement and valve: what the output
    drives, never an input of its test (the inner loop holds its measurement at it), which
    is predicted from the process conditions that drive it (item 7)."""
    inner = {lp.sp: lp for lp in loops if lp.fixed is None and lp.sp}
    return {
        lp.out: tuple(t for t in (inner[lp.out].pv, inner[lp.out].out) if t)
        for lp in loops
        if lp.out and lp.out in inner
    }


def controller_output(sp: str, tags: Sequence[str]) -> str | None:
    """The output tag of the controller whose set-point is ``sp``, by the DCS naming of a
    controller block's parameters: the set-point's name with its suffix (``SP``, ``SETPOINT``)
    replaced by an output's (:data:`OUTPUT_NAMES`: ``OUT``, ``OP``, ``MV``, ``CO``), any
    case, the same separator (``TIC103.SP`` → ``TIC103.OUT``); None where no such tag is in
    ``tags``."""
    m = re.search(r"([._\-\s]?)(SP|SETPOINT|SET_POINT)$", sp, flags=re.IGNORECASE)
    if m is None:
        return None
    stem, sep = sp[: m.start()], m.group(1)
    have = {t.upper(): t for t in tags}
    for name in OUTPUT_NAMES:
        if (hit := have.get(f"{stem}{sep}{name}".upper())) is not None:
            return hit
    return None


def loop_test(ctx: _Context, tag: str, sp: str | InputSpec, *, test: str) -> TestChoice:
    """The test of a controlled tag: its model is the control loop's own relation, the
    measurement at its set-point plus the loop's steady offset (``track``,
    :mod:`diag_plugin.models.track`), so its residual is the control error, at any set-point
    an operator enters. Chosen for every tag a controller holds: modelled from the other
    tags instead, such a tag is predicted from whatever moved with the operators' set-point
    choices in the window, which another period's choices break (false alarms); a fitted
    function of the set-point (a rule grid, a polynomial) is unknown or bends away from the
    identity at set-points the window never saw. ``sp`` a set-point tag, or a fixed
    set-point's ``const(120.4)`` spec (no response time: it never moves)."""
    out = ctx.vars[tag]
    y = ctx.column(tag)
    base = sp if isinstance(sp, InputSpec) else InputSpec("", (sp,), 0)
    # one scorer: its base is the training mean, each variant the loop at a response time
    rb = _rulebase(test, out, [ctx.spec_variable(base)], ctx.period, method=LOOP_METHOD)
    scorer = BlockScorer(rb, [], y, ctx.block)
    tracks = f"{base.param:.12g}" if base.fn == "const" else base.tags[0]
    choice = TestChoice(test, tag, scorer.base_rmse, method=LOOP_METHOD, tracks=tracks)
    # the loop's response time: the set-point as it was d samples ago, d on held-out error
    # over the dead-time horizon (a slow loop — an averaging level — lags a set-point step)
    scored = []
    # (no response time either from a set-point that never moved in the window)
    for lag in loop_lags(ctx.max_lag) if not base.fn and sp not in ctx.fixed_sp else [0]:
        spec = base.with_lag(lag)
        ins, cols = [ctx.spec_variable(spec)], [ctx.spec_column(spec)]
        rmse, cov = scorer.score(ins, cols)
        if math.isfinite(rmse):
            scored.append((rmse, lag, cov))
    if not scored:  # no held-out block scored: too few rows (a piece that barely ran)
        raise UserError(
            f"loop {tag}: its test could not be scored on any held-out block of the "
            f"{int(np.isfinite(y).sum())} rows it learns from (a declared piece's: where it "
            "runs): too few; build on a longer window"
        )
    low = min(r for r, _, _ in scored)
    rmse, lag, cov = min((x for x in scored if x[0] <= low * (1 + TOLERANCE)), key=lambda x: x[1])
    choice.steps.append(Step(str(base.with_lag(lag)), rmse, cov))
    return choice


def loop_lags(max_lag: int, n: int = 12) -> list[int]:
    """Response times tried for a loop: 0 and ``n`` steps spaced geometrically up to
    ``max_lag`` samples (a few seconds and many minutes both within reach at 1 s)."""
    if max_lag < 1:
        return [0]
    return sorted({0, *np.unique(np.round(np.geomspace(1, max_lag, n)).astype(int)).tolist()})


def evaluation_for(period: str) -> dict[str, float | int]:
    """Residual evaluation for the model's grid: the example unit's delays (30 samples of
    1 s) and filter (cut-off 0.01 of Nyquist at 1 s) kept in time, but never under 3
    samples of delay nor a filter longer than ~5 samples — on a grid of minutes the data
    are already averaged per period and a delay of 30 samples would be hours."""
    s = pd.Timedelta(period).total_seconds()
    delay = int(min(30, max(3, round(30.0 / s))))
    lowpass = float(f"{min(0.2, max(0.01, 0.01 * s)):.3g}")
    return {"lowpass": lowpass, "on_delay": delay, "off_delay": delay}


def alarm_settings(period: str, rows: int | None = None) -> dict[str, float]:
    """ISA-18.2 alarm settings in time for the unit file (:mod:`~diag_plugin.diagnose.
    unitloops`): the on-delay of :func:`evaluation_for` in seconds; an off-delay of at least
    :data:`OFF_DELAY_S` (with the on-delay it spaces two alarms of one test by more than a
    third of :data:`CHATTER_WINDOW_S`, so no fault raises more than 3 episodes in it); a
    :data:`DEADBAND` of the threshold; the spread tests' window :data:`SPREAD_WINDOW_S`, at
    least 20 samples; the oscillation hold's window, :data:`OSCILLATION_WINDOWS` spread
    windows (a test that swung there and back, + − +, within two of it stays on until a side
    is quiet for one: a limit cycle is one alarm, issue 34 item 6;
    :class:`~diag_plugin.diagnose.unitloops.OscillationHold`), at most
    :func:`oscillation_cap` of a window of ``rows`` samples (None: no cap)."""
    s = pd.Timedelta(period).total_seconds()
    ev = evaluation_for(period)
    on_s = ev["on_delay"] * s
    spread = float(max(SPREAD_WINDOW_S, 20 * s))
    return {
        "on_delay_s": float(on_s),
        "off_delay_s": float(max(ev["off_delay"] * s, OFF_DELAY_S)),
        "deadband": DEADBAND,
        "spread_window_s": spread,
        "oscillation_window_s": min(OSCILLATION_WINDOWS * spread, oscillation_cap(rows, s)),
    }


def oscillation_cap(rows: int | None, period_s: float) -> float:
    """The longest oscillation hold window (seconds) a window of ``rows`` samples supports:
    the hold arms on :data:`~diag_plugin.diagnose.unitloops.OSCILLATION_CHANGES` side changes
    within as many windows, and that span must fit in one of the :data:`FOLDS` time blocks
    the thresholds were learned and checked over (a swing longer than a block is one the
    thresholds never saw as one; issue 34 H11: 400 samples at 3 min, a spread window of 20
    samples, four of them 80 and the span 160 of the window's 400; capped: 40). None: no
    cap."""
    from diag_plugin.diagnose.unitloops import OSCILLATION_CHANGES

    if rows is None:
        return math.inf
    return float(math.floor(rows / (FOLDS * OSCILLATION_CHANGES)) * period_s)


#: ISA-18.2 settings ``diag unit build`` writes (seconds; a share of the threshold)
OFF_DELAY_S = 240.0
DEADBAND = 0.1
SPREAD_WINDOW_S = 600.0
#: the oscillation hold's window in spread windows ``W``: the spread test's running MAD sees
#: a cycle of period up to ``2W`` (half a cycle in its window spans both extremes); both
#: sides' alarms of such a cycle fall within one period, and a stick-slip cycle's periods
#: vary by a factor of two and more (the jacket of tests/jacket4.py: 43–244 samples between
#: up-crossings), hence twice that. Chosen between 2 and 4 on the tuning runs (the chemical
#: plant's tv104_stiction: 3.7 / 2.0 episodes at 0.1 %; tests/jacket4.py: 7–11 / 1–2 a day),
#: the fault-free alarms the same at both (docs/how-to/unit-loops.md)
OSCILLATION_WINDOWS = 4.0
#: the window of the chattering rule: more than 3 alarm episodes in it is chattering
CHATTER_WINDOW_S = 600.0


def warm_kernels() -> None:
    """Load the compiled Wang–Mendel kernels (fit, every level's inference, a coarse level's
    design and the choice's normal equations, the search of set counts) into this process
    before the build's worker pools fork, so every worker of every pool inherits them
    instead of loading them from numba's cache again (~0.3 s CPU a process)."""
    from diag_plugin.fuzzy.wang_mendel import WangMendelRegressor, scoring_node_fit

    x = np.linspace(0.0, 0.5, 40)
    X = np.column_stack([x, x[::-1]])
    m = WangMendelRegressor([(0.0, 1.0), (0.0, 1.0)], (0.0, 1.0), n_sets=9)
    m.fit(X, X.sum(axis=1) / 2).predict_detail(np.column_stack([x + 0.1, x]))
    m.level_nodes(1)  # a coarse level's design (compiled corners and smoothness)
    with scoring_node_fit():  # the choice's normal equations over each rule's corners
        m.fit(X, X.sum(axis=1) / 2).level_nodes(1)
    sets_for_data([x], [(0.0, 1.0)])  # the compiled search of set counts


def _reader(frame: pd.DataFrame):
    idx = frame.index

    def read(a: pd.Timestamp, b: pd.Timestamp) -> pd.DataFrame:
        return frame.iloc[idx.searchsorted(a) : idx.searchsorted(b)]

    return read


@dataclass
class _FitJob:
    """What training one test's model needs (:func:`_fit_test`) beside the window and its
    context: the same for every test."""

    name: str
    folder: Path
    info: dict
    period: str
    start: pd.Timestamp
    end: pd.Timestamp
    source: str
    write: bool  # the worker writes the model file (a local pool); else the client does
    short: bool = False  # a short window (short.Plan.short): a linear test guards its range


def _fit_test(
    ch: TestChoice, job: _FitJob, frame: pd.DataFrame, ctx: _Context
) -> tuple[float, str, str, TestModel | None]:
    """Train ``ch``'s model on the window: its validation error, the model file's name, its
    text and the model as the unit loads it from that text. With ``job.write`` (a local
    worker's share, see :mod:`.parallel`) the worker writes the file and reads it back, so
    the parent parses none; on a Dask cluster the worker cannot reach the folder, and the
    client writes the text once every test is trained."""
    from diag_plugin.diagnose.unit import model_of_test
    from diag_plugin.diagnose.unitfile import UnitError
    from diag_plugin.training.chunked import train

    period = job.period
    specs = [InputSpec.parse(s) for s in ch.inputs]
    cols = [ctx.spec_column(s) for s in specs]
    ins = _with_sets([ctx.spec_variable(s) for s in specs], cols, len(frame))
    if ch.sets:  # a short window's grid: the sets its cells were judged at
        ins = [dc_replace(v, sets=ch.sets) for v in ins]
    if ch.method == short.LINEAR:  # a span from a few hundred samples only scales
        ins = [_linear_span(v, s, ctx, job.short) for v, s in zip(ins, specs, strict=True)]
    mpath = job.folder / f"{job.name}_{ch.test}.toml"
    rb = _rulebase(f"{job.name}_{ch.test}", ctx.vars[ch.tag], ins, period, mpath, ch.method)
    rb.doc["model"]["description"] = (
        f"built by diag unit build {job.name} from {job.start.isoformat()} … {job.end.isoformat()}"
    )
    if ch.balance and ch.method == short.LINEAR:  # a level's rate: its noise corrected for
        from diag_plugin.unitbuild.balance import input_noise

        noise = input_noise(specs, ctx)
        if noise is not None:
            rb.doc["rules"][INPUT_NOISE] = noise
    if ch.method == short.LINEAR and ins and job.short:
        learned = _learned_output(ch.tag, ctx)
        if learned is not None:
            rb.doc["rules"][LEARNED_OUTPUT] = [float(f"{v:.10g}") for v in learned]
    rb.edited()
    res = train(rb, _reader(frame), job.start, job.end, holdout=HOLDOUT)
    validation = float(res.validation.get("rmse_pct", math.nan))
    rb.apply_training(
        res.model,
        {
            "source": job.source or "diag unit build",
            "from": job.start.isoformat(),
            "to": job.end.isoformat(),
            "samples": res.samples,
            "validation_rmse_pct": _r(validation) or "n/a",
            "trained_at": pd.Timestamp.now(tz="UTC").floor("s").isoformat(),
        },
    )
    if job.write:
        rb.save(mpath)  # the file as written, read back (RuleBase.save)
    else:
        rb = RuleBase(rb.dumps(), mpath)  # the file as it will be written and read
    try:
        tm = model_of_test(ch.test, rb)
    except UnitError:  # Unit.load reads it again and says where it is broken
        tm = None
    return validation, mpath.name, rb.text, tm


def _linear_span(v: Variable, spec: InputSpec, ctx: _Context, short_window: bool) -> Variable:
    """A linear test's input ``v`` with the span its test guards (past it the line answers only
    within ``linear.EDGE_MOVE``, then the test is unknown): a tag without an instrument range,
    its observed range :func:`short.widened`; in a short window a tag with one (a tags CSV's
    ``lo``/``hi``), that widened range clipped to it (:func:`short.guarded`; issue 34, item 3).
    A long window's ranged tag, a function's input and a constant set-point keep their span."""
    tag = spec.tags[0] if not spec.fn else ""
    if not tag:
        return v
    info = ctx.info.get(tag)
    if not (info and info.span):
        return dc_replace(v, span=short.widened(v.span))
    if not short_window or tag not in ctx.vars:
        return v
    seen = variable_for(str(InputSpec("", (tag,), 0)), frame=ctx.frame, tag_info={}).span
    return dc_replace(v, span=short.guarded(seen, info.span))


def _learned_output(tag: str, ctx: _Context) -> tuple[float, float] | None:
    """A short window's linear test's output range as learned (the observed range, as a tag
    without an instrument range gets for its span), where the tag's span is an instrument's
    and wider: the line's allowance past an input's span is a share of it
    (:data:`~diag_plugin.models.linear.LEARNED_OUTPUT`; issue 34, item 3). None otherwise."""
    info = ctx.info.get(tag)
    if not (info and info.span) or tag not in ctx.vars:
        return None
    seen = variable_for(str(InputSpec("", (tag,), 0)), frame=ctx.frame, tag_info={}).span
    lo, hi = max(seen[0], info.span[0]), min(seen[1], info.span[1])
    return (lo, hi) if lo < hi and hi - lo < info.span[1] - info.span[0] else None


def _written(folder: Path, fits: list, kept: Sequence[TestChoice], name: str) -> None:
    """The model files trained on a cluster, written by the client (atomically, as
    ``RuleBase.save``)."""
    for ch, (_, _, text, _) in zip(kept, fits, strict=True):
        path = folder / f"{name}_{ch.test}.toml"
        tmp = path.with_suffix(path.suffix + ".tmp")
        tmp.write_text(text, encoding="utf-8")
        tmp.replace(path)


def build_unit(
    name: str,
    frame: pd.DataFrame,
    *,
    folder: str | Path,
    period: str,
    tag_info: Mapping[str, TagInfo | Mapping[str, object]] | None = None,
    tags: Sequence[str] | None = None,
    far: float | None = None,
    max_inputs: int = MAX_INPUTS,
    force: bool = False,
    source: str = "",
    progress: Callable[[str, int, int], None] | None = None,
    loops: Sequence[Loop] = (),
    workers: int | DaskPool | None = None,
    manual: Sequence[Manual | str] = (),
    disturbances: Sequence[Disturbance | str] = (),
    running: Running | str | None = None,
    equipment: Sequence[Running] = (),
    states: Sequence[str] = (),
) -> BuildResult:
    """Build unit ``name`` from ``frame`` (the fault-free window, aligned on ``period``; every
    column a candidate input) into ``folder``: model files ``NAME_TEST.toml`` and
    ``NAME.unit.toml`` with thresholds learned to ``far`` false alarms per hour of
    operation. ``tags``: the tests (default: :func:`choose_tests`). ``progress(stage, done,
    total)`` is called as the stages advance; ``workers``: processes that choose the
    tests' inputs, train their models and compute their residuals for the thresholds
    (default: every core, :mod:`~diag_plugin.unitbuild.parallel`), or a
    :class:`~diag_plugin.unitbuild.parallel.DaskPool` to do that work on a Dask cluster (the
    same unit). ``manual``: hand valves (:mod:`~diag_plugin.diagnose.manual`), never tested,
    their span written in ``[manual]``; ``disturbances``: measured disturbances
    (:mod:`~diag_plugin.unitbuild.loops`), never tested, candidate inputs; ``running``: the
    run condition (:mod:`~diag_plugin.diagnose.running`): everything is learned from the rows
    where the unit runs, the stopped ones as an outage. Raises
    :class:`~historian.errors.UserError` on input the build cannot use; a build that fails
    leaves none of the files it wrote and puts back those it overwrote (:func:`_remove_partial`)."""
    folder = Path(folder)
    made = not folder.exists()
    since = time.time_ns() - 100_000_000  # file times lag the clock by a tick
    before = _unit_files(folder, name)
    try:
        with one_blas_thread():
            return _build_unit(name, frame, folder=folder, period=period, tag_info=tag_info,
                               tags=tags, far=far, max_inputs=max_inputs, force=force,
                               source=source, progress=progress, loops=loops,
                               workers=workers, manual=manual,
                               disturbances=disturbances, running=running,
                               equipment=equipment, states=states)  # fmt: skip
    except BaseException:
        _remove_partial(folder, name, since, made, before)
        raise
    finally:
        if isinstance(workers, DaskPool):
            workers.release()


def _ours(p: Path, name: str) -> bool:
    """Whether ``p`` is one of unit ``name``'s files (its unit file, a model file, their
    temporary copies while written)."""
    from diag_plugin.rulebase.folder import UNIT_SUFFIX

    return p.name in (f"{name}{UNIT_SUFFIX}", f"{name}{UNIT_SUFFIX}.tmp") or (
        p.name.startswith(f"{name}_") and p.name.endswith((".toml", ".toml.tmp"))
    )


def _unit_files(folder: Path, name: str) -> dict[str, bytes]:
    """Unit ``name``'s files in ``folder`` before a build, by content (what a failed
    ``--force`` rebuild puts back)."""
    if not folder.is_dir():
        return {}
    return {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file() and _ours(p, name)}


def _remove_partial(
    folder: Path, name: str, since: int, made: bool, before: dict[str, bytes] | None = None
) -> None:
    """After a failed build: the unit's files this build wrote (written since ``since``, ns)
    removed, those it overwrote (under ``--force``) put back as they were (``before``), and
    ``folder`` removed too if the build made it and it is left empty — no half-written unit,
    and a unit that was there before is there as it was."""
    if not folder.is_dir():
        return
    before = before or {}
    gone, back = [], []
    for p in folder.iterdir():
        try:
            if not (_ours(p, name) and p.is_file() and p.stat().st_mtime_ns >= since):
                continue
            old = before.get(p.name)
            if old is None:
                p.unlink()
                gone.append(p.name)
            elif p.read_bytes() != old:
                tmp = p.with_name(p.name + ".restore")
                tmp.write_bytes(old)
                os.replace(tmp, p)
                back.append(p.name)
        except OSError:  # pragma: no cover - removed meanwhile
            continue
    if gone or back:
        log.warning("build of %s failed: removed %d file(s) it wrote and put back %d it "
                    "overwrote in %s", name, len(gone), len(back), folder)  # fmt: skip
    if made:
        with contextlib.suppress(OSError):
            folder.rmdir()  # only if empty


def _build_unit(
    name: str,
    frame: pd.DataFrame,
    *,
    folder: str | Path,
    period: str,
    tag_info,
    tags,
    far,
    max_inputs: int,
    force: bool,
    source: str,
    progress,
    loops: Sequence[Loop],
    workers: int | DaskPool | None,
    manual: Sequence[Manual | str] = (),
    disturbances: Sequence[Disturbance | str] = (),
    running: Running | str | None = None,
    equipment: Sequence[Running] = (),
    states: Sequence[str] = (),
) -> BuildResult:
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.diagnose.unitfile import UnitError, new_unit_text
    from diag_plugin.learn.thresholds import DEFAULT_FAR, LearnError, learn_thresholds
    from diag_plugin.rulebase.folder import UNIT_SUFFIX

    far = DEFAULT_FAR if far is None else far
    check_far(far)
    folder = Path(folder)
    path = folder / f"{name}{UNIT_SUFFIX}"
    if path.exists() and not force:
        raise UserError(f"{path} exists (use --force to overwrite)")
    if isinstance(frame.index, pd.DatetimeIndex) and frame.index.tz is None:
        frame = frame.tz_localize("UTC")  # naive timestamps: UTC, as diag import reads them
    run_col = None
    run_note = ""
    if running is not None:  # the stopped rows as an outage; the run tag no candidate
        rc, run_col, run_note = run_condition(frame, running, loops, manual, disturbances)
        frame = learnable(frame, rc).drop(columns=[rc.tag])
        # a mode declared a state too (a tags CSV's role state, --running MODE=1): the run
        # condition says what it does; where the unit runs it holds one value
        states = [t for t in states if t != rc.tag]
    # pieces of equipment (diagnose/equipment.py): their tests learn where each runs
    eqs, eq_notes = equipment_conditions(frame, equipment, None if running is None else rc.tag)
    have = frame.notna().any(axis=1).to_numpy()
    rows = int(have.sum())
    if rows == 0:
        raise UserError(
            "the window holds no samples of these tags"
            + (f" where the unit runs ({run_note})" if run_col is not None else "")
        )
    # the declared window may reach past the data: judge the tags over the span they cover
    first, last = np.flatnonzero(have)[[0, -1]]
    trimmed = first > 0 or last < len(frame) - 1
    if trimmed:
        frame = frame.iloc[first : last + 1]
    if rows < MIN_ROWS:
        raise UserError(
            f"the window holds {rows} samples of the {period} grid; a unit needs at least "
            f"{MIN_ROWS} (give a longer window)"
        )
    if tags is not None:
        unknown = [t for t in tags if t not in frame.columns]
        if unknown:
            raise UserError(f"tag(s) {', '.join(unknown)} not in the data")
    seconds: dict[str, float] = {}
    t_start = time.perf_counter()
    info = tag_infos(tag_info)
    loops = checked_loops(loops, list(frame.columns))
    declared = {lp.pv: lp for lp in loops}
    hand = hand_valves(frame, info, manual, loops)
    driven = declared_disturbances(frame, manual, disturbances, loops)
    outs = cascade_outputs(loops)
    # with a run condition a tag's good samples are counted among the rows where it runs
    judged = frame if run_col is None else frame.loc[frame.notna().any(axis=1)]
    tests, skipped = choose_tests(judged, info, tags, [lp.sp for lp in loops],
                                  {**{m.tag: hand_plan(m, info) for m in hand},
                                   **{t: DISTURBANCE_PLAN for t in driven}},
                                  [lp.out for lp in loops if lp.out],
                                  checked_states(states, list(frame.columns), loops))  # fmt: skip
    if tags is not None and skipped:
        raise UserError("cannot test: " + "; ".join(f"{t}: {why}" for t, why in skipped.items()))
    if not tests:
        why = "; ".join(f"{t}: {w}" for t, w in skipped.items())
        raise UserError(f"no tag of the window can be tested ({why})")
    taken: set[str] = set()
    names = {tag: test_name(tag, taken) for tag in tests}
    exist = [p for t in names.values() if (p := folder / f"{name}_{t}.toml").exists()]
    if exist and not force:
        raise UserError(
            f"model file(s) {', '.join(str(p) for p in exist[:3])}"
            + (f" and {len(exist) - 3} more" if len(exist) > 3 else "")
            + " exist (use --force to overwrite, or another unit name)"
        )
    hand_tags = frozenset(m.tag for m in hand)
    ctx = _Context(frame, info, period, hand_tags)
    loop_notes = []
    held_sp: list[ManualSpan] = []  # the held set-points' [fixed] rows
    for lp in loops:
        if lp.pv in frame.columns and not frame[lp.pv].notna().any():
            # as a hand valve's: the declared loop would vanish, its measurement untested
            raise UserError(
                f"{lp.where(lp.pv)}: loop {lp}: its measurement {lp.pv} has no value in the "
                "window (give a window where it reads)"
            )
        if lp.fixed is not None or lp.sp in ctx.vars or lp.pv not in ctx.vars:
            continue
        if ctx.hold_set_point(lp.sp, lp.pv):
            here = held_set_points(judged, {lp.sp: lp.pv})
            held_sp += here
            at = "".join(f" ({learned_text(r).removesuffix(' over its window')} ± {r.margin:.4g})"
                         for r in here)  # fmt: skip
            loop_notes.append(
                f"{lp.pv}: its set-point {lp.sp} did not move over the window{at}: "
                "the loop's test reads it as it is (the control error), with no response time; "
                "every other test learned the plant only there, so moved beyond the farthest "
                f"{lp.pv} went from it the unit is CHECK_FUNCTION naming it ([fixed]; a "
                "window with set-point moves, or `diag unit accept` of one, learns it)"
            )
        else:
            loop_notes.append(
                f"{lp.pv}: its set-point {lp.sp} has no value in the window: no loop test, "
                f"{lp.pv} is modelled from the other tags"
            )
    plan = short.plan_for(
        rows, period, max_inputs, evaluation_for(period)["lowpass"], ACTUATOR_MAX_INPUTS
    )
    # a long fast window: inputs chosen on a coarser grid (short.coarse_frame)
    sel = ctx
    if plan.factor > 1:
        sel = _Context(short.coarse_frame(frame, plan.factor), info, plan.select_period, hand_tags)
    short.slow_inputs(plan, list(ctx.vars), ctx.column)
    same = same_measurement(frame, list(ctx.vars), workers)
    warm_kernels()
    seconds["read and screen"] = time.perf_counter() - t_start

    t0 = time.perf_counter()
    tick = (lambda d, n: progress("choose inputs", d, n)) if progress else None
    named = {
        out: sp
        for sp in frame.columns
        if is_set_point(sp, info.get(sp)) and (out := controller_output(sp, list(ctx.vars)))
    }  # a controller output found by its name → its set-point
    # each controller output → the tag its loop holds (an undeclared loop's unknown: None)
    held: dict[str, str | None] = dict.fromkeys(named)
    held.update({lp.out: lp.pv for lp in loops if lp.out})  # declared: the tag it holds
    asks = asked_for(loops, named)
    # a controller output and what it drives are a cause and its effect, not one measurement
    same = driven_reads_output(same, held)
    ctxs = {None: (ctx, sel, frame)}
    for e in eqs:  # a piece's tests choose their inputs from the rows where it runs
        # among its own tags, the unit-wide ones and the others' run tags (issue 34)
        left = foreign_tags(e, eqs, loops, ctx.vars)
        f_e = learnable_for(frame, e).drop(columns=[t for ts in left.values() for t in ts])
        if left:
            eq_notes.append(own_inputs_note(e, left))
        # the load it carries where the pieces share one: a unit-wide derived input
        shares = share_inputs(e, eqs, shared_loads([t for t in driven if t in ctx.vars], info))
        if shares:
            eq_notes.append(share_note(e, shares))
        f_e = with_shares(f_e, shares)
        c_e = _Context(f_e, info, period, hand_tags)
        for lp in loops:  # a loop's held set-point, as the window's
            if lp.sp in ctx.fixed_sp:
                c_e.fixed_sp[lp.sp] = ctx.fixed_sp[lp.sp]
            elif lp.sp in ctx.vars and lp.sp not in c_e.vars and lp.pv in c_e.vars:
                c_e.hold_set_point(lp.sp, lp.pv)
        s_e = c_e if plan.factor <= 1 else _Context(short.coarse_frame(f_e, plan.factor), info,
                                                      plan.select_period, hand_tags)  # fmt: skip
        c_e.derived = s_e.derived = {s.base: s for s in shares}
        ctxs[e.name] = (c_e, s_e, f_e)

    def _choice_args(e):
        c, s_, f = ctxs[None if e is None else e.name]
        return (names, same, c, s_, plan, f, info, declared, held, asks, outs)

    choices = map_by_equipment(
        _choose, tests, lambda t: t, _choice_args, eqs,
        lambda fn, items, args: map_tests(fn, items, args, workers=workers, progress=tick),
    )  # fmt: skip
    seconds["choose inputs"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    folder.mkdir(parents=True, exist_ok=True)
    idx = frame.index
    start, end = idx[0], idx[-1] + pd.Timedelta(period)
    models: dict[str, str] = {}
    notes: list[str] = []
    notes.extend(plan.reasons)
    if run_note:
        notes.append(run_note)
    notes.extend(eq_notes)
    notes.extend(loop_notes)
    if trimmed:
        notes.append(
            f"the data cover {frame.index[0]} … {frame.index[-1] + pd.Timedelta(period)} of "
            "the window: the tags are judged and the unit learned over that span"
        )

    kept: list[TestChoice] = []
    # the tags no test reads a relation of, in order: those left untested, then a short
    # window's slow tags tested only on their level
    untested = list(skipped)
    slow_level: set[str] = set()
    for ch in choices:
        if not ch.steps and plan.short and not ch.tracks:
            why = short.level_test(ch, ctx.column(ch.tag), MIN_GAIN)
            if why:  # a slow level test (True) reads no relation; a reason: no test
                untested.append(ch.tag)
            if why is True:
                slow_level.add(ch.tag)
            if isinstance(why, str):
                skipped[ch.tag] = why
                continue
        elif not ch.steps:
            untested.append(ch.tag)
            skipped[ch.tag] = (
                "no other tag predicts it on held-out data (best cut of the error under "
                f"{MIN_GAIN:.0%}): nothing to model it from"
            )
            continue
        kept.append(ch)
    if plan.short:
        kept.extend(joint_tests(kept, ctx, taken, notes))
        # a hand valve, a declared disturbance: no test; a slow level test does not see the
        # common move of a slow pair whose other tag's test reads it (a pair test does); a
        # discrete state is a mode of the plant, never a tag at fault: no pair test watches it
        # (a filter's state washed once in 400 samples, acceptance-filters.md)
        blind = [
            t
            for t in untested
            if t not in {m.tag for m in hand}
            and t not in driven
            and not skipped.get(t, "").startswith((DISCRETE_WHY, RARE_WHY))
        ]
        kept.extend(blind_pair_tests(kept, blind, plan, ctx, taken))
        kept = unread_slow_levels(kept, slow_level, skipped)
    t1 = time.perf_counter()
    kept.extend(
        _balance_tests(kept, names, taken, notes, ctx, sel, plan, info=info, held=held,
                       loops=loops, set_point_of=named, same=same, workers=workers)
    )  # fmt: skip
    seconds["choose inputs"] += time.perf_counter() - t1
    t0 += time.perf_counter() - t1  # the training's time without the balance tests' choice
    # each model trained and written on its own: on every core, as the inputs were chosen
    tick = (lambda d, n: progress("train models", d, n)) if progress else None
    loaded: dict[Path, TestModel] = {}  # model file → its model, as Unit.load reads it
    job = _FitJob(name, folder, info, period, start, end, source,
                  write=not isinstance(workers, DaskPool), short=plan.short)  # fmt: skip
    # the window and its context: on a cluster, the objects the choice already scattered
    fits = map_by_equipment(
        _fit_test, kept, lambda ch: None if ch.balance else ch.tag,
        lambda e: (job, ctxs[None if e is None else e.name][2],
                   ctxs[None if e is None else e.name][0]), eqs,
        lambda fn, items, args: map_tests(fn, items, args, workers=workers, progress=tick),
    )  # fmt: skip
    if not job.write:
        _written(folder, fits, kept, name)
    for ch, (validation, fname, _, tm) in zip(kept, fits, strict=True):
        ch.validation_rmse_pct = validation
        models[ch.test] = os.path.relpath((folder / fname).resolve(), folder.resolve())
        if tm is not None:
            loaded[tm.path.resolve()] = tm
    if not kept:
        raise UserError("no tag could be modelled from the others: nothing to test")
    edges = edgeless_note([(ch.test, loaded.get((folder / models[ch.test]).resolve()))
                           for ch in kept])  # fmt: skip
    kept.extend(spread_tests(kept, models, taken))
    seconds["train models"] = time.perf_counter() - t0

    text = new_unit_text(
        name,
        models,
        description=f"built by diag unit build from {start.isoformat()} … {end.isoformat()}",
    )
    doc = tomlkit.parse(text)
    for ch in kept:
        if ch.actuator:
            doc["tests"][ch.test]["actuator"] = ch.actuator
        if ch.tracks:
            doc["tests"][ch.test]["set_point"] = ch.tracks
        if ch.statistic != "level":
            doc["tests"][ch.test]["statistic"] = ch.statistic
        if not ch.combined:
            doc["tests"][ch.test]["combined"] = False
        if ch.balance:
            doc["tests"][ch.test]["balance"] = True
    for k, v in {**evaluation_for(period), **alarm_settings(period, rows)}.items():
        doc["evaluation"][k] = v
    doc["evaluation"]["oscillation_window_s"].comment(
        "4 x spread_window_s (at most a tenth of the window): a test swung there and back"
        " (+ - +) within two of it stays on until a side is quiet for one (a limit cycle,"
        " one alarm)"
    )
    if plan.lowpass is not None:
        doc["evaluation"]["lowpass"] = plan.lowpass
    # a unit-level combined test beside the per-tag tests, and alarms isolated to tags
    # (docs/reference/units.md, "The combined test and isolation to tags")
    doc["evaluation"]["combined"] = True
    doc["evaluation"]["isolation"] = "tags"
    doc["build"] = _build_table(kept, skipped, start, end, period, far, plan.max_inputs)
    if plan.reasons:
        doc["build"]["plan"] = plan.reasons
    # the window's set-points, as judged here (name or description): the unit never blames
    # one (unittags.structure), and it has no historian metadata at run time
    # (a cascade's inner set-point, the outer controller's output, is no operator's entry)
    doc["build"]["set_points"] = [
        t for t in frame.columns if is_set_point(t, info.get(t)) and t not in outs
    ]
    # the discrete states left out of the tests (a pump's run feedback): a mode of the plant,
    # never a tag at fault either (unittags.structure)
    doc["build"]["states"] = [t for t, why in skipped.items() if why.startswith(DISCRETE_WHY)]
    if run_col is not None:
        doc["build"]["running"] = run_note
        doc["running"] = running_table(rc)
    if eqs:
        doc["equipment"] = equipment_table(eqs)
    if hand:
        doc["manual"] = manual_table(hand)
    # a piece's run tag constant over the window (it ran throughout) is no [fixed] tag
    fixed = constant_tags(judged, info, [lp.sp for lp in loops],
                          [m.tag for m in hand] + [e.rc.tag for e in eqs])  # fmt: skip
    if fixed or held_sp:  # held_sp: a declared loop's held set-point (its loop note says it)
        doc["fixed"] = fixed_table([*fixed, *held_sp])
    if fixed:
        notes.append(fixed_note(fixed))
    declared_sp = {lp.sp for lp in loops}
    unguarded = [t for t, why in skipped.items() if why.startswith(CONSTANT_WHY)
                 and is_set_point(t, info.get(t)) and t not in declared_sp]  # fmt: skip
    if unguarded:
        notes.append(unguarded_note(unguarded))
    narrow = narrow_spans(judged, info, kept, skipped, unguarded)
    if narrow:  # the inputs learned over a narrow part of their span: said whatever the count
        doc["build"]["narrow"] = narrow
        notes.append(narrow_note(narrow))
    if own := narrow_outputs(judged, kept):  # their own tests unknown outside (issue 34)
        doc["narrow"] = narrow_table(own)
        notes.append(narrow_outputs_note(own))
    if chosen := chosen_set_points(judged, kept, outs):  # the tests reading them, unknown
        doc["chosen"] = chosen_table(chosen)
        notes.append(chosen_note(chosen))
    path.write_text(tomlkit.dumps(doc), encoding="utf-8")

    t0 = time.perf_counter()
    try:
        unit = Unit.load(path, folder, models_cache=loaded)
        learned = learn_thresholds(
            unit, [frame], far=far, mapper=lambda fn, items, args: map_tests(fn, items, args,
                                                                            workers=workers)
        )  # fmt: skip
        uf = unit.file  # the unit file as just written and read (learning only reads it)
        uf.set_learned(learned)
        # the settles after an operator's set-point step, a hand valve's move and a state's
        # change (a pump started), from the window's own (diagnose/settle.py), on the unit
        # with its thresholds: one pass, the window's steps found once, its residuals
        # replayed at most once; the run tag beside the learned rows (its starts are the
        # run condition's changes)
        settle_frame = frame if run_col is None else frame.assign(**{rc.tag: run_col})
        # the combinations of the discrete states the window held long enough to teach the
        # models (diagnose/combos.py), their dwell the unit's quiet time: first, so that the
        # states no model reads are watched by the state settle too (settle.unit_combos)
        combos = state_combos(unit, frame, list(doc["build"]["states"]))
        if combos is not None:
            put_states(uf, *combos)
        settle_unit = Unit(uf, unit.models, unit.matrix)
        replay = Replay(settle_unit, settle_frame)  # the window's residuals, replayed once
        settles = settle_bounds(settle_unit, settle_frame, replay)
        for key, says, value, how in settles:
            if value > 0:
                uf.doc["evaluation"][key] = value
                uf.build[says] = how
                uf.doc["build"][says] = how
                notes.append(how)
        # each piece's own start's bound, from its own starts on its own tests
        pieces = piece_settle_bounds(settle_unit, settle_frame, replay)
        for piece, value, how in pieces:
            if value is not None:
                uf.doc["equipment"][piece]["settle_max_s"] = value
            notes.append(how)
        if pieces:
            uf.doc["build"]["equipment_settle"] = [how for *_, how in pieces]
        # a start's envelope (diagnose/envelope.py): a fault present at a start ends its
        # settle; learned from the held-out residuals the thresholds were learned from
        held = HeldOut(settle_unit, settle_frame, learned.scaled)
        envs = settle_envelopes(settle_unit, settle_frame, held,
                                {key: value for key, _, value, _ in settles},
                                {piece: value for piece, value, _ in pieces})  # fmt: skip
        if any(env is not None for _, env, _ in envs):
            uf.doc["envelope"] = {k: env.as_table() for k, env, _ in envs if env is not None}
        if envs:
            uf.doc["build"]["envelope"] = [how for *_, how in envs]
            notes.extend(how for *_, how in envs)
        if combos is not None:
            # and those visited repeatedly, each visit shorter, once a state settle holds
            # the changes into them (state_settle_max_s)
            visited = short_combos(unit, frame, combos,
                                 uf.doc["evaluation"].get("state_settle_max_s"))  # fmt: skip
            if visited:
                combos = (combos[0], sorted({*combos[1], *visited}), combos[2])
                put_states(uf, *combos)
            notes.append(combos_note(unit, *combos, short=visited))
        # the spread tests' release on a long window (diagnose/unitloops.ReleaseHold): after
        # the settles, which never read it (it never raises)
        rel_s, rel_how = release_window(
            frame, [(ch.tag, ch.tracks) for ch in kept if ch.statistic == "spread"],
            pd.Timedelta(period).total_seconds(),
        )  # fmt: skip
        release = release_thresholds(unit, frame, rel_s) if rel_s > 0 else {}
        if release:
            uf.doc["evaluation"]["release_window_s"] = rel_s
            uf.doc["evaluation"]["release_window_s"].comment(
                "a spread test on stays on while its spread over this window is above its"
                " release (the build's largest, and at least its median x"
                f" {1 + RELEASE_SE * RELEASE_PRECISION:g}): " + rel_how
            )
            for t, v in release.items():
                uf.doc["tests"][t]["release"] = v
        if (any(value > 0 for *_, value, _ in settles) or combos is not None or pieces or envs
                or release):  # fmt: skip
            uf.save()
        else:
            uf.save(as_read=True)  # the text set_learned read back: not dumped again
    except UnitError as exc:
        raise UserError("the built unit has problems:\n" + "\n".join(exc.problems)) from None
    except LearnError as exc:
        models = unit.models
        hints = short_run_hints(
            eqs, frame, exc.problems, lambda t: models[t].output if t in models else None
        )
        raise UserError(
            f"unit {name}: cannot learn thresholds:\n"
            + "\n".join("  " + p for p in [*exc.problems, *hints])
        ) from None
    notes.extend(learned.warnings)
    if edges:  # after what the unit decided (settles, states): the terminal shows four notes
        notes.append(edges)
    seconds["learn thresholds"] = time.perf_counter() - t0
    seconds["total"] = time.perf_counter() - t_start
    if progress:
        progress("learn thresholds", 1, 1)
    window = (start.isoformat(), end.isoformat())
    return BuildResult(
        name, path, period, window, kept, skipped, far, learned, seconds, notes, manual=hand
    )


def run_condition(
    frame: pd.DataFrame,
    running: Running | str,
    loops: Sequence[Loop],
    manual: Sequence[Manual | str],
    disturbances: Sequence[Disturbance | str],
) -> tuple[RunCondition, pd.Series, str]:
    """The declared run condition (``--running TAG[=VALUE]``, a tags CSV's role ``running``;
    :mod:`~diag_plugin.diagnose.running`) checked against the window: its tag in the data,
    in no loop, no hand valve nor disturbance, two-valued over the window, ``VALUE`` one of
    the two (default: the higher), or a mode of more values, ``VALUE`` one of them
    (:func:`~diag_plugin.unitbuild.runlevels.unit_run`). Returns the condition (with the
    share of the window's samples it ran on), the tag's column and the plan's note of it. A
    problem names the tag and where it was declared."""
    rc = running if isinstance(running, Running) else parse_running(running)
    where, tag = rc.where, rc.tag
    if tag not in frame.columns:
        raise UserError(f"{where}: run condition {tag} (running) is not in the data")
    parts = {t: lp for lp in loops for t in (lp.pv, lp.sp, lp.out) if t}
    if tag in parts:
        raise UserError(
            f"{where}: run condition {tag} (running) is a tag of loop {parts[tag]}: a run "
            "condition is a state, no loop's part"
        )
    named = {m.tag if isinstance(m, Manual) else m for m in manual}
    named |= {d.tag if isinstance(d, Disturbance) else d for d in disturbances}
    if tag in named:
        raise UserError(
            f"{where}: run condition {tag} (running) is also declared a hand valve or a "
            "measured disturbance: declare it one or the other"
        )
    col = frame[tag].astype(float)
    x = col.to_numpy()
    x = x[np.isfinite(x)]
    got = unit_run(rc, x)
    n_run = int(got.runs(x).sum())
    note = (
        f"{tag}: the run condition (declared: judged only while {tag} = {got.run:g}"
        + (f", stopped at {listed([v for v in got.levels if v != got.run])}" if got.levels else "")
        + f"); the unit ran on {got.share:.1%} of the window's samples ({n_run} of {x.size}): "
        "learned from those only, the stopped ones as an outage"
    )
    return got, col, note


def running_table(rc: RunCondition) -> tomlkit.items.Table:
    """The unit file's ``[running]`` table (:mod:`~diag_plugin.diagnose.running`)."""
    t = tomlkit.table()
    t.comment("written by `diag unit build --running`: judged only while it runs")
    for k, v in rc.as_table().items():
        t[k] = v
    return t


def hand_valves(
    frame: pd.DataFrame, info: Mapping[str, TagInfo], manual: Sequence[Manual | str],
    loops: Sequence[Loop],
) -> list[ManualSpan]:  # fmt: skip
    """The declared hand valves (``--manual``, a tags CSV's role ``manual``) with the span the
    window holds each in (:func:`~diag_plugin.diagnose.manual.learned_span`); a tag not in the
    data, in a loop, or without a value in the window is refused naming it and where it was
    declared."""
    decl = [m if isinstance(m, Manual) else Manual(m) for m in manual]
    where = {}
    for m in decl:
        where.setdefault(m.tag, m.where)
    out = []
    for tag in checked_manual(decl, list(frame.columns), loops):
        span = learned_span(tag, frame[tag].to_numpy(float))
        if span is None:
            raise UserError(f"{where[tag]}: hand valve {tag} (manual) has no value in the window")
        out.append(span)
    return out


#: what the build's plan says of a declared measured disturbance
DISTURBANCE_PLAN = (
    "a measured disturbance (declared: it drives the process, nothing here sets it): an "
    "input, never tested"
)


def checked_states(
    states: Sequence[str], columns: Sequence[str], loops: Sequence[Loop]
) -> list[str]:
    """The declared discrete states (``--state``, a tags CSV's role ``state``), each in
    ``columns`` and in no declared loop; else :class:`~historian.errors.UserError`."""
    in_loops = {t for lp in loops for t in (lp.pv, lp.sp, lp.out) if t}
    for t in states:
        if t not in columns:
            raise UserError(f"--state {t}: not in the data")
        if t in in_loops:
            raise UserError(f"--state {t}: a tag of a declared loop, not a mode of the plant")
    return list(states)


def declared_disturbances(
    frame: pd.DataFrame, manual: Sequence[Manual | str],
    disturbances: Sequence[Disturbance | str], loops: Sequence[Loop],
) -> list[str]:  # fmt: skip
    """The declared measured disturbances' tags (``--disturbance``, a tags CSV's role
    ``disturbance``); one not in the data, in a loop or also declared a hand valve is refused
    naming it and where it was declared."""
    decl = [d if isinstance(d, Disturbance) else Disturbance(d) for d in disturbances]
    hands = [m if isinstance(m, Manual) else Manual(m) for m in manual]
    have = set(checked_declared([*hands, *decl], list(frame.columns), loops))
    return [t for t in dict.fromkeys(d.tag for d in decl) if t in have]


def hand_plan(span: ManualSpan, info: Mapping[str, TagInfo]) -> str:
    """What the build's plan says of a hand valve: ``manual (an operator's setting): an input,
    never tested; learned 20–35 %``, with the margin."""
    unit = getattr(info.get(span.tag), "unit", "") or ""
    unit = f" {unit}" if unit else ""
    margin = (
        f" (± {span.margin:.3g} margin: {MARGIN_SAYS})" if span.margin > 0
        else " (no margin: it reads without noise)"
    )  # fmt: skip
    return (
        f"manual (an operator's setting): an input, never tested; learned "
        f"{span.min:.4g}–{span.max:.4g}{unit}{margin}"
    )


def manual_table(spans: Sequence[ManualSpan]) -> tomlkit.items.Table:
    """The unit file's ``[manual]`` table (docs/reference/units.md)."""
    return span_table(
        spans,
        "written by `diag unit build --manual`: hand valves, never tested; min/max as the "
        f"window learned them, margin {MARGIN_SAYS}; outside [min - margin, max + margin] "
        "the tests reading one are unknown",
    )


def span_table(spans: Sequence[ManualSpan], comment: str) -> tomlkit.items.Table:
    """A table of ``{min, max, margin}`` rows under ``comment`` (``[manual]``, ``[fixed]``)."""
    t = tomlkit.table()
    t.add(tomlkit.comment(comment))
    for s in spans:
        row = tomlkit.inline_table()
        row.update(s.as_row())
        t[s.tag] = row
    return t


def _balance_tests(kept, names, taken, notes, ctx, sel, plan, *, workers, **plans):
    """A second test for each manipulated flow, its balance (:mod:`.balance`): chosen on
    every core, kept where its held-out error is small enough; the others said in
    ``notes``."""
    from diag_plugin.unitbuild import balance

    todo = balance.balance_plans(kept, names, taken, **plans)
    out = []
    for bp, ch in zip(todo, map_tests(balance.choose_balance, todo, (ctx, sel, plan),
                                      workers=workers), strict=True):  # fmt: skip
        if balance.kept(ch, bp.held):
            out.append(ch)
        else:
            taken.discard(bp.test)
            notes.append(f"no balance test of {bp.tag}: {ch.why}")
    return out


def joint_tests(
    kept: Sequence[TestChoice], ctx: _Context, taken: set[str], notes: list[str]
) -> list[TestChoice]:
    """A short window's joint tests (:func:`short.joint_groups`): one per group of tags whose
    tests (linear or a grid) predict each other, where the window shows enough of the group's common
    direction; the output is the group's tag with the largest |loading| on its first
    component (:func:`short.joint_groups` puts it first), the others its inputs (method
    ``joint``, :mod:`diag_plugin.models.joint`), and its ``why`` names it. Groups left out
    are said in ``notes``."""
    lin = [ch for ch in kept if ch.steps and not ch.tracks and ch.method != short.JOINT]
    pairs = [(ch.tag, [InputSpec.parse(s).tags[0] for s in ch.inputs]) for ch in lin]
    out = []
    for group, n, why in short.joint_groups(pairs, ctx.column):
        if why:
            notes.append(f"no joint test of {', '.join(group)}: {why}")
            continue
        base = next(ch for ch in lin if ch.tag == group[0])
        ch = TestChoice(
            test_name(f"{group[0]}_joint", taken),
            group[0],
            base.baseline_rmse_pct,
            steps=[Step(str(InputSpec("", (t,))), math.nan, 1.0) for t in group[1:]],
            method=short.JOINT,
            why=(
                f"joint test of {', '.join(group)}: their tests predict each other, so a "
                "common rise cancels in each; this one watches the group's score on its first "
                f"principal component (T² of their standardised deviations, {n:.0f} "
                f"independent values in the window), written as a model of {group[0]}, the "
                "tag with the largest loading on that component"
            ),
        )
        out.append(ch)
    return out


def unread_slow_levels(
    kept: Sequence[TestChoice], slow_level: set[str], skipped: dict[str, str]
) -> list[TestChoice]:
    """The tests kept, less the slow level tests (:func:`short.level_test`) of tags another
    test reads: such a tag is watched through that relation (a pair test where both are slow,
    :func:`blind_pair_tests`), and a level test of it would only share the budget, raising
    every other test's threshold (the cooler's sticking valve, ``tests/test_unit_valves.py``:
    its cooling-water temperature read by two tests, 4 independent values). The tag is then
    left untested (``skipped``, naming the tests that read it)."""
    readers: dict[str, list[str]] = {}
    for ch in kept:
        for spec in ch.inputs:
            for tag in InputSpec.parse(spec).tags:
                if tag in slow_level and ch.test not in readers.setdefault(tag, []):
                    readers[tag].append(ch.test)
    out = []
    for ch in kept:
        if ch.tag in slow_level and not ch.steps and not ch.combined and readers.get(ch.tag):
            skipped[ch.tag] = (
                f"no other tag predicts it on held-out data and it is too slow for a level test "
                f"in T² (under {short.SHORT_LEVEL_INDEPENDENT} independent values); read by "
                f"{', '.join(readers[ch.tag])}, which watch it"
            )
            continue
        out.append(ch)
    return out


def blind_pair_tests(
    kept: Sequence[TestChoice],
    untested: Sequence[str],
    plan: short.Plan,
    ctx: _Context,
    taken: set[str],
) -> list[TestChoice]:
    """A short window's joint test of each slow tag left blind with the slow tag whose test
    reads it (:func:`short.blind_pairs`): the pair's score on its first component (method
    ``joint``, :func:`short.component`; the output the tag whose test reads the other, the
    other at the dead time that test found — two tags' standardised loadings are equal, and
    at its dead time the pair's relation, and so its common direction, is the test's),
    whatever the independent values it holds — it covers a tag that has no test at all. It
    stays out of the combined ``T²`` (``combined = false``): a test added for a blind tag
    sees nothing of the faults the unit's other tests see, and as one more dimension of
    ``T²`` it would lower ``T²`` under its limit through them (SKAB's tuning runs, round 13:
    the leak other/4 75 → 0 % at 0.1); it keeps its own thresholds and share of the budget."""
    lin = [ch for ch in kept if ch.steps and not ch.tracks and ch.method != short.JOINT]
    out = []
    for a, spec in short.blind_pairs([(ch.tag, ch.inputs) for ch in lin], untested, plan.slow):
        b = InputSpec.parse(spec)
        got = short.component([ctx.column(a), ctx.spec_column(b)])
        if got is None:
            continue
        base = next(ch for ch in lin if ch.tag == a)
        out.append(
            TestChoice(
                test_name(f"{a}_pair", taken),
                a,
                base.baseline_rmse_pct,
                steps=[Step(spec, math.nan, 1.0)],
                method=short.JOINT,
                combined=False,
                why=(
                    f"pair test of {a} and {spec}: {b.tags[0]} is too slow for a test of its "
                    f"own ({plan.slow[b.tags[0]]:.0f} independent values) and {a}'s test reads "
                    "it, so their common move is seen by no test; this one watches the pair's "
                    f"score on its first principal component ({got[1]:.0f} independent values "
                    "in the window), at the dead time the test found; kept out of the "
                    "combined T² (combined = false): it covers a blind tag"
                ),
            )
        )
    return out


#: grids a note names by test before it counts the rest (:func:`edgeless_note`)
EDGELESS_NAMED = 3


#: an input the window saw at most this many independent values of is named by the build's
#: narrow-span note (:func:`narrow_spans`): of its later values, at its own pace, a share
#: ``2 / (n + 1)`` falls outside the window's range, a quarter or more here
NARROW_INDEPENDENT = 7
#: how the narrow-span note begins: the CLI prints it whatever the count of notes
NARROW_SAID = "learned over a narrow part of their span"
#: a narrow input's line where no guard watches it (:func:`narrow_spans`)
UNWATCHED_SAID = "not watched: its moves are judged by the tests, declare its loop"


def narrow_spans(
    frame: pd.DataFrame,
    info: Mapping[str, TagInfo],
    kept: Sequence[TestChoice],
    skipped: Mapping[str, str],
    unwatched: Collection[str] = (),
) -> list[str]:
    """The unit's inputs the window saw too little of: held at one value, or moving slower
    than the window shows, so that the plant takes them past what the unit learned in its
    ordinary operation. Judged by the input's own time scale against the window's length:
    the window holds ``n`` independent values of it
    (:func:`~diag_plugin.models.series.effective_samples`, ``n / τ`` with ``τ`` its
    integrated autocorrelation time), and of ``n`` independent values the smallest and the
    largest enclose on average a share ``(n − 1) / (n + 1)`` of the values it takes (the
    order statistics' coverage, distribution-free: Wilks 1941), so ``2 / (n + 1)`` of its
    later values fall outside the window's range. Named: an input held at one value (a
    set-point, a mode, a speed the window did not move: every later move falls outside),
    or one of at most :data:`NARROW_INDEPENDENT` independent values (a quarter or more
    outside) whose window covers less than half its span (the tag's ``lo`` … ``hi``, as the
    models scale it; a tag without them is not judged). A fast input the window saw at a
    small part of its span is not named: the window saw its spread, and a loop holds it
    there (a controlled temperature at 73.2 °C of 0 … 100, about 80 values).

    Which inputs: every plain input of a kept test, and the tags left out as a discrete
    state, a set-point or a constant (kept candidate inputs, read by the unit). One line
    each: the tag, the span the window shows (its learned span), its span and the share,
    and its independent values; ``[]`` where none. The short window of the pasteuriser
    (400 samples of 10 s, one rate) learned its feed pump's speed at one value and the
    rate's set-point at 10.4 of 0 … 20 m³/h; its notes were cut at four and this was not
    on the screen (issue 34 item 5, ``i34-cip``). Under 5 % of the span, the rule before,
    it named 11 of its inputs, with the loops' controlled temperatures at 0.2 % (issue 34
    item 3, ``i34-review``): 7 now.

    ``unwatched``: the tags no guard watches (:func:`unguarded_note`: a set-point held over the
    window that no loop declares), their line saying so: the note's "where one leaves it the
    unit says so" is not true of them (issue 34, item 5)."""
    from diag_plugin.models.series import effective_samples

    read = [InputSpec.parse(s).tags[0] for ch in kept for s in ch.inputs
            if InputSpec.parse(s).fn == ""]  # fmt: skip
    left = [t for t, why in skipped.items()
            if why.startswith((DISCRETE_WHY, CONSTANT_WHY, "a set-point"))]  # fmt: skip
    out = []
    for t in dict.fromkeys([*read, *left]):
        span = getattr(info.get(t), "span", None)
        if span is None or t not in frame.columns:
            continue
        v = frame[t].to_numpy(float)
        v = v[np.isfinite(v)]
        if not v.size:
            continue
        lo, hi = float(v.min()), float(v.max())
        share = (hi - lo) / (span[1] - span[0])
        n = effective_samples(v) if hi > lo else 0.0
        if hi > lo and (n > NARROW_INDEPENDENT or 2 * share >= 1):
            continue
        why = skipped.get(t, "an input").split(" (")[0]
        seen = (
            "held at one value, every later move outside"
            if hi == lo
            else f"about {n:.1f} independent values: {2 / (n + 1):.0%} of later ones outside"
        )
        if t in unwatched:
            why += f"; {UNWATCHED_SAID}"
        out.append(f"{t} {lo:.4g} … {hi:.4g} ({share:.1%} of its span {span[0]:.4g} … "
                   f"{span[1]:.4g}; {seen}; {why})")  # fmt: skip
    return out


def narrow_outputs(frame: pd.DataFrame, kept: Sequence[TestChoice]) -> list[ManualSpan]:
    """The tags a rule grid tests that the window saw at most :data:`NARROW_INDEPENDENT`
    independent values of (:func:`narrow_spans`' count, its span not needed: of ``n``
    independent values a share ``2 / (n + 1)`` of the later ones falls outside the window's
    range, a quarter or more here), each with the span the window shows it in
    (:func:`~diag_plugin.diagnose.manual.learned_span`: its extremes, 3 × its noise beyond).

    A rule grid's answer is a weighted mean of its rules' conclusions, values its window
    showed: where the tag it tests is outside them its residual is at least the distance to
    them, the excursion itself. For a tag moving faster than the window that is rare and a
    fault; for one of a few independent values it is ordinary operation (a hand valve no one
    declared, at a position its window never held: docs/how-to/unit-loops.md, "The line
    imported off the grid"), so the unit makes that test unknown there and names the tag
    (:class:`~diag_plugin.diagnose.manual.ManualGuard`), as it does the tests reading it. A
    linear or a loop's test extrapolates and is not named; a tag held at one value is not
    tested."""
    from diag_plugin.models.series import effective_samples

    out: dict[str, ManualSpan] = {}
    for ch in kept:
        if not ch.method.startswith("wm") or ch.tag in out or ch.tag not in frame.columns:
            continue
        x = frame[ch.tag].to_numpy(float)
        v = x[np.isfinite(x)]
        if v.size < 2 or v.min() == v.max() or effective_samples(v) > NARROW_INDEPENDENT:
            continue
        span = learned_span(ch.tag, x)
        if span is not None:
            out[ch.tag] = span
    return list(out.values())


#: a ``[chosen]`` set-point's margin is at least this share of its magnitude: a set-point's
#: value written with fewer digits (a CSV's six, a float32 historian's seven) is no move
CHOSEN_RESOLUTION = 1e-4


def chosen_set_points(
    frame: pd.DataFrame, kept: Sequence[TestChoice], cascade: Collection[str] = ()
) -> list[ManualSpan]:
    """The loops' set-points the window saw at most :data:`NARROW_INDEPENDENT` independent
    values of (an operator's choice, moved a few times over the window; not held at one
    value, which ``[fixed]`` and the settle guard cover; not a cascade's inner set-point,
    ``cascade``, which the outer controller moves and a fault may), each with the span the
    window shows it in (:func:`~diag_plugin.diagnose.manual.learned_span`); none where no line
    (a test that is not a rule grid nor a loop's own) reads one of them or the measurement a
    loop holds at one (a rule grid has no rule where the window had no sample, Kościelny et
    al., eq. 5, and is unknown past the set-points it learned already; a line answers
    everywhere).

    A test reading such an input learned the plant at the window's few operating points:
    the chemical plant at 1 s, three days, each loop's set-point at 3.5–7 independent
    values, predicted its recycle valve by a line through three of them (``FIC102.OUT =
    f(FI102, LI101, FIC102.SP)``, the level ``LI101`` standing in for the recycle drum's,
    which had moved with it), and at the next days' set-points that line was off by more
    than its band on 54–88 % of the samples. The margin is the window's (3 × the set-point's
    noise, 0 for an operator's entry) but at least :data:`CHOSEN_RESOLUTION` of its
    magnitude. Where such a set-point is outside what the
    window showed, the unit makes every such line unknown (the operators set the window's
    points together: a move of any is a point the lines never saw) and names it
    (:class:`~diag_plugin.diagnose.manual.ManualGuard`, ``[chosen]``); the loops' own tests
    (the measurement against its set-point, its spread) keep judging."""
    from diag_plugin.models.series import effective_samples

    held: dict[str, set[str]] = {}
    for ch in kept:
        if ch.tracks and ch.tracks in frame.columns and ch.tracks not in cascade:
            held.setdefault(ch.tracks, set()).add(ch.tag)
    out = []
    for sp in held:
        x = frame[sp].to_numpy(float)
        v = x[np.isfinite(x)]
        if v.size < 2 or v.min() == v.max() or effective_samples(v) > NARROW_INDEPENDENT:
            continue
        span = learned_span(sp, x)
        if span is not None:  # a value written with fewer digits is no move
            floor = CHOSEN_RESOLUTION * max(1.0, abs(span.min), abs(span.max))
            out.append(dc_replace(span, margin=max(span.margin, floor)))
    pvs = {t for s in out for t in held[s.tag]}
    lines = [
        {InputSpec.parse(i).tags[0] for i in ch.inputs if InputSpec.parse(i).fn == ""}
        for ch in kept
        if not ch.tracks and not ch.method.startswith("wm")
    ]
    if not any(plain & ({s.tag for s in out} | pvs) for plain in lines):
        return []  # no line reads one: the rows would guard nothing
    return out


def chosen_table(spans: Sequence[ManualSpan]) -> tomlkit.items.Table:
    """The unit file's ``[chosen]`` table (:func:`chosen_set_points`)."""
    return span_table(
        spans,
        f"written by `diag unit build`: loops' set-points the window saw at most "
        f"{NARROW_INDEPENDENT} independent values of; min/max as the window learned them, "
        f"margin {MARGIN_SAYS}; where one is outside [min - margin, max + margin] the lines "
        "reading any of them, or a measurement a loop holds at one, are unknown (not the loops' "
        "own tests, nor the rule grids) and the unit names it",
    )


#: how the chosen set-points' note begins: the CLI prints it whatever the count of notes
CHOSEN_SAID = "set-point(s) seen at"


def spans_said(spans: Sequence[ManualSpan]) -> str:
    """``N <what> at most 7 independent values in the window (TAG lo … hi; …)`` without the
    what: the head of the notes of :func:`chosen_note` and :func:`narrow_outputs_note`."""
    said = "; ".join(f"{s.tag} {s.min:.4g} … {s.max:.4g}" for s in spans)
    return f"at most {NARROW_INDEPENDENT} independent values in the window ({said})"


def chosen_note(spans: Sequence[ManualSpan]) -> str:
    """The build's note of :func:`chosen_set_points`."""
    return (
        f"{len(spans)} {CHOSEN_SAID} {spans_said(spans)}: the lines reading one, or a "
        "measurement a loop holds at one, learned the plant at those few operating points; "
        "where any one is outside, they are unknown and the unit names it (CHECK_FUNCTION), "
        "the loops' own tests judging on, and `diag unit accept` of a period at the new "
        "set-point teaches it"
    )


def narrow_table(spans: Sequence[ManualSpan]) -> tomlkit.items.Table:
    """The unit file's ``[narrow]`` table (:func:`narrow_outputs`)."""
    return span_table(
        spans,
        f"written by `diag unit build`: tags a rule grid tests that the window saw at most "
        f"{NARROW_INDEPENDENT} independent values of; min/max as the window learned them, "
        f"margin {MARGIN_SAYS}; outside [min - margin, max + margin] the tag's own test is "
        "unknown (its residual there is the excursion) and the unit names it",
    )


#: how the narrow-outputs note begins: the CLI prints it whatever the count of notes
NARROW_OUTPUTS_SAID = "tested tag(s) seen at"


def narrow_outputs_note(spans: Sequence[ManualSpan]) -> str:
    """The build's note of :func:`narrow_outputs`."""
    return (
        f"{len(spans)} {NARROW_OUTPUTS_SAID} {spans_said(spans)}: a quarter or more of their "
        "later values fall outside; there each one's own test is unknown and the unit names "
        "it (CHECK_FUNCTION), and `diag unit accept` of a period where it moved teaches it more"
    )


def narrow_note(spans: Sequence[str]) -> str:
    """The build's note of :func:`narrow_spans` (``""``: none)."""
    if not spans:
        return ""
    but = ", but for one marked not watched" if any(UNWATCHED_SAID in s for s in spans) else ""
    return (
        f"{len(spans)} input(s) {NARROW_SAID} (held at one value, or at most "
        f"{NARROW_INDEPENDENT} independent values in the window over under half their span: "
        "at their own pace a quarter or more of their later values fall outside what the window "
        f"showed): {'; '.join(spans)}: the unit knows the plant only there; where one leaves "
        f"it the unit says so (CHECK_FUNCTION){but}, and a longer window, or `diag unit accept` "
        "of a period where it moved, teaches it more"
    )


def edgeless_note(tests: Sequence[tuple[str, TestModel | None]]) -> str:
    """The build's note on the rule grids that answer nothing past the window's range of an
    input (issue 34, item 3): a grid whose first or last set of an input holds no rule (a span
    from the window's range, padded by 2 %, is more than half a set's step wider than that
    range from 27 sets on, :func:`~diag_plugin.selection.spans.variable_for`). A Wang–Mendel
    model clips an input past its span to the edge set and answers there only from a rule, and
    its coarse levels only between the first and last sets holding data
    (:mod:`diag_plugin.fuzzy.wang_mendel`): right past the window the test is unknown, the unit
    CHECK_FUNCTION naming the input (:mod:`diag_plugin.diagnose.operating`), where a window under
    :data:`.short.SHORT_ROWS` samples' linear test answers a quarter of the input's range
    further (:func:`.short.widened`). Answering there instead cost the long windows' detection
    (docs/how-to/unit-short-windows.md, seventh try), so the build says it. ``tests``: per
    test its name and model as the unit loads it (None: not loaded); "" where no grid is
    edgeless."""
    from diag_plugin.diagnose.operating import model_ranges

    grids, said = 0, []
    for name, tm in tests:
        m = getattr(tm, "model", None)
        parts = getattr(m, "partitions_", None)
        if parts is None or not getattr(m, "keys_", np.empty(0)).size:
            continue
        grids += 1
        cells = m.cell_indices()
        plain = [InputSpec.parse(s).fn == "" for s in tm.inputs]
        ranges = iter(model_ranges(m, tm.inputs))
        for j, p in enumerate(parts):
            if not plain[j]:
                continue
            tag, lo, hi = next(ranges)
            if cells[:, j].min() > 0 or cells[:, j].max() < p.n - 1:
                said.append(f"{name} ({InputSpec.parse(tm.inputs[j])} {lo:.4g} … {hi:.4g}, its "
                            f"span {p.lo:.4g} … {p.hi:.4g} in {p.n} sets)")  # fmt: skip
                break
    if not said:
        return ""
    more = f" and {len(said) - EDGELESS_NAMED} more" if len(said) > EDGELESS_NAMED else ""
    return (
        f"{len(said)} of {grids} rule grids answer nothing past the range their rules cover "
        f"of an input (no rule in an edge set): {'; '.join(said[:EDGELESS_NAMED])}{more}; "
        "past it the unit is CHECK_FUNCTION and names the input (diag unit accept learns the "
        f"new range), where a window under {short.SHORT_ROWS:,} samples' linear test answers "
        "a quarter of the input's range past the window"
    )


def spread_tests(kept: Sequence[TestChoice], models: dict[str, str], taken: set[str]):
    """A spread test beside each loop test with an actuator (:mod:`~diag_plugin.unitbuild.
    loops`): the same model, ``statistic = "spread"``, named ``<test>_spread``; its model
    file entered in ``models``."""
    out = []
    for ch in list(kept):
        if ch.tracks and ch.actuator and ch.statistic == "level":
            name = test_name(f"{ch.test}_spread", taken)
            models[name] = models[ch.test]
            out.append(dc_replace(ch, test=name, statistic="spread", steps=list(ch.steps)))
    return out


#: the relative standard error (one s.e.) the spread release's long window knows the loop
#: error's MAD to (:func:`release_window`; benchmarks/line7_spread_window.py, fixed before it
#: was replayed)
RELEASE_PRECISION = 0.2


def release_window(frame: pd.DataFrame, loops: Sequence[tuple[str, str]], period_s: float
                   ) -> tuple[float, str]:  # fmt: skip
    """The spread release's window (seconds; :class:`~diag_plugin.diagnose.unitloops.
    ReleaseHold`): the one whose running MAD of each loop's fault-free control error
    ``PV − SP`` rests on ``(1.166 / RELEASE_PRECISION)²`` independent samples (the MAD's
    asymptotic variance ``1.36 σ² / n``), ``n`` samples holding ``n / (1 + 2 Σ ρ_k)``
    independent ones (``ρ`` the error's autocorrelation, summed to its first zero); the
    longest over the loops, and how it was got (0: no loop with enough samples)."""
    from diag_plugin.models.series import autocorrelation

    n = (1.166 / RELEASE_PRECISION) ** 2
    best, how = 0.0, ""
    for pv, sp in loops:
        if pv not in frame.columns or sp not in frame.columns:
            continue
        e = (frame[pv] - frame[sp]).to_numpy(float)
        e = e[np.isfinite(e)]
        if e.size < 20:
            continue
        e = e - e.mean()
        if not np.any(e):
            continue
        rho, zero = autocorrelation(e)
        factor = max(1.0, 1.0 + 2.0 * float(rho[1:zero].sum()))
        if n * factor * period_s > best:
            best = n * factor * period_s
            how = (f"{n:.0f} independent samples of {pv} - {sp} x {factor:.1f} samples each "
                   f"(its autocorrelation to its first zero, lag {zero})")  # fmt: skip
    return float(f"{best:.6g}"), how


#: the release sits at least this many of the long window's standard errors
#: (:data:`RELEASE_PRECISION`) above the window's median long spread (:func:`release_thresholds`)
RELEASE_SE = 3.0


def release_thresholds(unit, frame: pd.DataFrame, window_s: float) -> dict[str, float]:
    """Per spread test the largest running spread (:class:`~diag_plugin.diagnose.unitloops.
    RunningSpread`) of its raw residual over ``window_s`` on the build's window, and at least
    its median × (1 + :data:`RELEASE_SE` × :data:`RELEASE_PRECISION`): a fault-free run's
    stiction alarm is held past its short window only beyond anything the build saw, and
    beyond what the long window's own error (:func:`release_window`) puts a fault-free run at.

    The largest alone is an in-sample figure. Where the loop error's long spread hardly
    moves over the window (a level held at 1 s: 0.2006 median, 0.2025 largest, % of span,
    over three days of the chemical plant) a run at another operating point sits above it
    for hours (0.200–0.206 on a tuning seed): each brief symptom of the loop then raised a
    hold that did not let go (the spread tests of three level and flow loops on 33–74 % of a
    fault-free run, docs/explanation/chemplant-benchmark.md "At 1 s")."""
    from diag_plugin.diagnose.unitloops import RunningSpread, spread_samples

    cols = unit.spread_cols
    if not cols.size or window_s <= 0:
        return {}
    raw = unit.reset().raw_residuals(frame).to_numpy(float)[:, cols]
    unit.reset()
    spread = RunningSpread(spread_samples(window_s, unit.period), len(cols)).transform(raw)
    out = {}
    floor = 1.0 + RELEASE_SE * RELEASE_PRECISION
    for k, j in enumerate(cols):
        x = spread[:, k]
        if np.isfinite(x).any() and np.nanmax(x) > 0:
            out[unit.tests[j]] = float(f"{max(np.nanmax(x), floor * np.nanmedian(x)):.6g}")
    return out


def _build_table(kept, skipped, start, end, period, far, max_inputs) -> tomlkit.items.Table:
    t = tomlkit.table()
    t.add(
        tomlkit.comment(
            "written by `diag unit build`: how each test's inputs were chosen (held-out error "
            "in % of span: before any input, then after each)"
        )
    )
    t["from"], t["to"] = start.isoformat(), end.isoformat()
    t["period"] = period
    t["far"] = float(f"{far:.6g}")
    t["max_inputs"] = max_inputs
    t["same_corr"] = SAME_CORR
    sk = tomlkit.table()
    for tag, why in skipped.items():
        sk[tag] = why
    tests = tomlkit.table()
    for ch in kept:
        row = tomlkit.inline_table()
        d = ch.as_dict()
        row["tag"] = ch.tag
        row["inputs"] = d["inputs"]
        row["rmse_pct"] = [x for x in d["rmse_pct"] if x is not None]
        row["coverage"] = [x for x in d["coverage"] if x is not None]
        if ch.excluded:
            row["same_as"] = ch.excluded
        if ch.tracks or ch.why or ch.method != "wm-avg":
            row["method"] = ch.method
        if ch.tracks:
            row["tracks"] = ch.tracks
        if ch.why:
            row["why"] = ch.why
        if ch.actuator:
            row["actuator"] = ch.actuator
        if ch.statistic != "level":
            row["statistic"] = ch.statistic
        if ch.declared:
            row["declared"] = True
        if ch.balance:
            row["balance"] = True
        tests[ch.test] = row
    t["tests"] = tests
    t["skipped"] = sk
    return t


def build_from_historian(
    url: str,
    name: str,
    start: pd.Timestamp,
    end: pd.Timestamp,
    *,
    folder: str | Path,
    tags: Sequence[str] | None = None,
    far: float | None = None,
    max_inputs: int = MAX_INPUTS,
    force: bool = False,
    progress: Callable[[str, int, int], None] | None = None,
    loops: Sequence[Loop] = (),
    period: str | None = None,
    workers: int | DaskPool | None = None,
    manual: Sequence[Manual | str] = (),
    disturbances: Sequence[Disturbance | str] = (),
    running: Running | str | None = None,
    equipment: Sequence[Running] = (),
    states: Sequence[str] = (),
) -> BuildResult:
    """:func:`build_unit` on the historian's window ``[start, end)``: every tag it holds is
    a candidate input; the grid period is ``period`` (``--period``: a faster tag averaged
    over each period, as ``diag model new --period``), else it comes from the data (the
    longest typical spacing of the tags, as ``diag model new`` chooses it)."""
    from historian.access import open_data, tag_sampling
    from historian.sampling import format_period, model_period
    from historian.store import Historian
    from historian.times import period_us

    if end <= start:
        raise UserError(f"--to {end} is not after --from {start}")
    with Historian.open(url) as h:
        known = sorted(str(t) for t in h.tags()["name"])
        last = h.time_range(known)[1] if known else None  # for the note on --to
    if not known:
        raise UserError("the historian holds no tags: diag import a file first")
    if tags is not None:
        unknown = [t for t in tags if t not in known]
        if unknown:
            raise UserError(
                f"tag(s) {', '.join(unknown)} not in the historian (it has: {', '.join(known)})"
            )
    t_read = time.perf_counter()
    # the tags read in shares on the local pool's workers (a Dask cluster's workers have no
    # access to the historian: read here); the same sampling and window as one read
    shares = (
        1 if isinstance(workers, DaskPool) else default_workers() if workers is None else workers
    )

    def mapper(fn, items, args):
        return map_tests(fn, items, args, workers=workers)

    if shares > 1:
        sampling = read_sampling(url, known, start, end, shares, mapper)
    else:
        sampling = tag_sampling(url, known, start, end)
    sampled = [s for s in sampling.values() if s.median_us > 0]
    if not sampled:
        raise UserError(f"no samples in the window {start} … {end}")
    said = "(--period)"
    if period is not None:
        try:
            period = format_period(period_us(period))
        except ValueError:
            raise UserError(f"--period {period!r} is not a duration like 10s or 3min") from None
    else:
        said = "from the data (the longest typical spacing of the tags)"
        try:
            period = format_period(model_period(sampled))
        except ValueError as exc:
            raise UserError(str(exc)) from None
    try:
        if shares > 1:
            frame, info = read_window(url, known, start, end, period, shares, mapper)
        else:
            frame, info = open_data(url, known, start, end, period)
    except (KeyError, ValueError) as exc:
        raise UserError(str(exc)) from None
    frame.attrs = {}
    frame = frame.astype(float)
    read_s = time.perf_counter() - t_read
    res = build_unit(
        name,
        frame,
        folder=folder,
        period=period,
        tag_info=info,
        tags=tags,
        far=far,
        max_inputs=max_inputs,
        force=force,
        progress=progress,
        source="diag unit build",
        loops=loops,
        workers=workers,
        manual=manual,
        disturbances=disturbances,
        running=running,
        equipment=equipment,
        states=states,
    )
    res.seconds = {"read": read_s, **res.seconds}
    res.seconds["total"] += read_s
    res.notes.insert(0, f"period {period} {said}")
    if left := last_left_out(last, end, period):
        res.notes.insert(1, left)
    return res


def last_left_out(last: pd.Timestamp | None, end: pd.Timestamp, period: str) -> str:
    """A note when the historian's last sample ``last`` lies at ``end`` or less than a
    period after it: the window ``[start, end)`` leaves it out, as it does when a user types
    an export's last time as ``--to`` (the 7-tag line at 1 min: one row of 8,641 moved the
    combined threshold 218 → 198, docs/how-to/unit-loops.md, "The line imported off the
    grid"); ``""`` otherwise."""
    step = pd.Timedelta(period)
    if last is None or not (end <= last < end + step):
        return ""
    return (
        f"the historian's last sample ({last}) is at or after --to {end}, which is exclusive: "
        f"the window leaves it out; --to {end + step} takes it in"
    )
