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
the window. The build takes the unit's quiet time (:func:`~.settle.quiet_samples`: the
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
from typing import Any

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


def combo_visits(frame: pd.DataFrame, tags: Sequence[str]) -> dict[str, list[tuple[float, bool]]]:
    """Each combination of ``tags`` in ``frame`` (rows in time order) with its runs: ``(s,
    cut)``, the run's length in seconds and whether the window cut it (the window's first or
    last run, or one ending at a hole: it may have been held longer). A run's length is from
    its first row to the next run's first row, and at most to its last row plus the median
    spacing (the last run, and a run that ends at a hole in the rows: an outage of an
    ungridded frame is no time the plant was seen in the combination). A row where a state
    has no value ends a run and starts none; so does a spacing of more than twice the median
    (the row after a hole starts a run)."""
    x = frame[list(tags)].to_numpy(float)
    t = frame.index.as_unit("ns").asi8 if isinstance(frame.index, pd.DatetimeIndex) else None
    if not len(x) or t is None:
        return {}
    dt = np.diff(t)
    step = int(np.median(dt)) if len(t) > 1 else 0
    ok = np.isfinite(x).all(axis=1)
    hole = dt > 2 * step
    change = np.r_[True, (x[1:] != x[:-1]).any(axis=1) | (ok[1:] != ok[:-1]) | hole]
    starts = np.flatnonzero(change)
    last = np.r_[starts[1:] - 1, len(t) - 1]  # each run's last row
    ends_t = np.minimum(np.r_[t[starts[1:]], t[-1] + step], t[last] + step)
    cut_end = np.r_[hole[last[:-1]] | ~ok[last[:-1] + 1], True]
    cut_start = np.r_[True, ~ok[starts[1:] - 1] | hole[starts[1:] - 1]]
    out: dict[str, list[tuple[float, bool]]] = {}
    for a, e, c in zip(starts.tolist(), ends_t.tolist(), (cut_start | cut_end).tolist(),
                       strict=True):  # fmt: skip
        if ok[a]:
            out.setdefault(combo_text(x[a]), []).append(((e - t[a]) / 1e9, bool(c)))
    return out


def learned_combos(
    visits: Mapping[str, Sequence[tuple[float, bool]]], held_s: float, cut_unbounded: bool = True
) -> dict[str, float]:
    """The combinations :func:`combo_visits` makes learned — held ``held_s`` in one run (the
    quiet time: a sample where every test read only it) — each with the longest it was held
    (s; ``inf`` when that run was cut by the window: no bound). ``cut_unbounded`` False (an
    accepted period): a run the window cut counts with the length it was seen. A state
    visited often but shorter than ``held_s`` each time (a 10 min CIP rinse) is still not
    learned: at 10 s the pasteuriser's unit has no state settle, and judged, the rinse's
    transient raised FAILURE (docs/explanation/acceptance-pasteuriser.md)."""
    out = {}
    for combo, runs in visits.items():
        if any(s >= held_s for s, _ in runs):
            s, cut = max(runs)
            out[combo] = float("inf") if cut and cut_unbounded else float(s)
    return dict(sorted(out.items()))


def held_combos(frame: pd.DataFrame, tags: Sequence[str], held_s: float) -> list[str]:
    """The combinations of ``tags`` in ``frame`` (rows in time order) held at least
    ``held_s`` in one run (:func:`combo_visits`'s runs). Sorted as written."""
    return sorted(c for c, runs in combo_visits(frame, tags).items()
                  if any(s >= held_s for s, _ in runs))  # fmt: skip


class CombosGuard(FixedGuard):
    """The unit's discrete states (``tags``, model names; ``names``: model tag → plant tag),
    the combinations it learned (``seen``), the longest the window held each (``longest``,
    s; ``inf`` or none: no bound) and the state of a run in one it did not, or in a learned
    one for longer than that (module doc). Every state is one column of
    :class:`~.fixed.FixedGuard`'s kernel, all with the row's code, so each carries its own
    last value."""

    def __init__(
        self,
        tags: Sequence[str],
        seen: Sequence[str],
        names: Mapping[str, str],
        on_delay: int,
        off_delay: int,
        longest: Sequence[float] | None = None,
    ):
        self.tags = [str(t) for t in tags]
        self.plant = [names.get(t, t) for t in self.tags]
        k = len(self.tags)
        ok = [parse_combo(s, k) is not None for s in seen]
        rows = [c for c in (parse_combo(s, k) for s in seen) if c is not None]
        self.seen = np.array(rows, float).reshape(len(rows), k)
        self.tol = np.vectorize(tolerance, otypes=[float])(self.seen) if len(rows) else self.seen
        self.learned = "; ".join(combo_text(r) for r in self.seen)
        bound = list(longest) if longest is not None and len(longest) == len(seen) else None
        self.longest = np.array([float(b) for b, o in zip(bound, ok, strict=True) if o]
                                if bound else [np.inf] * len(rows), float)  # fmt: skip
        self.bounded = bool(np.isfinite(self.longest).any())
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
                   unit.ev["off_delay"], st.get("longest_s"))  # fmt: skip

    def reset(self) -> CombosGuard:
        super().reset()
        self.cur = -2  # the combination held now (its row of seen; -1 another, -2 none yet)
        self.cur_start = 0  # since when (UTC ns)
        return self

    def to_state(self) -> dict[str, Any]:
        """:meth:`~.fixed.FixedGuard.to_state` and the combination held now, since when."""
        return {**super().to_state(), "cur": int(self.cur), "cur_start": int(self.cur_start)}

    def load_state(self, state: Mapping[str, Any]) -> CombosGuard:
        super().load_state(state)
        self.cur = int(state.get("cur", -2))
        self.cur_start = int(state.get("cur_start", 0))
        return self

    def which(self, x: np.ndarray) -> np.ndarray:
        """Per row of ``x`` (rows × :attr:`tags`) its row of the learned combinations, -1
        none."""
        if not len(self.seen):
            return np.full(len(x), -1, np.int64)
        near = np.abs(x[:, None, :] - self.seen[None, :, :]) <= self.tol[None, :, :]
        hit = near.all(axis=2)
        return np.where(hit.any(axis=1), hit.argmax(axis=1), -1)

    def learned_rows(self, x: np.ndarray) -> np.ndarray:
        """Per row of ``x`` (rows × :attr:`tags`) whether its combination is one learned."""
        return self.which(x) >= 0

    def codes(self, x: np.ndarray, ns: np.ndarray | None = None) -> np.ndarray:
        """Per row ``1`` a combination never learned, or a learned one held longer than the
        window held it (``ns`` the rows' times; advances the combination held), ``0`` a
        learned one, ``-1`` a state without a value; one column per state (the kernel's
        layout)."""
        gap = np.isnan(x).any(axis=1)
        idx = self.which(x)
        code = np.where(gap, -1, (idx < 0).astype(np.int8)).astype(np.int8)
        if ns is not None and len(x):
            key = np.where(gap, -3, idx)
            change = np.r_[key[0] != self.cur, key[1:] != key[:-1]]
            at = np.maximum.accumulate(np.where(change, np.arange(len(key)), -1))
            start = np.where(at >= 0, ns[np.maximum(at, 0)], self.cur_start)
            if self.bounded:
                bound = np.where(idx >= 0, self.longest[np.maximum(idx, 0)], np.inf)
                code[(idx >= 0) & ((ns - start) / 1e9 > bound)] = 1
            self.cur, self.cur_start = int(key[-1]), int(start[-1])
        return np.repeat(code[:, None], len(self.tags), axis=1)

    def idle(self, x: np.ndarray) -> bool:
        """True when :meth:`transform` of the one row ``x`` would hold nothing and change
        nothing (the live loop's shortcut; never with a bound on how long a combination is
        held: the time it has been is carried)."""
        if self.active.any() or self.run.any() or self.bounded:
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
            self.codes(x, ns), ns, self.on_delay, self.off_delay,
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
        1,0; 1,1) since T``; of a learned one held too long: ``MODE = 0, FDV = 0: held longer
        than the unit learned it (at most 8040 s in its window) since T``."""
        when = pd.Timestamp(int(ns), tz="UTC")
        if tz is not None:
            when = when.tz_convert(tz)
        each = ", ".join(f"{p} = {v:.4g}" for p, v in zip(self.plant, values, strict=True))
        i = int(self.which(np.asarray(values, float)[None, :])[0])
        if i >= 0:
            return (f"{each}: held longer than the unit learned it (at most "
                    f"{self.longest[i]:.0f} s in its window: new operating data) since "
                    f"{when.isoformat()}")  # fmt: skip
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
        out = {"tags": [str(t) for t in tags], "seen": [str(s) for s in seen],
               "held_s": float(held)}  # fmt: skip
        longest = table.get("longest_s")
        if longest is not None:
            if not (isinstance(longest, Sequence) and not isinstance(longest, str)
                    and len(longest) == len(seen)
                    and all(isinstance(v, int | float) and not isinstance(v, bool) and v > 0
                            for v in longest)):  # fmt: skip
                error(line_of("longest_s"), "[states] longest_s: one number of seconds > 0 "
                                            "(or inf) per combination of seen")  # fmt: skip
                return None
            out["longest_s"] = [float(v) for v in longest]
        return out
    error(line_of("tags"), "[states] needs tags = [\"A\", …], seen = [\"1,0\", …] and "
                           "held_s = seconds ≥ 0")  # fmt: skip
    return None


def states_table(
    tags: Sequence[str], seen: Sequence[str], held_s: float, longest: Sequence[float] = ()
):
    """The unit file's ``[states]`` table (docs/reference/units.md)."""
    import tomlkit

    t = tomlkit.table()
    t.add(tomlkit.comment(
        "written by `diag unit build`: the combinations of the discrete states (tags, in this "
        "order) the window held for held_s (the unit's quiet time) or longer; longest_s the "
        "longest the window held each (inf: the window cut it); another one held for the "
        "on-delay, or one held longer than its longest_s: CHECK_FUNCTION naming it; `diag "
        "unit accept` adds the accepted window's"
    ))  # fmt: skip
    t["tags"] = list(tags)
    seen_arr = tomlkit.array()
    seen_arr.extend(list(seen))
    t["seen"] = seen_arr
    t["held_s"] = float(held_s)
    if len(longest):
        arr = tomlkit.array()
        arr.extend([float(v) for v in longest])
        t["longest_s"] = arr
    return t


def widen(states: Mapping | None, frame: pd.DataFrame) -> tuple[list[str], dict[str, float]]:
    """What the accepted window ``frame`` (models' tag names) adds to the table: the
    combinations :func:`learned_combos` learns that it does not have yet, and every
    combination's longest (s) where the window held it longer (both ``{combo: s}``; the
    new first as a list of combos)."""
    if not states or any(t not in frame.columns for t in states["tags"]):
        return [], {}
    k = len(states["tags"])
    have = {parse_combo(s, k): s for s in states["seen"]}
    longest = dict(zip(states["seen"], states.get("longest_s") or [np.inf] * len(states["seen"]),
                       strict=True))  # fmt: skip
    learned = learned_combos(
        combo_visits(frame, states["tags"]), states["held_s"], cut_unbounded=False
    )
    added, bounds = [], {}
    for c, s in learned.items():
        old = have.get(parse_combo(c, k))
        if old is None:
            added.append(c)
            bounds[c] = s
        elif s > longest[old]:
            bounds[old] = s
    return added, bounds
