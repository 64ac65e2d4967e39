"""Combinations of the unit's discrete states it never learned: CHECK_FUNCTION, named (issue
34, item 5).

A unit's discrete states (``[build] states``: a pump's run feedback, 0/1) are never tested,
only read by the models as inputs. Each state may have been seen at both its values over the
build window and still the plant can run in a mode the window never held: the window showed
pump 1 alone and pumps 1 + 2, and at night pump 2 runs alone. No state is outside its values
(neither :mod:`~.fixed` nor the learned ranges fire), yet the models that read the states
answer at a mode they never saw (a station's night in 44 % alarm,
docs/how-to/unit-short-windows.md). So the build records the combinations the window held
(:func:`held_combos`), in the state tags' order::

    [states]
    tags = ["RUN1", "RUN2"]
    seen = ["1,0", "1,1"]
    held_s = 163.0

``held_s`` is the dwell that makes a combination learned: a run of it at least that long in
the window. The build takes the unit's quiet time before the hold (:func:`~.settle.quiet_parts`: the
longest history a test reads, plus the residual filter's delay, plus the on-delay, times the
period): a combination held that long has at least one sample where every test read only
it and its residual passed the filter; a shorter one (a start sequence, a changeover) taught
the models nothing of its own. At run time a row whose combination is none of ``seen`` (each
value within :func:`~.fixed.tolerance` of the learned one) for the unit's on-delay (a
switch's transient passes through combinations briefly: it raises nothing) makes the unit
CHECK_FUNCTION — no alarm, no fault, its diagnosis unknown — with ``RUN1 = 0, RUN2 = 1: a
combination of states the unit never learned (it learned 1,0; 1,1) since T``, until a learned
combination has held for the off-delay (:class:`CombosGuard`, the kernel of
:class:`~.fixed.FixedGuard`: every state tag one column with the row's code). A row where a
state has no value changes nothing. ``diag unit accept`` adds the accepted window's
combinations held ``held_s`` (:func:`widen`); rollback restores the file. A unit without the
table: as before.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from diag_plugin.diagnose.fixed import FixedGuard, _kernel, tolerance


def combo_text(row: Sequence[float]) -> str:
    """A combination as the table writes it: ``"1,0,0"`` (``%g`` per state)."""
    return ",".join(f"{float(v):g}" for v in row)


def parse_combo(text: str, k: int) -> tuple[float, ...] | None:
    """``"1,0,0"`` back to values (None: not ``k`` numbers)."""
    try:
        vals = tuple(float(p) for p in str(text).split(","))
    except ValueError:
        return None
    return vals if len(vals) == k and all(np.isfinite(vals)) else None


def held_combos(frame: pd.DataFrame, tags: Sequence[str], held_s: float) -> list[str]:
    """The combinations of ``tags`` in ``frame`` (rows in time order) held at least
    ``held_s`` in one run: a run's length is from its first row to the next run's first row,
    and at most to its last row plus the median spacing (the last run, and a run that ends
    at a hole in the rows: an outage of an ungridded frame is no time the plant was seen in
    the combination). A row where a state has no value ends a run and starts none; so does a
    spacing of more than twice the median (the row after a hole starts a run). Sorted as
    written."""
    need = int(round(float(held_s) * 1e9))
    return sorted({c for c, ns, _, _ in combo_runs(frame, tags) if ns >= need})


#: a combination visited this many times in the window, each visit shorter than ``held_s``,
#: is learned where the unit has a state settle (:func:`visited_combos`)
MIN_VISITS = 2


def visited_combos(
    frame: pd.DataFrame, tags: Sequence[str], held_s: float, least_s: float
) -> list[str]:
    """The combinations of ``tags`` in ``frame`` never held ``held_s`` in one run but visited
    :data:`MIN_VISITS` times or more for ``least_s`` (the unit's on-delay: a switch passing
    through one for less raises nothing) each, and never as a step of a sequence, sorted: a
    short state the plant returns to (a CIP's rinse, 10 min, three a CIP; a filter's
    backwash), whose changes the state settle holds (issue 34 item 5, ``i34-cip``). A visit
    shorter than the quiet time teaches the models nothing of its own, but it is one the
    plant makes: the unit judges it through the settle its change opens rather than naming
    it never learned on every visit.

    A visit entered through one state's change and left through another's, none changing at
    both ends (a production start's diversion: ``MODE`` 0 → 1, then the diversion valve
    forward minutes later), is a step inside a sequence, not a state: a combination with
    such a visit is not learned (it stays CHECK_FUNCTION while it lasts). Learned, the
    pasteuriser's start at 1 s showed the start's alarm over the diversion, FAILURE 0.62 →
    0.95 % of each fault-free day; its rinses (``MODE`` in and out) are learned."""
    need = int(round(float(held_s) * 1e9))
    least = int(round(float(least_s) * 1e9))
    runs = combo_runs(frame, tags)
    held = {c for c, ns, _, _ in runs if ns >= need}
    count: dict[str, int] = {}
    transit: set[str] = set()
    for c, ns, came, left in runs:
        if c in held or ns < least:
            continue
        count[c] = count.get(c, 0) + 1
        if came.any() and left.any() and not (came & left).any():
            transit.add(c)
    return sorted(c for c, k in count.items() if k >= MIN_VISITS and c not in transit)


def combo_runs(
    frame: pd.DataFrame, tags: Sequence[str]
) -> list[tuple[str, int, np.ndarray, np.ndarray]]:
    """The runs of one combination of ``tags`` in ``frame``, in time order: ``(combination,
    its length in ns, the states whose change began it, those whose change ended it)`` each
    (:func:`held_combos`' rule; rows where a state has no value none; the masks all False
    at the frame's ends, a hole or a row without a value)."""
    x = frame[list(tags)].to_numpy(float)
    if not len(x):
        return []
    t = frame.index.as_unit("ns").asi8 if isinstance(frame.index, pd.DatetimeIndex) else None
    if t is None:
        return []
    dt = np.diff(t)
    step = int(np.median(dt)) if len(t) > 1 else 0
    ok = np.isfinite(x).all(axis=1)
    hole = dt > 2 * step
    moved = (x[1:] != x[:-1]) & (ok[1:] & ok[:-1] & ~hole)[:, None]
    change = np.r_[True, moved.any(axis=1) | (ok[1:] != ok[:-1]) | hole]
    starts = np.flatnonzero(change)
    last = np.r_[starts[1:] - 1, len(t) - 1]  # each run's last row
    ends_t = np.minimum(np.r_[t[starts[1:]], t[-1] + step], t[last] + step)
    none = np.zeros(len(tags), bool)
    out = []
    for a, b, e in zip(starts.tolist(), last.tolist(), ends_t.tolist(), strict=True):
        if ok[a]:
            came = moved[a - 1] if a > 0 else none
            left = moved[b] if b < len(moved) else none
            out.append((combo_text(x[a]), e - t[a], came, left))
    return out


class CombosGuard(FixedGuard):
    """The unit's discrete states (``tags``, model names; ``names``: model tag → plant tag),
    the combinations it learned (``seen``) and the state of a run in one it did not (module
    doc). Every state is one column of :class:`~.fixed.FixedGuard`'s kernel, all with the
    row's code, so each carries its own last value."""

    def __init__(
        self,
        tags: Sequence[str],
        seen: Sequence[str],
        names: Mapping[str, str],
        on_delay: int,
        off_delay: int,
    ):
        self.tags = [str(t) for t in tags]
        self.plant = [names.get(t, t) for t in self.tags]
        k = len(self.tags)
        rows = [c for c in (parse_combo(s, k) for s in seen) if c is not None]
        self.seen = np.array(rows, float).reshape(len(rows), k)
        self.tol = np.vectorize(tolerance, otypes=[float])(self.seen) if len(rows) else self.seen
        self.learned = "; ".join(combo_text(r) for r in self.seen)
        self.on_delay = max(1, int(on_delay))
        self.off_delay = max(1, int(off_delay))
        self.reset()

    @classmethod
    def of(cls, unit) -> CombosGuard | None:
        """The guard of a :class:`~diag_plugin.diagnose.unit.Unit` (None without
        ``[states]``)."""
        st = getattr(unit.file, "states", None)
        if not st:
            return None
        return cls(st["tags"], st["seen"], unit.file.tags, unit.ev["on_delay"],
                   unit.ev["off_delay"])  # fmt: skip

    def learned_rows(self, x: np.ndarray) -> np.ndarray:
        """Per row of ``x`` (rows × :attr:`tags`) whether its combination is one learned."""
        if not len(self.seen):
            return np.zeros(len(x), bool)
        near = np.abs(x[:, None, :] - self.seen[None, :, :]) <= self.tol[None, :, :]
        return near.all(axis=2).any(axis=1)

    def codes(self, x: np.ndarray) -> np.ndarray:
        """Per row ``1`` a combination never learned, ``0`` a learned one, ``-1`` a state
        without a value; one column per state (the kernel's layout)."""
        gap = np.isnan(x).any(axis=1)
        code = np.where(gap, -1, (~self.learned_rows(x)).astype(np.int8)).astype(np.int8)
        return np.repeat(code[:, None], len(self.tags), axis=1)

    def idle(self, x: np.ndarray) -> bool:
        """True when :meth:`transform` of the one row ``x`` would hold nothing and change
        nothing (the live loop's shortcut)."""
        if self.active.any() or self.run.any():
            return False
        row = np.asarray(x, float)[None, :]
        return bool(np.isnan(row).any() or self.learned_rows(row)[0])

    def transform(self, index, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per row of ``x`` (rows × :attr:`tags`, plant values; ``index`` their times)
        whether the unit is held CHECK_FUNCTION, and why (``""`` elsewhere). Advances the
        state."""
        x = np.asarray(x, float).reshape(len(index), len(self.tags))
        times = pd.DatetimeIndex(index)
        ns = times.as_unit("ns").asi8
        on, when, val = _kernel(
            self.codes(x), ns, self.on_delay, self.off_delay,
            self.run, self.back, self.active, self.start, self.since, self.last, x,
        )  # fmt: skip
        held = on[:, 0] if len(self.tags) else np.zeros(len(index), bool)
        why = np.full(len(index), "", dtype=object)
        rows = np.flatnonzero(held)
        if len(rows):
            keys = [(tuple(v), w) for v, w in zip(val[rows].tolist(), when[rows, 0].tolist(),
                                                    strict=True)]  # fmt: skip
            said = {k: self.sentence(k[0], k[1], times.tz) for k in dict.fromkeys(keys)}
            why[rows] = [said[k] for k in keys]
        return held, why

    def sentence(self, values: Sequence[float], ns: int, tz) -> str:  # type: ignore[override]
        """``RUN1 = 0, RUN2 = 1: a combination of states the unit never learned (it learned
        1,0; 1,1) since T``."""
        when = pd.Timestamp(int(ns), tz="UTC")
        if tz is not None:
            when = when.tz_convert(tz)
        each = ", ".join(f"{p} = {v:.4g}" for p, v in zip(self.plant, values, strict=True))
        return (f"{each}: a combination of states the unit never learned (it learned "
                f"{self.learned or 'none'}) since {when.isoformat()}")  # fmt: skip


def read_states(table: Mapping, error, line_of) -> dict | None:
    """The ``[states]`` table of a unit file: ``{"tags": [...], "seen": [...], "held_s": s}``
    (None: no table); a bad table is ``error(line, what)`` and read as none."""
    if not table:
        return None
    tags, seen, held = table.get("tags"), table.get("seen"), table.get("held_s", 0.0)
    ok = (
        isinstance(tags, Sequence) and not isinstance(tags, str) and len(tags) > 0
        and isinstance(seen, Sequence) and not isinstance(seen, str)
        and isinstance(held, int | float) and not isinstance(held, bool) and held >= 0
    )  # fmt: skip
    if ok:
        bad = [s for s in seen if parse_combo(s, len(tags)) is None]
        if bad:
            error(line_of("seen"), f"[states] seen: {bad[0]!r} is not {len(tags)} numbers "
                                   "(one per state of tags, comma-separated)")  # fmt: skip
            return None
        return {"tags": [str(t) for t in tags], "seen": [str(s) for s in seen],
                "held_s": float(held)}  # fmt: skip
    error(line_of("tags"), "[states] needs tags = [\"A\", …], seen = [\"1,0\", …] and "
                           "held_s = seconds ≥ 0")  # fmt: skip
    return None


def states_table(tags: Sequence[str], seen: Sequence[str], held_s: float):
    """The unit file's ``[states]`` table (docs/reference/units.md)."""
    import tomlkit

    t = tomlkit.table()
    t.add(tomlkit.comment(
        "written by `diag unit build`: the combinations of the discrete states (tags, in this "
        "order) the window held for held_s (the unit's quiet time) or longer; another one held "
        "for the on-delay: CHECK_FUNCTION naming it; `diag unit accept` adds the accepted "
        "window's"
    ))  # fmt: skip
    t["tags"] = list(tags)
    seen_arr = tomlkit.array()
    seen_arr.extend(list(seen))
    t["seen"] = seen_arr
    t["held_s"] = float(held_s)
    return t


def widen(states: Mapping | None, frame: pd.DataFrame) -> list[str]:
    """The combinations of the accepted window ``frame`` (models' tag names) held
    ``held_s`` that the table does not have yet."""
    if not states or any(t not in frame.columns for t in states["tags"]):
        return []
    k = len(states["tags"])
    have = {parse_combo(s, k) for s in states["seen"]}
    return [c for c in held_combos(frame, states["tags"], states["held_s"])
            if parse_combo(c, k) not in have]  # fmt: skip
