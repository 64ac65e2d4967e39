"""A loop's valve at its limit is named (issue 34, item 7).

A loop whose valve is fully open (or shut) can no longer act: its measurement leaves the
set-point and the loop's own test fires, and the ranking names the measurement (the distillate
valve of the column of docs/explanation/acceptance-column.md at 100 % with the feed beyond
its capacity: FAILURE named ``DrumLevel`` on 97 % of the samples, the valve on 2 %). What an
operator acts on is the valve: ``dist_valve at its limit (100): loop DrumLevel cannot hold
its set-point``.

The rule (:class:`Saturation`): a loop test (``set_point`` and ``actuator`` in the unit file,
statistic ``level``) whose symptom is on while its actuator reads within
:data:`AT_LIMIT` of its span from an edge of the span of its own test's output — the tag's
metadata range where the historian gives one, else the range the build window saw, which it
never passed — names the actuator first (the ranking's first tag, the isolated fault), held
to the end of the alarm episode as the other names are (:class:`~.unitloops.EpisodeHold`).
Detection is unchanged: only the names and the reason are.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

#: an actuator reads "at its limit" within this share of its span from an edge
AT_LIMIT = 0.005


@dataclass
class _Loop:
    test: int  # the loop test's column
    pv: str  # the measurement (plant name), for the sentence
    actuator: str  # plant name
    model_tag: str  # the actuator's name in the models (what Columns reads)
    lo: float
    hi: float


def _sentence(lp: _Loop, value: float, at_limit: bool, tol: float) -> str:
    """The reason of a sample on which ``lp``'s actuator is named: at its limit now, or (the
    name held to the episode's end) earlier in this alarm, with the value it reads now
    (acceptance pass 10: a pasteuriser's balance-tank valve, shut at a production start,
    named for the 6.5 h alarm after it, said `at its limit (50.4, …)` at 50.4 %)."""
    span = f"its span {lp.lo:g} … {lp.hi:g}"
    if not at_limit:
        return (
            f"{lp.actuator} at its limit earlier in this alarm (now {value:.4g}, {span}): "
            f"loop {lp.pv} could not hold its set-point"
        )
    edge = lp.hi if value >= lp.hi - tol else lp.lo
    val = value if np.isfinite(value) else edge
    return f"{lp.actuator} at its limit ({val:.4g}, {span}): loop {lp.pv} cannot hold its set-point"


class Saturation:
    """The loops whose actuator's limits the unit knows, and per loop whether the current
    alarm episode has named its actuator (carried across pieces)."""

    def __init__(self, loops: list[_Loop]) -> None:
        self.loops = loops
        self.reset()

    @classmethod
    def of(cls, unit) -> Saturation | None:
        """The unit's loop tests whose actuator has a test of its own (its span: the output
        variable's); None where there is none."""
        mapping = unit.file.tags
        out_of = {}
        for t in unit.tests:
            m = unit.models[t]
            tag = m.output.split("[")[0]
            if m.out_range is not None:
                out_of.setdefault(tag, m.out_range)
        loops = []
        for j, t in enumerate(unit.tests):
            spec = unit.file.test(t)
            act = getattr(spec, "actuator", None)
            if not act or not getattr(spec, "set_point", None):
                continue
            if getattr(spec, "statistic", "level") != "level":
                continue
            model_tag = next((k for k, v in mapping.items() if v == act), act)
            rng = out_of.get(model_tag)
            if rng is None:
                continue
            pv = unit.models[t].output.split("[")[0]
            loops.append(_Loop(j, mapping.get(pv, pv), act, model_tag, *map(float, rng)))
        return cls(loops) if loops else None

    def reset(self) -> None:
        self.active = False  # the last sample of the previous piece was in alarm
        self.named = np.zeros(len(self.loops), bool)  # per loop: named in that episode

    def to_state(self) -> dict[str, Any]:
        return {"active": bool(self.active), "named": self.named.tolist()}

    def load_state(self, state: dict[str, Any]) -> None:
        self.active = bool(state["active"])
        self.named = np.asarray(state["named"], bool)

    def transform(self, cols, on: np.ndarray, active: np.ndarray):
        """Per sample the loop whose actuator is named (-1: none; the first loop in the
        file's order where two are) and the sentence: ``on`` the symptoms on (samples × tests),
        ``active`` the unit's alarm. Advances the carried state."""
        n = len(active)
        which = np.full(n, -1, np.int64)
        text = np.full(n, "", dtype=object)
        starts = active & ~np.r_[self.active, active[:-1]]
        for k, lp in enumerate(self.loops):
            v = np.asarray(cols.values(lp.model_tag), float)
            tol = AT_LIMIT * (lp.hi - lp.lo)
            with np.errstate(invalid="ignore"):
                at = (v >= lp.hi - tol) | (v <= lp.lo + tol)
            hit = (active & on[:, lp.test] & at).astype(np.int64)
            cum = np.cumsum(hit)
            # the hits before each episode's start, carried forward: the count within it
            base = np.maximum.accumulate(np.where(starts, cum - hit, 0))
            carried = self.named[k] & (np.cumsum(starts) == 0)
            named = active & (((cum - base) > 0) | carried)
            free = named & (which < 0)
            which[free] = k
            for i in np.flatnonzero(free):
                text[i] = _sentence(lp, float(v[i]), bool(at[i]) or not np.isfinite(v[i]), tol)
            if n:
                self.named[k] = bool(named[-1])
        if n:
            self.active = bool(active[-1])
        return which, text

    def name_first(self, which: np.ndarray, text: np.ndarray, faults, top) -> None:
        """In place: on the samples ``which`` names, the actuator as the fault and first in
        the ranking (``top``: the columns of :func:`~.unittags.top_columns_at`) where there is
        one, with its own share (else the first tag's); the sentence keeps the last known
        value over a sample the actuator has none (held)."""
        last = ""
        for i in range(len(which)):
            k = which[i]
            if k < 0:
                continue
            if text[i]:
                last = text[i]
            elif last:
                text[i] = last
            act = self.loops[k].actuator
            faults[i] = act
            if top is None:
                continue
            names = [top[f"top{j}"][i] for j in range(1, 4) if f"top{j}" in top]
            shares = [top[f"share{j}"][i] for j in range(1, 4) if f"share{j}" in top]
            if not any(names):  # no ranking here (the combined test unknown): none invented
                continue
            pairs = [(a, s) for a, s in zip(names, shares, strict=True) if a and a != act]
            own = next((s for a, s in zip(names, shares, strict=True) if a == act), None)
            first = own if own is not None else (shares[0] if shares else np.nan)
            pairs = [(act, first), *pairs][: len(names)]
            for j, (a, s) in enumerate(pairs, start=1):
                top[f"top{j}"][i] = a
                top[f"share{j}"][i] = s
