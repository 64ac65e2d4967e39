"""An operator's set-point step is not an alarm (issue 34, items 5 and 6; ISA-18.2's
state-based alarming after a set-point change).

A loop's set-point stepped by an operator moves its measurement, its controller output and
every relation downstream for the loop's settling time; a unit that never learned that
transient raises an alarm for it. The **settle guard** suppresses that alarm, and only the
alarm: the unit's judgement goes on.

- **A step** of a loop's set-point (a test with ``set_point = "TAG"``, its residual the loop's
  control error, ``statistic = "level"``, the tag read by the unit's models): the set-point
  held (two consecutive samples equal, within :data:`HELD_SHARE` of the band), then within
  :data:`MOVE_SAMPLES` samples (a historian's mean may split a step over two) more than the
  loop test's band away from that held value (the band: the smaller of the test's thresholds,
  in % of its span, in the set-point's units), and held again there (when it is confirmed).
  A ramp (the chemical plant's production rate, an hour long) and a cascade set-point (the
  output of an outer controller, which moves every sample) are never steps: a fault that
  moves a cascade set-point alarms as before.
- **A settle** opens at the step, unless the unit was in alarm within the quiet time (below)
  before it (a fault in progress is not hidden). While it is open, a sample the unit would
  raise as an alarm (``detected`` after the unit's off-delay) becomes CHECK_FUNCTION, its
  faults none, its ``why`` ``LVL_TGT 0 → -20 at 2026-03-07T10:15Z: loop DRUM_LVL settling``;
  from the first such sample on, every sample of the settle is (latched: no flicker). The
  other samples are as without the guard (NORMAL stays NORMAL). A step's alarm must begin
  within ``settle_max_s`` less the quiet time (the build's 2 × the median settling time; at
  least the on-delay) of the step, else the settle closes unused.
- **It ends** when the loop test's residual has been inside its thresholds with no test (nor
  the combined test) on for the quiet time — the longest history a test reads (its model's
  longest lag; a spread test's window), plus the residual filter's delay (its step response
  to 95 %: :func:`filter_samples`), plus the on-delay — and the unit's alarm, held by its
  off-delay (``off_delay_s``, 240 s: longer than a short quiet time at 1 s), has dropped —
  or ``settle_max_s`` after the sample the set-point left its hold (the unit file's
  ``[evaluation]``, written by ``diag unit build`` from the window's own steps,
  :func:`~diag_plugin.unitbuild.loops.settle_max`), whichever is first. A fault that
  persists past it is the unit's alarm again (FAILURE). A step of the same tag during an open
  settle keeps its end and its age, whether or not it has suppressed anything: one event
  (before, an open settle that had suppressed nothing restarted, so a start's age hung on
  whether it had alarmed yet, and the envelope learned on the window could not know it).
  ``settle_max_s = 0`` (unit files written before it): no guard.

- **A hand valve's move** (its ``[manual]`` span, :mod:`~diag_plugin.diagnose.manual`;
  ``manual_settle_max_s`` > 0): the same step rule on the valve's reading (held within its
  noise margin; a jump beyond :data:`HAND_BAND_SHARE` of its learned span) **to a position
  within that span** opens a settle as a set-point step does, its why ``HAND_VALVE 49 → 43
  at …: settling after a hand valve's move``; it ends when no test is on for the quiet
  time and its alarm dropped (the valve has no loop error to wait for), or
  ``manual_settle_max_s`` after the move
  (:func:`~diag_plugin.unitbuild.loops.manual_settle_max`). Outside the span the manual
  guard answers.

- **A state change** (a discrete state the build listed in ``[build] states``, read by a model:
  a pump's or a motor's run feedback, or one of ``[states]`` no model reads, a plant's mode;
  ``state_settle_max_s`` > 0): the same step rule on the
  state's reading (held, a jump beyond :data:`STATE_BAND_SHARE` of the range the models
  learned it in, held again) opens a settle as a hand valve's move does, its why ``PMP3_ON 0
  → 1 at …: settling after a state change``; it ends when no test is on for the quiet time
  and its alarm dropped — the quiet time the unit file's ``[envelope.state] quiet_s`` says
  where the build learned one from the window's own changes (the longest pause of their
  symptoms before one came back, widened: :func:`~diag_plugin.unitbuild.loops.start_quiet`;
  the pasteuriser at 10 s: 50 s for 760 s) —, or ``state_settle_max_s`` after the change
  (:func:`~diag_plugin.unitbuild.loops.state_settle_max`): ISA-18.2's state-based alarming
  (a pump's start is not an alarm; a fault that outlasts the settle is). With the unit
  file's ``[envelope.state]`` (:mod:`~.envelope`, learned by the build from the window's own
  changes) a test beyond what those changes showed at the settle's age, for the on-delay,
  ends the settle at once: a fault present at the change is raised, its why ``I1 beyond
  what 8 state changes showed 12 min after a change (…)``. A piece of
  equipment's run tag (``[equipment]``, :mod:`~.equipment`) is no such state: its start
  holds its own tests off for ``state_settle_max_s``, the rest of the unit answers on.

- **A start's steps are one event** (issue 34, items 3 and 6): a production start steps the
  rate's set-point, the mode and, minutes later, the diversion valve. Tags stepping at one
  sample open the settle of the one whose ``*_max_s`` is longest; a tag stepping inside an
  open settle whose own settle would outlast the open one's rest carries it on (from its
  step, to its bound; its why names it and when the settle opened). The pasteuriser at 1 s on
  one day: the rate's set-point step's 873 s ended while the start's transient was still in
  a spread test's window, on 10 of its 12 fault-free episodes; the state change's bound is
  3,052 s. It still ends as soon as the unit is quiet. A step inside the open settle, of its
  own tag or another, is part of the same event: the settle's **age** (what its envelope is
  judged at, and what the build counts its changes by, :func:`settle_replay`) goes on from the
  event's first step; only its bound is counted from a carrying step. Before, the carrying
  step aged the settle from 0 again: the pasteuriser's every start (its run's, then its
  diversion valve's 2 min later) was two changes, 34 for 17 starts.

The replay (:meth:`~diag_plugin.diagnose.unit.Unit.evaluate`), the live loop's stacked path
(:class:`~diag_plugin.diagnose.plant.Plant`) and a restart (the carried state) give the same
statuses: one compiled kernel, row by row, its state carried across pieces.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
import pandas as pd

from diag_plugin.diagnose.envelope import STATE, Envelope, beyond, says
from diag_plugin.diagnose.equipment import PieceReplay
from diag_plugin.regressors import parse_specs

#: samples a step may take to leave its held value by more than the band (a historian's
#: mean over a period holds part of the old and part of the new value)
MOVE_SAMPLES = 2
#: the set-point counts as held when two samples differ by at most this share of the band
HELD_SHARE = 1e-3
#: samples since the unit's last alarm, for a unit that has never been in alarm
NEVER = 1 << 40
#: a hand valve's move is a step beyond this share of its learned span (at least twice its
#: noise margin): the line's 40–47 % valve, 0.07 %; the heater's 29.7–49.0 %, 0.6 % (its
#: margin's 0.3 % twice)
HAND_BAND_SHARE = 0.01
#: a state's change is a step beyond this share of the range its models learned it in (the
#: two states 0 and 1 learned as 0–1, or a rule grid's −0.25–1.25: a change is 1, the band
#: 0.25 or 0.375; a historian's mean of a minute a pump started in is a move, held on the
#: next)
STATE_BAND_SHARE = 0.25


@dataclass(frozen=True)
class SettleLoop:
    """A loop the guard watches: its set-point (model tag), measurement (plant tag, for the
    why), loop test (position among the unit's tests), thresholds and band in the
    set-point's units. A hand valve (``hand``): ``sp`` its model tag, ``pv`` its plant tag,
    no loop test (``test`` -1), ``held`` the change within which it counts as held (its
    noise margin), and a step only to a position within its learned span ``span``. A
    discrete state (``state``): as a hand valve, its span the range its models learned."""

    sp: str
    pv: str
    test: int
    lo: float
    hi: float
    band: float
    hand: bool = False
    held: float = 0.0
    span: tuple[float, float] = (-math.inf, math.inf)
    state: bool = False

    @property
    def kind(self) -> str:
        """What steps: ``loop`` (a set-point), ``hand`` (a hand valve), ``state``."""
        return "state" if self.state else "hand" if self.hand else "loop"

    @property
    def tol(self) -> float:
        """Two samples this close count as held."""
        return max(self.held, HELD_SHARE * self.band)


def settle_loops(unit: Any) -> list[SettleLoop]:
    """The loops of ``unit`` (a :class:`~diag_plugin.diagnose.unit.Unit`) whose set-point is
    a tag its models read and whose loop test has thresholds."""
    out = []
    read = set(unit.model_tags)
    for j, t in enumerate(unit.file.tests):
        sp = t.set_point
        if not sp or t.statistic != "level" or t.limits is None or sp not in read:
            continue
        try:
            float(sp)
            continue  # a fixed set-point: never steps
        except ValueError:
            pass
        lo, hi = t.limits
        m = unit.models[t.name]
        band = min(abs(lo), abs(hi)) * m.span / 100.0
        out_tag = parse_specs([m.output])[0].tags[0]
        pv = unit.file.tags.get(out_tag, out_tag)
        out.append(SettleLoop(sp, pv, j, float(lo), float(hi), float(band)))
    return out


def hand_valves(unit: Any) -> list[SettleLoop]:
    """The hand valves of ``unit`` (its ``[manual]`` spans, :mod:`~.manual`) its models read,
    as the guard watches them: a move beyond :data:`HAND_BAND_SHARE` of the learned span (at
    least twice the valve's noise margin), held within that margin (or :data:`HELD_SHARE` of
    the band, for a valve read without noise)."""
    out = []
    read = set(unit.model_tags)
    for tag, s in getattr(unit.file, "manual", {}).items():
        if tag not in read:
            continue
        band = max(HAND_BAND_SHARE * (s.max - s.min), 2.0 * s.margin)
        if not band > 0:
            continue  # a valve never moved in the window: no step to tell from noise
        pv = unit.file.tags.get(tag, tag)
        out.append(SettleLoop(tag, pv, -1, 0.0, 0.0, band, True, s.margin, (s.lo, s.hi)))
    return out


def state_tags(unit: Any) -> list[SettleLoop]:
    """The discrete states of ``unit`` (``[build] states``, model tag names) its models read,
    as the guard watches them: a change beyond :data:`STATE_BAND_SHARE` of the range its
    models learned it in (the union over the tests reading it), to a value within it; and
    the ``[states]`` tags no model reads, over the values ``seen`` holds them at
    (:func:`unit_combos`)."""
    from diag_plugin.diagnose.operating import learned_ranges

    read = set(unit.model_tags)
    states = [str(x) for x in (unit.file.build or {}).get("states", []) if str(x) in read]
    combos = unit_combos(unit)
    rc = getattr(unit.file, "running", None)
    out = []
    if rc is not None:  # the run condition (diagnose/running.py): a start is a state change
        lo, hi = min(rc.run, rc.stop), max(rc.run, rc.stop)
        pv = unit.file.tags.get(rc.tag, rc.tag)
        band = STATE_BAND_SHARE * (hi - lo)
        out.append(SettleLoop(rc.tag, pv, -1, 0.0, 0.0, band, span=(lo, hi), state=True))
    if not states and not combos:
        return out
    ranges = learned_ranges(unit.models, unit.tests)
    # a state no model reads, of the [states] table: over the values the table holds it at
    taken = {*states, *([rc.tag] if rc is not None else [])}
    for tag in [*states, *(t for t in combos if t not in taken)]:
        got = [(r.lo, r.hi) for r in ranges if r.tag == tag] or combos.get(tag, [])
        if not got:
            continue  # read only through a derived input: no learned range
        lo, hi = min(a for a, _ in got), max(b for _, b in got)
        band = STATE_BAND_SHARE * min(hi - lo, level_gap(unit, tag))
        if not (np.isfinite(band) and band > 0):
            continue
        pv = unit.file.tags.get(tag, tag)
        out.append(SettleLoop(tag, pv, -1, 0.0, 0.0, band, span=(lo, hi), state=True))
    return out


def unit_combos(unit: Any) -> dict[str, list[tuple[float, float]]]:
    """The unit's ``[states]`` tags (:mod:`~.combos`) no model reads, each with the range of
    the values ``seen`` holds it at (one ``(lo, hi)``). A mode no test reads still moves the
    plant: the pasteuriser at 10 s reads neither its ``MODE`` nor its diversion valve in any
    model (their effects, the flow's set-point, are read), and its CIP's changes opened no
    settle (issue 34 item 5, ``i34-cip``). A state a model reads is watched over the range
    its models learned it in (:func:`state_tags`); a piece of equipment's run tag is not
    (its start holds its own tests, :mod:`~.equipment`); ``{}`` without the table."""
    from diag_plugin.diagnose.combos import parse_combo

    st = getattr(unit.file, "states", None) or {}
    tags = [str(t) for t in st.get("tags", ())]
    rows = [r for r in (parse_combo(c, len(tags)) for c in st.get("seen", ())) if r is not None]
    read = set(unit.model_tags)
    # a piece of equipment's run tag is no such state: its start holds its own tests
    read |= {e.rc.tag for e in getattr(unit.file, "equipment", None) or ()}
    out = {}
    for j, tag in enumerate(tags):
        vals = [r[j] for r in rows]
        if tag not in read and len(set(vals)) > 1:
            out[tag] = [(min(vals), max(vals))]
    return out


def level_gap(unit: Any, tag: str) -> float:
    """The smallest gap between the values ``tag`` held in the combinations of states the
    unit learned (``[states] seen``; inf where it is not listed or held one value). A mode of
    five values (idle 0, production 1, CIP 2-4) learned over 0-4 moves by 1: the band of
    :data:`STATE_BAND_SHARE` of its range (1.0) saw no step between neighbouring values, so a
    production start opened no state settle (issue 34, items 3 and 6); of the gap it is 0.25."""
    from diag_plugin.diagnose.combos import parse_combo

    st = getattr(unit.file, "states", None) or {}
    tags = list(st.get("tags", ()))
    if tag not in tags:
        return math.inf
    j = tags.index(tag)
    rows = (parse_combo(c, len(tags)) for c in st.get("seen", ()))
    vals = np.unique([r[j] for r in rows if r is not None])
    gaps = np.diff(vals)
    return float(gaps.min()) if gaps.size else math.inf


#: a settle's why after a step of a hand valve, a state
SAYS = {"hand": "settling after a hand valve's move", "state": "settling after a state change"}
#: the guard's keys in ``[evaluation]`` and what each watches
WATCHED = (
    ("settle_max_s", settle_loops),
    ("manual_settle_max_s", hand_valves),
    ("state_settle_max_s", state_tags),
)


def settle_guard(
    unit: Any, bounds: Mapping[str, float] | None = None, envelope: bool = True
) -> SettleGuard | None:
    """The guard of ``unit`` from its file (None: ``settle_max_s``, ``manual_settle_max_s``
    and ``state_settle_max_s`` 0, or nothing to watch): its loops at most ``settle_max_s``,
    its hand valves at most ``manual_settle_max_s``, its states at most
    ``state_settle_max_s``. ``bounds``: those keys from elsewhere than ``[evaluation]`` (the
    build's, before it writes them); ``envelope`` False: without the file's
    ``[envelope.state]`` (the guard the envelope is learned under, :func:`settle_ages`)."""
    loops, max_n = [], []
    ev = unit.ev if bounds is None else {**unit.ev, **bounds}
    for key, found in WATCHED:
        max_s = float(ev.get(key, 0.0) or 0.0)
        if max_s <= 0:
            continue
        got = found(unit)
        if key == "state_settle_max_s":  # a piece's start holds its own tests only
            pieces = {e.rc.tag for e in getattr(unit, "equipment", None) or ()}
            got = [lp for lp in got if lp.sp not in pieces]
        loops += got
        max_n += [max(1, math.ceil(max_s / unit.period_s - 1e-9))] * len(got)
    if not loops:
        return None
    env = (getattr(unit.file, "envelope", None) or {}).get(STATE) if envelope else None
    return SettleGuard(loops, max_n, quiet_samples(unit), unit.period_s, unit.ev["on_delay"],
                       None if env is None else (env, unit.tests))  # fmt: skip


def settle_ages(
    unit: Any, frame: pd.DataFrame, bounds: Mapping[str, float] | None = None
) -> np.ndarray:
    """The ages of :func:`settle_replay` alone."""
    return settle_replay(unit, frame, bounds)[0]


def settle_replay(
    unit: Any, frame: pd.DataFrame, bounds: Mapping[str, float] | None = None,
    holds: Sequence[int] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:  # fmt: skip
    """The events a state change's envelope is learned over and judged in, and their ages
    (issue 34, items 5-6): per row of ``frame`` (models' tag names, the run tag beside) the
    age in samples at which the unit's settle guard judges it against ``[envelope.state]``
    (the settle's age, counted as :meth:`SettleGuard.transform` counts it), -1 where no
    state's settle is open. The guard itself replays the window: ``unit`` (``bounds``: the
    settles' bounds, where its ``[evaluation]`` does not hold them yet) evaluated on
    ``frame`` with its guard but no envelope, so every rule of the guard holds as at run
    time — the steps at one sample settling as the longest, a step of the same tag inside
    an open settle keeping its age, another tag's carrying it on, a start after a stop from
    the run tag's hold alone (:meth:`SettleGuard.forget_holds`), no settle opened while the
    unit is in alarm. Before, the build cut the window at every step and counted each
    step's age from itself: a production start whose diversion valve steps three times in
    its first minutes (the pasteuriser at 10 s) was learned as four young changes, judged at
    run time as one older settle, and its transient 7 min after the start alarmed
    (fault-free FAILURE 0 → 3.8-4.3 %). Also per row whether a test or the combined test
    was on (after its on-delay; False where not judged): what the settle's quiet time is
    learned from (:func:`~diag_plugin.unitbuild.loops.start_quiet`). With ``holds`` (per
    piece of equipment its settle's bound in samples), from the same replay, rows × pieces
    the age at which each piece's start settle judges the row (-1: none;
    :func:`~.equipment.piece_ages`, its envelope unread), else None."""
    n = len(frame)
    out = np.full(n, -1, np.int64)
    on = np.zeros(n, bool)
    guard = settle_guard(unit, bounds, envelope=False)
    if guard is None and holds is None:
        return out, on, None
    replay = None if holds is None else PieceReplay(list(holds))
    if guard is not None:
        guard.ages_seen = []
    try:  # the unit's own guard left as it is (the pieces' own, without one: no state)
        unit.reset().evaluate(frame, settle=guard, pieces=replay)
    finally:
        unit.reset()
    eq = None
    if replay is not None:
        eq = np.full((n, len(replay.holds)), -1, np.int64)
        if replay.seen:
            ix = np.concatenate([np.asarray(i) for i, _ in replay.seen])
            at = pd.Index(frame.index).get_indexer(ix)
            got = np.concatenate([a for _, a in replay.seen])
            eq[at[at >= 0]] = got[at >= 0]
    if guard is None or not guard.ages_seen:
        return out, on, eq
    state = np.array([lp.kind == "state" for lp in guard.loops], bool)
    index = np.concatenate([np.asarray(ix) for ix, *_ in guard.ages_seen])
    got = np.concatenate([a for _, a, _ in guard.ages_seen])
    active = np.concatenate([b for *_, b in guard.ages_seen])
    got = np.where((got[:, 0] >= 0) & state[np.maximum(got[:, 1], 0)], got[:, 0], -1)
    at = pd.Index(frame.index).get_indexer(index)
    ok = at >= 0
    out[at[ok]] = got[ok]
    on[at[ok]] = active[ok]
    return out, on, eq


#: the residual filter's delay: samples its step response takes to reach this share of the
#: step (a residual's jump just past a threshold crosses it about then)
FILTER_REACH = 0.95


def filter_samples(wn: float, order: int) -> int:
    """Samples the unit's residual low-pass (Butterworth ``order``, cut-off ``wn`` of Nyquist,
    :class:`~diag_plugin.diagnose.residuals.LowPass`) takes from a residual's step to
    :data:`FILTER_REACH` of it (0: no filter). At 1 min (``wn`` 0.2, order 4) 7 samples;
    at 1 s (0.01) 133."""
    if not wn or wn <= 0:
        return 0
    from diag_plugin.diagnose.butterworth import butter_sos

    # the filter's own design (scipy's butter, the same bits) and sosfilt's recursion
    # (direct form II transposed) on a unit step, in Python until it reaches the share: a
    # unit's load reads this, and neither scipy.signal (~0.9 s of each diag diagnose's
    # start) nor a first numba dispatch (which imports scipy.linalg before the read starts)
    sos = butter_sos(int(order), float(wn))
    z = np.zeros((len(sos), 2))
    for i in range(int(np.ceil(40.0 / wn))):  # well past the rise at any cut-off
        x = 1.0
        for k, (b0, b1, b2, _, a1, a2) in enumerate(sos):
            y = b0 * x + z[k, 0]
            z[k, 0] = b1 * x - a1 * y + z[k, 1]
            z[k, 1] = b2 * x - a2 * y
            x = y
        if x >= FILTER_REACH:
            return i
    return int(np.ceil(40.0 / wn))


def quiet_samples(unit: Any) -> int:
    """Samples a settle needs without a symptom to end: the longest history a test reads
    (its model's longest lag; a spread test's window), plus the residual filter's delay
    (:func:`filter_samples`: a residual that moves at the last sample a test reads is
    filtered up to its threshold that much later), plus the on-delay (at least 1)."""
    return max(1, sum(quiet_parts(unit)))


def quiet_parts(unit: Any) -> tuple[int, int, int]:
    """The quiet time's parts in samples: the longest history a test reads, the residual
    filter's delay, the on-delay."""
    from diag_plugin.diagnose.unitloops import spread_samples

    depth = int(unit.test_depth.max(initial=0))
    if len(unit.spread_cols):
        depth = max(depth, spread_samples(unit.ev["spread_window_s"] or 600.0, unit.period))
    lag = filter_samples(unit.ev["lowpass"], unit.ev["order"])
    return depth, lag, int(unit.ev["on_delay"])


@numba.njit(cache=True, nogil=True)
def _record(steps, k, step, s_from, s_to, i, s_back, again):  # pragma: no cover - numba
    """Row ``k`` of the steps found: the loop, from, to, the row it was confirmed at, the
    samples back it left its hold, and whether it steps inside an open settle (1) or opens
    one (0)."""
    steps[k, 0] = step
    steps[k, 1] = s_from
    steps[k, 2] = s_to
    steps[k, 3] = i
    steps[k, 4] = s_back
    steps[k, 5] = again


@numba.njit(cache=True, nogil=True)
def _settle_kernel(
    sp,
    r,
    lo,
    hi,
    band,
    tol,
    s_lo,
    s_hi,
    active,
    alarm,
    prev,
    anchor,
    run,
    moved,
    g,
    max_n,
    quiet_n,
    begin_n,
    end_n,
    sup,
    sid,
    steps,
    u,
    edges,
    env,
    enveloped,
    over,
    on_n,
    hit,
    after,
    age,
):  # pragma: no cover - numba
    # g: open, elapsed (since the step whose bound holds), quiet, latched, loop, last alarm,
    # samples since the unit's last alarm, an envelope's alarm on, the event's age (since its
    # first step: what the envelope is judged at; int64); row by row, state in place.
    # an envelope (envelope.py) on a loop ``enveloped``: a test beyond it at the settle's age
    # (``u``: samples × tests, threshold units) for ``on_n`` samples ends the settle; ``hit``
    # that test on the row, ``after`` the rows of the alarm it raised
    # sid per row: -1 no settle, -2 the settle carried in, k >= 0 the k-th step of this piece;
    # max_n, begin_n per loop (a hand valve's own); a hand valve's r is 0 (lo = hi = 0)
    n, m = sp.shape
    k = 0
    cur = -2
    keep_age = age.shape[0] > 0  # asked for (settle_ages): else age is (0, 2), never read
    for i in range(n):
        step = -1
        s_from = 0.0
        s_to = 0.0
        s_back = 0
        for j in range(m):
            x = sp[i, j]
            if np.isnan(x):
                continue
            p = prev[j]
            if not np.isnan(p) and abs(x - p) <= tol[j]:
                run[j] += 1
                if run[j] >= 2:  # held again: a step if it left its last hold lately
                    if (
                        not np.isnan(anchor[j])
                        and 0 < moved[j] <= MOVE_SAMPLES
                        and abs(x - anchor[j]) > band[j]
                        and s_lo[j] <= x <= s_hi[j]
                        and (step < 0 or max_n[j] > max_n[step])
                    ):
                        step = j
                        s_from = anchor[j]
                        s_to = x
                        s_back = moved[j]
                    anchor[j] = x
                    moved[j] = 0
            else:
                run[j] = 1
                moved[j] += 1
            prev[j] = x
        if step >= 0 and g[6] >= quiet_n and g[0] == 0:
            g[0] = 1
            g[1] = s_back  # counted from the sample the set-point left its hold
            g[8] = s_back  # the event's age, from the same sample
            g[2] = 0
            g[3] = 0
            g[4] = step
            over[:] = 0
            _record(steps, k, step, s_from, s_to, i, s_back, 0)
            cur = k
            k += 1
        elif step >= 0 and g[0] == 1 and (step == g[4] or max_n[step] > max_n[g[4]] - g[1]):
            # the tag the settle is for steps again (a filter's backwash 1, then
            # filter-to-waste 2, then filtering 0; a start's diversion valve forward, back,
            # forward) without reopening it, latched or not: the settle keeps its end and its
            # age (one event, as the envelope learned it: settle_ages), its why names this
            # latest step.
            # Another tag whose settle outlasts the open one's rest (a production start's
            # diversion valve forward minutes after the rate's step) carries it on: one event,
            # its bound from this step (g[1]), its age (g[8]: the envelope's, the count of
            # changes) still from the event's first step: a consequence of the start is no
            # start of its own (before, the pasteuriser's every start was two changes, the
            # run's and its diversion valve's 2 min later, the second aged from 0)
            if step != g[4]:
                g[1] = s_back
                g[4] = step
            g[2] = 0  # quiet counted from this step: its transient is still to come
            _record(steps, k, step, s_from, s_to, i, s_back, 1)
            cur = k
            k += 1
        if keep_age:
            age[i, 0] = -1
        if g[0] == 1:
            g[1] += 1
            g[8] += 1
            if keep_age:  # the age this row is judged at, and whose (settle_ages)
                age[i, 0] = g[8]
                age[i, 1] = g[4]
            j = g[4]
            if alarm[i] and (g[3] == 1 or g[1] <= begin_n[j]):
                g[3] = 1
            if g[3] == 1:
                sup[i] = True
                sid[i] = cur
            t = beyond(u[i], edges, env, g[8], over, on_n) if enveloped[j] else -1
            if t >= 0:  # a residual far beyond what the window's changes showed: raised
                g[0] = 0
                g[3] = 0
                g[7] = 1
                sup[i] = False
                sid[i] = -1
                hit[i, 0] = t
                hit[i, 1] = g[8]
            e = r[i, j]
            if g[0] == 0:
                pass
            elif (not np.isnan(e)) and lo[j] <= e <= hi[j] and not active[i]:
                g[2] += 1
            else:
                g[2] = 0
            # quiet: and a latched settle's alarm, held by the unit's off-delay, dropped
            # (at 1 s the hold, 240 s, outlasts a short quiet time: 163 samples)
            # (end_n: per loop the quiet time that ends its settle; a state's learned from
            # the window's own starts where its envelope holds one, else quiet_n)
            quiet = g[2] >= end_n[j] and not (g[3] == 1 and alarm[i])
            if quiet or g[1] >= max_n[j] or (g[3] == 0 and g[1] >= begin_n[j]):
                g[0] = 0
                g[3] = 0
        if not alarm[i]:
            g[7] = 0
        after[i] = g[7] == 1
        g[5] = 1 if alarm[i] else 0
        g[6] = 0 if alarm[i] else g[6] + 1
    return k


class SettleGuard:
    """The settle guard of one unit (see module doc); state carried across pieces."""

    def __init__(
        self,
        loops: list[SettleLoop],
        max_n: int | list[int],
        quiet_n: int,
        period_s: float = 1.0,
        on_delay: int = 1,
        envelope: tuple[Envelope, list[str]] | None = None,
    ) -> None:
        self.loops = loops
        self.period = pd.Timedelta(seconds=period_s)
        #: per loop, a settle ends at the latest this many samples after its step
        self.max_n = np.broadcast_to(np.asarray(max_n, np.int64), (len(loops),)).copy()
        self.quiet_n = int(quiet_n)
        self.on_delay = int(on_delay)
        #: a step's alarm begins within this many samples of it: ``max_n`` less the quiet
        #: time (the build's 2 × the median settling time), at least the on-delay
        self.begin_n = np.maximum(max(1, self.on_delay), self.max_n - self.quiet_n)
        self.lo = np.array([lp.lo for lp in loops], float)
        self.hi = np.array([lp.hi for lp in loops], float)
        self.band = np.array([lp.band for lp in loops], float)
        self.tol = np.array([lp.tol for lp in loops], float)
        self.s_lo = np.array([lp.span[0] for lp in loops], float)
        self.s_hi = np.array([lp.span[1] for lp in loops], float)
        #: no loop test (a hand valve, a state): only the unit's tests end its settle
        self.free = np.array([lp.test < 0 for lp in loops], bool)
        self.tests = np.array([max(lp.test, 0) for lp in loops], np.intp)
        #: a state change's envelope (:mod:`~.envelope`; None: the settle as before)
        self.envelope = envelope
        self.enveloped = np.array([lp.state and envelope is not None for lp in loops], bool)
        if envelope is not None:
            self.edges, self.env = envelope[0].arrays(envelope[1], period_s)
        else:
            self.edges, self.env = np.zeros(0, np.int64), np.zeros((0, 0))
        #: per loop the samples without a symptom that end its settle: the quiet time, or
        #: for a state change the one its envelope learned from the window's own starts
        #: (``quiet_s``: the longest lull before a symptom came back, widened; not longer)
        self.end_n = np.full(len(loops), self.quiet_n, np.int64)
        quiet_s = None if envelope is None else envelope[0].quiet_s
        if quiet_s is not None:
            learned = max(1, math.ceil(quiet_s / period_s - 1e-9))
            self.end_n[self.enveloped] = min(self.quiet_n, learned)
        #: a list to collect each piece's (index, per row the settle's age and whose, per
        #: row whether a test or the combined test was on) in, or None (:func:`settle_ages`)
        self.ages_seen: list[tuple[pd.Index, np.ndarray, np.ndarray]] | None = None
        self.reset()

    def reset(self) -> None:
        m = len(self.loops)
        self.prev = np.full(m, np.nan)
        self.anchor = np.full(m, np.nan)
        self.run = np.zeros(m, np.int64)
        self.moved = np.zeros(m, np.int64)
        # open, elapsed, quiet, latched, loop, last alarm, samples since the last alarm, an
        # envelope's alarm on, the event's age
        self.g = np.array([0, 0, 0, 0, 0, 0, NEVER, 0, 0], np.int64)
        self.over = np.zeros(self.env.shape[1], np.int64)  # per test: beyond its envelope
        self.text = ""  # the open settle's why
        self.opened = ""  # when the open settle's step was
        self.broke = ""  # the why of the alarm an envelope raised (while it is on)

    def forget_holds(self, keep: str | None = None) -> None:
        """At a unit's stop (:mod:`~.running`): every set-point's, hand valve's and state's
        held value is let go but the run tag's (``keep``), whose start is the state change
        the next settle is for. Across a stop a set-point moves with the plant (a
        pasteuriser's flow 9 m³/h in one production run, 14 in CIP, 0 idle, 9.7 in the
        next): its value after the start against the one before the stop is no operator's
        step, and a loop's settle in its stead would end at ``settle_max_s``, shorter than
        the start's ``state_settle_max_s`` (issue 34 item 5, acceptance pass 10)."""
        lose = np.array([lp.sp != keep for lp in self.loops], bool)
        self.prev[lose] = np.nan
        self.anchor[lose] = np.nan
        self.run[lose] = 0
        self.moved[lose] = 0

    def transform(
        self,
        index: pd.Index,
        sp: np.ndarray,
        r: np.ndarray,
        active: np.ndarray,
        alarm: np.ndarray,
        u: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Per sample whether its alarm is suppressed, and the why there ('' elsewhere;
        where an envelope ended a settle, its why while the alarm it raised is on).

        ``sp``: samples × loops, each loop's set-point; ``r``: samples × loops, its loop
        test's filtered residual; ``active``: any test or the combined test on (before the
        off-delay); ``alarm``: the unit would raise an alarm (``detected`` after it); ``u``:
        samples × tests, the filtered residuals in units of their thresholds
        (:func:`~.envelope.scaled`; read only with an envelope)."""
        n = len(index)
        sup = np.zeros(n, np.bool_)
        sid = np.full(n, -1, np.int64)
        steps = np.zeros((n, 6))
        hit = np.full((n, 2), -1, np.int64)
        after = np.zeros(n, np.bool_)
        # per row the settle's age and whose, kept only for a caller who collects them
        # (settle_ages; a replay's 2 × 8 bytes a row written and dropped before)
        age = np.full((n if self.ages_seen is not None else 0, 2), -1, np.int64)
        if u is None or self.envelope is None:
            u = np.zeros((n, self.env.shape[1]))
        r = np.asarray(r, float).reshape(n, len(self.loops))
        if self.free.any():  # a hand valve, a state: no loop test, the unit's tests end it
            r = np.where(self.free, 0.0, r)
        k = _settle_kernel(
            np.ascontiguousarray(sp, float).reshape(n, len(self.loops)),
            np.ascontiguousarray(r),
            self.lo, self.hi, self.band, self.tol, self.s_lo, self.s_hi,
            np.asarray(active, np.bool_), np.asarray(alarm, np.bool_),
            self.prev, self.anchor, self.run, self.moved, self.g,
            self.max_n, self.quiet_n, self.begin_n, self.end_n, sup, sid, steps,
            np.ascontiguousarray(u, float), self.edges, self.env, self.enveloped, self.over,
            max(1, self.on_delay), hit, after, age,
        )  # fmt: skip
        if self.ages_seen is not None:
            self.ages_seen.append((index, age, np.asarray(active, np.bool_)))
        broke = self._broke(u, hit, after)
        texts = [self.text]
        for q in range(k):
            lp = self.loops[int(steps[q, 0])]
            # the sample the set-point left its hold (confirmed once held again)
            at = _when(index[int(steps[q, 3])] - int(steps[q, 4]) * self.period)
            what = SAYS.get(lp.kind, f"loop {lp.pv} settling")
            again = ""
            if steps[q, 5]:  # a later step of the same tag inside the open settle
                again = f" (the settle open since {self.opened})" if self.opened else ""
            else:
                self.opened = at
            texts.append(f"{lp.sp if lp.kind == 'loop' else lp.pv} {steps[q, 1]:g} → "
                         f"{steps[q, 2]:g} at {at}: {what}{again}")  # fmt: skip
        if k:
            self.text = texts[-1]
        if not self.g[0]:
            self.text = ""
            self.opened = ""
        why = np.full(n, "", dtype=object)
        rows = np.flatnonzero(sup)
        if rows.size:
            # -2 (the settle carried in): its text as carried, texts[0]; step k: texts[k + 1]
            why[rows] = np.asarray(texts, dtype=object)[np.maximum(sid[rows] + 1, 0)]
        why[after] = broke[after]
        return sup, why

    def _broke(self, u: np.ndarray, hit: np.ndarray, after: np.ndarray) -> np.ndarray:
        """Per sample the why of the alarm an envelope raised: from the row it ended the
        settle on (``hit``: the test and the settle's age there) while that alarm is on
        (``after``), the one carried in before the first; '' elsewhere."""
        out = np.full(len(hit), "", dtype=object)
        text = self.broke
        for i in np.flatnonzero(after):
            t, age = int(hit[i, 0]), int(hit[i, 1])
            if t >= 0:
                env, names = self.envelope
                b = int(np.searchsorted(self.edges, age, side="right")) - 1
                age_s = age * self.period.total_seconds()
                text = says(names[t], env, age_s, float(u[i, t]), float(self.env[b, t]),
                            "state changes", "a change")  # fmt: skip
            out[i] = text
        self.broke = text if len(after) and after[-1] else ""
        return out

    def steps(self, sp: np.ndarray) -> list[tuple[int, float, float, int]]:
        """The set-point steps in ``sp`` (samples × loops) as the guard finds them, from
        rest, its state untouched: (loop, from, to, row) each."""
        g = SettleGuard(self.loops, self.max_n, self.quiet_n, self.period.total_seconds())
        n = len(sp)
        m = len(self.loops)
        out = np.zeros((n, 6))
        sup, sid = np.zeros(n, np.bool_), np.full(n, -1, np.int64)
        no = np.zeros(n, np.bool_)
        one = np.ones(m, np.int64)
        found = []
        # one settle at a time: each step opens one (quiet_n = 1 closes it at once)
        k = _settle_kernel(
            np.ascontiguousarray(sp, float).reshape(n, m), np.zeros((n, m)), g.lo, g.hi,
            g.band, g.tol, g.s_lo, g.s_hi, no, no, g.prev, g.anchor, g.run, g.moved, g.g,
            one, 1, one, one, sup, sid, out, np.zeros((n, 0)), g.edges, g.env, g.enveloped,
            g.over, 1, np.full((n, 2), -1, np.int64), np.zeros(n, np.bool_),
            np.zeros((0, 2), np.int64),
        )  # fmt: skip
        for q in range(k):
            if out[q, 5]:
                continue  # a step inside an open settle (none here: nothing latches)
            row = int(out[q, 3]) - int(out[q, 4])  # where it left its hold
            found.append((int(out[q, 0]), float(out[q, 1]), float(out[q, 2]), row))
        return found

    def openings(self, sp: np.ndarray) -> np.ndarray:
        """Per sample of ``sp`` (samples × loops, the piece :meth:`transform` reads next)
        the bound in samples of a settle a step opens there (``max_n`` less the samples it
        took to leave its hold; 0 elsewhere), every step found, the held values carried (a
        guard of its own, not one that :meth:`transform` reads): what the oscillation hold
        reads as a known transient (:class:`~diag_plugin.diagnose.unitloops.OscillationHold`,
        issue 34 H11)."""
        n, m = len(sp), len(self.loops)
        out = np.zeros(n, np.int64)
        if not n:
            return out
        rows = np.zeros((n, 6))
        sup, sid = np.zeros(n, np.bool_), np.full(n, -1, np.int64)
        no = np.zeros(n, np.bool_)
        one = np.ones(m, np.int64)
        g = np.array([0, 0, 0, 0, 0, 0, NEVER, 0, 0], np.int64)
        # each step opens a settle that closes at once (quiet_n = max_n = 1): every step
        # found; no envelope read (none of the loops enveloped, its counts a copy)
        k = _settle_kernel(
            np.ascontiguousarray(sp, float).reshape(n, m), np.zeros((n, m)), self.lo, self.hi,
            self.band, self.tol, self.s_lo, self.s_hi, no, no, self.prev, self.anchor,
            self.run, self.moved, g, one, 1, one, one, sup, sid, rows, np.zeros((n, 0)),
            self.edges, self.env, np.zeros_like(self.enveloped), np.zeros_like(self.over), 1,
            np.full((n, 2), -1, np.int64), np.zeros(n, np.bool_), np.zeros((0, 2), np.int64),
        )  # fmt: skip
        for q in range(k):
            i, j = int(rows[q, 3]), int(rows[q, 0])
            out[i] = max(out[i], int(self.max_n[j]) - int(rows[q, 4]), 1)
        return out

    def to_state(self) -> dict[str, Any]:
        def f(a):
            return [None if np.isnan(v) else float(v) for v in a]

        return {
            "prev": f(self.prev),
            "anchor": f(self.anchor),
            "run": self.run.tolist(),
            "moved": self.moved.tolist(),
            "g": self.g.tolist(),
            "text": self.text,
            "opened": self.opened,
            "over": self.over.tolist(),
            "broke": self.broke,
        }

    def load_state(self, state: dict[str, Any]) -> None:
        def f(v):
            return np.array([np.nan if x is None else x for x in v], float)

        self.prev, self.anchor = f(state["prev"]), f(state["anchor"])
        self.run = np.asarray(state["run"], np.int64)
        self.moved = np.asarray(state["moved"], np.int64)
        g = np.asarray(state["g"], np.int64)
        # states saved before: 7 long (no envelope's alarm), 8 (the event's age: its
        # bound's elapsed, as it was counted then)
        self.g = np.r_[g, np.zeros(max(0, 8 - g.size), np.int64), g[1:2]][:9]
        self.text = str(state["text"])
        over = state.get("over")  # states saved before the envelope: none beyond it
        if over is not None and len(over) == self.over.size:
            self.over = np.asarray(over, np.int64)
        self.broke = str(state.get("broke", ""))
        self.opened = str(state.get("opened", ""))  # states saved before it: none


def _when(ts: Any) -> str:
    """A step's time as the why gives it: ``2026-03-07T10:15Z`` (seconds when not 0)."""
    t = pd.Timestamp(ts)
    z = ""
    if t.tzinfo is not None:
        t, z = t.tz_convert("UTC"), "Z"
    fmt = "%Y-%m-%dT%H:%M" if t.second == 0 else "%Y-%m-%dT%H:%M:%S"
    return t.strftime(fmt) + z


def apply(status: np.ndarray, faults: np.ndarray, sup: np.ndarray) -> None:
    """The suppressed samples' status CHECK_FUNCTION and faults none, in place."""
    from diag_plugin.status import NE107

    status[sup] = NE107.CHECK_FUNCTION
    faults[sup] = ""


def prepend(why: np.ndarray, sup: np.ndarray, text: np.ndarray) -> np.ndarray:
    """``why`` with the settle's text first on the suppressed samples."""
    out = np.asarray(why, dtype=object).copy()
    for i in np.flatnonzero(sup):
        out[i] = f"{text[i]}; {out[i]}" if out[i] else text[i]
    return out
