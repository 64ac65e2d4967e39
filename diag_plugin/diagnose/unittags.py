"""The unit-level combined test and isolation to tags (issue 25).

A unit made from a plant's history has one model per tag and no expert matrix. Two things
let it see and name what single tests miss.

**The combined test** (``combined = true`` in the unit file's ``[evaluation]``). Each test's
filtered residual ``r_j`` (the one its thresholds judge) is centred and scaled by what it does
on fault-free data the models did not see, ``z_j = (r_j − c_j) / s_j`` with ``c_j`` the median
and ``s_j`` the robust standard deviation (1.4826 · MAD) of the cross-fitted residuals,
widened by how few independent values the window holds of that residual (its predictive
spread, :func:`~diag_plugin.learn.thresholds.predictive_widening`); the combined statistic is
Hotelling's

    ``T² = zᵀ S⁻¹ z``   (MacGregor & Kourti, 1995, eq. 3)

(after ``diag unit accept``, each window an operating point: ``c_j`` and ``s_j`` those of the
point whose means of the tags are nearest the sample, ``S`` the pooled within-point one,
:func:`~diag_plugin.learn.thresholds.learn_combined`) with ``S`` the covariance of ``z``
over the same window shrunk toward its diagonal,
``S = (1 − λ) Ŝ + λ diag(Ŝ)``, ``λ = T / (T + n_eff)`` (``T`` tests, ``n_eff`` the fewest
independent values of a test's residual, :func:`~diag_plugin.models.series.effective_samples`:
a filtered residual holds few, and an unshrunk inverse would chase noise). A coordinated small
move of several tags, each residual inside its thresholds, adds up in ``T²``. Where some tests
are unknown ``T²`` is taken over the known ones (``S`` restricted to them) and mapped to the
same false-alarm level with ``T`` degrees of freedom, ``F⁻¹_T(F_k(T²_k))`` with ``F_k`` the χ²
distribution function of ``k`` degrees of freedom; with fewer than half the tests known it is
unknown. Its threshold ``high`` is learned like the tests' (:mod:`~diag_plugin.learn.budget`:
alarm episodes with the unit's on/off delays, counted on ``T²`` computed from residuals
cross-fitted over the time blocks, and ``c``, ``s``, ``S`` themselves learned without the
block they score) under the same budget: the combined test gets :data:`COMBINED_SHARE` of the
unit's ``far``, the per-tag tests share the rest as before (``far · (1 − COMBINED_SHARE) / 2T``
a side). When the combined test alone is on, the unit is FAILURE and the fault is the
top-ranked tag (``isolation = "tags"``) or ``unit``.

**Isolation to tags** (``isolation = "tags"``). Without an expert matrix the unit's matrix is
derived from its models (:func:`derived_matrix`): one fault column per tag, named by the tag,
with ``1`` in every test that reads the tag (an input, any lag, derived or not) or models it
(its output), ``0`` elsewhere, so the crisp nearest-signature isolation names tags: only a
column the symptoms match exactly (``Unit.exact_only``; a nearer column that gets a test wrong
is not a hypothesis consistent with them), and a sample in alarm no column explains names the
ranking's first tag, as the combined test alone does (a leak from tank A was isolated as
tank B's level, the shortest column holding two of its three symptoms;
docs/how-to/unit-loops.md); where a column matches but the ranking's first tag is another
whose column allows every symptom on (a small fault of it fires only its tests nearest their
thresholds), that tag is named too (:func:`with_ranked`). An expert
matrix file, when given, takes precedence for the faults; the ranking below is still reported.
A test with an ``actuator`` (a loop's control error, written by ``diag unit build``) has ``1``
in that controller output's column too; a loop's own sensor has ``1`` in every other test
that reads its loop's set-point (the loop takes the sensor's bias and drives the process as a
set-point step would: its actuator's test, the tags downstream; :func:`compensating_tests`);
set-points are never columns (an operator's entry has no sensor or actuator to fail). A
*process* fault (fouling, a leak) has no column: it moves the tests whose relations it breaks,
and shows up as the tags those tests involve, ranked as below.

**Ranking by contribution.** For each tag ``X`` a fault direction ``ξ_X`` in ``z`` space: a
bias ``b`` of X's sensor moves test ``j``'s residual by ``(1{X is j's output} − g_jX) · b ·
100 / span_j`` (eq. 6), ``g_jX`` the mean gain ``∂ŷ_j/∂X`` of ``j``'s model over the learning
window (summed over the lags it reads X at; zero for derived inputs such as a rate, which a
bias does not move), divided by ``s_j``. The reconstruction-based contribution
(Alcala & Qin, 2009, eq. 13)

    ``RBC_X = (ξ_Xᵀ S⁻¹ z)² / (ξ_Xᵀ S⁻¹ ξ_X)``

is how much of ``T²`` a bias along ``ξ_X`` explains (``0 ≤ RBC_X ≤ T²``). A loop's actuator
moves its loop test's residual by an amount and sign no gain says (zero while the loop
compensates, either way once the valve sticks or saturates): its contribution is taken over the
plane of its own direction and that test's axis, the multidimensional form ``uᵀ(ΞᵀS⁻¹Ξ)⁻¹u``,
``Ξ = [ξ_X e_loop]``, ``u = ΞᵀS⁻¹z`` (Alcala & Qin, 2009); and a third direction, the
valve truly moved with the tags whose models read it following (:func:`moved_directions`: a
loop compensating a fouled cooler, the flow through the valve following it). A loop's own
sensor is not given
that plane: its direction is ``1`` on its loop test, as any tag's own test, plus the move of
the compensating loop on the tests reading the set-point (``−g_SP``); a plane would give it one
more degree of freedom than the tags it is ranked against, and a share of every deviation
that moves its loop's error. A tag outside loops has a second direction, a change of the
true quantity, which the tags whose models read it follow (:func:`process_directions`): its
contribution is the larger of the two one-dimensional ones (a warmer feed moves the tests that
read the mixed temperature, not those reading the feed). A loop's own sensor whose bias the
loop compensates moves its actuator's test and the tests beyond it; where the samples hold
both moves, each :data:`COMPENSATED_SE` standard errors clear of zero and saying the same bias,
every test known and no more left unexplained than a fault-free sample leaves
(:data:`COMPENSATED_REST`), its contribution is taken over the plane of the two
(:meth:`CombinedModel._compensated_rbc`: how far the actuator moves per unit of bias no gain
fixes), and the actuator's move is not left to the actuator. A bias the loop takes only
in part (its actuator at a limit) leaves the rest on its loop test: where the tests beyond
the actuator and the loop's error say the same bias, the sensor's contribution is taken
over its beyond-direction, its loop test's axis and its actuator's (what the limit left,
:meth:`CombinedModel._compensated_rbc`). The share
``RBC_X / T²`` ranks the tags (1: a bias of X alone explains the deviation). Tags touching
the same tests in the same proportions cannot be told apart and share a rank. Before
``diag unit learn`` has written ``[combined]`` the ranking uses ``z = r / high``, ``S = I`` and
the derived matrix's 0/1 columns as directions (rough, sign-blind). A test kept out of ``T²``
(``combined = false``) adds to no share; in alarm it names its own tags ahead of them
(:class:`TestNames`); so does any test in alarm where ``T²`` names no tag. And a measured
input beyond the range the unit learned whose excursion explains every test in alarm (its own
test, a test reading it off by no more than its excess times the test's gain on it, or a
test reading a tag whose own test, reading the input, is unknown) is named before the shares,
not the loop that absorbs it (:class:`Excursions`); so are a test's output and its one input
where the test is unknown, both beyond their ranges on the sides its gain says cannot go
together (a lost feed: the flow at 0, its valve open).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from diag_plugin.diagnose.matrix import DiagnosticMatrix
from diag_plugin.diagnose.unitfile import CombinedSpec
from diag_plugin.regressors import parse_specs

#: share of the unit's false-alarm budget given to the combined test (the per-tag tests share
#: the rest): the unit's multivariate detector counts as much as all its single tests together;
#: thresholds move with the log of their share, so halving the tests' costs them little
COMBINED_SHARE = 0.5
#: the combined statistic is unknown with fewer known tests than this share
MIN_KNOWN_SHARE = 0.5
#: tags reported per alarm
TOP = 3
#: shares of ``T²`` at most this name no tag where only they would (:class:`TestNames`): the
#: absolute tolerance :func:`rank` ties shares at, and the floor :meth:`CombinedModel._share`
#: takes for ``T²`` (a ``T²`` of 1e-56 gave shares of 1e-43, lost in an episode's mean)
NO_SHARE = 1e-12
#: where a test in alarm names tags because ``T²`` names none, the tags it reads rank after
#: the tag it models at equal ``ρ``: their value lower by this much, relative (more than
#: :data:`TIE`; a tie-break, not a weight)
READ_BELOW = 1e-6


def _tag(spec_tags: list[str], mapping: dict[str, str]) -> list[str]:
    return [mapping.get(t, t) for t in spec_tags]


def is_set_point(tag: str, info=None) -> bool:
    """A set-point by its name (``….SP``, ``…_SP``, ``…SETPOINT``) or, given a
    :class:`~historian.taginfo.TagInfo`, its description."""
    if re.search(r"(^|[._\-\s])(SP|SETPOINT|SET_POINT)$", tag.upper()):
        return True
    d = (getattr(info, "description", "") or "").lower()
    return "set-point" in d or "setpoint" in d or "set point" in d


def declared_set_points(unit) -> set[str]:
    """The tags the unit file says are set-points (plant names): ``[build] set_points``, the
    window's set-points as ``diag unit build`` judged them from the historian's metadata (by
    name or by description, :func:`is_set_point`), and the set-point each loop test tracks
    (``[build.tests] … tracks``, also in files built before ``set_points`` was written)."""
    build = unit.file.build or {}
    out = {str(x) for x in build.get("set_points", [])}
    for row in (build.get("tests") or {}).values():
        if isinstance(row, dict) and isinstance(row.get("tracks"), str):
            out.add(row["tracks"])
    return out


def structure(unit) -> tuple[list[str], dict[str, str], dict[str, list[str]]]:
    """The unit's tags that can be at fault (plant names, outputs first in test order, then
    inputs; never a set-point, by its name or as the unit file declares it (a loop test's
    ``set_point``, :func:`declared_set_points`): it is the operator's entry, with no sensor
    or actuator that could fail — unless it is a loop's actuator with a test of its own, a
    cascade's inner set-point, which the outer controller sets (issue 34, item 7); nor a
    hand valve, :func:`hand_valves`, nor a discrete state, :func:`states`), each test's
    output tag and the tags each test reads (inputs, any lag)."""
    outputs: dict[str, str] = {}
    reads: dict[str, list[str]] = {}
    mapping = unit.file.tags
    for t in unit.tests:
        m = unit.models[t]
        outputs[t] = _tag(parse_specs([m.output])[0].tags, mapping)[0]
        reads[t] = list(
            dict.fromkeys(x for s in parse_specs(m.inputs) for x in _tag(s.tags, mapping))
        )
        act = unit.file.test(t).actuator
        if act and act not in reads[t] and act != outputs[t]:
            reads[t].append(act)  # a loop's actuator: its fault moves the loop's error
    sps = set_points(unit) | declared_set_points(unit) | hand_valves(unit) | states(unit)
    tags = list(dict.fromkeys([*outputs.values(), *(x for r in reads.values() for x in r)]))
    # a controller output with a test of its own is a tag at fault though another loop holds
    # its measurement at it (a cascade's inner set-point: the outer controller's output)
    acts = {unit.file.test(t).actuator for t in unit.tests} & set(outputs.values())
    keep = [x for x in tags if x in acts or (not is_set_point(x) and x not in sps)]
    return keep, outputs, reads


def unbridge(unit) -> None:
    """Mark on each rule-grid model of ``unit`` the inputs whose gaps no level bridges
    (:meth:`~diag_plugin.fuzzy.wang_mendel.WangMendelRegressor.unbridged_gaps`): the plain
    inputs an operator chooses — a set-point (by name, description or as the file declares
    it), a hand valve, a discrete state (issue 34 item 5: a pasteuriser's new production rate
    between the learned ones, where a level's bridged answer was wrong and named the pump).

    Only in a unit that runs in regimes: one with ``[states]`` that learned two or more of
    their combinations (:class:`~.combos.CombosGuard`). There a gap of an operator's input is
    where the plant changes regime (the pasteuriser's production rates, 0 and 9.3–11.3 m³/h,
    and its cleaning flow, 14 m³/h, a different ``MODE``), and the answer between them is not
    support. A unit of one regime (no states: the 7-tag line of ``tests/line7.py``) holds its
    set-point and hand valve at a few values for hours within one operating range, where the
    levels interpolate as the paper's do: none is marked."""
    guard = getattr(unit, "combos", None)
    if guard is None or len(guard.seen) < 2:
        return
    chosen = set_points(unit) | declared_set_points(unit) | hand_valves(unit) | states(unit)
    mapping = unit.file.tags
    for t in unit.tests:
        m = unit.models[t]
        if not hasattr(m.model, "unbridged_gaps"):
            continue
        specs = parse_specs(m.inputs)
        m.model.unbridged = tuple(
            k for k, s in enumerate(specs)
            if s.fn == "" and (_tag(s.tags, mapping)[0] in chosen or is_set_point(
                _tag(s.tags, mapping)[0]))
        )  # fmt: skip


def hand_valves(unit) -> set[str]:
    """The hand valves the unit file declares (``[manual]``, plant names): an operator's
    setting, never a tag at fault (:mod:`~diag_plugin.diagnose.manual`)."""
    return {unit.file.tags.get(t, t) for t in getattr(unit.file, "manual", {})}


def states(unit) -> set[str]:
    """The discrete states the unit file declares (``[build] states``, plant names: a pump's
    run feedback, which ``diag unit build`` does not test): a mode of the plant, read by the
    tests as any input but never a tag at fault — a worn pump is named on its motor's current
    and the speed, not on the feedback that says it runs."""
    build = unit.file.build or {}
    return {unit.file.tags.get(str(x), str(x)) for x in build.get("states", [])}


def set_points(unit) -> set[str]:
    """The set-points the unit file declares (``set_point`` of its loop tests)."""
    return {t.set_point for t in unit.file.tests if getattr(t, "set_point", None)}


def _spread_test(unit, t: str) -> bool:
    return getattr(unit.file.test(t), "statistic", "level") == "spread"


def derived_matrix(unit) -> DiagnosticMatrix:
    """The matrix of a unit without an expert one: tests × tags, ``1`` where the test reads
    the tag (input, any lag) or models it (output), ``0`` elsewhere (see module doc)."""
    tags, outputs, reads = structure(unit)
    held: dict[str, set[str]] = {}
    for loop, others in compensating_tests(unit, reads).items():
        held.setdefault(outputs[loop], set()).update(others)
    rows = [
        [max(_names_tag(unit, t, x, outputs, reads), int(t in held.get(x, ()))) for x in tags]
        for t in unit.tests
    ]
    return DiagnosticMatrix(list(unit.tests), tags, rows, name=f"{unit.name} (derived: tags)")


def compensating_tests(unit, reads: dict[str, list[str]]) -> dict[str, list[str]]:
    """Per loop test (a ``level`` test with an actuator and a set-point) the other tests its
    loop's compensating move reaches: a bias ``b`` of the loop's sensor is taken by the loop,
    which drives the process as a set-point step of ``−b`` would, so every other test whose
    model reads the set-point (the actuator's own test, the tags downstream; not a spread
    test, nor a test of the same set-point) moves. The ranking's compensated direction puts
    ``−g · b`` on them (:func:`_compensated_sensors`), the derived matrix a ``1`` in the
    sensor's column. Without it the column held
    only the loop test (quiet once the loop has compensated) and the tests reading the sensor:
    a meter bias on the 7-tag line fired its valve's test alone, whose exact column is the
    supply pressure's, and the unit reported ``SUPPLY_P`` on 94 % of the alarm samples where
    its ranking named the meter on 99.6 % (issue 34, item 4)."""
    out: dict[str, list[str]] = {}
    for t in unit.tests:
        test = unit.file.test(t)
        if _spread_test(unit, t) or not (test.actuator and test.set_point):
            continue
        out[t] = [
            other for other in unit.tests
            if other != t and not _spread_test(unit, other)
            and unit.file.test(other).set_point != test.set_point
            and test.set_point in reads[other]
        ]  # fmt: skip
    return out


def _names_tag(unit, t: str, x: str, outputs: dict[str, str], reads: dict[str, list[str]]) -> int:
    """1 where test ``t``'s alarm points at tag ``x`` (its row of :func:`derived_matrix`): the
    tag it models or one it reads; a spread test (a loop's error) its actuator only."""
    if _spread_test(unit, t):  # the spread of a loop's error: its actuator (stiction)
        return 1 if x == unit.file.test(t).actuator else 0
    return 1 if (x == outputs[t] or x in reads[t]) else 0


def directions(unit, spec: CombinedSpec | None) -> tuple[np.ndarray, np.ndarray]:
    """Fault direction of each tag (columns, :func:`structure` order) in the space of the
    scaled residuals (rows, the unit's tests): see the module doc. And per tag the test
    whose control error its fault also moves by an unknown amount (a loop's actuator: a
    valve the loop compensates leaves the error at zero, a stuck or saturated one moves it
    either way), −1 for none: the ranking gives that tag the plane of its direction and that
    test's axis (:meth:`CombinedModel.evaluate`). Only actuators get a plane; a loop's own
    sensor has one direction (its loop test and the compensating move,
    :func:`_compensated_sensors`)."""
    tags, outputs, reads = structure(unit)
    xi = np.zeros((len(unit.tests), len(tags)))
    loop = np.full(len(tags), -1, np.int64)
    for j, t in enumerate(unit.tests):
        test = unit.file.test(t)
        if _spread_test(unit, t):  # only a sticking actuator widens its loop's error
            # (learned: a direction of its own, the actuator's second, process_directions)
            for k, x in enumerate(tags):
                if x == test.actuator and spec is None:
                    xi[j, k] = 1.0
            continue
        for k, x in enumerate(tags):
            if spec is None:
                xi[j, k] = 1.0 if (x == outputs[t] or x in reads[t]) else 0.0
                continue
            if x == test.actuator and x != outputs[t] and x not in spec.gains.get(t, {}):
                loop[k] = j
                continue
            # the loop's own sensor keeps one direction, as any tag: ``1`` on its loop test
            # (its own residual, the control error a bias moves before the loop compensates)
            # and, added below, the compensating move on the tests reading the set-point. Not
            # the plane of its direction and the loop test's axis: one more degree of
            # freedom than the other tags have, it took a share of every deviation that
            # moved the loop's error (chemical plant, tuning seeds: faulted tag in the top
            # three 28/45 with the plane, 31/45 without; docs/how-to/unit-loops.md)
            i = spec.tests.index(t)
            span = test.ymax if unit.ev["scale"] == "max" and test.ymax else unit.models[t].span
            g = spec.gains.get(t, {}).get(x, 0.0)
            xi[j, k] = ((1.0 if x == outputs[t] else 0.0) - g) * 100.0 / span / spec.scale[i]
    if spec is not None:
        _compensated_sensors(unit, spec, tags, outputs, reads, xi)
    return xi, loop


def point_directions(unit, spec: CombinedSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per operating point of ``spec`` (``diag unit accept``) the tags' directions
    (:func:`directions`) and true-change directions (:func:`process_directions`), points ×
    the unit's tests × tags, each in the residuals scaled at that point: a bias
    moves test ``j``'s residual by the same amount in % of span at every point, divided by
    the point's scale ``point_scale[p][j]`` and, for a level test with points of its own, by
    its ``point_scale[p]`` (:meth:`~diag_plugin.diagnose.unit.Unit.at_points`). The first
    point's scale alone ranked every sample by it (SKAB: the accelerometers' residuals
    spread 17× wider at the calibration run's point)."""
    level = {t.name: t.point_scale for t in unit.file.tests if t.point_scale is not None}
    xis, procs, moves = [], [], []
    for p, row in enumerate(spec.point_scale):
        scale = [float(row[i]) * (level[n][p] if n in level else 1.0)
                 for i, n in enumerate(spec.tests)]  # fmt: skip
        at = replace(spec, scale=scale)
        xi, _ = directions(unit, at)
        xis.append(xi)
        procs.append(process_directions(unit, at, xi))
        moves.append(moved_directions(unit, at))
    return np.stack(xis), np.stack(procs), np.stack(moves)


def process_directions(unit, spec: CombinedSpec, xi: np.ndarray) -> np.ndarray:
    """Each tag's second fault direction: a change of the *true* quantity (a process fault
    entering through it, a warmer feed), where :func:`directions` gives its sensor's bias.

    A true change ``b`` of ``X`` is followed by the tags whose models read ``X``: tag ``Y``
    (the output of test ``i``) moves by ``g_iX · b`` (one step along the models' gains, as the
    model says it follows) and the readings move by ``d = b (e_X + Σ_i g_iX e_Y(i))``. Test
    ``j``'s residual moves by ``(e_out(j) − g_j) · d · 100 / span_j`` (eq. 6 applied to every
    tag that moved), divided by ``s_j``: zero on the tests that follow ``X``, the move on the
    tests that read the followers but not ``X`` (a feed-temperature step seen by the models
    of the mixer's consumers) and on ``X``'s own test. A sensor bias moves only the reading of
    ``X``, so the two differ wherever a model reads ``X``. Loops' sensors and actuators keep
    their column of ``xi`` (a loop holds its measurement; an actuator has its plane); spread
    tests keep theirs. The ranking takes the larger of the two contributions
    (:meth:`CombinedModel.evaluate`).

    A loop's two fault modes get the second direction too. A loop's **actuator**: sticking,
    the spread of its loop's error alone (``1 / s_j`` on its spread test), its level
    direction in :func:`directions` without it — one direction for both let the spread test
    dilute a biased valve's match (its level test moved, its spread did not) and the tag an
    input of the valve's model took the valve's deviation. A loop's own **sensor**,
    compensated: the loop holds the reading at the set-point, so its loop test stays at zero
    and only the rest of its direction moves (the loop's compensating move, the tests reading
    it and the set-point's learned responses): its direction with its loop test's entry ``0``.
    A drifting sensor the loop follows shows that way and not as its loop's error (chemical
    plant, tuning seeds, at 1 % of calibration samples: faulted tag in the top three 36/45 →
    38/45; the compensated sensor alone, with the mixed actuator direction, 33/45: it took the
    biased and the fouled cooler's valve; docs/how-to/unit-loops.md).

    A manipulated flow with a **balance test** (``balance = true``, :mod:`~diag_plugin.
    unitbuild.balance`): its true quantity is what its valve sets (the valve's own test and
    direction), and what enters through the flow's line unseen is a loss or gain of the
    vessel its balance reads — that balance's residual alone (``1 / s_j`` on each balance
    test of the flow). A leak of the tank the flow drains then names the flow, not the
    balance's inflow meter, whose bias moves its own test too (docs/how-to/unit-loops.md). A
    flow its own loop holds keeps its compensated direction (above): a bias of its meter is
    what its balance test sees, the loop holding the reading and the true flow moving. No
    other tag's true change moves a balance (as an actuator's true move does not,
    :func:`moved_directions`): the out-flow following a level its model reads moved the
    feed meter's balance by the level's true change, and the level took the meter's bias
    (the 7-tag line at 5 min with the pair step; docs/how-to/unit-loops.md)."""
    tags, outputs, _ = structure(unit)
    col = {x: k for k, x in enumerate(tags)}
    spread = np.array([_spread_test(unit, t) for t in unit.tests])
    fixed = set()  # loops' sensors and actuators
    stiction: dict[int, list[int]] = {}  # actuator's column → its spread tests
    sensor_of: dict[int, int] = {}  # loop sensor's column → its loop test
    for j, t in enumerate(unit.tests):
        test = unit.file.test(t)
        if test.actuator:
            fixed.add(test.actuator)
            if not spread[j]:
                fixed.add(outputs[t])
                if outputs[t] in col and outputs[t] != test.actuator:
                    sensor_of[col[outputs[t]]] = j
        if spread[j] and test.actuator in col:
            stiction.setdefault(col[test.actuator], []).append(j)
    out = _true_changes(unit, spec, tags, outputs, spread)
    out[spread] = xi[spread]
    # a true change leaves a balance where it was: the vessel's level and its flows account
    # for it (as for an actuator's true move, :func:`moved_directions`); the one-step
    # followers would move one side only (a level the out-flow's model reads: the out-flow
    # follows, the feed the loop holds does not), and the level took a meter's balance alarm
    out[[getattr(unit.file.test(t), "balance", False) for t in unit.tests]] = 0.0
    keep = [k for k, x in enumerate(tags) if x in fixed]
    out[:, keep] = xi[:, keep]
    for k, j in sensor_of.items():  # compensated: its loop test held at zero
        out[j, k] = 0.0
    for k, rows in stiction.items():  # sticking: its spread tests alone
        out[:, k] = 0.0
        for j in rows:
            out[j, k] = 1.0 / spec.scale[spec.tests.index(unit.tests[j])]
    for k, rows in _balances(unit, outputs, col).items():  # a loss no meter sees: its balance
        if k in sensor_of:  # a flow its loop holds: compensated (above), its balance moving
            continue
        out[:, k] = 0.0
        for j in rows:
            out[j, k] = 1.0 / spec.scale[spec.tests.index(unit.tests[j])]
    return out


def _true_changes(unit, spec: CombinedSpec, tags, outputs, spread: np.ndarray) -> np.ndarray:
    """Each tag's true-change direction, tests × tags (:func:`process_directions`: ``((e_out
    − g) · d) · 100 / span / s``, the readings ``d`` a true change moves, the tag and the
    tags whose models read it), zero on the spread tests."""
    T, n = len(unit.tests), len(tags)
    col = {x: k for k, x in enumerate(tags)}
    own = np.zeros((T, n))  # e_out(j)
    gain = np.zeros((T, n))  # g_jX
    f = np.zeros(T)  # 100 / span_j / s_j
    for j, t in enumerate(unit.tests):
        if spread[j]:
            continue
        test = unit.file.test(t)
        span = test.ymax if unit.ev["scale"] == "max" and test.ymax else unit.models[t].span
        f[j] = 100.0 / span / spec.scale[spec.tests.index(t)]
        if outputs[t] in col:
            own[j, col[outputs[t]]] = 1.0
        for x, g in spec.gains.get(t, {}).items():
            if x in col:
                gain[j, col[x]] = g
    # d[:, X]: the readings a true change of X moves (X itself and its followers)
    follow = np.where(own.sum(axis=1, keepdims=True) > 0, gain, 0.0) * (1.0 - own)
    d = np.eye(n) + own.T @ follow
    return ((own - gain) @ d) * f[:, None]


def moved_directions(unit, spec: CombinedSpec) -> np.ndarray:
    """A loop's actuator's third direction, tests × tags (zero for every other tag): its
    **true move**, the tags whose models read it following it (:func:`_true_changes`). Its
    first direction (:func:`directions`) is a bias of the valve, the valve not where its
    output says: the tests reading the output see ``−g`` (a biased valve, a flow meter
    reading the valve's characteristic wrong); its second the spread of its loop's error
    (sticking). A loop that compensates a process fault (a fouled cooler) truly moves its
    valve, and a flow that follows the valve (its test the valve's characteristic,
    :func:`~diag_plugin.unitbuild.build.driven_reads_output`) follows it: the valve's own test
    moves, the flow's does not — neither of the other two directions. A balance test
    (``balance = true``) does not move either: what a valve truly passes, the vessel's level
    and other flows account for (its one-step followers would say otherwise, and took a
    leak's balance alarm for the valve)."""
    tags, outputs, _ = structure(unit)
    spread = np.array([_spread_test(unit, t) for t in unit.tests])
    acts = {unit.file.test(t).actuator for j, t in enumerate(unit.tests) if not spread[j]}
    out = _true_changes(unit, spec, tags, outputs, spread)
    out[:, [k for k, x in enumerate(tags) if x not in acts]] = 0.0
    out[[getattr(unit.file.test(t), "balance", False) for t in unit.tests]] = 0.0
    return out


def _balances(unit, outputs: dict[str, str], col: dict[str, int]) -> dict[int, list[int]]:
    """Each manipulated flow's column → its balance tests' rows (``balance = true``)."""
    out: dict[int, list[int]] = {}
    for j, t in enumerate(unit.tests):
        if getattr(unit.file.test(t), "balance", False) and outputs[t] in col:
            out.setdefault(col[outputs[t]], []).append(j)
    return out


#: standard errors each side of a compensated sensor's evidence must stand clear of zero
#: (:func:`compensated_loops`): the actuator's move and the move of the tests beyond it, as
#: ``[combined.responses]`` keeps a set-point's slope (:func:`~diag_plugin.learn.thresholds.
#: setpoint_responses`)
COMPENSATED_SE = 3.0
#: a compensated sensor is credited with its actuator's move only where what its bias leaves
#: unexplained is what a fault-free sample leaves: ``T² − plane`` at most the χ² quantile of
#: ``1 − COMPENSATED_REST`` with the known tests less the two fitted (a process fault the
#: loop holds moves tests the bias does not; :meth:`CombinedModel._compensated_rbc`)
COMPENSATED_REST = 0.05


def compensated_loops(unit, tags: list[str]) -> np.ndarray | None:
    """Per loop whose own sensor can be at fault and whose actuator has a test of its own
    (a controller output's test, issue 34 item 7), the sensor's column in ``tags``, the
    actuator's test's row and the loop test's row (loops × 3; None for none): where a bias
    of the sensor is told from a fault of the actuator (:meth:`CombinedModel._compensated_rbc`).

    A loop compensating a bias ``b`` of its sensor moves its actuator, and the true
    measurement moves by ``−b``, so the tests beyond the actuator move too (the sensor's
    compensated direction, :func:`process_directions`). A fault of the actuator itself (a
    biased or sticking valve), a true change of what its model reads (a supply pressure) or a
    process fault the loop holds (a fouled cooler) moves the actuator's test and leaves the
    measurement at its set-point: the tests beyond stay. So the actuator's move is the
    sensor's when the tests beyond it moved too, the way the same ``b`` moves them."""
    _, outputs, _ = structure(unit)
    own = {x: j for j, x in enumerate(outputs[t] for t in unit.tests)
           if not _spread_test(unit, unit.tests[j])}  # fmt: skip
    col = {x: k for k, x in enumerate(tags)}
    out = []
    for j, t in enumerate(unit.tests):
        test = unit.file.test(t)
        if _spread_test(unit, t) or not test.actuator or test.actuator == outputs[t]:
            continue
        if outputs[t] in col and test.actuator in own:
            out.append((col[outputs[t]], own[test.actuator], j))
    return np.array(sorted(set(out)), np.int64).reshape(-1, 3) if out else None


def _compensated_sensors(unit, spec: CombinedSpec, tags, outputs, reads, xi: np.ndarray) -> None:
    """In place: a loop's own sensor biased by ``b`` is compensated by its loop, which then
    drives the process as a set-point step of ``−b`` would: every other test whose model
    reads the set-point (the model of the loop's actuator, of the tags downstream) sees a
    residual ``−g · b``, ``g`` that model's gain on the set-point. Added to the sensor's
    direction. And where the window showed the residuals moving with the set-point (``[combined]
    responses``, :func:`~diag_plugin.learn.thresholds.setpoint_responses`: the plant's response
    that no model's gain carries, as where no model reads the measurement or the set-point),
    ``−β_j`` on each test ``j`` that moved, ``β_j`` its scaled residual's response to a unit
    move of the set-point: the compensated bias moves the true measurement as a set-point move
    of ``−b`` would."""
    for t, others in compensating_tests(unit, reads).items():
        sp = unit.file.test(t).set_point
        pv = outputs[t]
        if pv not in tags:
            continue
        k = tags.index(pv)
        for other, beta in spec.responses.get(sp, {}).items():
            if other in unit.tests and other != t:
                xi[unit.tests.index(other), k] -= beta
        for other in others:
            g = spec.gains.get(other, {}).get(sp)
            if not g:
                continue
            ot, m = unit.file.test(other), unit.models[other]
            span = ot.ymax if unit.ev["scale"] == "max" and ot.ymax else m.span
            j = unit.tests.index(other)
            xi[j, k] += -g * 100.0 / span / spec.scale[spec.tests.index(other)]


def outside_tests(unit) -> np.ndarray | None:
    """Per test of ``unit`` (its tests' order) whether it stays out of the combined ``T²``
    (``combined = false`` in its ``[tests]`` row, :class:`~diag_plugin.diagnose.unitfile.
    TestSpec`); None where every test is in — or none is, as ``T²`` needs one."""
    out = np.array([not t.combined for t in unit.file.tests], bool)  # unit.tests' order
    return out if out.any() and not out.all() else None


@dataclass(frozen=True)
class TestNames:
    """The tags the unit's tests in alarm name in its ranking, beside their shares of ``T²``.

    A test in alarm (its own symptom on) names the tags a single test's alarm names in the
    derived matrix (:func:`derived_matrix`: the tag it models and those it reads; a spread
    test its actuator), each with the value ``v = max(ρ, 1)``, ``ρ`` its filtered residual
    over its threshold on the side it leaves (``r / high`` above zero, ``r / low`` below;
    unknown, as over a gap its symptom is held through: 1). Where it does:

    - a test kept out of ``T²`` (``combined = false``, :func:`outside_tests`) contributes
      nothing to ``T²`` and so to no tag's share of it: in alarm it always names its tags.
      A tag's share of ``T²`` is at most 1 (``RBC_X ≤ T²``), so they rank first, before the
      ``T²`` contributions, among themselves by ``ρ`` and at equal ``v`` in the tags' order
      (the test's output before the tags it reads); a tag named both ways keeps the larger
      value;
    - every test on names its tags where the ``T²`` shares, held over the episode, name
      none (:meth:`fill`): ``T²`` unknown (fewer than :data:`MIN_KNOWN_SHARE` of the tests
      known) or giving no tag a share above :data:`NO_SHARE` (``T²`` 0 or next to it). The
      unit's alarm then named no tag (``faults`` ``unit``, ``top1`` empty) though the test
      on says where it is: the AHU acceptance pass at 1 min, 8-99 % of the alarm samples of
      its runs (docs/explanation/acceptance-ahu.md). These values are held over the episode
      by their own mean (:meth:`on_values`, a second
      :class:`~diag_plugin.diagnose.unitloops.EpisodeHold`), not mixed into the shares': a
      sample whose held shares name a tag names what it did. Here the tag the test models
      ranks first at equal ``ρ``, then the tags it reads (:data:`READ_BELOW`).

    The rule is structural (no tuning run chose it): the test's own statistic says how far
    out it is, and the tags are those the unit already blames for that test's alarm."""

    #: per test of the unit whether it is kept out of ``T²``
    kept: np.ndarray
    #: the tests' thresholds, low and high (NaN: none)
    low: np.ndarray
    high: np.ndarray
    #: per test the tags (:func:`structure` order) its alarm names
    names: np.ndarray
    #: ``names`` with the tags a test reads at ``1 - READ_BELOW``, the tag it models at 1
    first: np.ndarray

    @classmethod
    def of(cls, unit, tags: list[str]) -> TestNames:
        """From the unit file's tests over the ranking's ``tags``."""
        out = outside_tests(unit)
        _, outputs, reads = structure(unit)
        lims = [t.limits or (np.nan, np.nan) for t in unit.file.tests]  # unit.tests' order
        tests = unit.tests
        names = np.array([[_names_tag(unit, t, x, outputs, reads) for x in tags] for t in tests])
        names = names.reshape(len(unit.tests), len(tags)).astype(bool)
        own = np.array([[x == outputs[t] for x in tags] for t in unit.tests], bool)
        return cls(
            np.zeros(len(unit.tests), bool) if out is None else out,
            np.array([a for a, _ in lims], float),
            np.array([b for _, b in lims], float),
            names,
            names * np.where(own.reshape(names.shape), 1.0, 1.0 - READ_BELOW),
        )

    def values(self, r: np.ndarray, s: np.ndarray) -> np.ndarray:
        """Per sample (rows of the unit's filtered residuals ``r`` and symptoms ``s``, n × the
        unit's tests) each tag's value from the kept-out tests in alarm (see the class doc),
        0 where none names it (n × tags)."""
        k = np.flatnonzero(self.kept)
        r = np.asarray(r, float)[:, k]
        on = _on_any(np.asarray(s, float)[:, k])
        v = np.where(on, np.fmax(side_ratio(r, self.low[k], self.high[k]), 1.0), 0.0)
        return np.max(v[:, :, None] * self.names[k][None, :, :], axis=1, initial=0.0)

    def name(self, share: np.ndarray, r: np.ndarray, s: np.ndarray) -> np.ndarray:
        """``share`` (n × tags, shares of ``T²``, NaN unknown) with each tag's value from the
        kept-out tests in alarm where larger (a new array; ``share`` where none is)."""
        if not self.kept.any():
            return share
        v = self.values(r, s)
        hit = v > 0
        if not hit.any():
            return share
        return np.where(hit & ~(share >= v), v, share)

    def on_values(self, r: np.ndarray, s: np.ndarray) -> np.ndarray:
        """Per sample (as :meth:`values`) each tag's value from every test in alarm, the tag
        a test models first (:attr:`first`), 0 where none names it (n × tags): worked over
        the tests on only."""
        out = np.zeros((len(r), self.first.shape[1]))
        rows, tests = np.nonzero(_on_any(np.asarray(s, float)))
        if rows.size:
            x = np.asarray(r, float)[rows, tests]
            v = np.fmax(side_ratio(x, self.low[tests], self.high[tests]), 1.0)
            np.maximum.at(out, rows, v[:, None] * self.first[tests])
        return out

    @staticmethod
    def fill(held: np.ndarray, held_on: np.ndarray) -> np.ndarray:
        """The ranking's values per alarm sample: the held shares ``held`` (n × tags, NaN
        unknown), or where none is above :data:`NO_SHARE` the held values of the tests on
        ``held_on`` (:meth:`on_values` over the episode) where any is (the shares there next
        to 0 name nothing: 0; unknown stays NaN). A new array where any sample is filled."""
        empty = ~(held > NO_SHARE).any(axis=1) & (held_on > 0).any(axis=1)  # NaN: none
        if not empty.any():
            return held
        out = held.copy()
        h, v = held[empty], held_on[empty]
        out[empty] = np.where(v > 0, v, np.where(h > 0, 0.0, h))
        return out

    @staticmethod
    def fill_named(share: np.ndarray, before: np.ndarray, on: np.ndarray) -> np.ndarray:
        """``share`` (alarm samples × tags, before the episode hold) where ``T²`` was unknown
        (every share NaN in ``before``) and a tag is named all the same (a measured input's
        excursion, :class:`Excursions`): the tags the tests on name (``on``,
        :meth:`on_values`) after it, in their own order, at half the smallest named value
        scaled by theirs, so that the explicit name does not leave the rest of the ranking
        empty (as :meth:`fill` gives where nothing is named). A new array where any is."""
        named = share > NO_SHARE
        gaps = np.isnan(share) & (on > 0)
        rest = np.isnan(before).all(axis=1) & named.any(axis=1) & gaps.any(axis=1)
        if not rest.any():
            return share
        out = share.copy()
        h, v, g = share[rest], on[rest], gaps[rest]
        low = np.min(np.where(named[rest], h, np.inf), axis=1, keepdims=True)
        top = np.max(np.where(g, v, 0.0), axis=1, keepdims=True)
        out[rest] = np.where(g, 0.5 * low * v / top, h)
        return out


def side_ratio(r: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """A two-sided test's statistic over its limit: ``r / high`` above zero, ``r / low`` below
    (``low`` < 0 < ``high``, per column), so 1 is the threshold on either side; NaN where
    ``r`` is unknown or the test has no threshold (:class:`TestNames`, and the benchmarks'
    per-test statistics, :mod:`diag_plugin.bench.matched`)."""
    r = np.asarray(r, float)
    hi = np.asarray(high, float)
    lo = np.asarray(low, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        up = np.where(hi > 0, r / hi, np.nan)
        down = np.where(lo < 0, r / lo, np.nan)
    out = np.fmax(up, down)
    return np.where(np.isfinite(r), out, np.nan)


def _on_any(s: np.ndarray) -> np.ndarray:
    """Where a symptom is on: nonzero and known."""
    return np.nan_to_num(s, nan=0.0) != 0


#: the combined test's covariance up to this condition number has every pattern's inverse
#: computed in one stacked call, not one pseudo-inverse (an SVD) each: equal to within
#: ~T · BATCH_COND · 2.2e-16 relative (1e-10 for 45 tests), tests/test_unit_replay_exact.py
BATCH_COND = 1e4
#: rows per block of the combined test's evaluation (its arrays of rows × tests in the cache)
BLOCK_ROWS = 1024
#: rows from which :meth:`CombinedModel.evaluate` makes the scaled residuals per block
LAZY_Z_ROWS = 1 << 16


@dataclass
class CombinedModel:
    """The combined statistic and the contributions of a unit, ready to evaluate."""

    tags: list[str]
    center: np.ndarray
    scale: np.ndarray
    cov: np.ndarray
    xi: np.ndarray
    high: float | None
    #: per tag the test whose axis joins its direction (a loop's actuator), −1 for none
    loop: np.ndarray | None = None
    #: per tag a second direction, a change of the true quantity (:func:`process_directions`)
    process: np.ndarray | None = None
    #: a loop's actuator's third direction, its true move (:func:`moved_directions`)
    moved: np.ndarray | None = None
    #: per loop the sensor's column and its actuator's test's row (:func:`compensated_loops`)
    compensated: np.ndarray | None = None
    #: operating points (``[combined] point_*``): each test's centre and scale per point
    #: (points × T), the plant tags placing a sample, their mean per point (points × tags)
    #: and spans
    centers: np.ndarray | None = None
    scales: np.ndarray | None = None
    point_tags: list[str] = field(default_factory=list)
    point_at: np.ndarray | None = None
    point_span: np.ndarray | None = None
    #: per operating point the tags' directions (points × T × tags) and their true-change
    #: directions (:func:`point_directions`): each in the scaled residuals of that point
    point_xi: np.ndarray | None = None
    point_process: np.ndarray | None = None
    point_moved: np.ndarray | None = None
    #: per test whether it stays out of ``T²`` (the unit file's ``combined = false``,
    #: :func:`outside_tests`; None: every test is in): its scaled residual is unknown here,
    #: and ``T²``, the known share and the degrees of freedom count the other tests only
    outside: np.ndarray | None = None
    #: per operating point the model that ranks its samples (:meth:`_at_point`)
    _views: dict[int, CombinedModel] = field(default_factory=dict, repr=False)
    #: per pattern of known tests: S⁻¹ restricted to them and the directions' norms
    _inverses: dict[bytes, tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]] = (
        field(default_factory=dict)
    )
    #: whether ``S`` is well conditioned (:meth:`_well_conditioned`), once known
    _cond_ok: bool | None = field(default=None, repr=False)

    def _inverse(self, pat: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        key = pat.tobytes()
        if key not in self._inverses:
            k = np.flatnonzero(pat)
            m = np.linalg.pinv(self.cov[np.ix_(k, k)])
            xi = self.xi[k]
            pr = None if self.process is None else self.process[k]
            mv = None if self.moved is None else self.moved[k]
            self._inverses[key] = (
                m,
                np.einsum("tk,tu,uk->k", xi, m, xi),
                None if pr is None else np.einsum("tk,tu,uk->k", pr, m, pr),
                None if mv is None else np.einsum("tk,tu,uk->k", mv, m, mv),
            )
        return self._inverses[key]

    def _well_conditioned(self) -> bool:
        """``S`` is symmetric positive definite with a condition number of at most
        :data:`BATCH_COND`: then so is every ``S`` restricted to some tests (the eigenvalues
        of a principal submatrix lie between the extreme ones of ``S``, Cauchy interlacing),
        and its inverse is its pseudo-inverse to within ``~T · cond · ε`` relative."""
        if self._cond_ok is None:
            s = self.cov
            ok = s.size > 0 and bool(np.all(np.isfinite(s))) and np.allclose(s, s.T)
            if ok:
                ev = np.linalg.eigvalsh(s)
                ok = bool(ev[0] > 0 and ev[-1] <= BATCH_COND * ev[0])
            self._cond_ok = ok
        return self._cond_ok

    def _prepare(self, patterns: np.ndarray) -> None:
        """Cache the inverses of every new pattern of known tests in one stacked call: ``S``
        with the unknown tests' rows and columns replaced by the identity's is block diagonal
        (after ordering), so its inverse restricted to the known tests is ``S_kk⁻¹``. Only
        for a well-conditioned ``S`` (:meth:`_well_conditioned`); else each pattern gets
        its pseudo-inverse in :meth:`_inverse` as before."""
        new = [p for p in patterns if p.tobytes() not in self._inverses]
        if len(new) < 2 or not self._well_conditioned():
            return
        known = np.asarray(new, bool)
        T = known.shape[1]
        both = known[:, :, None] & known[:, None, :]
        a = np.where(both, self.cov, 0.0)
        idx = np.arange(T)
        a[:, idx, idx] = np.where(known, a[:, idx, idx], 1.0)
        inv = np.linalg.inv(a)
        inv = 0.5 * (inv + inv.transpose(0, 2, 1))  # as pinv's: symmetric to the last bit
        inv *= both  # the unknown tests' rows and columns out: ξᵀ S_kk⁻¹ ξ over the known
        den = np.einsum("ptk,tk->pk", inv @ self.xi, self.xi)
        pr, mv = self.process, self.moved
        dens_p = [None] * len(new) if pr is None else np.einsum("ptk,tk->pk", inv @ pr, pr)
        dens_m = [None] * len(new) if mv is None else np.einsum("ptk,tk->pk", inv @ mv, mv)
        for pat, m_full, d, dp, dm in zip(new, inv, den, dens_p, dens_m, strict=True):
            k = np.flatnonzero(pat)
            m = m_full if k.size == T else m_full[np.ix_(k, k)]
            self._inverses[pat.tobytes()] = (m, d, dp, dm)

    @classmethod
    def of(cls, unit) -> CombinedModel:
        """From the unit file's ``[combined]`` (reordered to the unit's tests), or, before it
        is learned, the rough ranking's scales (the thresholds, identity covariance)."""
        spec = unit.file.combined
        tags = structure(unit)[0]
        T = len(unit.tests)
        if spec is None:
            hi = np.array([t.high if t.high else 1.0 for t in unit.file.tests], float)
            xi, _ = directions(unit, None)
            return cls(tags, np.zeros(T), hi, np.eye(T), xi, None, outside=outside_tests(unit))
        order = [spec.tests.index(t) for t in unit.tests]
        cov = np.asarray(spec.cov, float)[np.ix_(order, order)]
        xi, loop = directions(unit, spec)
        points = {}
        if spec.point_center:
            pxi, pproc, pmoved = point_directions(unit, spec)
            points = {
                "point_xi": pxi,
                "point_process": pproc,
                "point_moved": pmoved if pmoved.any() else None,
                "centers": np.asarray(spec.point_center, float)[:, order],
                "scales": np.asarray(spec.point_scale, float)[:, order],
                "point_tags": list(spec.point_tags),
                "point_at": np.asarray(spec.point_at, float),
                "point_span": np.asarray(spec.point_span, float),
            }
        return cls(
            tags,
            np.asarray(spec.center, float)[order],
            np.asarray(spec.scale, float)[order],
            cov,
            xi,
            spec.high,
            loop if (loop >= 0).any() else None,
            process_directions(unit, spec, xi),
            moved=moved if (moved := moved_directions(unit, spec)).any() else None,
            compensated=compensated_loops(unit, tags),
            outside=outside_tests(unit),
            **points,
        )

    def point_of(self, frame: pd.DataFrame) -> np.ndarray | None:
        """Each sample's operating point (None: the model has one): the nearest point's mean
        in the plant tags ``point_tags`` of ``frame``, each tag's distance in its span (the
        joint test's rule, :meth:`~diag_plugin.models.joint.JointRegressor.nearest`), over
        the tags known at the sample; point 0 where none is."""
        if self.centers is None or self.point_at is None or self.point_span is None:
            return None
        if not self.point_tags:
            return np.zeros(len(frame), np.int64)
        return self.nearest_point(frame.reindex(columns=self.point_tags).to_numpy(float))

    def nearest_point(self, x: np.ndarray) -> np.ndarray:
        """:meth:`point_of` of rows ``x`` (n × ``point_tags``, NaN unknown)."""
        assert self.point_at is not None and self.point_span is not None
        x = x / self.point_span
        at = self.point_at / self.point_span
        d = np.stack([np.nansum((x - a) ** 2, axis=1) for a in at], axis=1)
        return np.argmin(d, axis=1)

    def _at_point(self, p: int) -> CombinedModel:
        """The model that ranks the samples of operating point ``p``: its directions, the
        rest (T², covariance) shared."""
        if p not in self._views:
            assert self.point_xi is not None
            self._views[p] = replace(
                self, xi=self.point_xi[p],
                process=None if self.point_process is None else self.point_process[p],
                moved=None if self.point_moved is None else self.point_moved[p],
                point_xi=None, point_process=None, point_moved=None, _views={}, _inverses={},
                _cond_ok=None,
            )  # fmt: skip
        return self._views[p]

    def _per_point_shares(self, r: np.ndarray, rows: np.ndarray, point: np.ndarray) -> np.ndarray:
        """:meth:`shares` where each operating point has its own directions."""
        at = np.flatnonzero(rows)
        out = np.full((at.size, len(self.tags)), np.nan)
        for p in np.unique(point[at]):
            sel = point[at] == p
            mask = np.zeros(len(r), bool)
            mask[at[sel]] = True
            out[sel] = self._at_point(int(p)).shares(r, mask, point)
        return out

    def z(self, r: np.ndarray, point: np.ndarray | None = None) -> np.ndarray:
        """Scaled residuals ``(r − c) / s`` (n × T, NaN unknown); ``c``, ``s`` those of each
        sample's operating point (``point``, :meth:`point_of`) where the model has points."""
        if point is None or self.centers is None or self.scales is None:
            center, scale = self.center, self.scale
        else:
            center, scale = self.centers[point], self.scales[point]
        z = np.subtract(r, center, dtype=float)
        z /= scale  # in place: one n × T array, not two
        if self.outside is not None:
            z[:, self.outside] = np.nan
        return z

    @property
    def dims(self) -> int:
        """The tests ``T²`` is taken over: the unit's, less those kept out (:attr:`outside`)."""
        T = len(self.center)
        return T if self.outside is None else T - int(self.outside.sum())

    def evaluate(
        self, r: np.ndarray, point: np.ndarray | None = None, shares: bool = True
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """``T²`` per sample (NaN unknown) and each tag's share of it, ``RBC_X / T²`` (n × tags),
        from filtered residuals ``r`` (n × T), each centred at its sample's operating point
        (``point``, :meth:`point_of`; None: the one centre): see the module doc.
        ``shares=False``: T² alone (the shares None; :meth:`shares` gives them for the rows
        that need them)."""
        if shares and point is not None and self.point_xi is not None:
            t2 = CombinedModel.evaluate(self, r, point, shares=False)[0]
            return t2, self._per_point_shares(r, np.ones(len(r), bool), point)
        # over many rows the scaled residuals made block by block as _blocks asks (the same
        # values): no n × T array of them beside the residuals; a piece's few rows at once
        # (making them twice, for the patterns and per block, cost more there)
        z = _ScaledRows(self, r, point) if len(r) > LAZY_Z_ROWS else self.z(r, point)
        n = z.shape[0]
        T = self.dims
        t2 = np.full(n, np.nan)
        share = np.full((n, len(self.tags)), np.nan) if shares else None
        partial: list[tuple[np.ndarray, np.ndarray, int]] = []
        for rows, k, inv, mz, q in self._blocks(z):
            if share is not None:
                share[rows] = self._share(mz, q, k, inv)
            t2[rows] = q
            if k.size < T:
                partial.append((rows, q, k.size))
        if partial:  # the same false-alarm level with T degrees of freedom (one call for all)
            rows = np.concatenate([p[0] for p in partial])
            q = np.concatenate([p[1] for p in partial])
            df = np.concatenate([np.full(p[1].size, p[2]) for p in partial])
            t2[rows] = same_level(q, df, T)
        return t2, share

    def shares(
        self, r: np.ndarray, rows: np.ndarray, point: np.ndarray | None = None
    ) -> np.ndarray:
        """Each tag's share of T² (as :meth:`evaluate`'s) at ``rows`` only (a boolean mask
        over the n samples of ``r``; ``point``: each of the n samples' operating point, as
        :meth:`evaluate`'s): ``len(rows[rows]) × tags``, in the rows' order."""
        if point is not None and self.point_xi is not None:
            return self._per_point_shares(r, np.asarray(rows, bool), point)
        at = np.flatnonzero(rows)
        return self.shares_of(self.z(r[at], None if point is None else point[at]))

    def shares_of(self, z: np.ndarray) -> np.ndarray:
        """Each tag's share of T² (as :meth:`shares`) from scaled residuals ``z`` (n × T, NaN
        unknown; :meth:`z`, or their mean over an alarm episode,
        :class:`~diag_plugin.diagnose.unitloops.EpisodeHold`)."""
        share = np.full((len(z), len(self.tags)), np.nan)
        for sub, k, inv, mz, q in self._blocks(z):
            share[sub] = self._share(mz, q, k, inv)
        return share

    def _blocks(self, z: np.ndarray):
        """The samples with enough known tests, grouped by their pattern of known tests, in
        blocks of at most :data:`BLOCK_ROWS` rows: per block its rows (ascending), the known
        tests ``k``, their :meth:`_inverse`, ``S_kk⁻¹ z`` and ``T² = zᵀ S_kk⁻¹ z`` (before
        the degrees of freedom)."""
        n, T = z.shape
        known = z.finite() if isinstance(z, _ScaledRows) else np.isfinite(z)
        enough = known.sum(axis=1) >= max(1, math.ceil(MIN_KNOWN_SHARE * self.dims))
        if not enough.any():
            return
        # the patterns of known tests, as one integer key per sample when they fit in 63
        # bits (a sort of n keys, not of n rows of T booleans)
        kn = known[enough]
        if T <= 63:  # bit j of a key is test j: the bits packed, 8 bytes read as one integer
            packed = np.zeros((kn.shape[0], 8), np.uint8)
            packed[:, : (T + 7) // 8] = np.packbits(kn, axis=1, bitorder="little")
            keys = packed.view("<u8").reshape(-1)
            ukeys, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
            patterns = kn[first]
        else:
            patterns, inverse = np.unique(kn, axis=0, return_inverse=True)
        rows_all = np.flatnonzero(enough)
        # each pattern's rows (ascending) as one slice of a stable sort, not a scan per pattern
        inverse = inverse.reshape(-1)
        by = rows_all[np.argsort(inverse, kind="stable")]
        ends = np.cumsum(np.bincount(inverse, minlength=len(patterns)))
        self._prepare(patterns)
        for p, pat in enumerate(patterns):
            k = np.flatnonzero(pat)
            inv = self._inverse(pat)
            m = inv[0]
            at = ends[p - 1] if p else 0
            # in blocks of rows whose arrays stay in the cache (one n × T pass per operation
            # was memory-bound: ~8 passes over 200 k × 45 doubles per replay)
            for a in range(at, ends[p], BLOCK_ROWS):
                rows = by[a : min(a + BLOCK_ROWS, ends[p])]
                if isinstance(z, _ScaledRows):
                    zk = z.take(rows, None if k.size == T else k)
                else:
                    zk = z[rows] if k.size == T else z[np.ix_(rows, k)]
                mz = zk @ m
                yield rows, k, inv, mz, np.einsum("ij,ij->i", mz, zk)

    def _share(self, mz: np.ndarray, q: np.ndarray, k: np.ndarray, inv: tuple) -> np.ndarray:
        """Each tag's ``RBC / T²`` in [0, 1] for one block of :meth:`_blocks` (known tests
        ``k``, their inverse, ``S_kk⁻¹ z`` and ``T²``): Alcala & Qin (2009), eq. 13, over each tag's
        direction, the larger of a sensor's bias and a true change, loops over their plane."""
        m, den, den_process, den_moved = inv
        with np.errstate(invalid="ignore", divide="ignore"):
            rbc = _rbc(mz, self.xi[k], den)
            if den_process is not None:  # a bias of the sensor or a true change
                np.maximum(rbc, _rbc(mz, self.process[k], den_process), out=rbc)
            if den_moved is not None:  # an actuator the loop truly moved
                np.maximum(rbc, _rbc(mz, self.moved[k], den_moved), out=rbc)
            if self.loop is not None:
                self._loop_rbc(rbc, mz, m, k)
            if self.compensated is not None and self.process is not None:
                self._compensated_rbc(rbc, mz, m, k, q)
            rbc /= np.maximum(q, 1e-12)[:, None]
            return np.clip(rbc, 0.0, 1.0, out=rbc)

    def _loop_rbc(self, rbc: np.ndarray, mz: np.ndarray, m: np.ndarray, k: np.ndarray) -> None:
        """In place: each loop actuator's contribution over the plane of its direction ``a``
        and its loop test's axis ``b`` (Alcala & Qin, 2009, the multidimensional form:
        ``uᵀ (ΞᵀS⁻¹Ξ)⁻¹ u`` with ``Ξ = [a b]``, ``u = ΞᵀS⁻¹z``), where that test is known;
        the larger of it and the one along its second direction (``rbc`` on entry: sticking,
        :func:`process_directions`)."""
        pos = {int(t): i for i, t in enumerate(k)}
        for c in np.flatnonzero(self.loop >= 0):
            j = pos.get(int(self.loop[c]))
            if j is None:
                continue
            a = self.xi[k, c]
            ma = m @ a
            g = np.array([[a @ ma, ma[j]], [ma[j], m[j, j]]])
            if not m[j, j] > 1e-12:
                continue
            if abs(np.linalg.det(g)) <= 1e-9 * g[0, 0] * g[1, 1]:  # no own direction beside
                plane = mz[:, j] ** 2 / m[j, j]
            else:
                u = np.column_stack([mz @ a, mz[:, j]])
                plane = np.einsum("ij,jk,ik->i", u, np.linalg.inv(g), u)
            # the larger of the plane and its second direction (sticking: the spread alone)
            np.maximum(rbc[:, c], plane, out=rbc[:, c])

    def _compensated_rbc(
        self, rbc: np.ndarray, mz: np.ndarray, m: np.ndarray, k: np.ndarray, q: np.ndarray
    ) -> None:
        """In place: a loop's own sensor whose bias the loop compensates, where the samples say
        so (:func:`compensated_loops`). Its compensated direction ``ξ`` (:func:`process_directions`)
        is split into its entry on the actuator's test ``e_a`` and the rest ``ξ_b`` (the tests
        beyond the actuator), and ``z`` is fitted on both, ``z ≈ α e_a + β ξ_b`` (generalised
        least squares in ``S⁻¹``: ``(α, β) = G⁻¹ u``, ``G = ΞᵀS⁻¹Ξ``, ``u = ΞᵀS⁻¹z``, ``Ξ =
        [e_a ξ_b]``, standard errors ``√diag(G⁻¹)``). Where both stand
        :data:`COMPENSATED_SE` standard errors clear of zero and say the same bias (``β`` and
        ``α / ξ_a`` of one sign: the tests beyond the actuator moved the way the bias that
        moved it moves them), the sensor's contribution is taken over the plane ``Ξ`` (Alcala
        & Qin, 2009, the multidimensional form ``uᵀG⁻¹u``, as an actuator's): how far the
        actuator moves per unit of bias is its model's gain on the set-point, learned over
        the window's moves, which a valve's characteristic need not follow at the point the
        bias takes it to (the 7-tag line's valve moved twice as far). Elsewhere the sensor
        keeps its one-dimensional contributions: the plane on every sample took a share of
        every deviation that moved its loop (docs/how-to/unit-loops.md).

        The two moves alone are not the sensor's: a process fault the loop holds (a fouled
        cooler, a cooling-water swing) or a stuck valve upstream moves the actuator and some
        tests beyond it too, and more besides. So the credit is also a test of fit: only
        where every test of the unit is known at the sample (``k`` all of :attr:`dims`: the
        tests that would contradict the bias are there) and what the plane leaves, ``q −
        uᵀG⁻¹u`` (``q = T²``), is at most what a fault-free sample leaves, the χ² quantile of
        ``1 −`` :data:`COMPENSATED_REST` with ``|k| − 2`` degrees of freedom (the two
        fitted). Without it the credit took the cooler's loop sensor into the top three of
        the chemical plant's cooling-water and stuck-steam-valve runs, and named a fault-free
        alarm of the 7-tag line on its meter (docs/how-to/unit-loops.md).

        A bias the loop cannot wholly take (its actuator at a limit: a drifting cooler-outlet
        sensor with the cooling-water valve at 100 %) leaves the rest on the loop's error: the
        reading moves off its set-point the way the bias moves it, while the tests beyond the
        actuator still move the way the compensated part moves them, and the actuator's test
        moves by whatever the limit left (its model extrapolating past the window, either
        sign). There ``z`` is fitted on ``ξ_b``, the loop test's axis and the actuator's,
        and where the coefficients of ``ξ_b`` and of the loop's error stand
        :data:`COMPENSATED_SE` standard errors clear of zero with one sign (the reading above
        its set-point and the tests beyond saying the true value is below it, or both the
        other way), the contribution is the larger of the sensor's and ``uᵀG⁻¹u`` over the
        three. A true move of the measurement (a fouled cooler, a stuck valve: the reading
        and the true value off the set-point together) moves the loop's error and the tests
        beyond with opposite signs and is not credited. No test of fit and no test need be
        known beyond the three: an actuator at its limit is a state the window did not hold,
        and the tests that read it leave their learned range with it (the cooler's
        cooling-water return). Chemical plant, tuning seeds, cooler-outlet drift: named
        first 2/3 → 3/3 runs (seed 103, its valve at 100 % for 9 h); the valve faults, the
        fouled cooler, the cooling-water swing and the fault-free runs keep their names."""
        # every test known: the tests that would contradict the bias are there, and its fit
        # can be checked
        full = k.size >= self.dims
        rest = float(chi2_isf(np.array(COMPENSATED_REST), max(k.size - 2, 1))) if full else 0.0
        pos = {int(t): i for i, t in enumerate(k)}
        for c, ja, jl in self.compensated:
            j = pos.get(int(ja))
            if j is None:
                continue
            xc = self.process[k, c]
            beyond = xc.copy()
            beyond[j] = 0.0
            if not xc[j] or not beyond.any():
                continue
            if full:
                a = np.zeros((len(k), 2))
                a[j, 0] = 1.0
                a[:, 1] = beyond
                _plane_credit(rbc, c, mz, m, a, xc[j], q, rest)
            i = pos.get(int(jl))
            if i is not None:
                # the loop could not take all of the bias (its actuator at a limit): the rest
                # is its loop's error, the actuator's move is what the limit left
                a = np.zeros((len(k), 3))
                a[:, 0] = beyond
                a[i, 1] = 1.0
                a[j, 2] = 1.0
                _plane_credit(rbc, c, mz, m, a, 1.0, q, None)


def _plane_credit(
    rbc: np.ndarray,
    c: int,
    mz: np.ndarray,
    m: np.ndarray,
    a: np.ndarray,
    sign: float,
    q: np.ndarray,
    rest: float | None,
) -> None:
    """In place: tag ``c``'s contribution over the directions ``a`` (known tests × 2 or 3,
    :meth:`CombinedModel._compensated_rbc`) where the samples say so: ``z`` fitted on them
    (``coef = G⁻¹ u``, ``G = aᵀS⁻¹a``, ``u = aᵀS⁻¹z``, standard errors ``√diag(G⁻¹)``), the
    first two coefficients each :data:`COMPENSATED_SE` standard errors clear of zero and of
    one sign (the first's times ``sign``), and, with ``rest``, what the plane leaves, ``q −
    uᵀG⁻¹u``, at most ``rest``; there the contribution is the larger of ``rbc``'s and
    ``uᵀG⁻¹u`` (Alcala & Qin, 2009, the multidimensional form)."""
    g = a.T @ m @ a
    d = np.diag(g)
    if not (d > 1e-12).all():
        return
    if abs(np.linalg.det(g)) <= 1e-9 * np.prod(d):
        return
    gi = np.linalg.inv(g)
    u = mz @ a
    coef = u @ gi
    se = np.sqrt(np.diag(gi))
    said = (
        (np.abs(coef[:, 0]) >= COMPENSATED_SE * se[0])
        & (np.abs(coef[:, 1]) >= COMPENSATED_SE * se[1])
        & (np.sign(coef[:, 0] / sign) == np.sign(coef[:, 1]))
    )
    if not said.any():
        return
    plane = np.einsum("ij,jk,ik->i", u[said], gi, u[said])
    fits = np.ones(plane.shape, bool) if rest is None else q[said] - plane <= rest
    at = np.flatnonzero(said)[fits]
    rbc[at, c] = np.maximum(rbc[at, c], plane[fits])


class _ScaledRows:
    """:meth:`CombinedModel.z` of residuals ``r`` (n × T; ``point``: each sample's operating
    point or None) made for the rows asked, when asked: what :meth:`CombinedModel._blocks`
    reads of the scaled residuals, without holding all of them (the same operations on the
    same numbers, so the same bits)."""

    def __init__(self, model: CombinedModel, r: np.ndarray, point: np.ndarray | None) -> None:
        self.model, self.r, self.point = model, r, point
        self.shape = r.shape

    def _z(self, rows) -> np.ndarray:
        return self.model.z(self.r[rows], None if self.point is None else self.point[rows])

    def finite(self) -> np.ndarray:
        """Where the scaled residuals are finite (n × T), made in blocks of rows."""
        n = self.shape[0]
        known = np.empty(self.shape, bool)
        for a in range(0, n, BLOCK_ROWS):
            np.isfinite(self._z(slice(a, min(a + BLOCK_ROWS, n))), out=known[a : a + BLOCK_ROWS])
        return known

    def take(self, rows: np.ndarray, k: np.ndarray | None = None) -> np.ndarray:
        """The scaled residuals at ``rows`` (of the tests ``k``; None: all)."""
        if k is None:
            return self._z(rows)
        # C-ordered, as ``z[np.ix_(rows, k)]`` is (``z[:, k]`` is column-major: the products
        # that read it would sum in another order)
        return np.ascontiguousarray(self._z(rows)[:, k])


def same_level(q: np.ndarray, df: np.ndarray, T: int) -> np.ndarray:
    """``F⁻¹_T(F_k(q))``: ``χ²`` values ``q`` on ``k = df`` degrees of freedom mapped to the
    same false-alarm level on ``T`` (the module doc: ``T²`` over the known tests only). Where
    the survival ``1 − F_k(q)`` underflows to 0 (from ``q ≈ 1,500``; ``F⁻¹_T`` of it is
    infinite: a large partial ``T²`` became ``inf``, and on SKAB one such sample held by the
    off-delay after a fault held every matched limit under 2 % at infinity) the levels are
    matched in logarithms, with the upper tail of the incomplete gamma function,
    ``ln Q(a, x) ≈ (a − 1) ln x − x − ln Γ(a) + ln(1 + (a − 1)/x + (a − 1)(a − 2)/x²)``
    (``a = k/2``, ``x = q/2``; Abramowitz and Stegun 6.5.32), solved for ``T``'s ``x`` by
    fixed-point iteration (its slope ``(a − 1)/x`` is small out there)."""
    from scipy import special

    q = np.asarray(q, float)
    df = np.broadcast_to(np.asarray(df, float), q.shape)
    out = chi2_isf(chi2_sf(q, df), T)
    far = np.isfinite(q) & ~np.isfinite(out)
    if far.any():

        def log_q(a, x):
            return (
                (a - 1) * np.log(x)
                - x
                - special.gammaln(a)
                + np.log1p((a - 1) / x + (a - 1) * (a - 2) / x**2)
            )

        a, x0 = df[far] / 2.0, q[far] / 2.0
        level = log_q(a, x0)
        b = T / 2.0
        x = x0.copy()
        for _ in range(50):
            x = (
                (b - 1) * np.log(x)
                - special.gammaln(b)
                + np.log1p((b - 1) / x + (b - 1) * (b - 2) / x**2)
                - level
            )
        out[far] = 2.0 * x
    return out


def chi2_sf(x: np.ndarray, df: np.ndarray) -> np.ndarray:
    """``scipy.stats.chi2.sf(x, df)``, the same values, from ``scipy.special.chdtrc`` (what
    it calls) without importing ``scipy.stats`` (~1 CPU s of each ``diag diagnose``, issue
    34): 1 at ``x ≤ 0``, 0 at ``x = ∞``, NaN where ``x`` is NaN or ``df ≤ 0``; ``x`` and
    ``df`` of one shape."""
    from scipy import special

    x = np.asarray(x, dtype=np.float64)
    df = np.asarray(df)
    ok = df > 0
    inside = ok & (x > 0) & (x < np.inf)
    out = np.zeros(x.shape)
    out[~ok | np.isnan(x)] = np.nan
    out[ok & (x <= 0)] = 1.0
    if inside.any():
        out[inside] = special.chdtrc(df[inside], x[inside])
    return out


def chi2_isf(p: np.ndarray, df: float) -> np.ndarray:
    """``scipy.stats.chi2.isf(p, df)``, the same values, from ``scipy.special.chdtri`` (as
    :func:`chi2_sf`): 0 at ``p = 1``, ∞ at ``p = 0``, NaN outside [0, 1] or where ``df ≤
    0``."""
    from scipy import special

    p = np.asarray(p, dtype=np.float64)
    out = np.full(p.shape, np.nan)
    if not df > 0:
        return out
    inside = (0 < p) & (p < 1)
    out[p == 1] = 0.0
    out[p == 0] = np.inf
    if inside.any():
        out[inside] = special.chdtri(df, p[inside])
    return out


def _rbc(mz: np.ndarray, xi: np.ndarray, den: np.ndarray) -> np.ndarray:
    """Reconstruction-based contribution of each direction (Alcala & Qin, 2009, eq. 13)."""
    out = mz @ xi
    np.square(out, out=out)
    out /= np.maximum(den, 1e-12)
    out[:, ~(den > 1e-12)] = 0.0
    return out


def top_tags(share: np.ndarray, tags: list[str], rows: np.ndarray, top: int = TOP) -> pd.DataFrame:
    """The ``top`` tags by share per sample (``top1``, ``share1``, …), filled where ``rows``
    (an alarm) and a ranking exists, empty elsewhere."""
    return top_tags_at(share[np.asarray(rows, bool)], tags, rows, top)


def top_tags_at(
    share_at: np.ndarray, tags: list[str], rows: np.ndarray, top: int = TOP
) -> pd.DataFrame:
    """:func:`top_tags` from the shares at ``rows`` only (``rows.sum()`` × tags, in order)."""
    return pd.DataFrame(top_columns_at(share_at, tags, rows, top))


#: shares equal to this relative tolerance are one share (:func:`rank`)
TIE = 1e-9
#: a tag no test models (an input only: a declared disturbance) ranks after a test's output
#: whose column holds its column where the output's share is at least this fraction of its
#: own (:class:`Untested`). The tuning plants' top three are the same at 0, 0.8 and never;
#: on ``tests/distplant.py`` 0.8 names its dew point's bias on the dew point and keeps a load
#: several tests read named on the load, which 0 does not (docs/how-to/unit-loops.md)
UNTESTED_RATIO = 0.8


class Untested:
    """The ranking's preference for a tested tag over an untested one that explains no more
    (issue 34, item 4). A tag no test models (an input only: a declared disturbance, a feed
    read by one test) has for column the tests that read it; where a test's output (a tag
    with a test of its own) has a column holding all of them, every symptom the input's
    fault gives the output's fault gives too, with its other tests not (yet) over their
    thresholds. The ranking then takes the input for more likely than the output as soon as
    one quiet test reads the output: the compressor station's dew-point drift fired only
    ``DRY_PDP = f(FT_PLANT[k-4], T_AMB[k-9])``, whose output two quiet tests also read, and
    the declared disturbance ``T_AMB`` (read by that test alone) was named first on every
    alarm sample at a share of 0.39 against ``DRY_PDP``'s 0.36. The input is ranked right
    after the best such output where that output's share is at least :data:`UNTESTED_RATIO`
    of the input's: a tie the structure cannot break goes to the tag that can be tested.
    An input read by tests of several outputs (a disturbance sensor's bias moving them all)
    has no such output and is ranked by its share. The shares reported are not changed."""

    def __init__(self, pairs: list[tuple[int, np.ndarray]]) -> None:
        #: (the input's column in the ranking's tags, the outputs' columns holding its tests)
        self.pairs = pairs

    @classmethod
    def of(cls, unit, tags: list[str]) -> Untested:
        """From the unit's tests over the ranking's ``tags``."""
        _, outputs, reads = structure(unit)
        own = set(outputs.values())
        cols = {
            x: frozenset(t for t in unit.tests if _names_tag(unit, t, x, outputs, reads))
            for x in tags
        }
        pairs = []
        for k, x in enumerate(tags):
            if x in own or not cols[x]:
                continue
            ys = [j for j, y in enumerate(tags) if y in own and cols[x] <= cols[y]]
            if ys:
                pairs.append((k, np.array(ys, np.intp)))
        return cls(pairs)

    def key(self, s: np.ndarray) -> np.ndarray | None:
        """The values :func:`rank` orders ``s`` (samples × tags, NaN as −1) by: ``s`` with
        each input's value put just under its best output's where that output's is at least
        :data:`UNTESTED_RATIO` of the input's and below it (None where no input moves)."""
        if not self.pairs or not len(s):
            return None
        out = None
        for k, ys in self.pairs:
            best = s[:, ys].max(axis=1)
            x = s[:, k]
            move = (x > best) & (best > NO_SHARE) & (best >= UNTESTED_RATIO * x)
            if move.any():
                if out is None:
                    out = s.copy()
                # after the output, beyond the tie (TIE) and before any tag below it
                out[move, k] = best[move] * (1.0 - 10 * TIE) - NO_SHARE
        return out


#: a test in alarm is explained by an input beyond what the unit learned where the move of its
#: residual from its centre is at most this many times the input's excess (how far it is beyond
#: the range the unit learned) times the test's gain on it in % of the test's span
#: (:class:`Excursions`): a model that did not follow the input beyond that range at all
#: would be off by that much, a valve's characteristic steeper there than where it was
#: learned twice as far (the 7-tag line's valve moved two to three times its gain,
#: docs/how-to/unit-loops.md); chosen on ``tests/cooler.py`` (below)
EXCURSION_EXPLAINS = 2.0


class Excursions:
    """A measured input beyond what the unit learned, named before the tags of the tests it
    moved (issue 34, items 4 and 7): the loop that absorbs a disturbance is not its cause.

    A loop compensating a measured input that went where the unit never saw it (cooling water
    warmer than any the learning window held) moves its valve: the valve's own test (the
    controller output predicted from the loads, item 7) fires, because its model does not
    know the plant there, and the ranking, reading one test off, names the valve. What tells
    the disturbance from a valve fault is the input. A test in alarm is **explained** by a
    tag ``X`` beyond the range the unit learned for it (by ``e``, in its units) where

    - ``X`` is the test's own output (the input's own test fires: it went where nothing the
      unit reads predicts it), or
    - the test reads ``X`` and its residual moved from its centre by no more than
      :data:`EXCURSION_EXPLAINS` times ``X``'s excess times the test's gain on it,
      ``|r_j − c_j| ≤ EXCURSION_EXPLAINS · |g_jX| · |e| · 100 / span_j`` (eq. 6: a model
      that did not follow ``X`` beyond its range at all is off by ``|g e|``; a valve's
      characteristic steeper there than where it was learned, twice as far), or
    - the test reads a tag ``X`` whose own test is **unknown** at the sample and reads ``X``'s
      input ``Z``, beyond its range (issue 34 item 4, branch ``i34-feedtemp``): the unit
      cannot say ``X`` is where its causes put it (its model has no rule there), and the one
      cause of ``X`` it sees outside what it learned is ``Z``. No bound on the residual: a
      model reading ``X`` inside its range learned ``X`` moved by its usual causes, and a
      new one moves it against the others the way no gain says (a feed's temperature step
      fired the tests reading the mixed feed at 6–10 times ``2 · |g g| · |e|``).

    Each explaining tag is then followed **upstream**: where it has a test of its own and an
    input of that test is beyond its learned range too, by a larger share of its range, that
    input is the source instead, and so on (a mixed temperature beyond its range because the
    feed it mixes is further beyond: the feed); likewise a tag the build found to carry the
    same measurement (``same_as``: a condensate's temperature that follows the cooling
    water's, smoothed) beyond by a larger share. Where one source explains **every** test in
    alarm at a sample, it is named: its value there ``1 +`` its excess as a share of its
    range, above every share of ``T²`` (at most 1), as a kept-out test's tags are
    (:class:`TestNames`); of several, the one beyond by the largest share. A biased or losing
    valve moves its test by more than a small excursion of its loads explains, a sticking one
    fires its spread test (which reads no input), and while the loads stay inside what the
    unit learned nothing changes: those samples are ranked as before, as is a sample with no
    test on (``T²`` alone).

    Candidates are the tags the ranking names that are no loop's measurement or actuator (a
    loop holds the one and moves the other; set-points, hand valves and states are not
    ranked at all), nor a tag the models say a loop drives: whose own test reads a loop's
    measurement, actuator or set-point, or a tag so driven, at any depth (a cooler's water
    return, modelled from the valve that sets its flow, is beyond its range because the loop
    moved it; a tank's outflow, modelled from the level a flow loop fills, because the loop
    cycles). The
    learned range of a tag is the narrowest its readers' models learned for it
    (:func:`~diag_plugin.diagnose.operating.learned_ranges`: a rule grid's sets that carry a
    rule, a linear model's span); a tag no test reads has none and is never a source. An
    input is judged at its value at the sample, whatever lag a model reads it at: a live
    cycle (:class:`~diag_plugin.diagnose.plant.Plant`'s fast path) holds that value only, and
    a replay names what a live cycle names.

    **A relation broken beyond the range** (issue 34 item 4, branch ``i34-feedloss``). A test
    whose input left its learned range is unknown (its model has no rule there), so a lost
    feed — the flow at 0 while its controller opens the valve to its limit — leaves no test
    on at the pair: the flow's test reads the valve, the valve's the flow, and both are
    unknown; ``T²`` is unknown too (most tests unknown) or spreads over the tags downstream,
    and no input explains those. What such a test still says is a **sign**: where it reads
    one input ``X`` alone, a model that follows ``X`` beyond its range in any monotone way
    moves its output ``Y`` beyond its own range the way ``g_YX · e_X`` says (its gain,
    ``[combined.gains]``; ``e_X`` the input's excess). Where ``e_Y · g_YX · e_X < 0`` — the
    output left its range on the side opposite to where its input's excursion takes it — no
    steeper or flatter characteristic explains it: the relation is broken, as the test would
    say if it could be evaluated. At such an alarm sample, the test unknown, ``Y`` and ``X``
    (where a candidate) are named, each at ``1 +`` its excess as a share of its range,
    whatever else is on (as a kept-out test's tags are, :class:`TestNames`). A valve and its
    flow moved together beyond what was learned (an A/C ratio step the A feed's
    loop follows) keep the sign and are ranked as before."""

    def __init__(
        self,
        reads: list[list[tuple[tuple[str, int], int, float]]],
        own: np.ndarray,
        ranges: dict[str, tuple[float, float]],
        keys: dict[int, str],
        up: dict[int, list[tuple[tuple[str, int], int]]],
        center: np.ndarray,
        broken: list[tuple[int, int, tuple[str, int], int, float]] | None = None,
        via: list[list[tuple[tuple[str, int], int, int]]] | None = None,
    ) -> None:
        #: per test: the inputs ``Z`` (value judged, ranking column) of the own test ``j_X``
        #: of a tag ``X`` it reads, and ``j_X`` — ``Z`` explains the test where ``j_X`` is
        #: unknown and ``Z`` beyond its range (class doc, an input the unit cannot judge)
        self.via = via or [[] for _ in reads]
        #: per test reading one input alone whose output is a candidate: (the test, its
        #: output's ranking column, the input's value judged, its ranking column or −1, the
        #: signed gain), the relations whose sign is judged beyond the range (class doc)
        self.broken = broken or []
        #: per test: (the value judged (model tag, lag), its ranking column, ``|g|·100/span``)
        self.reads = reads
        #: per test its output's ranking column where a candidate with a range, else −1
        self.own = own
        #: per model tag its learned range
        self.ranges = ranges
        #: per candidate ranking column its model tag (its own value, lag 0)
        self.keys = keys
        #: per ranking column the tags upstream of it (its test's inputs, same_as tags)
        self.up = up
        #: per test its residual's centre (``[combined] center``, the unit's tests' order)
        self.center = center

    @classmethod
    def of(cls, unit, tags: list[str]) -> Excursions | None:
        """From the unit file (None without ``[combined]`` or without a candidate)."""
        from diag_plugin.diagnose.operating import learned_ranges

        spec = unit.file.combined
        if spec is None:
            return None
        _, outputs, reads_all = structure(unit)
        plant = {m: unit.file.tags.get(m, m) for m in unit.model_tags}
        model_of = {p: m for m, p in plant.items()}
        loop = set()
        for t in unit.tests:
            test = unit.file.test(t)
            if test.actuator:
                loop.add(test.actuator)
                if not _spread_test(unit, t):
                    loop.add(outputs[t])
        # a tag the models say a loop drives: its test reads a loop's tag (its measurement,
        # actuator or set-point) or a tag so driven, at any depth
        sets = loop | set_points(unit) | declared_set_points(unit)
        driven: set[str] = set()
        grew = True
        while grew:
            new = {outputs[t] for t in unit.tests if set(reads_all[t]) & (sets | driven)}
            grew = bool(new - driven)
            driven |= new
        col = {x: k for k, x in enumerate(tags) if x not in loop and x not in driven}
        ranges: dict[str, tuple[float, float]] = {}
        for rg in learned_ranges(unit.models, unit.tests):
            if rg.gap or not (np.isfinite(rg.lo) and np.isfinite(rg.hi) and rg.hi > rg.lo):
                continue
            lo, hi = ranges.get(rg.tag, (-np.inf, np.inf))
            ranges[rg.tag] = (max(lo, rg.lo), min(hi, rg.hi))
        ranges = {t: v for t, v in ranges.items() if v[1] > v[0]}
        keys = {k: model_of.get(x, x) for x, k in col.items() if model_of.get(x, x) in ranges}
        build = (unit.file.build or {}).get("tests") or {}
        reads: list[list[tuple[tuple[str, int], int, float]]] = []
        own = np.full(len(unit.tests), -1, np.int64)
        up: dict[int, list[tuple[tuple[str, int], int]]] = {}
        broken: list[tuple[int, int, tuple[str, int], int, float]] = []
        for j, t in enumerate(unit.tests):
            row: list[tuple[tuple[str, int], int, float]] = []
            reads.append(row)
            if _spread_test(unit, t):  # a loop's cycling: no input explains it
                continue
            test = unit.file.test(t)
            span = test.ymax if unit.ev["scale"] == "max" and test.ymax else unit.models[t].span
            for s in parse_specs(unit.models[t].inputs):
                if s.fn != "" or len(s.tags) != 1 or s.tags[0] not in ranges:
                    continue
                k = col.get(plant.get(s.tags[0], s.tags[0]))
                g = abs(spec.gains.get(t, {}).get(tags[k], 0.0)) if k is not None else 0.0
                if g > 0 and span:
                    row.append(((s.tags[0], s.lag), k, g * 100.0 / span))
            k = col.get(outputs[t])
            if k is None or k not in keys:
                continue
            if not getattr(test, "balance", False):
                own[j] = k
                # a test reading one input alone: the sign of its gain fixes where the
                # output goes beyond its range (an input inside its range moves it an
                # unknown way: none here); a loop's tag too, only candidates are named
                specs = parse_specs(unit.models[t].inputs)
                s = specs[0] if len(specs) == 1 else None
                if s is not None and s.fn == "" and len(s.tags) == 1 and s.tags[0] in ranges:
                    x = plant.get(s.tags[0], s.tags[0])
                    g = float(spec.gains.get(t, {}).get(x, 0.0))
                    if g != 0.0:
                        broken.append((j, k, (s.tags[0], s.lag), col.get(x, -1), g))
            ups = up.setdefault(k, [])
            ups += [(key, kk) for key, kk, _ in row if (key, kk) not in ups]
            info = build.get(t) if isinstance(build.get(t), dict) else {}
            for other in info.get("same_as", []) or []:
                kk = col.get(other)
                if kk in keys and ((keys[kk], 0), kk) not in ups:
                    ups.append(((keys[kk], 0), kk))
        if not keys or not (any(reads) or (own >= 0).any()):
            return None
        # the tests through which a tag's own test reaches its readers: test j reads X,
        # X's own test j_X (not a spread or balance test) reads Z, a candidate with a range
        own_test = {}
        for j, t in enumerate(unit.tests):
            if not _spread_test(unit, t) and not getattr(unit.file.test(t), "balance", False):
                own_test.setdefault(outputs[t], j)
        via: list[list[tuple[tuple[str, int], int, int]]] = []
        for j, t in enumerate(unit.tests):
            row2: list[tuple[tuple[str, int], int, int]] = []
            via.append(row2)
            if _spread_test(unit, t):
                continue
            for s in parse_specs(unit.models[t].inputs):
                if s.fn != "" or len(s.tags) != 1:
                    continue
                jx = own_test.get(plant.get(s.tags[0], s.tags[0]))
                if jx is None or jx == j:
                    continue
                for z in parse_specs(unit.models[unit.tests[jx]].inputs):
                    if z.fn != "" or len(z.tags) != 1 or z.tags[0] not in ranges:
                        continue
                    kz = col.get(plant.get(z.tags[0], z.tags[0]))
                    if kz in keys and ((z.tags[0], 0), kz, jx) not in row2:
                        row2.append(((z.tags[0], 0), kz, jx))
        order = [spec.tests.index(t) for t in unit.tests]
        center = np.asarray(spec.center, float)[order]
        return cls(reads, own, ranges, keys, up, center, broken, via)

    def _beyond(self, values, key: tuple[str, int], at: np.ndarray, n: int, memo: dict):
        """The judged value's excess beyond its learned range at ``at`` (0 inside or unknown)
        and that excess as a share of the range."""
        if key not in memo:
            tag = key[0]  # its value now, whatever lag a model reads it at (as a live
            x = np.asarray(values(tag), float)[at]  # cycle has it: one row, no history)
            lo, hi = self.ranges[tag]
            with np.errstate(invalid="ignore"):
                e = np.where(x > hi, x - hi, np.where(x < lo, x - lo, 0.0))
            memo[key] = (e, np.abs(e) / (hi - lo))
        return memo[key]

    def name(
        self, share: np.ndarray, r: np.ndarray, s: np.ndarray, values, at: np.ndarray
    ) -> np.ndarray:
        """``share`` (the alarm samples ``at`` × tags) with the source an excursion explains
        named (see the class doc): ``r``, ``s`` the piece's filtered residuals and symptoms
        (n × tests), ``values(tag)`` a model tag's values over the piece's n samples."""
        at = np.flatnonzero(at)
        on = _on_any(np.asarray(s, float)[at]) if at.size else np.zeros((0, 0), bool)
        any_on = on.any(axis=1)
        n, m = len(r), share.shape[1]
        memo: dict = {}
        unknown = np.isnan(np.asarray(s, float)[at])
        share = self._name_broken(share, unknown, values, at, n, memo)
        if not any_on.any():
            return share
        # each candidate's source per sample (itself, or upstream) and the source's share
        src: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        for k, tag in self.keys.items():
            v = self._beyond(values, (tag, 0), at, n, memo)[1].copy()
            cur = np.full(at.size, k)
            for _ in range(len(self.up) + 1):  # a larger share each step: no cycle
                moved = False
                for kk in np.unique(cur):
                    sel = cur == kk
                    for key, k2 in self.up.get(int(kk), []):
                        if k2 not in self.keys:
                            continue
                        w = self._beyond(values, key, at, n, memo)[1]
                        go = sel & (w > v)
                        if go.any():
                            v[go], cur[go], moved = w[go], k2, True
                if not moved:
                    break
            src[k] = (cur, v)
        dev = np.abs(np.asarray(r, float)[at] - self.center)
        rows = np.arange(at.size)
        ok = np.zeros((at.size, m), bool)
        ok[any_on] = True
        for j in np.flatnonzero(on.any(axis=0)):
            hit = on[:, j] & ok.any(axis=1)
            if not hit.any():
                continue
            by = np.zeros((at.size, m), bool)  # the sources explaining test j
            k = int(self.own[j])
            if k >= 0:  # its own output beyond its range
                e, _ = self._beyond(values, (self.keys[k], 0), at, n, memo)
                x = hit & (e != 0)
                by[rows[x], src[k][0][x]] = True
            for key, k, f in self.reads[j]:
                if k not in src:
                    continue
                e, _ = self._beyond(values, key, at, n, memo)
                with np.errstate(invalid="ignore"):
                    x = hit & (e != 0) & (dev[:, j] <= EXCURSION_EXPLAINS * f * np.abs(e))
                by[rows[x], src[k][0][x]] = True
            for key, k, jx in self.via[j]:  # X's own test unknown: Z, beyond, moved X
                if k not in src:
                    continue
                e, _ = self._beyond(values, key, at, n, memo)
                x = hit & (e != 0) & unknown[:, jx]
                by[rows[x], src[k][0][x]] = True
            ok[on[:, j]] &= by[on[:, j]]
        named = ok.any(axis=1)
        if not named.any():
            return share
        val = np.zeros((at.size, m))
        for cur, v in src.values():
            val[rows, cur] = np.fmax(val[rows, cur], v)
        val = np.where(ok, val, -1.0)
        best = np.argmax(val, axis=1)
        out = share.copy()
        i = np.flatnonzero(named)
        out[i, best[i]] = np.fmax(np.nan_to_num(out[i, best[i]], nan=0.0), 1.0 + val[i, best[i]])
        return out

    def _name_broken(self, share: np.ndarray, unknown: np.ndarray, values, at, n, memo):
        """``share`` with the tags of each relation broken beyond the range named (class doc:
        a test unknown at an alarm sample ``at`` whose output left its range on the side
        opposite to ``g·e`` of its one input beyond its own); ``unknown`` the tests' unknown
        symptoms at ``at``."""
        if not self.broken or not at.size:
            return share
        out = None
        for j, k, key, kx, g in self.broken:
            if not unknown[:, j].any():
                continue
            e_y, w_y = self._beyond(values, (self.keys[k], 0), at, n, memo)
            e_x, w_x = self._beyond(values, key, at, n, memo)
            with np.errstate(invalid="ignore"):
                hit = unknown[:, j] & (e_y * g * np.nan_to_num(e_x) < 0)
            if not hit.any():
                continue
            if out is None:
                out = share.copy()
            i = np.flatnonzero(hit)
            for kk, w in [(k, w_y)] + ([(kx, w_x)] if kx in self.keys else []):
                x = i[np.nan_to_num(w[i]) > 0]
                out[x, kk] = np.fmax(np.nan_to_num(out[x, kk], nan=0.0), 1.0 + w[x])
        return share if out is None else out


def rank(s: np.ndarray) -> np.ndarray:
    """Per row of shares ``s`` (samples × tags; NaN as -1) the tags' positions, largest share
    first; shares equal to :data:`TIE` (relative) in the tags' order. Tags whose directions
    are parallel over the known tests (a loop's compensated sensor and a tag its valve's
    model reads; two linear tests reading each other) explain the same share, equal but for
    the last bit, which the path that computed them (one stacked inverse or each pattern's)
    decides: ranked by the last bit, which of them is named third — and which left out —
    would change with the piece a replay was cut into."""
    s = np.atleast_2d(s)
    order = np.argsort(-s, axis=1, kind="stable")
    v = np.take_along_axis(s, order, axis=1)
    tied = np.abs(np.diff(v, axis=1)) <= TIE * np.abs(v[:, :-1]) + NO_SHARE
    group = np.concatenate([np.zeros((len(v), 1), int), np.cumsum(~tied, axis=1)], axis=1)
    by = np.lexsort((order, group), axis=-1)
    return np.take_along_axis(order, by, axis=1)


def top_columns_at(
    share_at: np.ndarray,
    tags: list[str],
    rows: np.ndarray,
    top: int = TOP,
    untested: Untested | None = None,
) -> dict[str, np.ndarray]:
    """:func:`top_tags_at`'s columns as arrays (names as objects, shares as floats): what a
    replay edits (the unit's alarm hold) before it makes the one frame of them. ``untested``:
    the inputs ranked after a tested output (:class:`Untested`)."""
    n = len(rows)
    out: dict[str, np.ndarray] = {}
    at = np.flatnonzero(rows)  # ranked only where there is an alarm (the rest stay empty)
    s = np.nan_to_num(share_at, nan=-1.0)
    key = untested.key(s) if untested is not None else None
    order = rank(s if key is None else key)[:, :top] if len(tags) else np.zeros((0, 0), int)
    names = np.asarray(tags, dtype=object)
    for i in range(min(top, len(tags))):
        col = order[:, i]
        val = s[np.arange(at.size), col]
        ok = val > 0
        name = np.full(n, "", dtype=object)
        value = np.full(n, np.nan)
        name[at[ok]] = names[col[ok]]
        value[at[ok]] = val[ok]
        out[f"top{i + 1}"] = name
        out[f"share{i + 1}"] = value
    return out


def describe_top(row: pd.Series) -> str:
    """``tags: X 0.82, Y 0.40`` for a row of :func:`top_tags` (empty without a ranking)."""
    parts = []
    for i in range(1, TOP + 1):
        name = row.get(f"top{i}", "")
        if name:
            parts.append(f"{name} {row[f'share{i}']:.2f}")
    return "tags: " + ", ".join(parts) if parts else ""


def with_ranked(
    matrix: DiagnosticMatrix, faults: np.ndarray, first: np.ndarray, s: np.ndarray
) -> np.ndarray:
    """The isolated faults (``a|b``, per sample) with the ranking's first tag added where the
    derived matrix's exact column names other tags but the first tag's column holds every
    symptom that is on (``faults`` ``sumpLvl|DischFlow``): the two answers, never two
    different confident ones. ``first``: the ranking's first tag per sample ("" none);
    ``s``: the symptoms −1/0/+1/NaN (samples × the matrix's tests).

    Why: a column's ``1`` says the test reacts to the fault, not that a small fault crosses
    its threshold. A meter bias of 3 % of span moved the three tests of its column, but only
    the one it took nearest its threshold fired (a pumping station: ``sumpLvl = f(DischFlow[k-7])``
    fired, ``DischFlow``'s own test and ``InletFlow = f(DischFlow[k-7])`` stayed inside their
    bands); the exact match then named the tag whose column is that one test (``sumpLvl``),
    while the ranking, reading the residuals below their thresholds too, named the meter
    (``DischFlow``) on 97.7 % of the same samples (docs/explanation/acceptance-pumps.md). The
    pattern fits both: the first tag's fault with its other tests not (yet) over their
    thresholds. A first tag whose column does not allow a symptom that is on (a test it
    does not move fired, or with a sign it does not give) contradicts the matrix and is not
    added; nor on samples whose faults are the ranking's already or ``unit``."""
    out = np.asarray(faults, dtype=object).copy()
    col = {f: k for k, f in enumerate(matrix.faults)}
    pairs: dict[tuple[str, str], bool] = {}
    rows, ks = [], []
    for i, (f, x) in enumerate(zip(out, first, strict=True)):
        if not f or f == "unit" or not x or x not in col:
            continue
        new = pairs.get((f, x))
        if new is None:
            new = pairs[(f, x)] = x not in f.split("|")
        if new:
            rows.append(i)
            ks.append(col[x])
    if not rows:
        return out
    rows_a, k = np.array(rows), np.array(ks)
    sym = np.asarray(s, float)[rows_a]
    on = np.nan_to_num(sym) != 0
    idx = np.where(on, np.sign(np.nan_to_num(sym)), 0).astype(np.intp) + 1
    tests = np.arange(sym.shape[1])[None, :]
    allows = matrix.allowed[tests, k[:, None], idx]  # the column allows each test's symptom
    add = on.any(axis=1) & (allows | ~on).all(axis=1)
    for i in np.flatnonzero(add):
        out[rows_a[i]] = f"{out[rows_a[i]]}|{first[rows_a[i]]}"
    return out
