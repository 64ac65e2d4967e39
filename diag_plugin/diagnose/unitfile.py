"""The unit file: one plant unit's tests (models), residual evaluation, thresholds and matrix.

A *unit* (e.g. one positioner + servomotor + valve) is one TOML file beside the rule bases,
named ``NAME.unit.toml``, that an engineer can read and edit::

    # Servomotor–valve unit (Kościelny et al., Table 4)
    [unit]
    name = "valve_unit"
    description = "positioner + servomotor + valve, four models"
    matrix = "valve_unit.matrix.toml"   # optional: without a matrix the unit only detects
    outputs = "VALVE1"                  # prefix of the tags it publishes (VALVE1.status, …)

    [evaluation]
    lowpass = 0.01       # Butterworth cut-off / Nyquist (0.01 = π/100 rad/sample); 0 = off
    order = 4
    scale = "span"       # "span": % of the output's nominal span (eq. 6); "max": of its maximum
    latch = false        # keep a symptom once raised (seed 000)
    symptoms = "crisp"   # "crisp": thresholds and the nearest signature; "fuzzy": N/0/P
                         # memberships and rules (10)-(14) (seed 001)
    fuzzy_width = 0.5    # ramp width as a fraction of the threshold, for a test without
                         # its own learned `fuzzy` breakpoints (fuzzy only)
    on_delay = 30        # samples over the threshold before a symptom turns on
    off_delay = 30       # samples below it before it turns off
    certainty = 0.5      # a fault counts as isolated from this certainty on
    min_support = 0.9    # a residual counts only where trained rules carry this share of the
                         # firing weight; elsewhere (the edge of the trained region) unknown
    hold_isolation = true  # fading symptoms widen the isolation, never move it elsewhere
    combined = false     # a unit-level test: T² of the tests' scaled residuals (learned)
    isolation = "matrix" # "matrix": the matrix file (none: detect only); "tags": isolation
                         # to the tags, a matrix derived from the models' structure

    [thresholds]         # written by `diag unit learn`: the fault-free window they came from
    far = 0.001          # the false-alarm budget: alarms per hour of operation, all tests
    blocks = 5           # residuals cross-fitted over 5 time blocks (0: the models' own)
    from = "2026-01-01T00:00:00+00:00"
    to = "2026-01-08T00:00:00+00:00"

    [tests]              # one line per test: its model (rule-base file) and thresholds in %
    r1 = { model = "valve_r1.toml", high = 9.8, low = -9.6, spread = true, levels = [1.0, 1.7] }
    r2 = { model = "valve_r2.toml", high = 4.1 }    # low defaults to -high
    TI103 = { model = "u_TI103.toml", high = 0.6, actuator = "TIC103.OUT" }  # a loop's test
    A1_joint = { model = "u_A1_joint.toml", high = 3.2, combined = false }  # not in T²

    [learned]            # written by `diag unit learn`: what each test's thresholds rest on
    r1 = { far = 0.00012, method = "tail", supported = false, hours = 336.0, ...}

    [combined]           # written by `diag unit learn` with combined = true or isolation = "tags"
    high = 41.3          # threshold of the combined statistic (combined = true)
    far = 0.0005         # its share of the budget (COMBINED_SHARE of far)
    shrinkage = 0.2      # covariance shrunk this far toward its diagonal
    tests = ["r1", "r2"]
    center = [0.01, -0.02]   # per test: median of its filtered residual (fault-free)
    scale = [0.31, 0.2]      # per test: robust sd (1.4826 MAD) of it
    cov = [[1.1, 0.3], [0.3, 0.9]]  # covariance of the scaled residuals
    [combined.gains]     # per test: mean ∂ŷ/∂tag of its model over the window
    r1 = { U = 0.52 }
    [combined.responses] # per loop set-point: its move's effect on the tests' scaled residuals
    U_SP = { r2 = -0.8 }

    [faults]             # optional: NE 107 status a fault raises (default FAILURE)
    f_P0 = "MAINTENANCE_REQUIRED"

    [build]              # written by `diag unit build`: how each test's inputs were chosen
    from = "…"           # the window, and per test in [build.tests] the inputs and the
                         # held-out error before any input and after each
    set_points = ["FLOW_TARGET"]  # the window's set-points (by name or by the description
                         # the historian gives them): never a tag the unit blames

    [tags]               # optional: the plant tags this unit reads for the models' tags
    F = "V17.F"          # (one set of models serves a fleet of identical valves)

    [manual]             # written by `diag unit build --manual`: hand valves, never tested;
    HAND_VALVE = { min = 40.0, max = 47.0, margin = 0.0 }  # the span the unit learned

    [fixed]              # written by `diag unit build`: tags constant over its window
    PMP3_ON = { min = 0.0, max = 0.0, margin = 1e-09 }  # where it moves: CHECK_FUNCTION

    [narrow]             # written by `diag unit build`: tested tags of few independent values
    HAND_VALVE = { min = 40.0, max = 47.0, margin = 0.1 }  # outside: its own test unknown

    [chosen]             # written by `diag unit build`: loops' set-points of few values
    "LIC101.SP" = { min = 55.0, max = 60.0, margin = 0.0 }  # outside: tests reading it unknown

    [states]             # written by `diag unit build`: the combinations of states learned
    tags = ["PMP1_ON", "PMP2_ON"]
    seen = ["1,0", "1,1"]  # another one held for the on-delay: CHECK_FUNCTION
    held_s = 163.0

    [running]            # written by `diag unit build --running`: judged only while it runs
    tag = "AHU_ON"
    run = 1.0            # the value it runs at (stop: its other value); elsewhere nothing
    stop = 0.0           # is judged, CHECK_FUNCTION `not running …` (diagnose/running.py)

``[manual]`` (written by ``diag unit build`` for a declared hand valve, widened by ``diag unit
accept``): per hand valve (the models' tag name) the span the unit learned it in, ``min`` and
``max`` of the window and a ``margin`` from the data (3 × its noise); where it is outside
``[min − margin, max + margin]`` every test reading it is unknown and the unit
CHECK_FUNCTION, naming the valve (:mod:`diag_plugin.diagnose.manual`). A file without the
table: no test is made unknown by it.

``[fixed]`` (written by ``diag unit build`` for a tag constant over its window that is not a
set-point nor a hand valve, widened by ``diag unit accept``): the same rows, ``min = max`` the
value the window held it at and ``margin`` the build's own test of a constant (``1e-9 ·
max(1, |value|)``); no test reads the tag, but the unit does: where it is outside for the
on-delay, the unit is CHECK_FUNCTION naming it, the value and since when, until it is back
for the off-delay (:mod:`diag_plugin.diagnose.fixed`). A file without the table: as before.

``[narrow]`` (written by ``diag unit build``, widened by ``diag unit accept``): the same rows,
for each tag a rule grid tests that the window saw at most ``NARROW_INDEPENDENT`` independent
values of (:func:`~diag_plugin.unitbuild.build.narrow_outputs`): where it is outside ``[min −
margin, max + margin]`` its own test is unknown and the unit names it as an input outside what
it learned (a grid's answer never leaves what its window showed: its residual there measures
the excursion). A file without the table: as before.

``[chosen]`` (written by ``diag unit build``, widened by ``diag unit accept``): the same rows,
for each loop's set-point the window saw at most ``NARROW_INDEPENDENT`` independent values of
(:func:`~diag_plugin.unitbuild.build.chosen_set_points`): where one is outside ``[min −
margin, max + margin]`` every line reading any of them, or a measurement a loop holds at one,
is unknown — not a loop's own test (one with a ``set_point``), nor a rule grid — and the unit
names it as an input outside what it learned (:mod:`diag_plugin.diagnose.manual`). A file without
the table: as before.

``[states]`` (written by ``diag unit build`` for a unit with discrete states, extended by
``diag unit accept``): ``tags`` the states in order, ``seen`` the combinations of their values
the window held for ``held_s`` or longer (``"1,0"``: the first at 1, the second at 0); where
the states are in another combination for the on-delay, the unit is CHECK_FUNCTION naming the
states and their values, until a learned one has held for the off-delay
(:mod:`diag_plugin.diagnose.combos`). A file without the table: as before.

``spread = true`` (learned per test): the test's Wang–Mendel residual is divided by the spread of
the training outputs of the rules that answered, relative to the model's typical spread
(``Prediction.spread``, never below :data:`SPREAD_FLOOR`): where the plant varies more for the
same inputs (a steep or unmodelled region) a deviation must be larger to count, where it is
steady smaller. ``diag unit learn`` sets it for every test whose model keeps a spread
(Wang–Mendel); without the key the plain residual counts.

``actuator = "TAG"`` (written by ``diag unit build`` for a tag a controller holds, editable):
the controller output of the loop whose control error the test's residual is; with
``isolation = "tags"`` a fault of that actuator is a candidate when the test fires (a valve
its loop compensates leaves the error at zero, a stuck or saturated one moves it either way,
:func:`~diag_plugin.diagnose.unittags.directions`).

``statistic = "spread"`` and ``set_point = "TAG"`` (written by ``diag unit build`` for a
loop, editable): the test judges the running standard deviation of its residual (valve
stiction, a loop oscillating) instead of its level; the loop's set-point is never a tag at
fault. The alarm settings in time, ``on_delay_s``, ``off_delay_s`` (seconds, converted at the
models' period; 0: the sample counts ``on_delay``/``off_delay``), ``deadband`` (a symptom,
once on, clears only below ``(1 − deadband)`` × its threshold), ``spread_window_s`` (the
spread tests' window) and ``oscillation_window_s`` (a symptom that swung there and back
within two of it is held on until a side is quiet for one: an oscillation is one alarm; 0
or absent: no hold) and ``release_window_s`` with a spread test's ``release`` (a spread
test on stays on while its residual's spread over that window is above ``release``; 0 or
absent: released as it falls back, as before) are described in
:mod:`diag_plugin.diagnose.unitloops`;
``settle_max_s`` (written by ``diag unit build``; 0 or absent: no guard) bounds the settle
after an operator's set-point step, during which the unit's alarms are CHECK_FUNCTION
(:mod:`diag_plugin.diagnose.settle`); ``manual_settle_max_s`` (written by ``diag unit
build`` for a unit with a hand valve) the settle after a hand valve's move within its
learned span; ``state_settle_max_s`` (for a unit whose models read a discrete state, ``[build]
states``) the settle after a state's change (a pump started or stopped). ``[envelope.state]``
and ``[envelope.NAME]`` (written by ``diag unit build``): what the window's fault-free state
changes (a piece NAME's starts) showed per test and age; beyond it, a settle ends
(:mod:`diag_plugin.diagnose.envelope`).

``balance = true`` (written by ``diag unit build`` for a manipulated flow's second test,
``<tag>_balance``, :mod:`~diag_plugin.unitbuild.balance`): the test is the flow's balance
(the vessel's other flows and its level's rate); with ``isolation = "tags"`` its residual
alone is the flow's process direction — a loss or gain no meter sees names the flow
(:func:`~diag_plugin.diagnose.unittags.process_directions`).

``fuzzy = [n1, n0, p0, p1]`` (learned, editable; fuzzy symptoms only): the breakpoints of the
test's three sets, in the thresholds' units: μN is 1 below ``n1`` and 0 above ``n0``, μP is 0
below ``p0`` and 1 above ``p1``, μ0 = 1 − μN − μP. ``diag unit learn`` centres each ramp on its
threshold and makes it two fault-free standard deviations of the test's (cross-fitted, filtered)
residual wide, so a residual one standard deviation past the threshold is wholly N or P and one
short of it wholly 0 (:func:`diag_plugin.learn.thresholds.fuzzy_sets`).

``levels`` (learned) are the residual scales of the coarser rule levels behind a Wang–Mendel
model's fine grid: a residual answered at level ``l`` is divided by ``levels[l]`` (level 0: 1),
so a coarser, less exact answer needs a proportionally larger deviation to raise a symptom. A
test without ``levels`` counts only answers of the fine grid; answers at levels beyond the list
are unknown (never calibrated).

``combined = false`` (written by ``diag unit build`` for a test added only to cover a tag
the window leaves blind, :func:`~diag_plugin.unitbuild.build.blind_pair_tests`; editable): the
test stays out of the unit's combined ``T²`` (not one of its dimensions; its residual is
neither centred, scaled nor ranked there) and keeps its own thresholds, alarm and share of the
budget. A test that sees nothing of a fault the others see would otherwise add a dimension to
``T²`` and lower it under its limit (SKAB, docs/how-to/unit-short-windows.md, round 14).

``point_center = [...]``, ``point_scale = [...]`` (written by ``diag unit accept`` for a level
test, a tag against its mean: one number per ``[combined]`` operating point): the test's raw
residual is ``(r − point_center[k]) / point_scale[k]`` at the sample's nearest point ``k``
(:func:`~diag_plugin.learn.thresholds.level_points`).

``combined = true`` and ``isolation = "tags"`` (both off by default, so a unit without them
behaves as before) and the ``[combined]`` table are described in
:mod:`diag_plugin.diagnose.unittags`.

Paths are relative to the unit file. Problems are reported all at once as ``file:line: what``,
like ``diag rules check``. Saving after :meth:`UnitFile.set_thresholds` keeps comments and
layout (tomlkit round trip).
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from diag_plugin.diagnose.combos import read_states
from diag_plugin.diagnose.envelope import read_envelopes
from diag_plugin.diagnose.equipment import read_equipment
from diag_plugin.diagnose.fixed import read_fixed
from diag_plugin.diagnose.manual import read_manual
from diag_plugin.diagnose.running import read_running
from diag_plugin.rulebase.folder import UNIT_SUFFIX
from diag_plugin.rulebase.folder import unit_path as unit_path  # where it was
from diag_plugin.status import NE107
from diag_plugin.tomllines import LinedFile, syntax_error
from historian.errors import ProblemsError

if TYPE_CHECKING:
    import tomlkit

TABLES = (
    "unit",
    "evaluation",
    "thresholds",
    "tests",
    "faults",
    "tags",
    "learned",
    "combined",
    "build",
    "manual",
    "fixed",
    "narrow",
    "chosen",
    "states",
    "running",
    "equipment",
    "envelope",
)

#: why a residual is unknown: the reasons ``diag unit learn`` counts (``unknown_<reason>``
#: in ``[learned]``) and ``diag unit show`` words
WHY = {
    "missing": "an input or the output missing (NaN, bad quality, lags not yet filled)",
    "no_rule": "no trained rule at any level (outside the trained region)",
    "low_support": "the edge of the trained region (support below min_support)",
    "level": "answered at a coarser level the window could not calibrate",
}


def hours(h: float) -> str:
    """Hours as a person reads them: ``40,000 h``, ``336 h``, ``0.11 h``."""
    return f"{h:,.0f} h" if h >= 10 else f"{h:.2g} h"


EVALUATION_DEFAULTS: dict[str, Any] = {
    "lowpass": 0.01,
    "order": 4,
    "scale": "span",
    "latch": False,
    "symptoms": "crisp",
    "fuzzy_width": 0.5,
    "on_delay": 30,
    "off_delay": 30,
    "certainty": 0.5,
    "min_support": 0.9,
    "hold_isolation": True,
    "combined": False,
    "isolation": "matrix",
    "on_delay_s": 0.0,
    "off_delay_s": 0.0,
    "deadband": 0.0,
    "spread_window_s": 0.0,
    "oscillation_window_s": 0.0,
    "release_window_s": 0.0,
    "settle_max_s": 0.0,
    "manual_settle_max_s": 0.0,
    "state_settle_max_s": 0.0,
}
#: keys new_unit_text writes only when they differ from the default (files written before
#: them regenerate byte for byte)
NEW_KEYS = (
    "combined",
    "isolation",
    "on_delay_s",
    "off_delay_s",
    "deadband",
    "spread_window_s",
    "oscillation_window_s",
    "release_window_s",
    "settle_max_s",
    "manual_settle_max_s",
    "state_settle_max_s",
)
#: a residual is never amplified more than 1 / SPREAD_FLOOR by a small local spread. Of 0.5,
#: 0.75 and 1 (attenuate only), 0.5 widened r3's thresholds (its cells at the travel limits
#: have almost no spread, and their transients were doubled) and 1 left one marginal crossing
#: on the tour's 30 days; chosen on those and seeds 41, 59, checked on seeds never used
SPREAD_FLOOR = 0.75
_KINDS = {
    "lowpass": float,
    "order": int,
    "scale": str,
    "latch": bool,
    "symptoms": str,
    "fuzzy_width": float,
    "on_delay": int,
    "off_delay": int,
    "certainty": float,
    "min_support": float,
    "hold_isolation": bool,
    "combined": bool,
    "isolation": str,
    "on_delay_s": float,
    "off_delay_s": float,
    "deadband": float,
    "spread_window_s": float,
    "oscillation_window_s": float,
    "release_window_s": float,
    "settle_max_s": float,
    "manual_settle_max_s": float,
    "state_settle_max_s": float,
}
_CHOICES = {
    "scale": ("span", "max"),
    "symptoms": ("crisp", "fuzzy"),
    "isolation": ("matrix", "tags"),
}


#: what a test's residual is judged as: the residual, or its running spread
STATISTICS = ("level", "spread")


class UnitError(ProblemsError):
    """Problems of a unit file, each ``file:line: what``."""


@dataclass
class TestSpec:
    """One test of a unit: its residual comes from ``model`` (a rule-base file)."""

    name: str
    model: str
    high: float | None = None
    low: float | None = None
    ymax: float | None = None  # signal maximum for scale = "max" (learned)
    line: int = 0
    #: residual scale per rule level (learned; level 0 = 1); None: the fine grid only
    levels: tuple[float, ...] | None = None
    #: residuals in units of the model's local spread (learned)
    spread: bool = False
    #: breakpoints n1 ≤ n0 ≤ p0 ≤ p1 of the N, 0, P sets (fuzzy symptoms; learned or edited)
    fuzzy: tuple[float, float, float, float] | None = None
    #: the actuator (a controller output tag) of the control loop whose error this test's
    #: residual is: a fault of it is a candidate when the test fires (isolation to tags)
    actuator: str | None = None
    #: "level" (the residual itself) or "spread" (its running standard deviation over
    #: ``spread_window_s``: a loop's oscillation, valve stiction; :mod:`~diag_plugin.diagnose.
    #: unitloops`)
    statistic: str = "level"
    #: the set-point of the loop (declared or found by ``diag unit build``): never a tag at fault
    set_point: str | None = None
    #: a level test's operating points (``diag unit accept``; None: one, the model's mean):
    #: per point of ``[combined]`` the centre of its raw residual (% of span: the point's mean
    #: of the tag less the model's) and its spread relative to the quietest point's; a
    #: sample's residual is ``(r − point_center[k]) / point_scale[k]`` at its nearest point k
    point_center: tuple[float, ...] | None = None
    point_scale: tuple[float, ...] | None = None
    #: False (``combined = false``, written by ``diag unit build``): the test stays out of
    #: the combined ``T²`` — its own thresholds and budget share as any test's
    combined: bool = True
    #: a manipulated flow's balance test (``diag unit build``, :mod:`~diag_plugin.unitbuild.
    #: balance`): its residual alone names the flow it models (a loss or gain no meter sees)
    balance: bool = False
    #: a spread test's release threshold (``diag unit build``; None: none): once on, its
    #: symptom is held while the running spread of its residual over ``release_window_s``
    #: stays above it (:class:`~diag_plugin.diagnose.unitloops.ReleaseHold`)
    release: float | None = None

    @property
    def limits(self) -> tuple[float, float] | None:
        if self.high is None:
            return None
        return (-self.high if self.low is None else self.low), self.high


@dataclass
class CombinedSpec:
    """The unit-level test and the tag directions as learned (the unit file's ``[combined]``,
    see :mod:`diag_plugin.diagnose.unittags`): per test (in ``tests`` order) the centre and
    robust scale of its filtered residual, the covariance of the scaled residuals and how far
    it was shrunk, the threshold ``high`` of the combined statistic (None: not a test, only the
    ranking's scales), and per test its model's mean gain ``∂ŷ/∂tag`` for each input tag."""

    tests: list[str]
    center: list[float]
    scale: list[float]
    cov: list[list[float]]
    shrinkage: float = 0.0
    high: float | None = None
    gains: dict[str, dict[str, float]] = field(default_factory=dict)
    #: per loop set-point tag, the response of each test's scaled residual to a unit move of
    #: it over the window, where the window shows one (:func:`~diag_plugin.learn.thresholds.
    #: setpoint_responses`): what a bias of the loop's sensor does once the loop compensates
    responses: dict[str, dict[str, float]] = field(default_factory=dict)
    #: what the threshold rests on (far, method, supported, hours, …), written as is
    notes: dict[str, Any] = field(default_factory=dict)
    #: operating points (``diag unit accept``; empty: one, ``center`` alone): the plant tags
    #: that place a sample, per point their mean (``point_at``, points × tags), the tags'
    #: spans the distance is measured in, and per point each test's centre and scale
    #: (``point_center``, ``point_scale``, points × tests; ``center`` and ``scale`` are the
    #: first point's); a sample's residuals are centred and scaled at its nearest point, and
    #: ``cov`` is the pooled within-point one
    point_tags: list[str] = field(default_factory=list)
    point_at: list[list[float]] = field(default_factory=list)
    point_span: list[float] = field(default_factory=list)
    point_center: list[list[float]] = field(default_factory=list)
    point_scale: list[list[float]] = field(default_factory=list)


#: keys of [combined] for its operating points (:class:`CombinedSpec`)
POINT_KEYS = ("point_tags", "point_at", "point_span", "point_center", "point_scale")
#: keys of [combined] besides the arrays, what they hold
COMBINED_NOTES = ("far", "method", "supported", "hours", "hours_needed", "independent", "share")


def _plain(v: Any) -> Any:
    return v.unwrap() if hasattr(v, "unwrap") else v


def kept_digits(x: float, places: int = 4) -> float:
    """``x`` as the unit file keeps a learned number: ``places`` decimals, except a non-zero
    value those decimals would write as 0 keeps 4 significant digits (issue 34, H8). Rounding
    is monotone, so ``n1 ≤ n0 < 0 < p0 ≤ p1`` and ``low < 0 < high`` hold as written: a test
    whose fault-free residual never crosses 0 has its threshold on that side at the 1e-4
    floor and its fuzzy ramp within 0.1 % of it (``p0 ≈ 1e-7``), which 4 decimals wrote as
    0.0 and the file then refused to read."""
    r = round(float(x), places)
    return r if r != 0.0 or x == 0.0 else float(f"{float(x):.4g}")


def _tomlkit_parse(text: str, path: Path) -> tomlkit.TOMLDocument:
    """tomlkit's document of a unit file's text; a syntax error as ``file:line``."""
    import tomlkit
    from tomlkit.exceptions import ParseError

    try:
        return tomlkit.parse(text)
    except ParseError as exc:
        raise UnitError([syntax_error(path, exc)]) from None


def _same_values(values: dict, doc: tomlkit.TOMLDocument) -> bool:
    """``doc`` holds ``values`` (tomllib's parse of a text): it then stands for tomlkit's parse
    of that text (which dumps it back to the text, its source)."""
    try:
        return doc.unwrap() == values
    except (ValueError, TypeError):
        return False


def _number_array(values: list[float]) -> tomlkit.items.Array:
    """``tomlkit.item(values)`` of plain numbers (``[1.0, 2.0, …]`` on one line), built in one
    pass: tomlkit appends an item at a time and re-indexes the array at each (a 200-test
    unit's covariance, 40,000 numbers: ~1 s)."""
    import tomlkit
    from tomlkit.items import Array, Float, Trivia, Whitespace

    parts: list[Any] = []
    for i, x in enumerate(values):
        if i:
            parts += [Whitespace(","), Whitespace(" ")]
        # a float as tomlkit.item makes it (its text str(x)), without its type dispatch
        parts.append(Float(x, Trivia(), str(x)) if type(x) is float else tomlkit.item(x))
    return Array(parts, Trivia())


class UnitFile(LinedFile):
    """A unit file in memory (see module doc); :meth:`load` reports ``file:line`` problems."""

    Error = UnitError

    def __init__(
        self, text: str, path: str | Path = "<unit>", doc: tomlkit.TOMLDocument | None = None
    ) -> None:
        """The file is read with the stdlib's ``tomllib`` (the 45-test unit of
        ``bench_diagnose_cli.py``: 0.076 → 0.010 CPU s, tomlkit's parse alone 0.064 s);
        tomlkit's document, which keeps comments and layout for the ``set_*`` edits, is parsed
        only when :attr:`doc` is first asked for. A text ``tomllib`` rejects is parsed by
        tomlkit at once, as before: its error (``file:line``) or its document's values.
        ``doc``: the document ``text`` was written from (:meth:`_reread`), kept as :attr:`doc`
        where it holds the values read."""
        self.path = Path(path)
        self.text = text
        self.lines = text.splitlines()
        self.problems: list[str] = []
        try:
            values = tomllib.loads(text)
        except tomllib.TOMLDecodeError:
            doc = _tomlkit_parse(text, self.path)
            values = doc.unwrap()
        else:
            if doc is not None and not _same_values(values, doc):
                doc = None
        self._doc = doc
        self._values = values
        self._read()
        if self.problems:
            raise UnitError(self.problems)

    @property
    def doc(self) -> tomlkit.TOMLDocument:
        """The file as tomlkit's document (comments and layout kept), parsed at first use:
        what the ``set_*`` methods edit and :meth:`dumps` writes."""
        if self._doc is None:
            self._doc = _tomlkit_parse(self.text, self.path)
        return self._doc

    # ------------------------------------------------------------ reading
    def line_of(self, section: str, key: str | None = None) -> int:
        """1-based line of ``[section]`` or of ``key =`` inside it (the header if absent)."""
        from diag_plugin.tomllines import line_of

        return line_of(self.lines, section, key)

    def _table(self, name: str, required: bool = False) -> dict:
        t = self._values.get(name)
        if t is None:
            if required:
                self.error(1, f"missing [{name}] table")
            return {}
        if not isinstance(t, dict):
            self.error(self.line_of(name), f"[{name}] must be a table")
            return {}
        return t

    def _read(self) -> None:
        for key in self._values:
            if key not in TABLES:
                self.error(self.line_of(key), f"unknown table [{key}]")
        unit = self._table("unit", required=True)
        for key in unit:
            if key not in ("name", "description", "matrix", "outputs"):
                self.error(self.line_of("unit", key), f"unknown key {key!r} in [unit]")
        self.name = str(_plain(unit.get("name", self.path.name.removesuffix(UNIT_SUFFIX))))
        self.description = str(_plain(unit.get("description", "")))
        m = _plain(unit.get("matrix"))
        if m is not None and not isinstance(m, str):
            self.error(self.line_of("unit", "matrix"), "matrix must be a file name")
            m = None
        self.matrix = m
        self.outputs = str(_plain(unit.get("outputs", self.name)))
        self.evaluation = self._evaluation(self._table("evaluation"))
        self.thresholds = {k: _plain(v) for k, v in self._table("thresholds").items()}
        self.learned = {
            str(k): dict(_plain(v)) if isinstance(_plain(v), dict) else {}
            for k, v in self._table("learned").items()
        }
        # written by `diag unit build` (how each test's inputs were chosen); read, not checked
        self.build = _plain(self._table("build")) if "build" in self._values else {}
        for key in ("set_points", "states"):
            sps = self.build.get(key, [])
            if not isinstance(sps, list) or not all(isinstance(x, str) and x for x in sps):
                self.error(self.line_of("build", key), f"{key} must be a list of tags")
                self.build.pop(key)
        self.tests = self._tests(self._table("tests", required=True))
        self.fault_status = self._faults(self._table("faults"))
        self.combined = self._combined(self._table("combined"))
        self.manual = read_manual(
            self._table("manual"), self.error, lambda k: self.line_of("manual", k)
        )
        self.fixed = read_fixed(
            self._table("fixed"), self.error, lambda k: self.line_of("fixed", k)
        )
        self.narrow = read_manual(
            self._table("narrow"), self.error, lambda k: self.line_of("narrow", k), "narrow"
        )
        self.chosen = read_manual(
            self._table("chosen"), self.error, lambda k: self.line_of("chosen", k), "chosen"
        )
        self.states = read_states(
            self._table("states"), self.error, lambda k: self.line_of("states", k)
        )
        self.running = read_running(
            self._table("running"), self.error, lambda k: self.line_of("running", k)
        )
        self.equipment = read_equipment(
            self._table("equipment"), self.error, lambda k: self.line_of("equipment", k)
        )
        self.envelope = read_envelopes(
            _plain(self._table("envelope")), self.error, lambda k: self.line_of("envelope", k)
        )
        self.tags: dict[str, str] = {}
        for k, v in self._table("tags").items():
            v = _plain(v)
            if not isinstance(v, str) or not v:
                self.error(self.line_of("tags", k), f"tag {k!r} must map to a tag name")
            else:
                self.tags[str(k)] = v

    def _evaluation(self, table: dict) -> dict[str, Any]:
        ev = dict(EVALUATION_DEFAULTS)
        for key, raw in table.items():
            v = _plain(raw)
            line = self.line_of("evaluation", key)
            kind = _KINDS.get(key)
            if kind is None:
                self.error(
                    line, f"unknown key {key!r} in [evaluation] (known: {', '.join(_KINDS)})"
                )
                continue
            if kind is float and isinstance(v, int) and not isinstance(v, bool):
                v = float(v)
            if not isinstance(v, kind) or (kind is not bool and isinstance(v, bool)):
                self.error(line, f"{key} must be {kind.__name__}, got {v!r}")
                continue
            if key in _CHOICES and v not in _CHOICES[key]:
                self.error(line, f"{key} must be one of {', '.join(_CHOICES[key])}, got {v!r}")
                continue
            ev[key] = v
        checks = (
            ("lowpass", 0.0 <= ev["lowpass"] < 1.0, "lowpass must be in [0, 1) (0 = off)"),
            ("order", 1 <= ev["order"] <= 10, "order must be 1..10"),
            ("on_delay", ev["on_delay"] >= 1, "on_delay counts samples, ≥ 1"),
            ("off_delay", ev["off_delay"] >= 1, "off_delay counts samples, ≥ 1"),
            ("certainty", 0.0 < ev["certainty"] <= 1.0, "certainty must be in (0, 1]"),
            ("min_support", 0.0 <= ev["min_support"] <= 1.0, "min_support must be in [0, 1]"),
            ("fuzzy_width", 0.0 <= ev["fuzzy_width"] <= 2.0, "fuzzy_width must be in [0, 2]"),
            ("on_delay_s", ev["on_delay_s"] >= 0, "on_delay_s is seconds, ≥ 0 (0: on_delay)"),
            ("off_delay_s", ev["off_delay_s"] >= 0, "off_delay_s is seconds, ≥ 0 (0: off_delay)"),
            ("deadband", 0.0 <= ev["deadband"] < 1.0, "deadband: share of the threshold, [0, 1)"),
            ("spread_window_s", ev["spread_window_s"] >= 0, "spread_window_s is seconds, ≥ 0"),
            ("oscillation_window_s", ev["oscillation_window_s"] >= 0, "seconds, ≥ 0 (0: off)"),
            ("release_window_s", ev["release_window_s"] >= 0, "seconds, ≥ 0 (0: off)"),
            ("settle_max_s", ev["settle_max_s"] >= 0, "settle_max_s is seconds, ≥ 0"),
            ("manual_settle_max_s", ev["manual_settle_max_s"] >= 0, "seconds, ≥ 0"),
            ("state_settle_max_s", ev["state_settle_max_s"] >= 0, "seconds, ≥ 0"),
        )
        for key, ok, msg in checks:
            if not ok:
                self.error(self.line_of("evaluation", key), msg)
        return ev

    def _tests(self, table: dict) -> list[TestSpec]:
        tests = []
        for name, raw in table.items():
            line = self.line_of("tests", name)
            if not isinstance(raw, dict):
                self.error(line, f'test {name!r}: needs {{ model = "file.toml", high = … }}')
                continue
            v = {k: _plain(x) for k, x in raw.items()}
            known = {"model", "high", "low", "ymax", "levels", "spread", "fuzzy", "actuator",
                     "statistic", "set_point", "point_center", "point_scale",
                     "combined", "balance", "release"}  # fmt: skip
            for key in sorted(set(v) - known):
                self.error(line, f"test {name!r}: unknown key {key!r}")
            model = v.get("model")
            if not isinstance(model, str) or not model:
                self.error(line, f"test {name!r}: model must name a rule-base file")
                continue
            nums = {}
            for key in ("high", "low", "ymax", "release"):
                x = v.get(key)
                if x is None:
                    nums[key] = None
                elif isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
                    self.error(line, f"test {name!r}: {key} must be a finite number, got {x!r}")
                    nums[key] = None
                else:
                    nums[key] = float(x)
            if nums["high"] is not None and nums["high"] <= 0:
                self.error(line, f"test {name!r}: high must be > 0 (in the residual's unit)")
            if nums["low"] is not None and "high" not in v:
                self.error(line, f"test {name!r}: low given without high")
            elif None not in (nums["low"], nums["high"]) and nums["low"] >= nums["high"]:
                self.error(line, f"test {name!r}: low must be below high")
            if nums["ymax"] is not None and nums["ymax"] <= 0:
                self.error(line, f"test {name!r}: ymax must be > 0")
            levels = v.get("levels")
            if levels is not None:
                ok = (
                    isinstance(levels, list)
                    and levels
                    and all(
                        isinstance(x, int | float) and not isinstance(x, bool) and x >= 1
                        for x in levels
                    )
                    and levels[0] == 1
                )
                if not ok:
                    self.error(
                        line,
                        f"test {name!r}: levels must list the residual scale of each rule "
                        f"level, 1 for level 0 and ≥ 1 after it, got {levels!r}",
                    )
                    levels = None
            spread = v.get("spread", False)
            if not isinstance(spread, bool):
                self.error(line, f"test {name!r}: spread must be true or false, got {spread!r}")
                spread = False
            balance = v.get("balance", False)
            if not isinstance(balance, bool):
                self.error(line, f"test {name!r}: balance must be true or false, got {balance!r}")
                balance = False
            fuzzy = v.get("fuzzy")
            if fuzzy is not None:
                ok = (
                    isinstance(fuzzy, list)
                    and len(fuzzy) == 4
                    and all(
                        isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)
                        for x in fuzzy
                    )
                    and fuzzy[0] <= fuzzy[1] < 0 < fuzzy[2] <= fuzzy[3]
                )
                if not ok:
                    self.error(
                        line,
                        f"test {name!r}: fuzzy must list the N, 0, P breakpoints "
                        f"[n1, n0, p0, p1] with n1 ≤ n0 < 0 < p0 ≤ p1, got {fuzzy!r}",
                    )
                    fuzzy = None
            actuator = v.get("actuator")
            if actuator is not None and (not isinstance(actuator, str) or not actuator.strip()):
                self.error(
                    line,
                    f"test {name!r}: actuator must name the tag of the loop's controller "
                    f"output, got {actuator!r}",
                )
                actuator = None
            statistic = v.get("statistic", "level")
            if statistic not in STATISTICS:
                self.error(
                    line,
                    f"test {name!r}: statistic must be one of {', '.join(STATISTICS)}, "
                    f"got {statistic!r}",
                )
                statistic = "level"
            set_point = v.get("set_point")
            if set_point is not None and (not isinstance(set_point, str) or not set_point):
                self.error(line, f"test {name!r}: set_point must name a tag, got {set_point!r}")
                set_point = None
            center, scale = self._test_points(name, v, line)
            combined = v.get("combined", True)
            if not isinstance(combined, bool):
                self.error(line, f"test {name!r}: combined must be true or false, got {combined!r}")
                combined = True
            tests.append(
                TestSpec(
                    name,
                    model,
                    nums["high"],
                    nums["low"],
                    nums["ymax"],
                    line,
                    None if levels is None else tuple(float(x) for x in levels),
                    spread,
                    None if fuzzy is None else tuple(float(x) for x in fuzzy),  # type: ignore[arg-type]
                    actuator,
                    statistic,
                    set_point,
                    center,
                    scale,
                    combined,
                    balance,
                    nums["release"],
                )
            )
        if table and not tests and not self.problems:
            self.error(self.line_of("tests"), "no valid test")
        elif not table:
            self.error(self.line_of("tests"), "[tests] lists no test (one line per model)")
        return tests

    def _test_points(
        self, name: str, v: dict, line: int
    ) -> tuple[tuple[float, ...] | None, tuple[float, ...] | None]:
        """A test's ``point_center`` and ``point_scale`` (both or neither): one finite number
        per operating point, the scales > 0; their count is checked against ``[combined]``'s
        points by :class:`~diag_plugin.diagnose.unit.Unit`."""
        c, s = v.get("point_center"), v.get("point_scale")
        if c is None and s is None:
            return None, None

        def numbers(x: Any) -> bool:
            return (
                isinstance(x, list)
                and len(x) >= 2
                and all(
                    isinstance(e, int | float) and not isinstance(e, bool) and math.isfinite(e)
                    for e in x
                )
            )

        if not (numbers(c) and numbers(s) and len(c) == len(s) and min(s) > 0):
            self.error(
                line,
                f"test {name!r}: point_center and point_scale must list one finite number per "
                f"operating point (two or more, the scales > 0), got {c!r}, {s!r}",
            )
            return None, None
        return tuple(float(x) for x in c), tuple(float(x) for x in s)

    def _faults(self, table: dict) -> dict[str, NE107]:
        out = {}
        for fault, raw in table.items():
            v = _plain(raw)
            try:
                out[fault] = NE107[str(v).upper()] if isinstance(v, str) else NE107(v)
            except (KeyError, ValueError):
                names = ", ".join(s.name for s in NE107 if s != NE107.NORMAL)
                self.error(
                    self.line_of("faults", fault), f"fault {fault!r}: status {v!r} ({names})"
                )
                continue
            if out[fault] == NE107.NORMAL:
                self.error(self.line_of("faults", fault), f"fault {fault!r}: NORMAL is no fault")
        return out

    def _combined(self, table: dict) -> CombinedSpec | None:
        """The ``[combined]`` table (written by ``diag unit learn``), checked against the
        tests: one centre, scale and covariance row per test, finite, scales > 0."""
        if not table:
            return None
        v = {k: _plain(x) for k, x in table.items()}
        line = lambda k: self.line_of("combined", k)  # noqa: E731
        known = {
            "tests", "center", "scale", "cov", "shrinkage", "high", "gains", "responses",
            *POINT_KEYS, *COMBINED_NOTES,
        }  # fmt: skip
        for key in sorted(set(v) - known):
            self.error(line(key), f"unknown key {key!r} in [combined]")
        n0 = len(self.problems)
        tests = v.get("tests")
        if not isinstance(tests, list) or not all(isinstance(t, str) for t in tests):
            self.error(line("tests"), "[combined] tests must list the unit's test names")
            return None

        def numbers(key: str, row: Any, k: int) -> list[float]:
            ok = (
                isinstance(row, list)
                and len(row) == k
                and all(
                    isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)
                    for x in row
                )
            )
            if not ok:
                self.error(line(key), f"[combined] {key} must be {k} finite numbers, one per test")
                return [math.nan] * k
            return [float(x) for x in row]

        k = len(tests)
        center = numbers("center", v.get("center"), k)
        scale = numbers("scale", v.get("scale"), k)
        if not all(x > 0 for x in scale if math.isfinite(x)):
            self.error(line("scale"), "[combined] scale must be > 0 for every test")
        cov_raw = v.get("cov")
        if not isinstance(cov_raw, list) or len(cov_raw) != k:
            self.error(line("cov"), f"[combined] cov must be {k} rows of {k} numbers")
            cov = []
        else:
            cov = [numbers("cov", row, k) for row in cov_raw]
        shrink = v.get("shrinkage", 0.0)
        if isinstance(shrink, bool) or not isinstance(shrink, int | float) or not 0 <= shrink <= 1:
            self.error(line("shrinkage"), f"[combined] shrinkage must be in [0, 1], got {shrink!r}")
            shrink = 0.0
        high = v.get("high")
        if high is not None and (
            isinstance(high, bool) or not isinstance(high, int | float) or not high > 0
        ):
            self.error(line("high"), f"[combined] high must be a number > 0, got {high!r}")
            high = None
        gains = self._number_tables(v, "gains", "test = { TAG = gain }", "TAG = gain")
        responses = self._number_tables(v, "responses", "TAG = { test = r }", "test = response")
        names = [t.name for t in getattr(self, "tests", [])]
        if names and sorted(tests) != sorted(names):
            self.error(
                line("tests"),
                f"[combined] tests {tests} differ from the unit's tests {names}: "
                "run `diag unit learn` again",
            )
        for test in gains:
            if names and test not in names:
                self.error(self.line_of("combined.gains", test), f"unknown test {test!r}")
        for sp, row in responses.items():
            for test in row:
                if names and test not in names:
                    self.error(self.line_of("combined.responses", sp), f"unknown test {test!r}")
        points = self._combined_points(v, k, line)
        if len(self.problems) > n0:
            return None
        return CombinedSpec(
            tests=list(tests),
            center=center,
            scale=scale,
            cov=cov,
            shrinkage=float(shrink),
            high=None if high is None else float(high),
            gains=gains,
            responses=responses,
            notes={kk: v[kk] for kk in COMBINED_NOTES if kk in v},
            **points,
        )

    def _combined_points(self, v: dict, k: int, line) -> dict[str, list]:
        """``[combined]``'s operating points (:data:`POINT_KEYS`, all or none): tag names,
        per point their means and ``k`` tests' centres, the tags' spans (> 0)."""
        have = [key for key in POINT_KEYS if key in v]
        if not have:
            return {}
        if len(have) < len(POINT_KEYS):
            missing = sorted(set(POINT_KEYS) - set(have))
            self.error(line(have[0]), f"[combined] operating points lack {', '.join(missing)}")
            return {}
        tags = v["point_tags"]
        if not isinstance(tags, list) or not tags or not all(isinstance(t, str) for t in tags):
            self.error(line("point_tags"), "[combined] point_tags must list tag names")
            return {}

        def rows(key: str, width: int, what: str) -> list[list[float]]:
            raw = v[key]
            ok = isinstance(raw, list) and len(raw) >= 2 and all(
                isinstance(r, list) and len(r) == width
                and all(isinstance(x, int | float) and not isinstance(x, bool)
                        and math.isfinite(x) for x in r)
                for r in raw
            )  # fmt: skip
            if not ok:
                self.error(line(key), f"[combined] {key} must be rows of {width} finite {what}")
                return []
            return [[float(x) for x in r] for r in raw]

        at = rows("point_at", len(tags), "tag means, one row per point")
        center = rows("point_center", k, "centres, one row per point")
        scale = rows("point_scale", k, "scales, one row per point")
        if not all(x > 0 for r in scale for x in r):
            self.error(line("point_scale"), "[combined] point_scale must be > 0 everywhere")
        raw = v["point_span"]
        if not (
            isinstance(raw, list)
            and len(raw) == len(tags)
            and all(isinstance(x, int | float) and not isinstance(x, bool) and x > 0 for x in raw)
        ):
            self.error(line("point_span"), f"[combined] point_span must be {len(tags)} spans > 0")
            return {}
        span = [float(x) for x in raw]
        if at and not len(at) == len(center) == len(scale):
            self.error(line("point_center"), "[combined] point_center, point_scale: a row a point")
        return {
            "point_tags": list(tags), "point_at": at, "point_span": span,
            "point_center": center, "point_scale": scale,
        }  # fmt: skip

    # ------------------------------------------------------------ paths
    def resolve(self, name: str) -> Path:
        """A file named in the unit file, relative to the unit file."""
        p = Path(name)
        return p if p.is_absolute() else self.path.parent / p

    @property
    def matrix_path(self) -> Path | None:
        return None if self.matrix is None else self.resolve(self.matrix)

    def test(self, name: str) -> TestSpec:
        for t in self.tests:
            if t.name == name:
                return t
        raise KeyError(name)

    # ------------------------------------------------------------ writing
    def set_learned(self, learned: Any) -> None:
        """Write what :func:`diag_plugin.learn.thresholds.learn_thresholds` learned: the
        limits, the budget and window they hold, each test's level scales and signal maximum,
        and per test what its thresholds rest on (``[learned]``)."""
        self.set_thresholds(
            learned.limits,
            learned.window,
            far=learned.far,
            blocks=learned.blocks,
            samples=learned.samples,
            ymax=learned.ymax,
            levels=learned.levels,
            spread=learned.spread,
            notes=learned.notes(),
            fuzzy=learned.fuzzy,
            points=getattr(learned, "level_points", {}),
            _reread=False,
        )
        # the file is read back once, after both are written (a unit of 200 tests: ~1.5 s a
        # read); the combined table as read before is the one set_thresholds left in place
        if getattr(learned, "combined", None) is not None or self.combined is not None:
            self.set_combined(getattr(learned, "combined", None))
        else:
            self._reread()

    def set_thresholds(
        self,
        limits: dict[str, tuple[float, float]],
        window: tuple[str, str],
        *,
        samples: dict[str, int],
        far: float | None = None,
        blocks: int | None = None,
        ymax: dict[str, float] | None = None,
        levels: dict[str, list[float]] | None = None,
        spread: dict[str, bool] | None = None,
        notes: dict[str, dict[str, Any]] | None = None,
        fuzzy: dict[str, tuple[float, float, float, float]] | None = None,
        points: dict[str, tuple[list[float], list[float]]] | None = None,
        _reread: bool = True,
    ) -> None:
        """Write thresholds per test and the fault-free window they came from (and, when
        given, the budget, level scales and the ``[learned]`` notes; ``points``: per level
        test with operating points its ``point_center`` and ``point_scale``, any other
        test's removed). ``_reread`` False: the file is not read back (the caller writes more
        and reads it back once)."""
        import tomlkit

        for name, (lo, hi) in limits.items():
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < 0 < hi):
                raise ValueError(
                    f"test {name}: thresholds {lo:g} … {hi:g} are not a band around 0 "
                    "(the unit file needs low < 0 < high)"
                )
        th = self.doc.get("thresholds")
        if th is None:
            th = tomlkit.table()
            th.add(tomlkit.comment("written by `diag unit learn`: the fault-free window used"))
            self.doc["thresholds"] = th
        for old in ("quantile", "margin"):  # the budget replaced them
            if old in th:
                del th[old]
        if far is not None:
            th["far"] = float(f"{far:.6g}")
        if blocks is not None:
            th["blocks"] = int(blocks)
        th["from"], th["to"] = window
        th["samples"] = int(min(samples.values())) if samples else 0
        tests = self.doc["tests"]
        for name, (lo, hi) in limits.items():
            row = {k: _plain(v) for k, v in tests[name].items()}
            row["high"] = kept_digits(hi)
            row.pop("low", None)
            if abs(lo + hi) > 1e-12:
                row["low"] = kept_digits(lo)
            if ymax and name in ymax:
                row["ymax"] = kept_digits(ymax[name], 6)
            if spread is not None:
                row.pop("spread", None)
                if spread.get(name):
                    row["spread"] = True
            if levels is not None:
                row.pop("levels", None)
                if name in levels and len(levels[name]) > 1:
                    row["levels"] = [round(float(x), 3) for x in levels[name]]
            if fuzzy is not None:
                row.pop("fuzzy", None)
                if name in fuzzy:
                    row["fuzzy"] = [kept_digits(x) for x in fuzzy[name]]
            if points is not None:
                row.pop("point_center", None)
                row.pop("point_scale", None)
                if name in points:
                    row["point_center"] = [float(f"{x:.6g}") for x in points[name][0]]
                    row["point_scale"] = [float(f"{x:.6g}") for x in points[name][1]]
            fresh_row = tomlkit.inline_table()
            fresh_row.update(row)  # rebuilt, so tomlkit spaces it like a hand-written line
            tests[name] = fresh_row
        if notes is not None:
            lt = tomlkit.table()
            lt.add(
                tomlkit.comment("written by `diag unit learn`: what each test's thresholds rest on")
            )
            for name, note in notes.items():
                row = tomlkit.inline_table()
                row.update(note)
                lt[name] = row
            if "learned" in self.doc:
                del self.doc["learned"]
            self.doc["learned"] = lt
        if _reread:
            self._reread()

    def _reread(self) -> None:
        """Read the document back as written (its lines, tests and checks); the text read is
        kept for :meth:`save` (``as_read``)."""
        text = self.dumps()
        fresh = UnitFile(text, self.path, doc=self.doc)
        self.__dict__.update(fresh.__dict__)
        self._read_text = text

    def _number_tables(
        self, v: dict, key: str, form: str, row_form: str
    ) -> dict[str, dict[str, float]]:
        """``[combined.KEY]``: a table of ``name = { name = number, … }``, finite numbers;
        a bad row is a ``file:line`` error and left out."""
        out: dict[str, dict[str, float]] = {}
        raw = v.get(key, {})
        if not isinstance(raw, dict):
            self.error(self.line_of("combined", key), f"[combined] {key} must be a table of {form}")
            return out
        for name, row in raw.items():
            if not isinstance(row, dict) or not all(
                isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)
                for x in row.values()
            ):
                self.error(
                    self.line_of(f"combined.{key}", name),
                    f"[combined.{key}] {name}: must be {{ {row_form}, … }}",
                )
                continue
            out[str(name)] = {str(t): float(x) for t, x in row.items()}
        return out

    def set_combined(self, spec: CombinedSpec | None) -> None:
        """Write (or, with None, remove) the ``[combined]`` table."""
        import tomlkit

        if "combined" in self.doc:
            del self.doc["combined"]
        if spec is not None:
            t = tomlkit.table()
            t.add(
                tomlkit.comment(
                    "written by `diag unit learn`: the unit-level test and the tag directions"
                )
            )
            if spec.high is not None:
                t["high"] = float(f"{spec.high:.6g}")
            for k, x in spec.notes.items():
                t[k] = x
            t["shrinkage"] = round(float(spec.shrinkage), 4)
            t["tests"] = list(spec.tests)
            t["center"] = [float(f"{x:.5g}") for x in spec.center]
            t["scale"] = [float(f"{x:.5g}") for x in spec.scale]
            cov = tomlkit.array()
            for row in spec.cov:
                cov.append(_number_array([float(f"{x:.5g}") for x in row]))
            cov.multiline(True)
            t["cov"] = cov
            if spec.point_center:
                t["point_tags"] = list(spec.point_tags)
                t["point_span"] = [float(f"{x:.6g}") for x in spec.point_span]
                for key in ("point_at", "point_center", "point_scale"):
                    arr = tomlkit.array()
                    for row in getattr(spec, key):
                        arr.append(_number_array([float(f"{x:.6g}") for x in row]))
                    arr.multiline(True)
                    t[key] = arr
            g = tomlkit.table()
            for test in spec.tests:
                row = tomlkit.inline_table()
                row.update({k: float(f"{x:.5g}") for k, x in spec.gains.get(test, {}).items()})
                g[test] = row
            t["gains"] = g
            if spec.responses:
                rs = tomlkit.table()
                for sp, resp in spec.responses.items():
                    row = tomlkit.inline_table()
                    row.update({k: float(f"{x:.5g}") for k, x in resp.items()})
                    rs[sp] = row
                t["responses"] = rs
            self.doc["combined"] = t
        self._reread()

    def dumps(self) -> str:
        import tomlkit

        return tomlkit.dumps(self.doc)

    def save(self, path: str | Path | None = None, *, as_read: bool = False) -> Path:
        """Write the file atomically (a killed process leaves the old or the new file).
        ``as_read``: right after a ``set_*`` method, the text it read back (the same as
        dumping the unchanged document again, without the dump: ~1 s for 200 tests)."""
        target = Path(path) if path is not None else self.path
        tmp = target.with_name(target.name + ".tmp")
        text = getattr(self, "_read_text", None) if as_read else None
        tmp.write_text(self.dumps() if text is None else text, encoding="utf-8")
        tmp.replace(target)
        self.path = target
        return target


def new_unit_text(
    name: str,
    tests: dict[str, str],
    *,
    matrix: str | None = None,
    description: str = "",
    outputs: str | None = None,
    evaluation: dict[str, Any] | None = None,
) -> str:
    """The text of a new unit file with default evaluation (``evaluation``: keys set to other
    values, e.g. ``{"combined": True, "isolation": "tags"}``) and no thresholds yet."""
    import tomlkit

    doc = tomlkit.document()
    doc.add(tomlkit.comment(f"Unit {name}: models (tests), residual evaluation, thresholds"))
    unit = tomlkit.table()
    unit["name"] = name
    if description:
        unit["description"] = description
    if matrix:
        unit["matrix"] = matrix
    unit["outputs"] = outputs or name
    doc["unit"] = unit
    ev = tomlkit.table()
    for k, v in {**EVALUATION_DEFAULTS, **(evaluation or {})}.items():
        if k in NEW_KEYS and v == EVALUATION_DEFAULTS[k]:
            continue  # files written before these keys regenerate byte for byte
        ev[k] = v
    doc["evaluation"] = ev
    t = tomlkit.table()
    for test, model in tests.items():
        row = tomlkit.inline_table()
        row["model"] = model
        t[test] = row
    doc["tests"] = t
    return tomlkit.dumps(doc)
