"""A unit is judged only while it runs (issue 34, items 5 and 6; ISA-18.2's state-based
alarming, its designed suppression: the alarms of equipment that is not running are
suppressed by design).

A plant that stops — an air-handling unit switched off every night, a pump on standby, a
compressor between batches — is a different plant while stopped: the loops are off, the
valves closed, the measurements drift to ambient. A unit that learned those rows learned two
plants at once (its bands wide enough for both); one that judges them raises alarms on a
plant that is not there (a valve "at its limit" with the fan off).

``diag unit build --running TAG`` (or ``TAG=VALUE``, or the role ``running`` in a tags CSV,
:mod:`diag_plugin.unitbuild.loops`) declares the run condition: a two-valued state tag, the
unit running where it is at its higher value (or at ``VALUE``). The unit file's ``[running]``
table keeps it::

    [running]      # written by `diag unit build --running`: judged only while it runs
    tag = "AHU_ON"
    run = 1.0      # the value at which the unit runs
    stop = 0.0     # its other value
    share = 0.54   # of the build window's samples, the unit ran on this share

A mode of more levels (issue 34 item 5, acceptance pass 10: an HTST pasteuriser's idle 0,
production 1, CIP 2-4; ``--running MODE=1``) runs at ``VALUE``, any of its levels, and is
stopped at every other; ``levels`` lists them (``stop`` the nearest other, for the why) and a
sample runs where its nearest level is ``run`` (:meth:`RunCondition.runs`)::

    [running]
    tag = "MODE"
    run = 1.0
    stop = 0.0
    share = 0.62
    levels = [0.0, 1.0, 2.0, 3.0, 4.0]

- **Learning** (the build, ``diag unit accept``): the stopped rows are as an outage, every
  tag NaN there (:func:`learnable`): the models, their inputs, the thresholds, the settle
  bounds, ``[fixed]`` and ``[states]`` learn only the running plant.
- **Judging** (:meth:`~diag_plugin.diagnose.unit.Unit.evaluate`, ``diag diagnose``, the live
  :class:`~diag_plugin.diagnose.plant.Plant`): where the unit is stopped its tags are read
  as missing (its models' histories hold no stopped row after a start), no test is judged,
  nothing alarms, nothing is named, and the status is CHECK_FUNCTION with the why
  ``not running (AHU_ON = 0): judged only while it runs``. At each stop the alarm's
  carriers (the tests' on/off delays, the held symptoms, the unit's off-delay, the isolation
  and episode holds, the valve-at-limit rule) start from rest: no alarm is carried across a
  stop into the next start. The start itself is a state change of the settle guard
  (:func:`~diag_plugin.diagnose.settle.state_tags`): its transient is CHECK_FUNCTION for at
  most ``state_settle_max_s``, the build's bound from the window's own starts.
- A sample whose run tag has no value is judged (as without the declaration); a frame
  without the run tag (the learning's own, already masked) is judged everywhere.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd

#: at most this many distinct values of the run tag over a stopped stretch are each named in
#: its why (a discrete state's levels); more (an analog run tag): the stop value
WHY_LEVELS = 4


@dataclass(frozen=True)
class RunCondition:
    """The unit's run condition: the state tag (the models' name), the value at which the
    unit runs, its other value, and the share of the build window it ran on."""

    tag: str
    run: float
    stop: float
    share: float | None = None
    #: a mode's levels over the build window, where more than two (module doc); () for a
    #: two-valued run tag
    levels: tuple[float, ...] = ()

    def runs(self, values: np.ndarray) -> np.ndarray:
        """Per sample whether the unit runs: the tag at ``run`` (nearer to it than to
        ``stop``, as a historian's mean of a period it started in is not yet running; a
        mode's: nearer to ``run`` than to any other of its ``levels``, a tie running); a
        missing value counts as running (judged as without the declaration)."""
        x = np.asarray(values, float)
        others = [v for v in self.levels if v != self.run] or [self.stop]
        with np.errstate(invalid="ignore"):
            near = np.abs(x[..., None] - np.asarray(others, float)).min(axis=-1)
            stopped = near < np.abs(x - self.run)
        return ~stopped

    def why(self, value: float | None = None) -> str:
        """CHECK_FUNCTION's why on a stopped sample, the run tag at ``value`` (its stop value
        when not given)."""
        at = self.stop if value is None else value
        return f"not running ({self.tag} = {at:g}): judged only while it runs"

    def whys(self, values: np.ndarray) -> str | np.ndarray:
        """The why of each stopped sample of ``values`` (the run tag's): the value it holds
        where the tag takes a few levels (a filter stopped at backwash, 1, and at
        filter-to-waste, 2), else the stop value; one text where all say the same."""
        x = np.asarray(values, float)
        levels = stop_levels(x)
        if levels is None or len(levels) == 1:
            return self.why(None if levels is None else levels[0])
        out = np.full(len(x), self.why(), dtype=object)
        for v in levels:
            out[x == v] = self.why(v)
        return out

    def as_table(self) -> dict[str, object]:
        """The unit file's ``[running]`` row (module doc)."""
        out: dict[str, object] = {"tag": self.tag, "run": float(self.run), "stop": float(self.stop)}
        if self.share is not None:
            out["share"] = round(float(self.share), 4)
        if self.levels:
            out["levels"] = [float(v) for v in self.levels]
        return out


def stop_levels(values: np.ndarray) -> list[float] | None:
    """The values a run tag held over stopped samples, each named in their why where there
    are at most :data:`WHY_LEVELS` (a discrete state's levels); None for more (an analog run
    tag: its why names the stop value) or none."""
    x = np.asarray(values, float)
    levels = np.unique(x[np.isfinite(x)])
    return None if not 1 <= len(levels) <= WHY_LEVELS else [float(v) for v in levels]


def read_running(table: Mapping, error: Callable[[int, str], None], line_of) -> RunCondition | None:
    """The ``[running]`` table of a unit file (module doc), or None without one; problems
    reported through ``error(line, text)``."""
    if not table:
        return None
    tag = table.get("tag")
    if not isinstance(tag, str) or not tag:
        error(line_of("tag"), "[running] tag must be the run condition's tag name")
        return None
    vals = {}
    for key in ("run", "stop"):
        v = table.get(key)
        if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v):
            error(line_of(key), f"[running] {key} must be a number (the tag's value)")
            return None
        vals[key] = float(v)
    if vals["run"] == vals["stop"]:
        error(line_of("run"), "[running] run and stop must differ")
        return None
    share = table.get("share")
    share = float(share) if isinstance(share, int | float) and not isinstance(share, bool) else None
    levels = read_levels(table.get("levels"), vals["run"], vals["stop"])
    if levels is None:
        error(line_of("levels"), "[running] levels must be a list of three or more numbers, "
              "run and stop among them (the mode's values)")  # fmt: skip
        return None
    return RunCondition(tag, vals["run"], vals["stop"], share, levels)


def read_levels(got: object, run: float, stop: float) -> tuple[float, ...] | None:
    """A ``[running]`` table's ``levels`` (module doc): () without one, None when it is no
    list of three or more numbers holding ``run`` and ``stop``."""
    if got is None:
        return ()
    if not isinstance(got, list) or len(got) < 3:
        return None
    if any(isinstance(v, bool) or not isinstance(v, int | float) for v in got):
        return None
    levels = tuple(sorted(float(v) for v in got))
    return levels if run in levels and stop in levels else None


def learnable(frame: pd.DataFrame, rc: RunCondition | None) -> pd.DataFrame:
    """``frame`` (models' tag names) with every tag, the run tag's own too, NaN where the
    unit is stopped (an outage: what a build and an accept learn from). Without ``rc`` or
    its column: ``frame`` as it is."""
    col = None if rc is None else rc.tag
    if rc is None or col not in frame.columns:
        return frame
    stopped = ~rc.runs(frame[col].to_numpy(float))
    if not stopped.any():
        return frame
    out = frame.copy()
    out.loc[stopped, :] = np.nan
    return out


def segments(runs: np.ndarray) -> Iterator[tuple[int, int, bool]]:
    """The runs of equal values of ``runs``: ``(start, end, running)`` each, in order."""
    n = len(runs)
    if not n:
        return
    cut = np.flatnonzero(np.diff(runs.astype(np.int8))) + 1
    bounds = np.r_[0, cut, n]
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        yield int(a), int(b), bool(runs[a])
