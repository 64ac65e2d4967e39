"""A run condition per piece of equipment (issue 34, item 5: a stop is not a blackout).

A chilled-water plant runs on one chiller or two; an air-handling unit's heat-recovery wheel
stops in mild weather. The unit-wide run condition (:mod:`~diag_plugin.diagnose.running`)
judges nothing while it is stopped, the wrong answer for a plant that goes on running on its
other equipment. ``diag unit build --running 'CH2:Chlr2 Status=1:CH2_LWT,Chlr2 Cap%'`` (a
name, the run tag and its value, and the tags that belong to the equipment;
:func:`~diag_plugin.unitbuild.loops.parse_running`) declares a piece of equipment. The unit
file keeps one table per piece::

    [equipment.CH2]  # written by `diag unit build --running`: its tests judged while it runs
    tag = "Chlr2 Status"
    run = 1.0
    stop = 0.0
    share = 0.294     # of the build window's samples, it ran on this share
    tags = ["CH2_LWT", "Chlr2 Cap%"]
    settle_max_s = 3600.0  # its start's settle at most this long (the build's, from its starts)

- **Its tests** are those whose tested tag (the model's output) is one of ``tags`` (a loop's
  spread test too: it shares the loop's model).
- **Learning** (the build's input choice and models, the thresholds' residuals, the settle
  bounds, ``diag unit accept``): its tests learn from the rows where it runs only
  (:func:`learnable_for`), their inputs its own tags and the unit-wide ones, never another
  piece's (:func:`~diag_plugin.unitbuild.equipment.foreign_tags`); the other tests learn
  from every row, its tags among their candidate inputs as measured (a stopped chiller's
  power 0 is information).
- **Judging** (:meth:`~diag_plugin.diagnose.unit.Unit.evaluate`): where it is stopped its
  tests are off — no symptom, no alarm, not counted as unknown (the unit is NORMAL or in
  alarm by its other tests, never CHECK_FUNCTION for them) — and the sample's why says
  ``CH2 stopped (Chlr2 Status = 0): tests … off``, the value the run tag holds there (a
  filter run at 0 is stopped at backwash, 1, and at filter-to-waste, 2). Tests of other
  tags that read its tags stay as they are (their own guards say when an input leaves what
  they learned). After a start its tests stay off while it settles (:func:`settling`):
  until none of them has been on for the unit-wide settle's quiet time
  (:func:`~diag_plugin.diagnose.settle.quiet_samples`), at most its own ``settle_max_s``
  (``[equipment.NAME]``, measured by the build on its own starts,
  :func:`~diag_plugin.unitbuild.loops.piece_settle_bounds`; a file without it: the unit's
  ``state_settle_max_s``, else ``settle_max_s``), or until one of them stays beyond its
  start's envelope (``[envelope.NAME]``, :mod:`~.envelope`) for the on-delay; the rest of
  the unit answers on (a run tag
  its models read, a ``[build] states`` tag, is no state change of the unit-wide settle
  guard, :mod:`~diag_plugin.diagnose.settle`). A piece found running on the first sample
  with no history (a replay's, a fresh live start's lead-in: :data:`UNKNOWN_AGE`) is a
  start of unknown age: its settle opens there; a restart from a saved state goes on from
  the carried one.
- The summaries count its samples off on their own, not as unknown: ``diag unit show``'s
  ``off`` beside ``unknown`` (``[learned]`` ``off``, ``off_equipment``), ``diag diagnose``'s
  ``equipment_off`` (``Diagnosis.equipment``: per sample running, stopped or settling).
- Old unit files have no ``[equipment]``: nothing changes for them.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numba
import numpy as np
import pandas as pd

from diag_plugin.diagnose.envelope import Envelope, beyond, says
from diag_plugin.diagnose.running import RunCondition, stop_levels


@dataclass(frozen=True)
class Equipment:
    """A piece of equipment: its name, run condition and the tags that belong to it (the
    models' names)."""

    name: str
    rc: RunCondition
    tags: tuple[str, ...]
    #: the longest its start holds its tests off (``settle_max_s``, measured by the build on
    #: its own starts); None: the unit's ``state_settle_max_s`` (else ``settle_max_s``)
    settle_max_s: float | None = None

    def stopped(self, values: np.ndarray) -> np.ndarray:
        """Per sample whether it is stopped (a missing run tag: running)."""
        return ~self.rc.runs(values)

    def why(self, tests: Sequence[str] = (), value: float | None = None) -> str:
        """The reason on a sample where it is stopped, the run tag at ``value`` (its stop
        value when not given: a filter is stopped at backwash 1 and at filter-to-waste 2)."""
        off = f": tests {', '.join(tests)} off" if tests else ""
        at = self.rc.stop if value is None else value
        return f"{self.name} stopped ({self.rc.tag} = {at:g}){off}"

    def as_table(self) -> dict[str, object]:
        """The unit file's ``[equipment.NAME]`` row (module doc)."""
        out = {**self.rc.as_table(), "tags": list(self.tags)}
        if self.settle_max_s is not None:
            out["settle_max_s"] = float(self.settle_max_s)
        return out


def read_equipment(
    table: Mapping, error: Callable[[int, str], None], line_of: Callable[[str], int]
) -> list[Equipment]:
    """The ``[equipment]`` tables of a unit file (module doc); none without one; problems
    reported through ``error(line, text)``."""
    from diag_plugin.diagnose.running import read_running

    out = []
    for name, row in (table or {}).items():
        if not isinstance(row, Mapping):
            error(line_of(name), f"[equipment.{name}] must be a table")
            continue
        rc = read_running(row, error, lambda k, n=name: line_of(n))
        tags = row.get("tags")
        if not isinstance(tags, list) or not tags or not all(isinstance(t, str) for t in tags):
            error(line_of(name), f"[equipment.{name}] tags must be a list of its tag names")
            continue
        hold = row.get("settle_max_s")
        if hold is not None and (
            isinstance(hold, bool) or not isinstance(hold, int | float) or not hold > 0
        ):
            error(line_of(name), f"[equipment.{name}] settle_max_s must be a number of seconds > 0")
            continue
        if rc is not None:
            out.append(Equipment(str(name), rc, tuple(str(t) for t in tags),
                                 None if hold is None else float(hold)))  # fmt: skip
    return out


def output_tag(output: str) -> str:
    """A model's output spec's tag (``TAG`` of ``TAG[k]``)."""
    return output.split("[")[0].strip().strip('"')


def members(
    equipment: Sequence[Equipment], outputs: Sequence[str], reads: Sequence[Sequence[str]] = ()
) -> list[np.ndarray]:
    """Per piece the indices of the tests (their models' ``outputs``, in order) whose
    tested tag belongs to it; for a piece that never stopped over the build window (its
    ``share`` 1) also the tests that read its tags (``reads``: each test's model's tags): a
    stopped piece's tags are then values those tests never learned."""
    tags = [output_tag(o) for o in outputs]
    out = []
    for e in equipment:
        own = np.isin(tags, list(e.tags))
        if e.rc.share is not None and e.rc.share >= 1.0 and reads:
            own |= np.array([bool(set(r) & set(e.tags)) for r in reads], bool)
        out.append(np.flatnonzero(own))
    return out


def owner(equipment: Sequence[Equipment], tag: str) -> Equipment | None:
    """The piece ``tag`` belongs to, if any."""
    return next((e for e in equipment if tag in e.tags), None)


def learnable_for(frame: pd.DataFrame, eq: Equipment | None) -> pd.DataFrame:
    """``frame`` with every tag NaN where ``eq`` is stopped (what its tests learn from, as
    :func:`~diag_plugin.diagnose.running.learnable`); as it is without ``eq`` or its tag."""
    if eq is None or eq.rc.tag not in frame.columns:
        return frame
    stopped = eq.stopped(frame[eq.rc.tag].to_numpy(float))
    if not stopped.any():
        return frame
    out = frame.copy()
    out.loc[stopped, :] = np.nan
    return out


#: a piece's state per sample (:func:`off_mask`, ``Diagnosis.equipment``): running (its tests
#: judged), stopped, or settling after its start (its tests off in both)
RUNNING, STOPPED, SETTLING = 0, 1, 2


#: ``before`` of :func:`since_start` from rest (no sample before, a replay's or a fresh live
#: start's first): a piece running there started at an unknown time, and is taken as
#: starting there (its settle opens; the build's thresholds leave each run's first samples
#: out likewise, :func:`~diag_plugin.learn.thresholds.settled`). The compressed-air station
#: (docs/explanation/acceptance-compressors.md): C3 running cold on a judged run's first
#: sample, its discharge temperature 31 °C rising to 64 in 9 min, was judged at once: FAILURE
UNKNOWN_AGE = -2


def since_start(runs: np.ndarray, before: int) -> np.ndarray:
    """Per sample the samples since the piece last started (0 on the start's sample), -1
    where it is stopped; ``before``: the same at the sample before the piece (carried: -1
    stopped, large when running long; :data:`UNKNOWN_AGE` from rest, so that a piece running
    on the first sample starts there)."""
    n = runs.size
    idx = np.arange(n)
    prev = np.r_[before >= 0, runs[:-1]]
    start = runs & ~prev
    last = np.maximum.accumulate(np.where(start, idx, -1))
    since = np.where(last >= 0, idx - last, before + 1 + idx)
    return np.where(runs, since, -1)


#: a piece's quiet count (:func:`settling`) where no settle is open (running long, stopped)
DONE = 1 << 40


@numba.njit(cache=True, nogil=True)
def _settle_kernel(
    running, since, on, hold, quiet_n, q, u, edges, env, over, on_n, hit, after, brk
):  # pragma: no cover - numba
    # q[0]: samples in a row none of the piece's tests was on since its start (DONE: closed)
    # an envelope (envelope.py; ``edges`` empty: none): a test beyond it at that age (``u``:
    # samples × its tests, threshold units) for ``on_n`` samples ends the settle, ``hit``
    # the test and age on that row; ``after`` the rows of the alarm it raised (``brk[0]``:
    # carried, while a test of the piece stays on)
    n = running.size
    out = np.zeros(n, np.bool_)
    for i in range(n):
        if not running[i]:
            q[0] = DONE
            brk[0] = 0
            continue
        if since[i] == 0:  # a start opens its settle
            q[0] = 0
            over[:] = 0
            brk[0] = 0
        if q[0] < quiet_n and since[i] < hold:
            t = beyond(u[i], edges, env, since[i], over, on_n)
            if t >= 0:  # a residual far beyond what the window's starts showed: judged
                q[0] = DONE
                hit[i, 0] = t
                hit[i, 1] = since[i]
                brk[0] = 1
            else:
                out[i] = True
                q[0] = 0 if on[i] else q[0] + 1
        elif brk[0] == 1 and not on[i]:
            brk[0] = 0
        after[i] = brk[0] == 1
    return out


def piece_envelopes(
    equipment: Sequence[Equipment], tests: Sequence[np.ndarray], envelopes: Mapping,
    names: Sequence[str], period_s: float,
) -> list[tuple[Envelope, np.ndarray, np.ndarray] | None]:  # fmt: skip
    """Per piece its start's envelope (``[envelope.NAME]``, :mod:`~.envelope`) over its
    tests (``tests``: their positions): ``(envelope, each bin's first age in samples, bins ×
    its tests)``; None without one."""
    out = []
    for e, cols in zip(equipment, tests, strict=True):
        env = (envelopes or {}).get(e.name)
        out.append(None if env is None else (env, *env.arrays([names[j] for j in cols],
                                                                 period_s)))  # fmt: skip
    return out


class PieceState:
    """What a piece's envelope carries from one piece of data to the next: per piece of
    equipment the count of samples each test has been beyond its envelope, whether the
    alarm it raised is on, and that alarm's why."""

    def __init__(self, tests: Sequence[np.ndarray]) -> None:
        self.over = [np.zeros(len(c), np.int64) for c in tests]
        self.brk = [np.zeros(1, np.int64) for _ in tests]
        self.text = ["" for _ in tests]

    def to_state(self) -> dict:
        return {"over": [o.tolist() for o in self.over],
                "brk": [int(b[0]) for b in self.brk], "text": list(self.text)}  # fmt: skip

    def load_state(self, state: dict | None) -> None:
        """From :meth:`to_state` (None, or another shape: from rest)."""
        if not state or [len(o) for o in state["over"]] != [len(o) for o in self.over]:
            return
        self.over = [np.asarray(o, np.int64) for o in state["over"]]
        self.brk = [np.array([b], np.int64) for b in state["brk"]]
        self.text = [str(t) for t in state["text"]]


def off_mask(
    equipment: Sequence[Equipment], tests: Sequence[np.ndarray], runs: Mapping[str, np.ndarray],
    since: np.ndarray, names: Sequence[str], n: int,
) -> tuple[np.ndarray | None, list[tuple[np.ndarray, str]], np.ndarray, list]:  # fmt: skip
    """Samples × tests: the tests off where their piece is stopped, from each run tag's
    values ``runs`` (models' names); None where nothing is. ``since``: per piece
    :func:`since_start` at the sample before (updated in place). Also the samples and reason
    of each piece's stopped stretch, samples × pieces the pieces' states (:data:`RUNNING`,
    :data:`STOPPED`), and per piece ``(running, since_start)`` (None: no run tag or tests),
    what :func:`settling` reads once the tests' symptoms are known."""
    off = None
    said = []
    state = np.zeros((n, len(equipment)), np.int8)
    starts: list = []
    for k, (e, cols) in enumerate(zip(equipment, tests, strict=True)):
        v = runs.get(e.rc.tag)
        if v is None or not cols.size:
            starts.append(None)
            continue
        running = ~e.stopped(v)
        s = since_start(running, int(since[k]))
        since[k] = s[-1] if n else since[k]
        starts.append((running, s))
        stopped = ~running
        if not stopped.any():
            continue
        if off is None:
            off = np.zeros((n, len(names)), bool)
        off[np.ix_(stopped, cols)] = True
        state[stopped, k] = STOPPED
        which = [names[j] for j in cols]
        levels = stop_levels(v[stopped])  # the value it is stopped at (1 or 2; None: analog)
        if levels is None:
            said.append((stopped, e.why(which)))
        for value in levels or ():
            said.append((stopped & (v == value), e.why(which, value)))
    return off, said, state, starts


def settling(
    equipment: Sequence[Equipment], tests: Sequence[np.ndarray], starts: Sequence,
    on: np.ndarray, holds: Sequence[int], quiet_n: int, quiet: np.ndarray,
    names: Sequence[str], u: np.ndarray | None = None, envelopes: Sequence = (),
    carried: PieceState | None = None, on_n: int = 1, period_s: float = 1.0,
) -> tuple[np.ndarray | None, list[tuple[np.ndarray, str]], np.ndarray | None]:  # fmt: skip
    """Samples × tests: a piece's tests held off after its start while it settles (as the
    unit's settle, :mod:`~.settle`): until none of ITS tests (``on``: samples × tests, each
    test's symptom on, before the hold) has been on for ``quiet_n`` samples in a row, at
    most ``holds[k]`` samples, or until one of them stays beyond its envelope (``envelopes``
    per piece, :func:`piece_envelopes`; ``u``: samples × tests, the filtered residuals in
    threshold units) for ``on_n`` samples; None where none is. ``quiet``: per piece its count
    of quiet samples at the sample before (:data:`DONE`: no settle open; updated in place),
    ``carried`` the envelopes' (updated in place). Also the samples and reason of each
    settle (and of each alarm an envelope raised), and samples × pieces where each settles."""
    n = on.shape[0]
    off = None
    said = []
    where = None
    for k, (e, cols, got) in enumerate(zip(equipment, tests, starts, strict=True)):
        if got is None:
            continue
        running, since = got
        q = quiet[k : k + 1]
        mine = on[:, cols].any(axis=1)
        env = envelopes[k] if k < len(envelopes) else None
        state = carried or PieceState(tests)
        if env is None or u is None:
            edges, bound, uk = np.zeros(0, np.int64), np.zeros((0, cols.size)), np.zeros((n, 0))
        else:
            edges, bound, uk = env[1], env[2], np.ascontiguousarray(u[:, cols])
        hit, after = np.full((n, 2), -1, np.int64), np.zeros(n, np.bool_)
        held = _settle_kernel(running, since, mine, int(holds[k]), int(quiet_n), q, uk,
                              edges, bound, state.over[k], max(1, on_n), hit, after,
                              state.brk[k])  # fmt: skip
        if after.any() or state.text[k]:
            said += _broke(e, env, [names[j] for j in cols], uk, bound, edges, hit, after,
                           state, k, period_s)  # fmt: skip
        if not held.any():
            continue
        if off is None:
            off = np.zeros((n, len(names)), bool)
            where = np.zeros((n, len(equipment)), bool)
        off[np.ix_(held, cols)] = True
        where[held, k] = True
        which = ", ".join(names[j] for j in cols)
        said.append((held, f"{e.name} started ({e.rc.tag} = {e.rc.run:g}): tests {which} "
                           "off while it settles"))  # fmt: skip
    return off, said, where


@dataclass
class PieceReplay:
    """What the build's replay of its window hands the unit for its pieces (``evaluate``'s
    ``pieces``): each piece's hold in samples (the bounds just measured, not yet in the
    unit's file) and a list collecting, per piece of data, its index and :func:`piece_ages`;
    the pieces' envelopes unread (what they are learned at)."""

    holds: list[int]
    seen: list = field(default_factory=list)


def piece_ages(starts: Sequence, where: np.ndarray | None, n: int) -> np.ndarray:
    """Samples × pieces the age (samples since its start, :func:`since_start`) at which each
    piece's start settle judges the row, -1 where none is open, from :func:`off_mask`'s
    ``starts`` and :func:`settling`'s ``where``: the ages its envelope is learned at, as the
    guard counts them (:func:`~diag_plugin.unitbuild.loops.settle_envelopes`)."""
    out = np.full((n, len(starts)), -1, np.int64)
    if where is None:
        return out
    for k, got in enumerate(starts):
        if got is not None:
            out[where[:, k], k] = got[1][where[:, k]]
    return out


def _broke(e, env, names, u, bound, edges, hit, after, state: PieceState, k: int,
           period_s: float) -> list[tuple[np.ndarray, str]]:  # fmt: skip
    """The rows of the alarms piece ``k``'s envelope raised and their whys (the one carried
    in first); the last one carried on in ``state``."""
    out = []
    text = state.text[k]
    rows = np.flatnonzero(after)
    cut = np.flatnonzero(hit[rows, 0] >= 0)
    for a, b in zip(np.r_[0, cut], np.r_[cut, rows.size], strict=True):
        if a < b and a < rows.size:
            i = rows[a]
            t, age = int(hit[i, 0]), int(hit[i, 1])
            if t >= 0:
                j = int(np.searchsorted(edges, age, side="right")) - 1
                text = says(names[t], env[0], age * period_s, float(u[i, t]),
                            float(bound[j, t]), f"starts of {e.name}", "its start")  # fmt: skip
            mask = np.zeros(after.size, bool)
            mask[rows[a:b]] = True
            if text:
                out.append((mask, text))
    state.text[k] = text if after.size and after[-1] else ""
    return out
