"""Control loops declared by the user (issue 34, item 4): ``diag unit build --loop PV=SP:OUT``
and the ``loop`` / ``role`` columns of a tags CSV.

A loop whose names follow no convention (``FEED_FLOW`` held at ``FEED_TARGET`` by valve
``V101``) cannot be found from the names; :func:`tracked_set_point` still finds the set-point a
measurement follows, but not which output drives it. Declared, the build knows all three:

- the measurement's test is the loop's own relation (its control error), with the set-point
  and the actuator written in the unit file (``set_point``, ``actuator``);
- a second test judges the **spread** of that error (``statistic = "spread"``): a sticking
  valve makes the loop cycle, its error's level stays at zero and its spread grows; that test
  names the actuator;
- the set-point is never tested nor a tag at fault (an operator's entry);
- the actuator's own test (every controller output that varies is tested) predicts the valve
  position from what drives it — the set-point, load, feed, other loops' outputs — but never
  from the measurement its loop holds (which follows the set-point, not the valve).

In a tags CSV (the file ``diag import --tags`` reads, and checks as the build does:
:mod:`historian.tagroles`), rows sharing a ``loop`` name form one loop, each with a ``role``:
``pv`` (or ``sensor``: the measurement the loop holds), ``sp`` (its set-point), ``out`` (or
``actuator``: the controller output or valve position). A loop needs a ``pv`` and an ``sp``;
``out`` is optional.

**A fixed set-point** (one that is not a tag, as the Tennessee Eastman reactor temperature's
120.4 °C): ``--loop XMEAS9=120.4:XMV10``, or in the tags CSV a number in the ``set_point``
column of the loop's ``pv`` row (then no ``sp`` row). The loop's test is then the measurement
at that number plus the loop's steady offset (``track`` on ``const(120.4)[k]``): its residual is
the control error, as for a set-point tag.

**A hand valve** (issue 34, item 5): a tag an operator sets by hand (a manual drain valve, a
blowdown valve moved twice a day) is the operator's choice, not a process variable, and its
next position is a new operating point, not a fault. Declared with ``--manual TAG`` or the
role ``manual`` in a tags CSV (a row without a ``loop``), it is never a test, stays a
candidate input, and the unit records the span the window saw it in
(:mod:`diag_plugin.diagnose.manual`).

**A measured disturbance** (issue 34, item 4): a tag the process does not set but is set by —
the weather, an upstream unit's flow, a plant's influent — is a cause, not an effect: a test
of it is a relation the wrong way round (the water temperature "predicted" from the blower's
power, the influent from an air valve), and alarms when the disturbance does what it does
(a storm). Declared with ``--disturbance TAG`` or the role ``disturbance`` (or ``driver``,
``exogenous``) in a tags CSV (a row without a ``loop``), it is never a test and stays a
candidate input; where it leaves what a test learned, that test answers as for any input
(:mod:`diag_plugin.diagnose.operating`). A row without a loop whose role is none of
``manual``, these, or ``running`` (below) is refused as ``file:line``.

**A run condition** (issue 34, item 6; ISA-18.2's state-based alarming): a plant that stops —
an air-handling unit off every night, a pump on standby, a compressor between batches — is not
judged while it is stopped (a loop switched off with its plant is no loop that cannot hold its
set-point). Declared with ``--running TAG`` (the unit runs where the two-valued ``TAG`` is at
its higher value) or ``--running TAG=VALUE`` (where it equals ``VALUE``), or the role
``running`` in a tags CSV (a row without a loop; a ``set_point`` cell is not read for it: the
higher value), the build learns only from the rows where the unit runs (the stopped rows are
as an outage) and the unit judges nothing while it is stopped
(:mod:`diag_plugin.diagnose.running`).

**A piece of equipment** (issue 34, item 5: a chiller of two, a heat-recovery wheel): its own
run condition and the tags that belong to it (:mod:`diag_plugin.diagnose.equipment`).
Declared with ``--running [NAME:]TAG[=VALUE]:TAG1,TAG2,…`` or, in a tags CSV, an
``equipment`` column naming the piece each tag belongs to: the piece's row of role
``running`` is its run tag (exactly one per piece; it runs at the tag's higher value), its
other rows (a loop's, a plain tag's) its tags. A ``running`` row without an ``equipment`` cell
is the unit's own run condition.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

# the declarations of a tags CSV and of the flags: one reader and one set of checks for
# diag unit build --loops-from and diag import --tags (historian/tagroles.py)
from historian.errors import UserError
from historian.tagroles import (  # noqa: F401 - re-exported: the build's names
    Declared,
    Disturbance,
    Loop,
    Manual,
    Running,
    declared_in_tags_csv,
    disturbances_from_tags_csv,
    equipment_from_tags_csv,
    fixed_value,
    loops_from_tags_csv,
    manual_from_tags_csv,
    parse_loop,
    parse_running,
    running_from_tags_csv,
    states_from_tags_csv,
)


def checked_declared(
    declared: Iterable[Manual | Disturbance], columns: Sequence[str], loops: Iterable[Loop] = ()
) -> list[str]:
    """The tags of declared hand valves and disturbances, each in ``columns``, in no loop,
    and declared one kind only, once each; a problem names the tag and where it was declared."""
    have = set(columns)
    parts = {t: lp for lp in loops for t in (lp.pv, lp.sp, lp.out) if t}
    kinds: dict[str, type] = {}
    out: list[str] = []
    for m in declared:
        what = "hand valve" if isinstance(m, Manual) else "disturbance"
        role = "manual" if isinstance(m, Manual) else "disturbance"
        if m.tag not in have:
            raise UserError(f"{m.where}: {what} {m.tag} ({role}) is not in the data")
        if m.tag in parts:
            raise UserError(
                f"{m.where}: {what} {m.tag} ({role}) is a tag of loop {parts[m.tag]}: "
                "declare it one or the other"
            )
        if kinds.setdefault(m.tag, type(m)) is not type(m):
            raise UserError(
                f"{m.where}: {m.tag} is declared a hand valve and a measured disturbance: "
                "declare it one or the other"
            )
        if m.tag not in out:
            out.append(m.tag)
    return out


def checked_manual(
    manual: Iterable[Manual], columns: Sequence[str], loops: Iterable[Loop] = ()
) -> list[str]:
    """The hand valves' tags, each in ``columns`` and in no loop, once each; a problem names
    the tag and where it was declared (:func:`checked_declared`)."""
    return checked_declared(manual, columns, loops)


def checked_loops(loops: Iterable[Loop], columns: Sequence[str]) -> list[Loop]:
    """``loops`` with every tag in ``columns`` and no measurement declared twice."""
    have = set(columns)
    seen: dict[str, Loop] = {}
    out = []
    for lp in loops:
        sp = None if lp.fixed is not None else lp.sp
        unknown = [t for t in (lp.pv, sp, lp.out) if t and t not in have]
        if unknown:
            raise UserError(
                f"{lp.where(unknown[0])}: loop {lp}: tag(s) {', '.join(unknown)} not in the data"
            )
        if lp.pv in seen and seen[lp.pv] != lp:
            raise UserError(f"loop {lp}: {lp.pv} is already the measurement of loop {seen[lp.pv]}")
        if lp.pv not in seen:
            seen[lp.pv] = lp
            out.append(lp)
    return out


#: a step has settled once its loop's error stays within this share of it
SETTLE_BAND = 0.05
#: settle_max_s: this many times the median settling time of the window's own steps
SETTLE_FACTOR = 2.0
#: without a step in the window: this many times the settle's quiet time (the longest lag
#: the models read, the residual filter's delay, the on-delay)
SETTLE_FALLBACK = 4.0
#: state_settle_max_s: this quantile of the window's own state changes' settling times (a
#: change that did not settle before the next one censored, :func:`km_quantile`), an observed
#: time (issue 34, items 5/6: a start's settle ends when its transient is over, so a fault
#: that outlasts it is raised)
STATE_SETTLE_QUANTILE = 0.9


def settle_bounds(unit, frame, residuals=None) -> list[tuple[str, str, float, str]]:
    """The guard's three bounds for a built unit from its window ``frame``, in one pass:
    ``(key, the [build] note's name, value, what it rests on)`` for ``settle_max_s``
    (:func:`settle_max`), ``manual_settle_max_s`` (:func:`manual_settle_max`) and
    ``state_settle_max_s`` (:func:`state_settle_max`). The window's steps are found once for
    all kinds, and its residuals replayed at most once (only where a hand valve or a state
    stepped), as each function alone would find them: the same values and notes."""
    from diag_plugin.diagnose.settle import hand_valves, settle_loops, state_tags

    steps, quiet = _window_steps(unit, frame)
    residuals = residuals or Replay(unit, frame)
    loop = _loop_settle(unit, frame, steps, quiet) if settle_loops(unit) else (0.0, "")
    if loop[1]:
        loop = (loop[0], loop[1] + _under_band(frame, settle_loops(unit), quiet))
    out = [("settle_max_s", "settle", *loop)]
    for key, says, kind, found in (
        ("manual_settle_max_s", "manual_settle", "hand", hand_valves),
        ("state_settle_max_s", "state_settle", "state", state_tags),
    ):
        value = _free_settle(unit, kind, steps, quiet, residuals) if found(unit) else (0.0, "")
        out.append((key, says, *value))
    return out


def piece_starts(rc, values):
    """Per sample whether a piece runs (its run condition ``rc`` on the run tag's ``values``;
    a missing value counts as running, as judged) and the samples it starts on: running and
    known, the sample before known and stopped. A start seen only across missing values (a
    historian's gap, the join of ``diag unit accept``'s windows) is of unknown age and not
    one of the window's starts: counted, it was one more fault-free start of the envelope
    (:func:`settle_envelopes`; the twin chillers' accept counted 14 where B started 13
    times, the NaN rows between the two windows a start of 101 rows)."""
    import numpy as np

    v = np.asarray(values, float)
    runs = rc.runs(v)
    known = np.isfinite(v)
    before = np.r_[False, known[:-1] & ~runs[:-1]]
    return runs, np.flatnonzero(runs & known & before)


def piece_settle_bounds(unit, frame, residuals=None) -> list[tuple[str, float | None, str]]:
    """Per piece of equipment (``[equipment]``, :mod:`diag_plugin.diagnose.equipment`) the
    bound of its start's settle, measured on the window ``frame`` (models' tag names, its
    run tag among them) from its own starts on its own tests, as
    :func:`state_settle_max` measures a state's: each start settled from the sample from
    which every one of its tests' residuals (less its median) is back within
    :data:`SETTLE_BAND` of its excursion after the start (its noise where wider) for the
    quiet time, before the piece stops again; the bound the :data:`STATE_SETTLE_QUANTILE`
    quantile of those times plus the quiet time (:func:`_quantile_and_how`). ``(name,
    settle_max_s, what it rests on)`` each; ``settle_max_s`` None where no start moved its
    tests or fewer than half settled (the unit's bound kept)."""

    from diag_plugin.diagnose.settle import quiet_samples

    out: list[tuple[str, float | None, str]] = []
    eqs = getattr(unit, "equipment", None) or []
    if not eqs:
        return out
    residuals = residuals or Replay(unit, frame)
    quiet = quiet_samples(unit)
    for e, cols in zip(eqs, unit.equipment_tests, strict=True):
        if not cols.size or e.rc.tag not in frame.columns:
            continue
        starts, changes = _piece_changes(e.rc, frame[e.rc.tag].to_numpy(float))
        times, moved = _piece_times(unit, residuals, cols, changes, quiet)
        key = f"[equipment.{e.name}] settle_max_s"
        if not times or 2 * len(times) < moved:
            how = (f"{key} not written: {len(times)} of {e.name}'s {moved} start(s) that "
                   f"moved its tests settled (of {len(starts)} in the window); the unit's "
                   "bound kept")  # fmt: skip
            out.append((e.name, None, how))
            continue
        value, how = _quantile_and_how(key, f"{e.name} start", times, moved, unit)
        out.append((e.name, value, how))
    return out


def settle_max(unit, frame) -> tuple[float, str]:
    """``settle_max_s`` for a built unit (:mod:`diag_plugin.diagnose.settle`) from its window
    ``frame``, and what it rests on, in words.

    Each step of a loop's set-point the window holds (found as the guard finds them) has
    settled from the sample on which the loop's control error ``PV − SP`` (less its median
    over the window, the loop's steady offset) is back within :data:`SETTLE_BAND` of the
    step (the classic settling time's band; the error's own noise, 3 robust standard
    deviations, where that is wider) and stays there for the guard's quiet time (the
    longest history a test reads — its lags, a spread test's window —, the residual filter's
    delay and the on-delay); a
    step the window ends (or the next step comes) before that is not counted.
    ``settle_max_s`` is :data:`SETTLE_FACTOR` × the median of those settling times plus the
    quiet time (the guard ends a settle only after it); with none, :data:`SETTLE_FALLBACK` ×
    the quiet time. None of the unit's loops with a set-point tag: 0 (no guard)."""
    return settle_bounds(unit, frame)[0][2:]


def _loop_settle(unit, frame, steps: list, quiet: int) -> tuple[float, str]:
    """:func:`settle_max` on the window's ``steps`` (:func:`_window_steps`)."""
    import numpy as np

    from diag_plugin.regressors import parse_specs

    times: list[float] = []
    judged = 0  # steps whose settling was looked for (settled or not)
    for lp, a, b, i, end in steps:
        if lp.kind != "loop":
            continue
        out = parse_specs([unit.models[unit.tests[lp.test]].output])[0].tags[0]
        if out not in frame.columns:
            continue
        judged += 1
        e = frame[out].to_numpy(float) - frame[lp.sp].to_numpy(float)
        e = e - np.nanmedian(e)
        # settled: within 5 % of the step (the classic settling band), or the error's
        # own noise (3 robust sd) where that is wider
        tol = max(SETTLE_BAND * abs(b - a), 3 * 1.4826 * float(np.nanmedian(np.abs(e))))
        at = _settled(np.abs(e) <= tol, i, end, quiet)
        if at is not None:
            times.append(at * unit.period_s)
    return _max_and_how("settle_max_s", "set-point step", times, judged, unit)


def manual_settle_max(unit, frame) -> tuple[float, str]:
    """``manual_settle_max_s`` for a built unit with a hand valve
    (:mod:`diag_plugin.diagnose.settle`, :mod:`~diag_plugin.diagnose.manual`) from its
    window ``frame``, and what it rests on, in words: :func:`settle_max`'s rule on the
    window's own moves of its hand valves (found as the guard finds them), each move settled
    from the sample from which **every** test's residual (less its median over the window)
    is back within :data:`SETTLE_BAND` of its largest excursion before the next step (its own
    noise, 3 robust sd, where that is wider) for the quiet time — every test, not only those
    reading the valve: a hand valve moves what lies downstream of it (the line's outlet flow,
    whose test reads neither the valve nor the level) as much as what reads it. No hand
    valve the guard watches: 0."""
    return settle_bounds(unit, frame)[1][2:]


def state_settle_max(unit, frame) -> tuple[float, str]:
    """``state_settle_max_s`` for a built unit with a discrete state its models read (a
    pump's run feedback, ``[build] states``; :mod:`diag_plugin.diagnose.settle`) from its
    window ``frame``, and what it rests on, in words: :func:`manual_settle_max`'s settling
    time on the window's own state changes (a pump's start moves the header pressure, the
    speed and every current downstream of it), the bound their high quantile plus the quiet
    time (:func:`_quantile_and_how`), not 2 × their median: a fault that outlasts a start's
    transient is raised after it. A state the build lists changed in the window (else it would be
    constant, not a state); where no change moved a residual beyond its noise or settled,
    :data:`SETTLE_FALLBACK` × the quiet time, as for a hand valve. No state the guard
    watches: 0."""
    return settle_bounds(unit, frame)[2][2:]


class Replay:
    """The window's residuals (less each one's median over the window) and each one's noise
    (3 robust sd), replayed once, when first asked for."""

    def __init__(self, unit, frame) -> None:
        self.unit, self.frame, self.got = unit, frame, None

    def __call__(self):
        import numpy as np

        if self.got is None:
            r = self.unit.reset().evaluate(self.frame).residuals.to_numpy(float)
            self.unit.reset()
            self.raw = r
            e = r - np.nanmedian(r, axis=0)
            self.got = e, 3 * 1.4826 * np.nanmedian(np.abs(e), axis=0)
        return self.got

    def scaled(self):
        """The window's filtered residuals in units of their thresholds, as the envelope
        reads them (:func:`~diag_plugin.diagnose.envelope.scaled`)."""
        from diag_plugin.diagnose.envelope import scaled

        self()
        return scaled(self.raw, *self.unit._limits())


class HeldOut(Replay):
    """:class:`Replay`'s residuals from the thresholds' own held-out residuals
    (``scaled``: :attr:`~diag_plugin.learn.thresholds.Learned.scaled`, each block's from a
    model that did not see it) rather than the unit replayed on the window it was trained on,
    filtered as the unit filters them at run time: centred at each sample's operating point
    (a level test of a unit with several, :meth:`~diag_plugin.diagnose.unit.Unit.at_points`)
    and each run of the run condition after its stop as the unit filters it, by the unit's
    own rule (:meth:`~diag_plugin.diagnose.unit.Unit.run_segments`: its filters restart at
    every stop, :meth:`~diag_plugin.diagnose.unit.Unit._stopped`, and read the stopped
    samples as missing: a spread test's filter starts at its first value after a long
    stop). A figure learned from the window is
    judged on data its models did not see: an envelope read from in-sample residuals is as
    narrow as the models over-fit the starts (issue 34, items 5/6)."""

    def __init__(self, unit, frame, scaled) -> None:
        super().__init__(unit, frame)
        self.held = scaled

    def __call__(self):
        import numpy as np
        import pandas as pd

        if self.got is None:
            unit, frame = self.unit, self.frame
            x = self.held.reindex(index=frame.index, columns=unit.tests)
            if unit.level_points is not None and unit.cmodel is not None:
                plant = frame.rename(columns=unit.file.tags)
                x = unit.at_points(x, unit.cmodel.point_of(plant))
            x, names = x.to_numpy(float), x.columns
            r = np.full(x.shape, np.nan)
            unit.reset()
            # the unit's own rule (Unit.run_segments): at each stop its filters restart
            # and read the stopped samples as missing, as at run time: after a long stop
            # a spread test's filter starts at its first value, not from rest (the
            # pasteuriser's HW_TEMP_spread: 60 x its threshold 5 min after a start at run
            # time, 0 rising to 54 filtered from rest; its envelope missed every start)
            for a, b, on in unit.run_segments(unit.runs_of(frame)):
                part = x[a:b] if on else np.full((b - a, len(names)), np.nan)
                got = unit.filtered(pd.DataFrame(part, columns=names)).to_numpy(float)
                if on:  # a stopped row is judged at no residual
                    r[a:b] = got
            unit.reset()
            self.raw = r
            e = r - np.nanmedian(r, axis=0)
            self.got = e, 3 * 1.4826 * np.nanmedian(np.abs(e), axis=0)
        return self.got


def _free_settle(unit, kind: str, steps: list, quiet: int, residuals: Replay):
    """The settle's longest time after the window's own ``steps`` of ``kind`` (``hand``,
    ``state``: no loop test; every test's residual back within its band, module doc of
    :func:`manual_settle_max`), and what it rests on."""

    key, what = {"hand": ("manual_settle_max_s", "hand valve move"),
                 "state": ("state_settle_max_s", "state change")}[kind]  # fmt: skip
    censored: list[float] = []
    times, moved = _free_times(unit, kind, steps, quiet, residuals, censored)
    if kind == "state":
        return _quantile_and_how(key, what, times, moved, unit, censored)
    return _max_and_how(key, what, times, moved, unit)


def _free_times(unit, kind: str, steps: list, quiet: int, residuals: Replay,
                censored: list[float] | None = None):  # fmt: skip
    """The settling times (seconds) of the window's ``steps`` of ``kind`` that settled
    (:func:`_free_settle`), and how many moved a residual beyond its noise. ``censored``: a
    list to collect, per step that moved a residual but did not settle before the next step
    of its kind (or the window's end), the time it is known not to have settled by (s): its
    visit less the quiet time (a settling time is where the quiet time begins), at least 0."""
    times: list[float] = []
    moved = 0  # steps that moved a residual beyond its noise (settled or not)
    for lp, _, _, i, end in steps:
        if lp.kind != kind:
            continue
        e, noise = residuals()
        seen, at = _settling(e, noise, i, end, quiet)
        if not seen:
            continue  # it moved no residual beyond its noise: tells nothing of a settle
        moved += 1
        if at is not None:
            times.append(at * unit.period_s)
        elif censored is not None:
            censored.append(max(0, end - i - quiet) * unit.period_s)
    return times, moved


def km_quantile(times, censored, q: float) -> float | None:
    """The ``q`` quantile of a settling time from the ``times`` seen and the ``censored``
    ones (known only to be longer), by Kaplan and Meier's product-limit estimate (J. Amer.
    Statist. Assoc. 53, 1958, eq. 2: ``S(t) = Π_{t_j ≤ t} (1 − d_j / n_j)``, ``n_j`` the
    changes not settled nor censored before ``t_j``), as :func:`scipy.stats.ecdf` of
    :class:`scipy.stats.CensoredData` computes it: the first settling time ``t`` with
    ``1 − S(t) ≥ q`` (an observed one: the estimate steps only there), None where the
    estimate never reaches ``q`` (the window's visits end before the slowest changes would
    settle) or nothing settled. A censoring at a tied time counts as after the settlings
    there (the usual convention, scipy's: its ``n_j`` counts every change at ``t_j``)."""
    import numpy as np
    from scipy import stats

    times = np.asarray(times, float)
    if not times.size:
        return None
    cdf = stats.ecdf(stats.CensoredData(uncensored=times, right=np.asarray(censored, float))).cdf
    hit = np.flatnonzero(cdf.probabilities >= q - 1e-12)
    return float(cdf.quantiles[hit[0]]) if hit.size else None


def _window_steps(unit, frame) -> tuple[list, int]:
    """The window's steps of the unit's set-points, hand valves and states, as the guard
    finds them: ``(loop, from, to, row, the row its settling must end by)`` each, and the
    guard's quiet time (samples)."""
    import numpy as np

    from diag_plugin.diagnose.settle import WATCHED, SettleGuard, quiet_samples

    quiet = quiet_samples(unit)
    have = [lp for _, found in WATCHED for lp in found(unit) if lp.sp in frame.columns]
    if not have:
        return [], quiet
    guard = SettleGuard(have, 1, quiet, unit.period_s, unit.ev["on_delay"])
    found = guard.steps(np.column_stack([frame[lp.sp].to_numpy(float) for lp in have]))
    # each settles before the next step of its kind: a set-point step's (its loop's error
    # is all it reads), a hand valve's move (the set-point steps between: the loops' own), a
    # state's change
    out = []
    for j, a, b, i in found:
        after = (r for k, *_, r in found if have[k].kind == have[j].kind and r > i)
        out.append((have[j], a, b, i, next(after, len(frame))))
    return out, quiet


#: set-points a note of moves within the band names (the rest are counted)
UNDER_BAND_NAMED = 3


def _under_band(frame, loops, quiet: int) -> str:
    """What the guard will not take for a step, in words for the ``settle_max_s`` note: the
    window's jumps of each loop's set-point from one held value to another by no more than its
    loop test's band (the smaller threshold, in the set-point's units;
    :mod:`diag_plugin.diagnose.settle`) — held meaning within the loop's held tolerance for at
    least ``quiet`` samples (the guard's quiet time) on either side, the jump taking at most
    ``MOVE_SAMPLES`` between them, as an operator's entry does (a cascade set-point that
    rests a moment and moves on is none). Such a move opens no settle, so its transient
    alarms wherever it moves a test beyond its thresholds (the actuators', the spread
    tests'), as any other change would. ``""``: none.

    An aeration basin's day/night schedule (dissolved oxygen 2.0 by day, 1.5 by night) built
    at 1 s: the DO loops' bands were 0.52 and 0.85 mg/l, the schedule's 0.5 mg/l steps none
    of them, and each fault-free day alarmed at 06:02 and 22:02 (the fourth acceptance
    pass, docs/explanation/acceptance-aeration.md); the build said only that no set-point
    step settled."""
    import numpy as np

    from diag_plugin.diagnose.settle import MOVE_SAMPLES

    moves: dict[str, list[tuple[float, float, float]]] = {}
    for lp in loops:
        if lp.kind != "loop" or lp.sp not in frame.columns:
            continue
        x = frame[lp.sp].to_numpy(float)
        x = x[np.isfinite(x)]
        if x.size < 2:
            continue
        # runs of held samples: [start, end] with every step within the tolerance
        cut = np.flatnonzero(np.abs(np.diff(x)) > lp.tol) + 1
        starts, ends = np.r_[0, cut], np.r_[cut - 1, x.size - 1]
        long = ends - starts + 1 >= max(2, quiet)
        starts, ends = starts[long], ends[long]
        for j in range(len(starts) - 1):
            a, b = float(x[ends[j]]), float(x[starts[j + 1]])
            if starts[j + 1] - ends[j] - 1 <= MOVE_SAMPLES and lp.tol < abs(b - a) <= lp.band:
                moves.setdefault(lp.sp, []).append((a, b, lp.band))
    if not moves:
        return ""
    n = sum(map(len, moves.values()))
    named = []
    for sp, got in list(moves.items())[:UNDER_BAND_NAMED]:
        a, b, band = max(got, key=lambda m: abs(m[1] - m[0]))
        named.append(f"{sp} {a:.4g} → {b:.4g}, its loop's band {band:.4g}")
    more = ", …" if len(moves) > UNDER_BAND_NAMED else ""
    return (
        f"; {n} set-point move(s) within their loop test's band are not steps and open no "
        f"settle: their transients alarm as any change ({'; '.join(named)}{more})"
    )


def _settling(err, noise, i: int, end: int, quiet: int) -> tuple[bool, int | None]:
    """Whether the change at row ``i`` moved a residual of ``err`` (rows × tests, each less
    its median) beyond its ``noise``, its own excursion the largest within the quiet time
    after it (before row ``end``), and the samples to its settle (:func:`_settled`: every
    residual back within :data:`SETTLE_BAND` of its excursion, its noise where wider, for
    the quiet time before row ``end``; None where not, or where it moved none)."""
    import numpy as np

    peak = np.nanmax(np.abs(err[i : min(i + quiet, end)]), axis=0, initial=0.0)
    if not (peak > noise).any():
        return False, None
    tol = np.maximum(SETTLE_BAND * peak, noise)
    return True, _settled(~(np.abs(err) > tol).any(axis=1), int(i), end, quiet)


def _settled(ok, i: int, end: int, quiet: int) -> int | None:
    """Samples from row ``i`` to the first from which ``quiet`` rows in a row are ``ok``
    before row ``end`` (None: none)."""
    import numpy as np

    ok = np.r_[ok[i:end], False].astype(int)
    run = np.convolve(ok, np.ones(quiet, int), mode="valid") if len(ok) >= quiet else []
    at = np.flatnonzero(np.asarray(run) >= quiet)
    return int(at[0]) if at.size else None


def _quantile_and_how(
    key: str,
    what: str,
    times: list[float],
    judged: int,
    unit,
    censored: list[float] | None = None,
) -> tuple[float, str]:
    """A state's settle bound from the settling times (seconds) of the window's ``judged``
    changes, in words: the :data:`STATE_SETTLE_QUANTILE` quantile (``higher``: an observed
    time) of those that settled, plus the quiet time (the guard ends a settle only after
    it; without it the pumping station's fault-free starts, bound 19 min, alarmed past it,
    tests/test_unit_statesettle.py). A change's settling time ends where every residual is
    back within its band and stays there for the quiet time (:func:`manual_settle_max`), so
    the bound covers the window's transients but for the slowest tenth. A change that did
    not settle before the next change of its kind (a start before the stop) or the window's
    end is not counted; fewer than half settled: :func:`_max_and_how`'s fallback.

    ``2 × the median + the quiet time`` (:func:`_max_and_how`, kept for the loops and hand
    valves) let a persistent fault hold a start's settle for hours: the air-handling unit's
    starts, median 3.1 h, bound 8.75 h (docs/explanation/acceptance-ahu.md, H4 and H7);
    chiller 2's, 9.9 h, a pump trip at 08:00 CHECK_FUNCTION until 17:56
    (acceptance-chiller.md)."""
    import numpy as np

    if censored:  # the changes that did not settle in their visit: censored (km_quantile)
        got = _censored_and_how(key, what, times, censored, unit)
        if got is not None:
            return got
    if not times or 2 * len(times) < judged:
        return _max_and_how(key, what, times, judged, unit)
    from diag_plugin.diagnose.settle import quiet_samples

    ranked = np.sort(np.asarray(times, float))
    slow = float(np.quantile(ranked, STATE_SETTLE_QUANTILE, method="higher"))
    quiet_s = quiet_samples(unit) * unit.period_s
    value = slow + quiet_s
    seen = ", ".join(f"{t:.0f}" for t in ranked)
    how = (
        f"{key} = {value:.0f} s: the {STATE_SETTLE_QUANTILE:.0%} quantile ({slow:.0f} s) of "
        f"the settling times of the {len(times)} of the window's {judged} {what}(s) that "
        f"settled ({seen} s), plus the quiet time ({quiet_s:.0f} s): a fault that outlasts "
        "the change's transient is raised after it"
    )
    return float(f"{value:.6g}"), how


def _censored_and_how(
    key: str, what: str, times: list[float], censored: list[float], unit
) -> tuple[float, str] | None:
    """A state's settle bound where some of the window's changes did not settle before the
    next change (a CIP's 10 min rinse at a 760 s quiet time; issue 34 item 5, ``i34-cip``):
    the :data:`STATE_SETTLE_QUANTILE` quantile of the settling time by :func:`km_quantile`,
    each such change censored at its visit less the quiet time, plus the quiet time. A short
    visit tells only that its change had not settled by then; the changes into the long
    ones say how long the plant takes. Where the estimate never reaches the quantile (none
    settled, or the visits end before the slow ones would): None, and the rule as before
    (:func:`_quantile_and_how`: the settled ones' quantile where at least half settled, else
    :func:`_max_and_how`'s fallback; the pumping station's starts, whose one change that did
    not settle before the stop is censored late, keep their bound). Before, a unit whose
    states no model read learned none (the pasteuriser at 10 s)."""
    import numpy as np

    from diag_plugin.diagnose.settle import quiet_samples

    slow = km_quantile(times, censored, STATE_SETTLE_QUANTILE)
    judged = len(times) + len(censored)
    if slow is None:
        return None
    quiet_s = quiet_samples(unit) * unit.period_s
    value = slow + quiet_s
    seen = ", ".join(f"{t:.0f}" for t in np.sort(np.asarray(times, float)))
    short = sum(c <= 0 for c in censored)
    how = (
        f"{key} = {value:.0f} s: the {STATE_SETTLE_QUANTILE:.0%} quantile ({slow:.0f} s) of "
        f"the settling times of the {len(times)} of the window's {judged} {what}(s) that "
        f"settled ({seen} s), {len(censored)} more censored where the next change came first "
        f"({short} of them a visit shorter than the quiet time; Kaplan and Meier's "
        f"product-limit estimate), plus the quiet time ({quiet_s:.0f} s): a fault that "
        "outlasts the change's transient is raised after it"
    )
    return float(f"{value:.6g}"), how


def _max_and_how(key: str, what: str, times: list[float], judged: int, unit) -> tuple[float, str]:
    """The guard's longest settle from the settling times (seconds) of the window's
    ``judged`` steps, in words. A step that did not settle before the next (or the window's
    end) is censored: where fewer than half settled, their median settling time is beyond
    what the window shows and the median of the few that did stands for nothing, so the
    fallback (:data:`SETTLE_FALLBACK` × the quiet time) is used, as with none."""
    import numpy as np

    from diag_plugin.diagnose.settle import quiet_parts

    depth, lag, delay = quiet_parts(unit)
    quiet_s = max(1, depth + lag + delay) * unit.period_s
    quiet = (
        f"({quiet_s:.0f} s: the longest history a test reads, {depth} samples, plus the "
        f"residual filter's delay, {lag} (its step response to 95 %: order "
        f"{unit.ev['order']}, cut-off {unit.ev['lowpass']:g} of Nyquist), plus the on-delay, "
        f"{delay})"
    )
    if times and 2 * len(times) >= judged:
        med = float(np.median(times))
        value = SETTLE_FACTOR * med + quiet_s
        how = (
            f"{key} = {value:.0f} s: {SETTLE_FACTOR:g} × the median settling time "
            f"({med:.0f} s) of {len(times)} {what}(s) in the window, plus the quiet time {quiet}"
        )
    else:
        value = SETTLE_FALLBACK * quiet_s
        settled = (
            f"{len(times)} of the window's {judged} {what}s settled (fewer than half: their "
            "median settling time is not known)"
            if times
            else f"no {what} settled in the window"
        )
        how = f"{key} = {value:.0f} s: {settled}; {SETTLE_FALLBACK:g} × the quiet time {quiet}"
    return float(f"{value:.6g}"), how


#: an envelope's age bins begin at 0 and at these quantiles of the window's settling times
ENVELOPE_QUANTILES = (0.25, 0.5, 0.75)
#: an envelope's first bin (from 0 to the first quantile) cut in this many equal spans: a
#: start's transient is largest in its first minutes and gone by its settling time (B's own
#: water on the twin chillers: 247 × its threshold 6 min after B's start, 3.5 at 18 min, 0.5
#: at 22), so one bin to the first quartile (28 min) held a fault present at a start until
#: then. 4: 30 -> 23 min there, 8: 19-23 min with bins from fewer samples; the fault-free
#: samples the same either way (chosen on the twin chillers and the station, tuning plants)
ENVELOPE_SPLIT = 4
#: an envelope's margin: the largest peak seen widened by this / √(changes seen) of itself
#: (:func:`envelope_bound`)
ENVELOPE_WIDEN = 3.0


#: the share of fault-free changes whose settle an envelope may end (some test beyond its
#: bound at some age): one start in a hundred, spread over the envelope's tests × bins
#: (:func:`envelope_bound`)
ENVELOPE_MISS = 0.01
#: the one-sided confidence (95 %, a normal quantile) that the extrapolated bound is not
#: below the true quantile, from the changes seen (:func:`envelope_bound`)
ENVELOPE_CONFIDENCE_Z = 1.645


def envelope_bound(peaks, n_starts: int | None = None, cells: int = 1) -> float:
    """One test's envelope in one age bin (threshold units) from ``peaks``, each fault-free
    change's largest ``|residual|`` there (issue 34, items 5/6): the larger of

    - the largest (at least 1, the threshold) widened by :data:`ENVELOPE_WIDEN` / √n of
      itself, ``n`` the changes seen; and
    - a tolerance bound: the per-change peaks are maxima, so a Gumbel law (extreme values of
      type I) fitted by moments (scale ``s √6 / π``, the peaks' sd ``s``) and its quantile
      at ``1 − ENVELOPE_MISS / cells`` (``cells``: the envelope's tests × age bins, each a
      chance for a fault-free change to be beyond its bound: Bonferroni), ``mean + K s``
      with the frequency factor ``K = √6 / π · (−ln(−ln p) − 0.5772)``, raised by its
      standard error from ``n`` peaks (``s / √n · √(1 + 1.1396 K + 1.1 K²)``, the method of
      moments') × :data:`ENVELOPE_CONFIDENCE_Z`: a bound that is a quantile, not the
      largest of ``n``, which the next change passes with a chance ~1/(n + 1) per test.

    The largest of ``n`` draws is a scale known to about 1/√n of itself, and the tail beyond
    it is not known at all from a few: the station's 8 starts (tests/test_unit_statesettle.py)
    peaked at 0.63–1.02 × the pressure test's threshold, an unseen seed's first start at 1.88
    (the spacing of the top peaks, 0.04, said nothing of it). 3 / √n: 8 starts × 2.06, 14 ×
    1.80, 30 × 1.55: chosen on the tuning seeds 7–14 of that plant. With few changes the
    tolerance bound's error term widens it (126 cells: 5 changes mean + 12.7 s, 8 + 11.5 s,
    30 + 9.3 s)."""
    return envelope_bound_fitted(peaks, n_starts, cells)[0]


def envelope_bound_fitted(peaks, n_starts: int | None = None, cells: int = 1) -> tuple[float, bool]:
    """:func:`envelope_bound` and whether its tolerance bound (:func:`gumbel_bound`) is the
    larger of its two (what :func:`learn_envelope` counts and says), from one computation of
    each."""
    import numpy as np

    x = np.asarray(peaks, float)
    x = x[np.isfinite(x)]
    widened = widened_bound(x, n_starts)
    if x.size < 2:
        return widened, False
    tolerance = gumbel_bound(x, cells)
    return max(widened, tolerance), bool(tolerance > widened)


def widened_bound(peaks, n_starts: int | None = None) -> float:
    """The first bound of :func:`envelope_bound`: the largest peak (at least 1) widened by
    :data:`ENVELOPE_WIDEN` / √n of itself (inf: no peak known)."""
    import numpy as np

    x = np.asarray(peaks, float)
    x = x[np.isfinite(x)]
    if not x.size:
        return float("inf")
    n = x.size if n_starts is None else n_starts
    return float(max(1.0, x.max()) * (1.0 + ENVELOPE_WIDEN / np.sqrt(n)))


def gumbel_bound(x, cells: int = 1) -> float:
    """The tolerance bound of :func:`envelope_bound` from the peaks ``x`` (at least two)."""
    import numpy as np

    n = x.size
    p = 1.0 - ENVELOPE_MISS / max(1, int(cells))
    k = np.sqrt(6.0) / np.pi * (-np.log(-np.log(p)) - np.euler_gamma)
    s = float(np.std(x, ddof=1))
    se = s / np.sqrt(n) * np.sqrt(1.0 + 1.1396 * k + 1.1 * k * k)
    return float(np.mean(x) + k * s + ENVELOPE_CONFIDENCE_Z * se)


def age_events(age):
    """Per row the event it belongs to (0, 1, …; -1 none) from ``age``, per row the age it is
    judged at (samples, -1 none; :func:`~diag_plugin.diagnose.settle.settle_ages`): an event
    begins where a row's age does not continue the row before's by one (a settle opened; a
    step inside an open settle, its own tag's or another's that carries it on, does not
    restart its age: :mod:`~diag_plugin.diagnose.settle`)."""
    import numpy as np

    age = np.asarray(age, np.int64)
    on = age >= 0
    prev = np.r_[-2, age[:-1]]
    first = on & ~((prev >= 0) & (age == prev + 1))
    out = np.cumsum(first) - 1
    out[~on] = -1
    return out


def start_quiet(age, on, quiet_n: int, on_delay: int, period_s: float) -> tuple[float | None, str]:
    """The quiet time (s) that ends a settle of the window's changes, learned from their own
    lulls (issue 34, items 5/6), and what it rests on in words; None where the unit's quiet
    time stays (:func:`~diag_plugin.diagnose.settle.quiet_samples`, ``quiet_n`` samples).

    ``age``: per row the age the guard judged it at (:func:`age_events`' events), ``on``: per
    row whether a test or the combined test was on, both from the guard's own replay of the
    window (:func:`~diag_plugin.diagnose.settle.settle_replay`). A lull is a run of rows of
    an event with no test on that a test on follows within the event (from its start, or
    between two symptoms): a settle ended after it would have raised the start's own
    transient. The quiet time is the longest lull of the events that had a symptom, plus
    one, widened as an envelope is (:data:`ENVELOPE_WIDEN` / √n), at least the on-delay;
    kept only where shorter than ``quiet_n`` (the longest history a test reads, plus the
    filter's delay and the on-delay: what a settle waits without this), and from at least
    :data:`~diag_plugin.diagnose.envelope.MIN_STARTS` events. The pasteuriser at 10 s: its
    starts' tests on from 30 s after the start until the transient is over, without a lull;
    the unit's quiet time 760 s held every start's CHECK_FUNCTION 13 min after its last
    symptom."""
    import numpy as np

    from diag_plugin.diagnose.envelope import MIN_STARTS

    ev = age_events(age)
    on = np.asarray(on, bool)
    longest, n = -1, 0
    for e in np.unique(ev[ev >= 0]):
        hit = np.flatnonzero(on[ev == e])
        if not hit.size:
            continue  # no symptom: it tells nothing of a lull
        n += 1
        longest = max(longest, int(hit[0]), int((np.diff(hit) - 1).max(initial=0)))
    if n < MIN_STARTS:
        kept = f"the quiet time {quiet_n * period_s:.0f} s kept"
        return None, f"{kept} ({n} change(s) with a symptom)"
    q = max(int(on_delay), int(np.ceil((longest + 1) * (1.0 + ENVELOPE_WIDEN / np.sqrt(n)))))
    if q >= quiet_n:
        return None, (f"the quiet time {quiet_n * period_s:.0f} s kept (the longest lull of "
                      f"{n} change(s) {longest * period_s:.0f} s)")  # fmt: skip
    return q * period_s, (
        f"a settle ends {q * period_s:.0f} s without a symptom (the longest lull before a "
        f"symptom of {n} change(s), {longest * period_s:.0f} s, plus a sample, × (1 + "
        f"{ENVELOPE_WIDEN:g}/√n); the unit's quiet time {quiet_n * period_s:.0f} s)"
    )


def known_starts(age, starts):
    """``age`` (per row the age a piece's start settle judged it at, -1 none:
    :func:`~diag_plugin.diagnose.equipment.piece_ages`) with the events that did not begin
    at one of ``starts`` (:func:`piece_starts`: the run tag known and stopped on the sample
    before) set to -1: a piece found running on the window's first sample, or started
    across a historian's gap (the join of ``diag unit accept``'s windows), is judged from
    there at run time but started at an unknown time, and is not one of the window's
    starts."""
    import numpy as np

    age = np.asarray(age, np.int64).copy()
    ev = age_events(age)
    first = np.flatnonzero((ev >= 0) & (np.r_[-1, ev[:-1]] != ev))
    bad = ev[first[~np.isin(first, np.asarray(starts, np.int64))]]
    age[np.isin(ev, bad)] = -1
    return age


def learn_envelope(a, age, times: list[float], bound_s: float, period_s: float,
                   names: list[str]):  # fmt: skip
    """The envelope (:class:`~diag_plugin.diagnose.envelope.Envelope`) of the window's
    fault-free changes from ``a``, rows × tests (``names``) the residuals in threshold
    units, and ``age``, per row the age (samples) the guard judges it at after its change
    (-1: none; the events :func:`age_events`, those with no residual known not counted), and
    what it rests on in words; None where fewer than
    :data:`~diag_plugin.diagnose.envelope.MIN_STARTS` events. Bins: from 0 and
    from the :data:`ENVELOPE_QUANTILES` of the settling times ``times`` (seconds; fewer than
    :data:`~diag_plugin.diagnose.envelope.MIN_STARTS`: the same shares of the bound), the
    first of them cut in :data:`ENVELOPE_SPLIT` equal spans, up to the settle's bound
    ``bound_s``; a bin fewer events reached than that ends the envelope (the last bin
    kept holds from its age on). Per test and bin :func:`envelope_bound`; a bin a test is
    unknown throughout (a spread test's window filling) takes its widest bin's."""
    import numpy as np

    from diag_plugin.diagnose.envelope import MIN_STARTS, Envelope

    a = np.abs(np.asarray(a, float))
    age = np.asarray(age, np.int64)
    ev = age_events(age)
    live = np.unique(ev[(ev >= 0) & np.isfinite(a).any(axis=1)])
    if live.size < MIN_STARTS or not bound_s > 0:
        return None, f"no envelope: {live.size} change(s) (at least {MIN_STARTS} needed)"
    bound_n = int(np.ceil(bound_s / period_s))
    if len(times) >= MIN_STARTS:
        q = np.quantile(np.asarray(times, float), ENVELOPE_QUANTILES, method="higher")
    else:  # too few settled: the same shares of the bound
        q = np.asarray(ENVELOPE_QUANTILES) * bound_s
    cuts = [int(np.ceil(c / period_s)) for c in q]
    cuts = [c for c in cuts if 0 < c < bound_n]
    first = min(cuts, default=bound_n)  # the first bin: cut in ENVELOPE_SPLIT equal spans
    split = [first * k // ENVELOPE_SPLIT for k in range(1, ENVELOPE_SPLIT)]
    edges = sorted({0, *(c for c in split if c > 0), *cuts})
    ends = [*edges[1:], bound_n]
    mine = np.isin(ev, live)
    peaks, kept = [], []  # per bin: events × tests; its first age
    for lo, hi in zip(edges, ends, strict=True):
        rows = np.flatnonzero(mine & (age >= lo) & (age < hi))
        if not rows.size and not kept:
            continue  # younger than the guard judges any row (its first is at 1 or more)
        got, inv = np.unique(ev[rows], return_inverse=True)
        if got.size < MIN_STARTS:
            break
        peak = np.full((got.size, a.shape[1]), -np.inf)
        np.maximum.at(peak, inv.reshape(-1), np.where(np.isnan(a[rows]), -np.inf, a[rows]))
        peaks.append(peak)
        kept.append(lo)
    if not kept:
        return None, f"no envelope: fewer than {MIN_STARTS} changes reached its first age bin"
    edges = kept
    tests = {}
    # each test and bin a chance for a fault-free change to pass its bound (Bonferroni)
    judged = sum(bool(np.isfinite(np.concatenate([p[:, t] for p in peaks])).any())
                 for t in range(len(names)))  # fmt: skip
    cells = max(1, judged * len(peaks))
    fitted = 0
    for t, name in enumerate(names):
        pairs = [envelope_bound_fitted(p[:, t], cells=cells) for p in peaks]
        got = np.array([bound for bound, _ in pairs])
        known = np.isfinite(got)
        if known.any():  # a bin it is unknown in (a spread test's window filling): its widest
            tests[name] = tuple(float(v) for v in np.where(known, got, got[known].max()))
            fitted += sum(won for _, won in pairs)  # the tolerance bound the larger
    env = Envelope(int(live.size), tuple(float(e * period_s) for e in edges), tests)
    widest = max(tests, key=lambda k: tests[k][0], default="")
    reached = ", ".join(str(p.shape[0]) for p in peaks)
    how = (
        f"an envelope from {live.size} fault-free change(s), {len(edges)} age bin(s) from "
        f"{', '.join(f'{e * period_s:.0f}' for e in edges)} s (0, the quartiles of the "
        f"settling times, the first cut in {ENVELOPE_SPLIT}; changes reaching each: "
        f"{reached}), per test and bin the larger of the largest held-out |residual| "
        f"(threshold units, at least 1) × (1 + {ENVELOPE_WIDEN:g}/√n) and a tolerance bound "
        f"(a Gumbel law fitted to the changes' peaks, its 1 − {ENVELOPE_MISS:g}/{cells} "
        f"quantile, {judged} tests × {len(peaks)} bins, plus {ENVELOPE_CONFIDENCE_Z:g} "
        f"standard errors from n; the larger in {fitted} of {cells}): a test beyond it for "
        f"the on-delay ends the settle"
        + (f"; the widest first, {widest} {tests[widest][0]:.3g}" if widest else "")
    )
    return env, how


def settle_envelopes(
    unit, frame, residuals, bounds: dict[str, float], pieces: dict[str, float | None]
) -> list[tuple[str, object, str]]:
    """The envelopes of a built unit's state changes (``state``: every ``[build] states`` tag
    and the run condition, as :func:`state_settle_max` finds them) and of each piece's starts
    (:func:`piece_settle_bounds`), from its window ``frame``: ``(key, envelope or None, what
    it rests on)`` each (:mod:`diag_plugin.diagnose.envelope`). ``bounds``: the settles'
    bounds as the build wrote them (``[evaluation]``, :func:`settle_bounds`), ``pieces`` each
    piece's (None: the unit's state bound, else ``settle_max_s``). ``residuals``: the
    window's held-out residuals the thresholds were learned from (:class:`HeldOut`; the
    settling times that cut the bins too), so the envelope is judged on residuals the
    models did not see (issue 34: before, the unit replayed on its own window)."""

    from dataclasses import replace

    from diag_plugin.diagnose.envelope import STATE
    from diag_plugin.diagnose.settle import quiet_samples, settle_replay, state_tags

    out = []
    quiet = quiet_samples(unit)
    state_s = float(bounds.get("state_settle_max_s") or 0.0)
    unit_s = state_s or float(bounds.get("settle_max_s") or 0.0)
    eqs = list(getattr(unit, "equipment", None) or [])
    # each piece's start settle's bound (samples), as the unit will hold it
    holds = [math.ceil((pieces.get(e.name) or unit_s) / unit.period_s - 1e-9) for e in eqs]
    stated = bool(state_tags(unit)) and state_s > 0
    # the events and their ages as the guards count them at run time (one rule): the state
    # guard's and each piece's, from one replay of the window
    age, on, piece_age = settle_replay(unit, frame, bounds, holds if eqs else None)
    if stated:
        steps, _ = _window_steps(unit, frame)
        times, _ = _free_times(unit, "state", steps, quiet, residuals)
        env, how = learn_envelope(residuals.scaled(), age, times, state_s, unit.period_s,
                                  list(unit.tests))  # fmt: skip
        if env is not None:  # and the quiet time that ends them, from their own lulls
            q, says = start_quiet(age, on, quiet, int(unit.ev["on_delay"]), unit.period_s)
            env = replace(env, quiet_s=q)
            how = f"{how}; {says}"
        out.append((STATE, env, f"[envelope.{STATE}]: {how}"))
    for k, (e, cols) in enumerate(zip(eqs, unit.equipment_tests, strict=True)):
        hold_s = pieces.get(e.name) or unit_s
        if not cols.size or e.rc.tag not in frame.columns or not hold_s > 0:
            continue
        starts, changes = _piece_changes(e.rc, frame[e.rc.tag].to_numpy(float))
        times, _ = _piece_times(unit, residuals, cols, changes, quiet)
        env, how = learn_envelope(residuals.scaled()[:, cols],
                                  known_starts(piece_age[:, k], starts), times,
                                  hold_s, unit.period_s,
                                  [unit.tests[j] for j in cols])  # fmt: skip
        out.append((e.name, env, f"[envelope.{e.name}]: {how}"))
    return out


def _piece_changes(rc, values) -> tuple:
    """A piece's starts in the window (:func:`piece_starts` on its run tag's ``values``) and
    each as ``(row, the row of its next stop or the window's end)``."""
    import numpy as np

    runs, starts = piece_starts(rc, values)
    stops = np.flatnonzero(~runs)
    changes = []
    for i in starts:
        later = stops[stops > i]
        changes.append((int(i), int(later[0]) if later.size else len(runs)))
    return starts, changes


def _piece_times(unit, residuals, cols, changes, quiet: int) -> tuple[list[float], int]:
    """The settling times (seconds) of a piece's starts ``changes`` on its tests ``cols``
    (:func:`piece_settle_bounds`'s rule, :func:`_settling`) and how many moved a test
    beyond its noise (settled or not)."""
    e_all, noise_all = residuals()
    err, noise = e_all[:, cols], noise_all[cols]
    times: list[float] = []
    moved = 0
    for i, end in changes:
        seen, at = _settling(err, noise, i, end, quiet)
        moved += seen  # it moved none of its tests beyond their noise: not counted
        if at is not None:
            times.append(at * unit.period_s)
    return times, moved
