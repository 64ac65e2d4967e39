"""A loop's valve at its limit is named (issue 34, item 7).

A loop whose valve is fully open (or shut) can no longer act: its measurement leaves the
set-point and the loop's own test fires, and the ranking names the measurement (the distillate
valve of the column of docs/explanation/acceptance-column.md at 100 % with the feed beyond
its capacity: FAILURE named ``DrumLevel`` on 97 % of the samples, the valve on 2 %). What an
operator acts on is the valve: ``dist_valve at its limit (100): loop DrumLevel cannot hold
its set-point``.

The rule (:class:`Saturation`): a loop test (``set_point`` and ``actuator`` in the unit file,
statistic ``level``) whose symptom is on while its actuator reads within :data:`AT_LIMIT` of
its span from an edge of the span of its own test's output (or past it) — the tag's metadata
range where the historian gives one, else the range the build window saw padded 2 % a side,
so a valve at its window's own extreme is at its limit — names the actuator first (the
ranking's first tag, the isolated fault), held to the end of the alarm episode as the other
names are (:class:`~.unitloops.EpisodeHold`).
Detection is unchanged: only the names and the reason are.

It gives way (issue 34 item 4, branch ``i34-naming``) on a sample on which a test of another
tag is on — not the loop's own test, nor its measurement's or its actuator's other tests —
while the actuator's own test (its position predicted from the process conditions, learned
on the fault-free window) is quiet: the fault's own test carries the alarm, and a valve at a
limit its process conditions put it at is not news. There the first tag and the isolated
fault are left as they are and the actuator is listed after the first tag, with its reason.
The pasteuriser's balance-tank inlet valve (docs/explanation/acceptance-pasteuriser.md, built
``--running MODE=1``), shut at every production start while its level loop's test fires, was
named first on 73–91 % of every fault's alarm samples.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from diag_plugin.diagnose.unitloops import PINNED

#: an actuator reads "at its limit" within this share of its span from an edge (or past it):
#: the pinned-valve rule's share (:data:`~.unitloops.PINNED`), so one valve is at its edge
#: for both rules. A span the build took from its window is the window's range padded 2 % a
#: side (``selection/spans.variable_for``): 2 / 104 = 1.92 % of the span, so a valve at the
#: extreme its window saw (the tank's level valve clipped at 100 %, span -1.99 ... 101.6: 1.5 %
#: from the edge) is at its limit. At 0.5 % (until 2026-12-05) the rule fired only where a
#: valve passed its window's range or the tags CSV gave its ``lo``/``hi``: a valve that had
#: reached its limit while the unit learned was never named at it.
AT_LIMIT = PINNED


@dataclass
class _Loop:
    test: int  # the loop test's column
    pv: str  # the measurement (plant name), for the sentence
    actuator: str  # plant name
    model_tag: str  # the actuator's name in the models (what Columns reads)
    lo: float
    hi: float
    #: the columns of the loop's own tests (its measurement's and its actuator's): any other
    #: test on is a test of another tag, the fault's own
    own: tuple[int, ...] = ()
    #: the columns of the actuator's own tests (its position predicted from the process)
    act: tuple[int, ...] = ()


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


def actuator_span(unit, act: str) -> tuple[str, float, float] | None:
    """A loop's actuator ``act`` (its plant name) as the unit's models read it, with its
    span: the output range of the first of the unit's tests that models it (the metadata
    range, else the build window's); None where no test models it."""
    model_tag = next((k for k, v in unit.file.tags.items() if v == act), act)
    for t in unit.tests:
        m = unit.models[t]
        if m.output.split("[")[0] == model_tag and m.out_range is not None:
            return model_tag, *map(float, m.out_range)
    return None


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
        outs = [unit.models[u].output.split("[")[0] for u in unit.tests]
        loops = []
        for j, t in enumerate(unit.tests):
            spec = unit.file.test(t)
            act = getattr(spec, "actuator", None)
            if not act or not getattr(spec, "set_point", None):
                continue
            if getattr(spec, "statistic", "level") != "level":
                continue
            span = actuator_span(unit, act)
            if span is None:
                continue
            model_tag, lo, hi = span
            pv = unit.models[t].output.split("[")[0]
            own = tuple(i for i, o in enumerate(outs) if o in (pv, model_tag))
            mine = tuple(i for i, o in enumerate(outs) if o == model_tag)
            loops.append(_Loop(j, mapping.get(pv, pv), act, model_tag, lo, hi, own, mine))
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
        file's order where two are), the sentence, and whether it is named first: ``on`` the
        symptoms on (samples × tests), ``active`` the unit's alarm. Advances the carried state.

        An actuator named gives way (``first`` False: listed after the first tag, with its
        reason) on a sample on which a test of another tag is on — not the loop's own test,
        its measurement's or its actuator's — while the actuator's own test (its position
        predicted from the process conditions) is quiet: a valve at a limit its process
        conditions put it at (the balance tank's inlet valve, shut at every production start)
        is not the news that another tag's test is (the pasteuriser's pass: the at-limit name
        first on 73–91 % of every fault's alarm samples)."""
        n = len(active)
        which = np.full(n, -1, np.int64)
        first = np.zeros(n, bool)
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
            others = np.ones(on.shape[1], bool)
            others[list(lp.own)] = False
            other_on = on[:, others].any(axis=1) if others.any() else np.zeros(n, bool)
            act_on = on[:, list(lp.act)].any(axis=1) if lp.act else np.zeros(n, bool)
            first[free] = (~other_on | act_on)[free]
            for i in np.flatnonzero(free):
                text[i] = _sentence(lp, float(v[i]), bool(at[i]) or not np.isfinite(v[i]), tol)
            if n:
                self.named[k] = bool(named[-1])
        if n:
            self.active = bool(active[-1])
        return which, text, first

    def name_first(self, which: np.ndarray, text: np.ndarray, faults, top, first=None) -> None:
        """In place: on the samples ``which`` names, the actuator as the fault and first in
        the ranking (``top``: the columns of :func:`~.unittags.top_columns_at`) where there is
        one, with its own share (else the first tag's); where it gives way (``first`` False)
        the fault and the first tag are left as they are and the actuator is listed second,
        with its own share (else the share of the tag it displaces). The sentence keeps the
        last known value over a sample the actuator has none (held)."""
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
            lead = first is None or bool(first[i])
            if lead:
                faults[i] = act
            if top is None:
                continue
            names = [top[f"top{j}"][i] for j in range(1, 4) if f"top{j}" in top]
            shares = [top[f"share{j}"][i] for j in range(1, 4) if f"share{j}" in top]
            if not any(names):  # no ranking here (the combined test unknown): none invented
                continue
            own = next((s for a, s in zip(names, shares, strict=True) if a == act), None)
            if not lead and own is not None:  # ranked already: left where the shares put it
                continue
            pairs = [(a, s) for a, s in zip(names, shares, strict=True) if a and a != act]
            at = 0 if lead or not pairs else 1
            fill = (
                shares[at]
                if at < len(shares) and np.isfinite(shares[at])
                else pairs[-1][1]
                if pairs
                else np.nan
            )
            pairs.insert(at, (act, own if own is not None else fill))
            pairs = pairs[: len(names)]
            for j, (a, s) in enumerate(pairs, start=1):
                top[f"top{j}"][i] = a
                top[f"share{j}"][i] = s
