"""Hand valves: an operator's setting is an input, never tested, judged against the span the
unit learned it in (issue 34, item 5).

A hand valve (a manual drain valve, a blowdown valve moved twice a day) is set by an operator,
not by the process: a model of it learns the operators' choices of the window (a chance
correlation of a few moves), and its next position is a new operating point, not a fault.
Declared (``diag unit build --manual TAG`` or the role ``manual`` in a tags CSV,
:mod:`diag_plugin.unitbuild.loops`), the build never tests it, keeps it a candidate input of
the other tests, and writes in the unit file the span the window saw it in::

    [manual]
    HAND_VALVE = { min = 40.0, max = 47.0, margin = 0.0 }

``min``/``max`` as learned (the window's extremes), ``margin`` from the data: 3 × the tag's
noise, the robust standard deviation of its sample-to-sample changes
(1.4826 · MAD(Δx) / √2; an operator's moves are too few to move the median), so a reading at
a learned position is never outside; 0 for a setting recorded without noise. At run time,
where the tag is outside ``[min − margin, max + margin]``, every test reading it (any
method, at the lag it reads it) is unknown — the unit CHECK_FUNCTION, naming the valve
(:mod:`diag_plugin.diagnose.operating`) — and the tests that do not read it keep judging.
``diag unit accept`` of a period at the new position widens the span (``min`` and ``max``
merged exactly, the larger margin kept; :func:`merged`). Keys are the models' tag names.

A loop's set-point that the window saw at few values (an operator's choice, moved a few times
a day) gets the same rows in ``[chosen]`` (:func:`~diag_plugin.unitbuild.build.chosen_set_points`)::

    [chosen]
    "LIC101.SP" = { min = 55.0, max = 60.0, margin = 0.0 }

Where one is outside ``[min − margin, max + margin]`` (its value now), every line (a test that
is not a rule grid nor a loop's own) that reads any of them, or the measurement a loop holds
at one, is unknown: the plant is at an operating point the window never held, and a line
learned across the window's few points (the recycle valve's, through three of them, the
reactor's level standing in for the recycle drum's, whose set-points the operators had moved
together) is a guess there. The loops' own tests (those with a ``set_point``: the
measurement against its set-point, its spread) judge at any set-point; a rule grid has no
rule where the window had no sample (Kościelny et al., eq. 5) and is unknown past the
set-points it learned already. The unit names the set-point (:func:`chosen_ranges`);
``diag unit accept`` widens the row.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from diag_plugin.diagnose.operating import Range
from diag_plugin.regressors import parse_specs

#: the margin is this many times the tag's noise (robust sd of its sample-to-sample changes)
NOISE_MARGIN = 3.0
#: what the margin is, as the unit file's comment and the build's plan say it
MARGIN_SAYS = "3 × its noise (robust sd of its sample-to-sample changes)"


@dataclass(frozen=True)
class ManualSpan:
    """A hand valve's span as learned: its extremes and the margin beyond them."""

    tag: str
    min: float
    max: float
    margin: float = 0.0

    @property
    def lo(self) -> float:
        return self.min - self.margin

    @property
    def hi(self) -> float:
        return self.max + self.margin

    def as_row(self) -> dict[str, float]:
        return {"min": float(self.min), "max": float(self.max), "margin": float(self.margin)}


def learned_span(tag: str, x: np.ndarray) -> ManualSpan | None:
    """``tag``'s span over the values ``x`` (module doc); None without a finite value."""
    x = np.asarray(x, float)
    good = x[np.isfinite(x)]
    if not good.size:
        return None
    d = np.diff(x)
    d = d[np.isfinite(d)]
    noise = 1.4826 * float(np.median(np.abs(d - np.median(d)))) / np.sqrt(2) if d.size else 0.0
    return ManualSpan(tag, float(good.min()), float(good.max()), float(NOISE_MARGIN * noise))


def merged(a: ManualSpan, b: ManualSpan | None) -> ManualSpan:
    """The span of both windows: extremes merged exactly, the larger margin kept (the same
    whatever order windows are accepted in)."""
    if b is None:
        return a
    return ManualSpan(a.tag, min(a.min, b.min), max(a.max, b.max), max(a.margin, b.margin))


def read_manual(table: Mapping, error, line_of, name: str = "manual") -> dict[str, ManualSpan]:
    """The ``[manual]`` table of a unit file: tag → :class:`ManualSpan`; a bad row is
    ``error(line, what)`` and left out (``line_of(key)``: its line). ``name``: the table's,
    in the errors (``[fixed]`` has the same rows, :mod:`~diag_plugin.diagnose.fixed`)."""
    out = {}
    for tag, row in table.items():
        row = dict(row) if isinstance(row, Mapping) else None
        vals = {}
        if row is not None:
            vals = {
                k: float(v) for k, v in row.items()
                if isinstance(v, int | float) and not isinstance(v, bool) and np.isfinite(v)
            }  # fmt: skip
        if row is None or set(row) != {"min", "max", "margin"} or len(vals) != 3:
            error(line_of(tag), f"[{name}] {tag}: must be {{ min = …, max = …, margin = … }}"
                                f" ({_row_problem(row, vals)})")  # fmt: skip
            continue
        if not (vals["min"] <= vals["max"] and vals["margin"] >= 0):
            got = ", ".join(f"{k} {vals[k]:g}" for k in ("min", "max", "margin"))
            error(line_of(tag), f"[{name}] {tag}: needs min ≤ max and margin ≥ 0, got {got}")
            continue
        out[str(tag)] = ManualSpan(str(tag), vals["min"], vals["max"], vals["margin"])
    return out


def _row_problem(row: dict | None, vals: dict[str, float]) -> str:
    """What is wrong with a ``[manual]``/``[narrow]`` row, for its message."""
    if row is None:
        return "not a table"
    keys = ("min", "max", "margin")
    said = [f"{k} missing" for k in keys if k not in row]
    said += [f"{k} {row[k]!r} is not a finite number" for k in keys if k in row and k not in vals]
    said += [f"unknown key {k!r}" for k in row if k not in keys]
    return "; ".join(said) or "not numbers"


def manual_ranges(ranges: Sequence[Range], spans: Mapping[str, ManualSpan]) -> list[Range]:
    """The learned ranges with each hand valve's narrowed to its span and put first (the
    range a test reading it is judged on, so the unit names the valve and the span it
    learned before any input the valve's move took elsewhere)."""
    if not spans:
        return list(ranges)
    first, rest = [], []
    for r in ranges:
        s = spans.get(r.tag)
        if s is not None:
            first.append(Range(r.test, r.tag, max(r.lo, s.lo), min(r.hi, s.hi), r.lag))
        else:
            rest.append(r)
    return first + rest


def chosen_tests(
    models: Mapping,
    tests: Sequence[str],
    set_points: Sequence[str | None],
    chosen: Mapping[str, ManualSpan],
) -> dict[int, list[ManualSpan]]:
    """Per test position the ``[chosen]`` set-points that guard it (module doc): every one of
    them, for each line that reads one as a plain input or reads the measurement a loop
    holds at one (the output of a test with ``set_point`` = it): the line was fitted across
    the window's few operating points, which the operators set together, so a move of any of
    them past what the window showed is a point it never saw. Not a loop's own test (one
    with a ``set_point``: its residual is the control error at any set-point), not a rule
    grid (no rule where the window had no sample). ``{}`` where none."""
    held: dict[str, set[str]] = {}
    for j, name in enumerate(tests):
        sp = set_points[j]
        if sp in chosen:
            held.setdefault(sp, set()).add(parse_specs([models[name].output])[0].tags[0])
    spans = list(chosen.values())
    out: dict[int, list[ManualSpan]] = {}
    for j, name in enumerate(tests):
        grid = getattr(models[name].model, "partitions_", None) is not None
        if set_points[j] is not None or grid:
            continue
        read = {s.tags[0] for s in parse_specs(models[name].inputs) if s.fn == ""}
        if any(sp in read or read & held.get(sp, set()) for sp in chosen):
            out[j] = spans
    return out


def chosen_ranges(guarded: Mapping[int, Sequence[ManualSpan]]) -> list[Range]:
    """The ``[chosen]`` set-points as ranges of the tests they guard (:func:`chosen_tests`;
    lag 0, the value now): where one is outside, the unit names it as an input outside what
    it learned."""
    return [Range(j, s.tag, s.lo, s.hi) for j, spans in guarded.items() for s in spans]


def own_spans(
    models: Mapping, tests: Sequence[str], narrow: Mapping[str, ManualSpan]
) -> dict[int, ManualSpan]:
    """Per test position the ``[narrow]`` span of the tag it tests (its output, a plain tag
    read at lag 0; :func:`~diag_plugin.unitbuild.build.narrow_outputs`); ``{}`` where none."""
    out = {}
    for j, name in enumerate(tests):
        s = parse_specs([models[name].output])[0]
        if s.fn == "" and s.lag == 0 and s.tags[0] in narrow:
            out[j] = narrow[s.tags[0]]
    return out


def own_ranges(models: Mapping, tests: Sequence[str], narrow: Mapping[str, ManualSpan]) -> list:
    """The ``[narrow]`` tags as the ranges of their own tests
    (:class:`~diag_plugin.diagnose.operating.Range`, lag 0): where one is outside, its test
    unknown, the unit names it as an input outside what it learned."""
    return [Range(j, s.tag, s.lo, s.hi) for j, s in own_spans(models, tests, narrow).items()]


class ManualGuard:
    """Per test the columns of its design that read a hand valve, and its plain inputs with
    their learned ranges: :meth:`blank` makes the test unknown where a hand valve it reads is
    outside its span, and, while any of the unit's hand valves is outside (:meth:`moved`),
    where an input of its rule grid is outside the cells that carry a rule (the valve's move
    took it there: the grid would answer from its edge; a linear or a loop's test extrapolates
    and keeps judging). Tests whose inputs stay inside keep judging.

    ``own``: per test position the span of the tag the test itself models where the build
    found it narrow (``[narrow]``, :func:`own_spans`): a rule grid's answer never leaves the
    values its window showed, so where the tag is outside its span the residual measures the
    excursion, not a fault, and the test is unknown there, as a test reading a hand valve.

    ``chosen``: per test position the ``[chosen]`` set-points that guard it
    (:func:`chosen_tests`): the test is unknown where one of them is outside its row (its
    value now)."""

    def __init__(
        self,
        spans: Mapping[str, ManualSpan],
        cols: dict[int, tuple],
        own: Mapping[int, ManualSpan] | None = None,
        chosen: Mapping[int, Sequence[ManualSpan]] | None = None,
    ):
        self.spans = dict(spans)
        #: test position → (design columns, lo, hi, whether each is a hand valve's)
        self.cols = cols
        #: test position → the span of its own tag (``[narrow]``)
        self.own = dict(own or {})
        #: test position → the ``[chosen]`` set-points that guard it
        self.chosen = {j: list(v) for j, v in (chosen or {}).items()}

    @classmethod
    def of(
        cls,
        models: Mapping,
        tests: Sequence[str],
        spans: Mapping[str, ManualSpan],
        narrow: Mapping[str, ManualSpan] | None = None,
        chosen: Mapping[str, ManualSpan] | None = None,
        set_points: Sequence[str | None] = (),
    ):
        """The guard of a unit's tests (``models``: test → its
        :class:`~diag_plugin.diagnose.unit.TestModel`); None where the unit declares no hand
        valve or no test reads one, no test models a ``[narrow]`` tag and no ``[chosen]``
        set-point guards a test (a unit as before). ``set_points``: each test's
        ``set_point`` (None: none), for :func:`chosen_tests`."""
        from diag_plugin.diagnose.operating import model_ranges

        read = {s.tags[0] for name in tests for s in parse_specs(models[name].inputs)
                if s.fn == ""}  # fmt: skip
        spans = {t: s for t, s in spans.items() if t in read}
        own = own_spans(models, tests, narrow or {})
        sps = list(set_points) or [None] * len(tests)
        guarded = chosen_tests(models, tests, sps, chosen or {})
        if not spans and not own and not guarded:
            return None
        if not spans:
            return cls({}, {}, own, guarded)
        cols = {}
        for j, name in enumerate(tests):
            m = models[name]
            plain = [k for k, s in enumerate(parse_specs(m.inputs)) if s.fn == ""]
            grid = getattr(m.model, "partitions_", None) is not None
            learned = model_ranges(m.model, m.inputs) if grid else []
            if len(learned) != len(plain):  # not a rule grid: its hand valves only
                learned = [(parse_specs([m.inputs[k]])[0].tags[0], -np.inf, np.inf)
                           for k in plain]  # fmt: skip
            rows = []
            for k, (tag, lo, hi) in zip(plain, learned, strict=True):
                s = spans.get(tag)
                rows.append((k, lo, hi, False) if s is None else (k, s.lo, s.hi, True))
            if rows:
                k, lo, hi, hand = zip(*rows, strict=True)
                cols[j] = (np.array(k, np.intp), np.array(lo, float), np.array(hi, float),
                           np.array(hand, bool))  # fmt: skip
        return cls(spans, cols, own, guarded)

    def chosen_off(self, value) -> dict[str, np.ndarray]:
        """Per ``[chosen]`` set-point that guards a test, where it is outside its row over the
        piece's rows (``value(tag)``: its values, model tag names; no value: not outside)."""
        out: dict[str, np.ndarray] = {}
        for spans in self.chosen.values():
            for s in spans:
                if s.tag not in out:
                    x = np.asarray(value(s.tag), float)
                    with np.errstate(invalid="ignore"):
                        out[s.tag] = (x < s.lo) | (x > s.hi)
        return out

    def moved(self, value) -> np.ndarray | bool:
        """Where any hand valve is outside its span now (``value(tag)``: its values at the
        rows, model tag names; a valve without a value is not outside)."""
        off = False
        for tag, s in self.spans.items():
            x = np.asarray(value(tag), float)
            with np.errstate(invalid="ignore"):
                off = off | (x < s.lo) | (x > s.hi)
        return off

    def blank(
        self,
        out: np.ndarray,
        j: int,
        positions: np.ndarray,
        X: np.ndarray,
        moved,
        y: np.ndarray | None = None,
        chosen: Mapping[str, np.ndarray] | None = None,
    ) -> None:
        """Test ``j``'s residuals (row ``j`` of ``out``, tests × samples, at ``positions``,
        its design ``X``; ``moved``: :meth:`moved` over the piece's rows) unknown where a
        hand valve it reads is outside its span, or where a valve moved and an input of it
        is outside what it learned, or where its own tag (``y``, at ``positions``) is outside
        its ``[narrow]`` span, or where a ``[chosen]`` set-point that guards it is outside
        (``chosen``: :meth:`chosen_off` over the piece's rows)."""
        if chosen and positions.size:
            for sp in self.chosen.get(j, ()):
                off = chosen.get(sp.tag)
                if off is not None:
                    out[j, positions[off[positions]]] = np.nan
        s = self.own.get(j)
        if s is not None and y is not None and positions.size:
            with np.errstate(invalid="ignore"):
                yv = np.asarray(y, float)
                out[j, positions[(yv < s.lo) | (yv > s.hi)]] = np.nan
        got = self.cols.get(j)
        if got is None or not positions.size:
            return
        k, lo, hi, hand = got
        x = np.asarray(X, float)[:, k]
        off = (x < lo) | (x > hi)
        bad = off[:, hand].any(axis=1)
        if np.any(moved):
            bad |= np.asarray(moved)[positions] & off[:, ~hand].any(axis=1)
        out[j, positions[bad]] = np.nan

    def slots(
        self,
        first: int,
        inputs: Sequence[np.ndarray],
        column,
        outputs: Sequence[tuple[int, int]] = (),
    ) -> tuple[list, list]:
        """The plant's fast path (:class:`~diag_plugin.diagnose.plant.Plant`): per guarded
        test (slot ``first`` + its position, ``inputs[j]`` its ``(lag, column)`` rows) its
        judged inputs ``(slot, lag, column, lo, hi, hand valve?)``, and the valves' ``(column,
        lo, hi)`` (``column(tag)``: a model tag's column in the plant's history)."""
        rows = []
        for j, (k, lo, hi, hand) in self.cols.items():
            for c, a, b, h in zip(k.tolist(), lo.tolist(), hi.tolist(), hand.tolist(),
                                  strict=True):  # fmt: skip
                lag, col = inputs[j][c]
                rows.append((first + j, int(lag), int(col), a, b, h))
        for j, s in self.own.items():  # its own tag (``outputs[j]``: its lag, column)
            lag, col = outputs[j]
            rows.append((first + j, int(lag), int(col), s.lo, s.hi, True))
        for j, spans in self.chosen.items():  # its [chosen] set-points, now
            for s in spans:
                rows.append((first + j, 0, int(column(s.tag)), s.lo, s.hi, True))
        valves = [(column(t), s.lo, s.hi) for t, s in self.spans.items()]
        return rows, valves


class PlantGuard:
    """:meth:`ManualGuard.blank` on the plant's fast path, every unit's at once: one cycle's
    residuals ``r`` (per slot) from the history ``hist`` (lag × columns)."""

    def __init__(self, rows: list, valves: list, slot_unit: np.ndarray) -> None:
        a = np.array(rows, float).reshape(-1, 6)
        self.slot = a[:, 0].astype(np.intp)
        self.lag, self.col = a[:, 1].astype(np.intp), a[:, 2].astype(np.intp)
        self.lo, self.hi, self.hand = a[:, 3], a[:, 4], a[:, 5] > 0
        self.unit = slot_unit[self.slot]  # each judged input's unit
        v = np.array([(u, c, lo, hi) for u, vs in valves for c, lo, hi in vs], float).reshape(-1, 4)
        self.v_unit, self.v_col = v[:, 0].astype(np.intp), v[:, 1].astype(np.intp)
        self.v_lo, self.v_hi = v[:, 2], v[:, 3]

    def blank(self, r: np.ndarray, hist: np.ndarray) -> None:
        """``r`` NaN, in place, at the slots :meth:`ManualGuard.blank` makes unknown."""
        x = hist[self.lag, self.col]
        off = (x < self.lo) | (x > self.hi)
        now = hist[0, self.v_col]
        moved_units = self.v_unit[(now < self.v_lo) | (now > self.v_hi)]
        bad = off & (self.hand | np.isin(self.unit, moved_units))
        r[self.slot[bad]] = np.nan
