"""A second test for a manipulated flow: its balance (issue 34, items 4 and 7).

A flow that a controller output drives — the valve of a declared loop, or of a loop found by
its names (``LIC102.OUT`` beside ``LIC102.SP``) — is modelled by the build from that valve and
the pressure across it (``FI109`` from ``LIC102.OUT`` and ``PI101``): the best fit, and a
relation a leak does not break (the level loop closes the valve and the flow falls as the
valve says). The mass balance the leak breaks — the vessel's inflows against its outflows and
its level's rate — is fitted less closely, so the one test per tag never reads it.

So such a flow, where no loop holds the flow itself, gets a second test ``<tag>_balance``:
a linear (parity) relation of up to :data:`BALANCE_MAX_INPUTS` inputs chosen by the build's
forward selection (each kept where it cuts the held-out error over the window's time blocks
by :data:`~diag_plugin.unitbuild.build.MIN_GAIN`), with the valve, its loop's set-point and
measurement and the valve's pressure tags (the pressures the flow's own test reads) kept out
of its candidates; then a level's change per sample (``rate(LI102)[k]``, the accumulation
term) added where it cuts the held-out error by ``MIN_GAIN`` again. It is kept where its
held-out error is at most :data:`BALANCE_MAX_ERROR_PCT` % of the flow's span. It is a test
like any other (its own share of the false-alarm budget) and it models the flow, so its alarm
names the flow's tag.

A flow its own loop holds (the loop's measurement, a flow by :func:`tag_kind`) gets one too:
its loop test sees a bias of its meter not at all (the loop holds the biased reading at its
set-point and the true flow moves instead), and the vessel's balance does — the measured
inflow against the outflows and the level's rate. Its candidates leave out its loop's
set-point and valve and the pressures the valve's test reads (the loop's relation and the
valve's equation, which the bias does not break); the level's rate is tried over
:data:`HELD_RATE_SPANS` samples (a level's change over one fast sample is its noise: the
7-tag line's tank moves 0.8 mm in 15 s for 1 m³/h, its level reading 7 mm from one sample to
the next). The balance is taken in its integral form (branch ``i34-balance2``): the level's
change over ``n`` samples is the flows' sum over them, so the flows are read over the same
window (``mean(F,n)``, :func:`integral_form`) and the rate's coefficient is corrected for the
level's noise (:func:`input_noise`). It is kept
where its held-out error is at most :data:`HELD_MAX_ERROR_PCT` % of the flow's span (the only
test that sees the meter's bias; docs/how-to/unit-loops.md, "A balance for a loop-held flow").
Its alarm names the flow, whose compensated direction then moves it
(:func:`~diag_plugin.diagnose.unittags.process_directions`).

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
from diag_plugin.regressors import InputSpec, rate_samples
from diag_plugin.unitbuild import short
from diag_plugin.unitbuild.build import (
    ACTUATOR_MAX_INPUTS,
    MIN_GAIN,
    OUTPUT_NAMES,
    Step,
    TestChoice,
    _Context,
    _rulebase,
    select_inputs,
    test_name,
)
from diag_plugin.unitbuild.loops import Loop
from historian.taginfo import TagInfo

#: inputs of a balance test at most (as a controller output's linear test)
BALANCE_MAX_INPUTS = ACTUATOR_MAX_INPUTS
#: a balance test is kept where its held-out error is at most this share of the flow's span (%)
BALANCE_MAX_ERROR_PCT = 3.0
#: a loop-held flow's balance test is kept where its held-out error is at most this (%)
HELD_MAX_ERROR_PCT = 6.0
#: the spans (samples) of a level's rate a loop-held flow's balance test tries
HELD_RATE_SPANS = (1, 2, 4, 8, 16, 32, 64)
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
    held: bool = False  # a flow its own loop holds (the loop's measurement)


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
    info: Mapping[str, TagInfo],
    held: Mapping[str, str | None],
    loops: Sequence[Loop],
    set_point_of: Mapping[str, str],
    same: Mapping[str, Sequence[str]],
) -> list[BalancePlan]:
    """The balance tests to choose (module doc): one per flow whose own test reads a
    controller output (``held``: each output → the tag its loop holds, None where not
    declared) and that no loop holds (no loop test, no loop's measurement; a short window's
    pair test, kept out of T², is not the flow's test). Kept out of its
    candidates: the flow and what is the same measurement (``same``), the valves its test
    reads, their loops' set-points (``set_point_of``: an output found by its name → its
    set-point; a declared loop's own) and measurements, and the pressures its test reads."""
    loop_of: dict[str, set[str]] = {v: {t for t in (pv, set_point_of.get(v)) if t}
                                    for v, pv in held.items()}  # fmt: skip
    for lp in loops:
        if lp.out:
            loop_of.setdefault(lp.out, set()).update({lp.pv, lp.sp})
    held_tags = {lp.pv for lp in loops} | {ch.tag for ch in choices if ch.tracks}
    for ch in choices:  # a loop found by its set-point: its measurement is the loop test's
        if ch.tracks and ch.actuator:
            loop_of.setdefault(ch.actuator, set()).update({ch.tag, ch.tracks})
    plans = []
    for ch in choices:
        if (ch.tracks or ch.tag in held or ch.tag in held_tags or ch.statistic != "level"
                or not ch.combined or tag_kind(ch.tag, info.get(ch.tag)) != "flow"):  # fmt: skip
            continue
        reads = [InputSpec.parse(s).tags for s in ch.inputs]
        read = list(dict.fromkeys(t for tags in reads for t in tags))
        valves = tuple(t for t in read if t in held)
        if not valves:
            continue
        pressures = {t for t in read if tag_kind(t, info.get(t)) == "pressure"}
        out = {ch.tag, *same.get(ch.tag, ()), *valves, *pressures}
        out.update(t for v in valves for t in loop_of.get(v, ()))
        name = test_name(f"{names[ch.tag]}{SUFFIX}", taken)
        plans.append(BalancePlan(ch.tag, name, valves, frozenset(out)))
    plans.extend(_held_plans(choices, names, taken, info=info, loop_of=loop_of, same=same))
    return plans


def _held_plans(choices, names, taken, *, info, loop_of, same) -> list[BalancePlan]:
    """A loop-held flow's balance test (module doc): one per loop test (the level of its
    error, not the spread) whose measurement is a flow and whose valve is known. Kept out of
    its candidates: the flow and what is the same measurement, its loop's set-point and
    valve (the loop's own relation) and the pressures the valve's test reads (the valve's
    equation, which a meter's bias does not break: the loop moves valve and flow together)."""
    tests = {ch.tag: ch for ch in choices if not ch.tracks}
    plans = []
    for ch in choices:
        if (not ch.tracks or not ch.actuator or ch.statistic != "level" or ch.balance
                or tag_kind(ch.tag, info.get(ch.tag)) != "flow"):  # fmt: skip
            continue
        valve = tests.get(ch.actuator)
        read = [t for s in (valve.inputs if valve else ()) for t in InputSpec.parse(s).tags]
        pressures = {t for t in read if tag_kind(t, info.get(t)) == "pressure"}
        out = {ch.tag, *same.get(ch.tag, ()), ch.actuator, ch.tracks, *pressures}
        out.update(loop_of.get(ch.actuator, ()))
        name = test_name(f"{names[ch.tag]}{SUFFIX}", taken)
        plans.append(BalancePlan(ch.tag, name, (ch.actuator,), frozenset(out), held=True))
    return plans


def choose_balance(bp: BalancePlan, ctx: _Context, sel: _Context, plan) -> TestChoice:
    """A flow's balance test (module doc), chosen on the grid its own test was chosen on (a
    long fast window's coarse grid, its dead times then scaled to the data's); the caller
    keeps it where :func:`kept` says so."""
    use = sel if bp.tag in sel.vars else ctx
    k = plan.factor if use is sel else 1
    cands = [c for c in use.vars if c not in bp.kept_out and balance_term(c, use.info.get(c))]
    cands = short.inputs_for(plan, bp.tag, cands, use.column)
    ch = select_inputs(use, bp.tag, cands, test=bp.test, max_inputs=BALANCE_MAX_INPUTS,
                       method=short.LINEAR)  # fmt: skip
    ch.method, ch.balance = short.LINEAR, True
    if ch.steps:
        add_level_rates(use, ch, HELD_RATE_SPANS if bp.held else (1,), integral=bp.held)
    for st in ch.steps:
        st.input = _scaled(st.input, k)
    err = ch.steps[-1].rmse_pct if ch.steps else ch.baseline_rmse_pct
    what = "a flow its loop holds with" if bp.held else "a manipulated flow, driven by"
    ch.why = (
        f"the balance of {what} ({', '.join(bp.valves)}): linear test "
        f"of {len(ch.steps)} inputs, held-out error {err:.2f} % of span (kept at most "
        f"{HELD_MAX_ERROR_PCT if bp.held else BALANCE_MAX_ERROR_PCT:g} %); kept out: "
        f"{', '.join(sorted(bp.kept_out - {bp.tag}))}"
    )
    return ch


def balance_term(tag: str, info: TagInfo | None = None) -> bool:
    """Whether ``tag``'s value may be a term of a flow's balance: not a set-point (an
    operator's choice, not the vessel's state) nor a level (a level enters as its change,
    :func:`add_level_rates`). Read at its value, either relates the flow to what the
    operators chose over the window: at 1 s on three days of the chemical plant (three
    operating points) a loop-held flow's balance was ``FI102 = f(LI103)``, a level another
    loop holds at its set-point, broken at the next set-points a tuning seed chose (on 55 %
    and 100 % of two fault-free runs); at 3 min ``FI106_balance`` read ``TIC107.SP`` and
    ``PIC101.SP``."""
    return not is_set_point(tag, info) and tag_kind(tag, info) != "level"


def kept(ch: TestChoice, held: bool = False) -> bool:
    """A balance test is kept where it has inputs and its held-out error is at most
    :data:`BALANCE_MAX_ERROR_PCT` % of the flow's span (a loop-held flow's
    :data:`HELD_MAX_ERROR_PCT`)."""
    cap = HELD_MAX_ERROR_PCT if held else BALANCE_MAX_ERROR_PCT
    return bool(ch.steps) and ch.steps[-1].rmse_pct <= cap


def add_level_rates(
    ctx: _Context, ch: TestChoice, spans: Sequence[int] = (1,), *, integral: bool = False
) -> None:
    """Add to ``ch`` (a linear test) the level's change per sample ``rate(L)[k]`` that cuts its
    held-out error most, where it cuts it by more than ``MIN_GAIN``; again while it has fewer
    than :data:`BALANCE_MAX_INPUTS` inputs. The levels: every tag of the window
    :func:`tag_kind` calls one (the accumulation term of a vessel's balance).

    ``integral``: a rate over ``n`` samples is tried with the test's plain inputs read as
    their means over the same ``n`` samples (``mean(F,n)[k]``, :func:`integral_form`): the
    level's change over a window is the flows' sum over that window, so both sides are seen
    through one filter. A trailing rate against the flows' current values lags them by about
    ``n / 2`` samples, and after a step of an outflow (a hand valve moved) the tank drains
    along its time constant while the lag reads as a missing inflow of the meter bias's size
    (docs/how-to/unit-loops.md, branch ``i34-balance2``)."""
    from diag_plugin.selection.scoring import BlockScorer

    levels = [t for t in ctx.vars if tag_kind(t, ctx.info.get(t)) == "level"]
    specs = [InputSpec.parse(s) for s in ch.inputs]
    rb = _rulebase(ch.test, ctx.vars[ch.tag], [], ctx.period, method=short.LINEAR)
    scorer = BlockScorer(rb, [], ctx.column(ch.tag), ctx.block)
    current = ch.steps[-1].rmse_pct
    while len(specs) < BALANCE_MAX_INPUTS:
        best = None
        for lv, n in ((lv, n) for lv in levels for n in spans):
            spec = InputSpec("rate", (lv,), 0, None if n == 1 else float(n))
            if any(s.fn == "rate" and s.tags == spec.tags for s in specs):
                continue
            trial = [*(integral_form(specs, n) if integral else specs), spec]
            rmse, cov = scorer.score([ctx.spec_variable(s) for s in trial],
                                     [ctx.spec_column(s) for s in trial])  # fmt: skip
            if math.isfinite(rmse) and (best is None or rmse < best[0]):
                best = (rmse, cov, spec)
        if best is None or not best[0] < current * (1 - MIN_GAIN):
            return
        current, cov, spec = best
        if integral:  # the chosen inputs read over the rate's window, as scored
            specs = integral_form(specs, rate_samples(spec))
            for st, sp in zip(ch.steps, specs, strict=True):
                st.input = str(sp)
        specs.append(spec)
        ch.steps.append(Step(str(spec), current, cov))


def integral_form(specs: Sequence[InputSpec], n: int) -> list[InputSpec]:
    """``specs`` with each plain input ``F[k-d]`` (or a mean over another span) read as its
    mean over ``n`` samples, ``mean(F,n)[k-d]`` (``F[k-d]`` for ``n = 1``); rates and other
    derived inputs as they are."""
    out = []
    for s in specs:
        if s.fn in ("", "mean"):
            plain = InputSpec("", s.tags, s.lag)
            s = InputSpec("mean", s.tags, s.lag, float(n)) if n > 1 else plain
        out.append(s)
    return out


def input_noise(specs: Sequence[InputSpec], ctx: _Context) -> list[float] | None:
    """Per input of a balance test the variance of its measurement noise, for the linear fit's
    errors-in-variables correction (:data:`~diag_plugin.models.linear.INPUT_NOISE`): a
    level's rate over ``n > 1`` samples ``2σ²/n²`` (:func:`white_noise_var` of the level on
    the window), every other input 0; None where no input has any. Least squares shrink the
    rate's coefficient by its noise (the 7-tag line's tank: 1,069 where the tank's
    ``A / Δt`` is 1,200 at 64 samples of 15 s), and a drain never seen (a hand valve moved)
    then reads as a missing inflow of 11 % of the rate's term (docs/how-to/unit-loops.md,
    branch ``i34-balance2``)."""
    out = []
    for s in specs:
        n = rate_samples(s) if s.fn == "rate" else 1
        v = 2.0 * white_noise_var(ctx.column(s.tags[0], 0)) / n**2 if n > 1 else 0.0
        out.append(float(f"{v:.4g}"))
    return out if any(v > 0 for v in out) else None


def white_noise_var(x: np.ndarray) -> float:
    """The variance of a slow signal's white measurement noise ``e`` from its differences
    ``d[k] = Δs[k] + e[k] − e[k−1]``: ``var(d) = var(Δs) + 2σ²`` and, the signal's changes
    alike from one sample to the next, ``cov(d[k], d[k−1]) = var(Δs) − σ²``, so
    ``σ² = (var(d) − cov(d[k], d[k−1])) / 3`` (0 where that is negative)."""
    d = np.diff(np.asarray(x, float))
    a, b = d[1:], d[:-1]
    ok = np.isfinite(a) & np.isfinite(b)
    if ok.sum() < 3:
        return 0.0
    a, b = a[ok], b[ok]
    m = 0.5 * (a.mean() + b.mean())
    v = 0.5 * (np.mean((a - m) ** 2) + np.mean((b - m) ** 2))
    c1 = float(np.mean((a - m) * (b - m)))
    return max((v - c1) / 3.0, 0.0)


def _scaled(spec: str, factor: int) -> str:
    """An input chosen on the coarse grid on the data's grid: its dead time scaled, and a
    rate per coarse sample the rate over as many of the data's samples (``rate(L,f)``)."""
    if factor <= 1:
        return spec
    s = InputSpec.parse(spec)
    if s.fn == "mean":  # a mean over n coarse samples: over as many of the data's
        return str(InputSpec("mean", s.tags, s.lag * factor, float(factor * rate_samples(s))))
    if s.fn != "rate":
        return short.scale_lag(spec, factor)
    span = factor * (int(s.param) if s.param is not None else 1)
    return str(InputSpec("rate", s.tags, s.lag * factor, float(span)))
