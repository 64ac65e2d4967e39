"""A second test for a manipulated flow: its balance (issue 34, items 4 and 7).

A flow that a controller output drives — the valve of a declared loop, or of a loop found by
its names (``LIC102.OUT`` beside ``LIC102.SP``) — is modelled by the build from that valve and
the pressure across it (``FI109`` from ``LIC102.OUT`` and ``PI101``): the best fit, and a
relation a leak does not break (the level loop closes the valve and the flow falls as the
valve says). The mass balance the leak breaks — the vessel's inflows against its outflows and
its level's rate — is fitted less closely, so the one test per tag never reads it.

So a manipulated flow, where no loop holds the flow itself, gets a second test
``<tag>_balance``, chosen from the plant's structure, never from the inputs the flow's own test
happened to pick (a disturbance or a downstream flow can read a valve as well as the flow it
drives; H3's tank pair: the feed and tank B's gravity drain got balance tests "driven by" the
pump, the pumped flow none):

- **which flow, by what** (:func:`driven_by`): the controller outputs are the declared loops'
  (``--loop PV=SP:OUT``, the tags CSV's ``role = out``) and those found by their names beside
  a set-point; the flows are the tags :func:`tag_kind` calls one. An output drives a flow where
  its moves precede and explain the flow's: the flow's changes over a few samples follow the
  output's within :data:`DRIVE_MAX_DEAD_S` (a liquid-full line answers in seconds), with
  ``|r| ≥`` :data:`DRIVE_MIN_R`, and more than the output's changes follow the flow's (a
  disturbance the loop answers leads the valve; a flow that follows minutes later does so
  through a vessel's inventory and is that vessel's). Of several, the one that explains most.
- **which level** (:func:`vessel_of`): the level the output's loop holds, where it is a level;
  else the level whose rate of change the flow explains most (``|r| ≥``
  :data:`VESSEL_MIN_R`); none, no balance test (a steam or coolant flow). The vessel's other
  flows: each flow that cuts the variance of that level's rate left by the flows so far by
  :data:`STREAM_MIN_GAIN` (the mass balance fitted), so a third flow of another vessel, which
  only moves with these, is not one.
- **the test** (:func:`mass_balance`): the vessel's mass balance, a linear (parity) relation of
  its other flows as they are and the level's change per sample ``rate(L)[k]`` (the
  accumulation term); kept where the level's rate cuts the held-out error by ``MIN_GAIN`` and
  the error is at most :data:`BALANCE_MAX_ERROR_PCT` % of the flow's span. It never reads the
  valve, its loop's set-point and measurement, nor any tag of another vessel. It is a test like
  any other (its own share of the false-alarm budget) and it models the flow, so its alarm
  names the flow's tag. The build's notes say, per flow, what drove it and which level it
  balances against, and why a flow whose test reads a valve got none.

What a tag measures (:func:`tag_kind`) is read from its ISA-5.1 name (first letter ``F``,
``L``, ``P``), else its description (``flow``, ``level``, ``pressure``), else its unit (a
quantity per time, a pressure unit); a set-point or a controller output is none of these.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from diag_plugin.diagnose.unittags import is_set_point
from diag_plugin.regressors import InputSpec
from diag_plugin.unitbuild import short
from diag_plugin.unitbuild.build import (
    ACTUATOR_MAX_INPUTS,
    MIN_GAIN,
    OUTPUT_NAMES,
    Step,
    TestChoice,
    _Context,
    _rulebase,
    test_name,
)
from diag_plugin.unitbuild.loops import Loop
from historian.taginfo import TagInfo

#: inputs of a balance test at most (as a controller output's linear test)
BALANCE_MAX_INPUTS = ACTUATOR_MAX_INPUTS
#: a balance test is kept where its held-out error is at most this share of the flow's span (%)
BALANCE_MAX_ERROR_PCT = 3.0
#: the suffix of a balance test's name (``FI109`` → ``FI109_balance``)
SUFFIX = "_balance"

#: an ISA-5.1 tag: a first letter (the measured variable), up to three more, a number
_ISA = re.compile(r"([A-Z])[A-Z]{0,3}[-_ ]?\d+[A-Z]?", re.IGNORECASE)
_ISA_KIND = {"F": "flow", "L": "level", "P": "pressure"}
_WORDS = (("flow", "flow"), ("level", "level"), ("pressure", "pressure"))
_FLOW_UNITS = re.compile(
    r"(kscmh|scfm|gpm|sccm|slpm|nm3h|.+/(h|hr|min|s|d))", re.IGNORECASE
)  # fmt: skip
_PRESSURE_UNITS = {"pa", "kpa", "mpa", "hpa", "bar", "barg", "bara", "mbar", "psi", "psig",
                   "psia", "atm", "torr", "mmhg", "inh2o", "mmh2o", "kg/cm2"}  # fmt: skip
_OUTPUT = re.compile(rf"[._\-\s]({'|'.join(OUTPUT_NAMES)})$", re.IGNORECASE)


@dataclass(frozen=True)
class BalancePlan:
    """A manipulated flow's balance test to choose: the flow, the test's name, the valves its
    own test reads and every tag kept out of the candidates."""

    tag: str
    test: str
    valves: tuple[str, ...]
    kept_out: frozenset[str]
    level: str  # the level of the vessel it balances against
    streams: tuple[str, ...]  # that vessel's other flows: the test's inputs with the rate
    loop: frozenset[str]  # the flow, its actuator and the actuator's loop: never read


def tag_kind(tag: str, info: TagInfo | None = None) -> str | None:
    """``"flow"``, ``"level"`` or ``"pressure"``: what ``tag`` measures by its ISA-5.1 name's
    first letter (``X``, unclassified, read on), else its description's words (a "flow" in
    ``%`` is a valve's position), else its unit; None for anything else, a set-point or a
    controller output (``LIC101.OUT``, ``%``, "level controller output")."""
    if is_set_point(tag, info) or _OUTPUT.search(tag):
        return None
    m = _ISA.fullmatch(tag.strip())
    if m is not None and m.group(1).upper() != "X":  # X: unclassified (XMEAS1), read on
        return _ISA_KIND.get(m.group(1).upper())
    text = (info.description if info else "").lower()
    unit = (info.unit if info else "").strip().lower().replace("³", "3").replace(" ", "")
    if "output" in text or "valve" in text:
        return None
    for word, kind in _WORDS:
        if word in text:  # a "flow" in % of opening is a valve's (TEP's XMV7)
            return None if kind == "flow" and unit == "%" else kind
    if unit in _PRESSURE_UNITS:
        return "pressure"
    return "flow" if unit and _FLOW_UNITS.fullmatch(unit) else None


def balance_plans(
    choices: Sequence[TestChoice],
    names: Mapping[str, str],
    taken: set[str],
    *,
    ctx: _Context,
    info: Mapping[str, TagInfo],
    held: Mapping[str, str | None],
    loops: Sequence[Loop],
    set_point_of: Mapping[str, str],
    same: Mapping[str, Sequence[str]],
    notes: list[str] | None = None,
) -> list[BalancePlan]:
    """The balance tests to choose (module doc), from the plant's structure, not from the
    inputs a flow's own test happened to pick: one per flow (:func:`tag_kind`) that no loop
    holds (no loop test, no loop's measurement) and that a controller output drives
    (:func:`driven_by`: ``held``'s outputs, declared or found by name, whose moves precede
    and explain the flow's on ``ctx``'s grid), balanced against the level of the vessel it
    fills or drains (:func:`vessel_of`) with that vessel's other flows. Kept out of its
    candidates: the flow and what is the same measurement (``same``), its actuator and what
    is the same as it, the actuator's loop's set-point (``set_point_of``) and measurement, and
    every tag but the vessel's flows. What was chosen and why goes into ``notes``."""
    loop_of: dict[str, set[str]] = {v: {t for t in (pv, set_point_of.get(v)) if t}
                                    for v, pv in held.items()}  # fmt: skip
    pv_of: dict[str, str] = {v: pv for v, pv in held.items() if pv}
    for lp in loops:
        if lp.out:
            loop_of.setdefault(lp.out, set()).update({lp.pv, lp.sp})
            pv_of[lp.out] = lp.pv
    held_tags = {lp.pv for lp in loops} | {ch.tag for ch in choices if ch.tracks}
    for ch in choices:  # a loop found by its set-point: its measurement is the loop test's
        if ch.tracks and ch.actuator:
            loop_of.setdefault(ch.actuator, set()).update({ch.tag, ch.tracks})
            pv_of.setdefault(ch.actuator, ch.tag)
    every_flow = [t for t in ctx.vars if tag_kind(t, info.get(t)) == "flow" and t not in held]
    flows = [t for t in every_flow if t not in held_tags]  # a loop's measurement: not tested
    levels = [t for t in ctx.vars if tag_kind(t, info.get(t)) == "level"]
    actuators = [v for v in held if v in ctx.vars]
    said = notes if notes is not None else []
    plans = []
    for ch in choices:
        if (ch.tracks or ch.tag not in flows or ch.statistic != "level"
                or not ch.combined):  # fmt: skip
            continue
        drive = driven_by(ctx, ch.tag, actuators)
        if drive is None:
            read = {InputSpec.parse(s).tags[0] for s in ch.inputs if InputSpec.parse(s).tags}
            if reads := sorted(read & set(actuators)):
                said.append(
                    f"{ch.tag}: no balance test: its test reads {', '.join(reads)} but"
                    " no controller output's moves precede and explain its own (it is no "
                    "manipulated flow)"
                )
            continue
        valve, why = drive
        pv = pv_of.get(valve)
        others = [f for f in every_flow if f not in same.get(ch.tag, ())]  # not its twin
        vessel = vessel_of(ctx, ch.tag, levels, others, pv=pv,
                           pv_level=pv is not None and pv in levels)  # fmt: skip
        if vessel is None:
            said.append(
                f"{ch.tag}: driven by {valve} ({why}); no balance test: no level's "
                "rate it explains (no vessel it fills or drains is measured)"
            )
            continue
        level, streams, vwhy = vessel
        loop = {ch.tag, *same.get(ch.tag, ()), valve, *same.get(valve, ()),
                *loop_of.get(valve, ())}  # fmt: skip
        out = (set(ctx.vars) - set(streams)) | loop  # the level: its rate only
        name = test_name(f"{names[ch.tag]}{SUFFIX}", taken)
        said.append(f"{ch.tag}: driven by {valve} ({why}); balanced against {level} ({vwhy})")
        plans.append(BalancePlan(ch.tag, name, (valve,), frozenset(out), level,
                                 tuple(streams), frozenset(loop)))  # fmt: skip
    return plans


#: a controller output drives a flow where the output's changes, at a dead time of zero or
#: more samples, correlate with the flow's by at least this ``|r|`` (they explain at least a
#: quarter of its changes) and by more than the flow's changes with the output's later ones
DRIVE_MIN_R = 0.5
#: spans (samples of the choice's grid) over which changes are compared: a valve's moves are
#: seen over a few samples where a meter's noise hides them sample to sample
CHANGE_SPANS = (1, 3, 9)
#: a flow fills or drains a level's vessel where it correlates with the level's rate of
#: change (over one of :data:`CHANGE_SPANS`) by at least this ``|r|``
VESSEL_MIN_R = 0.3
#: a flow is one of a vessel's streams where it cuts the variance of the level's rate left
#: by the vessel's flows so far by at least this share
STREAM_MIN_GAIN = 0.05


def _change(x: np.ndarray, s: int) -> np.ndarray:
    """``x[k] - x[k-s]`` (NaN for the first ``s``)."""
    d = np.full(len(x), np.nan)
    d[s:] = x[s:] - x[:-s]
    return d


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson's ``r`` over the samples both have (0 where fewer than 10 or no spread)."""
    ok = np.isfinite(a) & np.isfinite(b)
    if ok.sum() < 10:
        return 0.0
    a, b = a[ok] - a[ok].mean(), b[ok] - b[ok].mean()
    den = math.sqrt(float(a @ a) * float(b @ b))
    return float(a @ b) / den if den > 0 else 0.0


def response(ctx: _Context, valve: str, flow: str) -> tuple[float, int, float, int]:
    """How ``valve``'s changes lead ``flow``'s on ``ctx``'s grid, over the span of
    :data:`CHANGE_SPANS` where they lead most within :func:`max_dead` samples: ``(r, d,
    r_back, s)``, ``r`` the largest ``|r|`` of ``Δflow[k]`` and ``Δvalve[k-d]`` over dead times
    ``0 ≤ d ≤ max_lag``, ``d`` its dead time, and ``r_back`` the largest for the flow's
    changes leading the valve's (``d < 0``, the other way: a disturbance a loop answers). A
    span whose best dead time is longer than :func:`max_dead` is passed over (a flow that
    follows a valve only minutes later does so through a vessel's inventory)."""
    x, y = ctx.column(valve), ctx.column(flow)
    best = (0.0, 0, 0.0, 1)
    horizon = max(1, min(ctx.max_lag, len(x) // 10))
    for s in CHANGE_SPANS:
        dx, dy = _change(x, s), _change(y, s)
        fwd = [abs(_corr(dx[: len(dx) - d], dy[d:])) for d in range(horizon + 1)]
        back = max(abs(_corr(dx[d:], dy[: len(dy) - d])) for d in range(1, horizon + 1))
        d = int(np.argmax(fwd))
        if d <= max_dead(ctx) and fwd[d] > best[0]:
            best = (fwd[d], d, back, s)
    return best


#: a flow follows the valve that drives it within this time (s) or one sample of the grid
#: (a liquid-full line answers in seconds; minutes later is through a vessel's inventory)
DRIVE_MAX_DEAD_S = 60.0


def max_dead(ctx: _Context) -> int:
    """:data:`DRIVE_MAX_DEAD_S` in samples of ``ctx``'s grid, at least one."""
    import pandas as pd

    return max(1, int(DRIVE_MAX_DEAD_S // pd.Timedelta(ctx.period).total_seconds()))


def driven_by(ctx: _Context, flow: str, actuators: Sequence[str]) -> tuple[str, str] | None:
    """The controller output that drives ``flow`` and why, or None: of ``actuators``, the one
    whose changes precede and explain the flow's most (:func:`response`: ``|r| ≥``
    :data:`DRIVE_MIN_R` within :func:`max_dead` samples, above the ``|r|`` the other way)."""
    best = None
    for v in actuators:
        r, d, back, s = response(ctx, v, flow)
        if r >= DRIVE_MIN_R and r > back and (best is None or r > best[1]):
            best = (v, r, d, back, s)
    if best is None:
        return None
    v, r, d, back, s = best
    return v, (
        f"its changes over {s} sample(s) follow {v}'s {d} sample(s) later, |r| "
        f"{r:.2f}; {back:.2f} the other way"
    )


def _mean_over(x: np.ndarray, s: int) -> np.ndarray:
    """A flow's mean over the span a level's rate ``(L[k] - L[k-s]) / s`` is taken over: the
    trapezoid of ``x[k-s] … x[k]`` (each sample a grid period's mean)."""
    w = np.ones(s + 1)
    w[[0, -1]] = 0.5
    out = np.full(len(x), np.nan)
    out[s:] = np.convolve(x, w / w.sum(), mode="valid")
    return out


def _level_rate(ctx: _Context, level: str, s: int) -> np.ndarray:
    return _change(ctx.column(level), s) / s


def vessel_of(
    ctx: _Context,
    flow: str,
    levels: Sequence[str],
    flows: Sequence[str],
    *,
    pv: str | None = None,
    pv_level: bool = False,
) -> tuple[str, list[str], str] | None:
    """The vessel ``flow`` fills or drains: its level, its other flows and why, or None. The
    level its actuator's loop holds (``pv``, where ``pv_level``), else the level whose rate of
    change the flow explains most (``|r| ≥`` :data:`VESSEL_MIN_R`); the vessel's other flows,
    forward from the flow: each flow that cuts the variance of the level's rate left by the
    flows so far by :data:`STREAM_MIN_GAIN` (a linear fit: the mass balance); then back, each
    flow whose removal raises it by less than that share is dropped. A flow of another vessel
    that only moves with the vessel's own (a third flow) cuts nothing once they are in."""
    scored = []
    for s in CHANGE_SPANS:
        y = _mean_over(ctx.column(flow), s)
        for lv in levels:
            scored.append((abs(_corr(y, _level_rate(ctx, lv, s))), lv, s))
    if pv_level and pv is not None:
        r, level, s = max(x for x in scored if x[1] == pv)
        why = f"the level its actuator's loop holds; |r| with its rate {r:.2f}"
    else:
        if not scored:
            return None
        r, level, s = max(scored)
        if r < VESSEL_MIN_R:
            return None
        why = f"the level whose rate it explains most, |r| {r:.2f}"
    rate = _level_rate(ctx, level, s)
    chosen = [flow]
    pool = [f for f in flows if f != flow]
    col = {f: _mean_over(ctx.column(f), s) for f in flows}
    left = _residual_var(rate, [col[f] for f in chosen])
    while pool:
        trial = [(_residual_var(rate, [col[f] for f in (*chosen, g)]), g) for g in pool]
        var, g = min(trial)
        if not var < left * (1 - STREAM_MIN_GAIN):
            break
        chosen.append(g)
        pool.remove(g)
        left = var
    while len(chosen) > 1:  # then back: a flow the later ones made redundant (a third flow)
        trial = [(_residual_var(rate, [col[f] for f in chosen if f != g]), g) for g in chosen[1:]]
        var, g = min(trial)
        if not var * (1 - STREAM_MIN_GAIN) < left:
            break
        chosen.remove(g)
        left = var
    streams = chosen[1:]
    why += f"; its other flows {', '.join(streams) if streams else 'none'}"
    return level, streams, why


def _residual_var(y: np.ndarray, cols: Sequence[np.ndarray]) -> float:
    """The variance of ``y`` left by a least-squares fit on ``cols`` and a constant."""
    X = np.column_stack([*cols, np.ones(len(y))])
    ok = np.isfinite(y) & np.isfinite(X).all(axis=1)
    if ok.sum() < X.shape[1] + 10:
        return math.inf
    coef, *_ = np.linalg.lstsq(X[ok], y[ok], rcond=None)
    return float(np.var(y[ok] - X[ok] @ coef))


def choose_balance(bp: BalancePlan, ctx: _Context, sel: _Context, plan) -> TestChoice:
    """A flow's balance test (module doc), chosen on the grid its own test was chosen on (a
    long fast window's coarse grid, its dead times then scaled to the data's); the caller
    keeps it where :func:`kept` says so."""
    use = sel if bp.tag in sel.vars else ctx
    k = plan.factor if use is sel else 1
    ch = mass_balance(use, bp)
    ch.method, ch.balance = short.LINEAR, True
    for st in ch.steps:
        st.input = _scaled(st.input, k)
    err = ch.steps[-1].rmse_pct if ch.steps else ch.baseline_rmse_pct
    ch.why = (
        f"the balance of a manipulated flow (driven by {', '.join(bp.valves)}): linear test "
        f"of {len(ch.steps)} inputs, held-out error {err:.2f} % of span (kept at most "
        f"{BALANCE_MAX_ERROR_PCT:g} %); from {bp.level}'s vessel: its rate and its other "
        f"flows ({', '.join(bp.streams) or 'none'}); kept out: "
        f"{', '.join(sorted(bp.loop - {bp.tag}))}"
    )
    if not any(s.startswith(f"rate({bp.level}") for s in ch.inputs):
        ch.why += f"; not kept: {bp.level}'s rate cut no error (no balance)"
    return ch


def mass_balance(ctx: _Context, bp: BalancePlan) -> TestChoice:
    """The vessel's mass balance as ``bp.tag``'s linear test: its other flows as they are
    (``FEED[k]``, at most :data:`BALANCE_MAX_INPUTS` - 1 of them, in the order
    :func:`vessel_of` found them) and the level's change per sample ``rate(L)[k]``, the
    accumulation term (``q_out = Σ q_in − A·dL/dt``); each step's held-out error recorded."""
    from diag_plugin.selection.scoring import BlockScorer

    ch = TestChoice(bp.test, bp.tag, math.nan)
    rb = _rulebase(bp.test, ctx.vars[bp.tag], [], ctx.period, method=short.LINEAR)
    scorer = BlockScorer(rb, [], ctx.column(bp.tag), ctx.block)
    ch.baseline_rmse_pct = scorer.base_rmse
    specs: list[InputSpec] = []
    want = [InputSpec("", (g,), 0) for g in bp.streams if g in ctx.vars]
    for spec in [*want[: BALANCE_MAX_INPUTS - 1], InputSpec("rate", (bp.level,), 0)]:
        specs.append(spec)
        rmse, cov = scorer.score([ctx.spec_variable(x) for x in specs],
                                 [ctx.spec_column(x) for x in specs])  # fmt: skip
        if not math.isfinite(rmse):
            specs.pop()
            continue
        ch.steps.append(Step(str(spec), rmse, cov))
    if len(ch.steps) >= 2 and not ch.steps[-1].rmse_pct < ch.steps[-2].rmse_pct * (1 - MIN_GAIN):
        ch.steps.pop()  # the level's rate cut nothing: no balance (not kept)
    return ch


def kept(ch: TestChoice) -> bool:
    """A balance test is kept where it has inputs, reads its vessel's level's rate (where
    it has a vessel) and its held-out error is at most :data:`BALANCE_MAX_ERROR_PCT` % of
    the flow's span."""
    return (bool(ch.steps) and ch.steps[-1].rmse_pct <= BALANCE_MAX_ERROR_PCT
            and "not kept:" not in (ch.why or ""))  # fmt: skip


def _scaled(spec: str, factor: int) -> str:
    """An input chosen on the coarse grid on the data's grid: its dead time scaled, and a
    rate per coarse sample the rate over as many of the data's samples (``rate(L,f)``)."""
    if factor <= 1:
        return spec
    s = InputSpec.parse(spec)
    if s.fn != "rate":
        return short.scale_lag(spec, factor)
    span = factor * (int(s.param) if s.param is not None else 1)
    return str(InputSpec("rate", s.tags, s.lag * factor, float(span)))
