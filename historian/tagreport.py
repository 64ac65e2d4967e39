"""Per-tag report of the historian: metadata, sampling interval and data quality (what
``diag tags`` shows; mixed into :class:`historian.store.Historian`)."""

from __future__ import annotations

from collections.abc import Collection

import numpy as np
import pandas as pd

from .discrete import MAX_MODE_LEVELS, discrete_levels, levels_text
from .quality import BAD
from .sampling import nice_period_us, snap_near
from .times import US, period_us, to_us
from .window import flat_runs, summarize, summary_frame


class TagReport:
    """``tag_report``. Needs ``self.tags()``, ``self._tag(name)`` and
    ``self._read_raw(tag_id, start, end)``."""

    def tag_report(
        self, start=None, end=None, *, flat="30min", states: Collection[str] = ()
    ) -> pd.DataFrame:
        """Per tag: metadata, sampling interval and the data-quality summary over its own
        time span (or [start, end)); what ``diag tags`` shows. ``states``: tags declared
        discrete states (a tags CSV's role ``state``, ``phase``, ``step`` or ``running``): a
        state whatever the rule says (a recipe's phase of six values)."""
        tags = self.tags()
        rows = {}
        for name, lo, hi in zip(tags["name"], tags["lo"], tags["hi"], strict=True):
            tag_id = self._tag(name)[0]
            s = to_us(start) if start is not None else np.iinfo(np.int64).min
            e = to_us(end) if end is not None else np.iinfo(np.int64).max
            ts, v, q = self._read_raw(tag_id, s, e)
            dt = int(np.median(np.diff(ts))) if len(ts) > 2 else 1_000_000
            # judged on the tag's own period (its median spacing, rounded as a model's
            # period is), each sample at its nearest grid point: jitter is no gap
            own = nice_period_us(dt, 0.05) if dt > 0 else 1_000_000
            s2 = snap_near(ts[0], own) if start is None and len(ts) else s
            e2 = snap_near(ts[-1], own) + own if end is None and len(ts) else e
            if not len(ts) and (start is None or end is None):
                s2, e2 = 0, 1
            row = summarize(ts, v, q, s2, e2, own, lo=_num(lo), hi=_num(hi), flat=period_us(flat))
            row["interval_s"] = dt / 1e6 if len(ts) > 2 else np.nan
            row.update(
                _state_holds(ts, v, q, period_us(flat), declared=name in states)
                if row["flat"]
                else NO_STATE
            )
            rows[name] = row
        report = summary_frame(rows).reset_index()
        for col in ("interval_s", *NO_STATE):
            report[col] = [rows[n][col] for n in report["tag"]]
        meta = tags.rename(columns={"name": "tag"}).drop(columns=["id"])
        return meta.merge(report, on="tag", how="left")


#: a tag that is no discrete state: what :func:`_state_holds` adds to its row
NO_STATE = {"state": None, "held": None, "held_s": 0.0}


#: the most values a declared state's levels are listed by (a recipe's phases; more: an
#: analog tag declared by mistake, left to the rule)
DECLARED_MAX_LEVELS = MAX_MODE_LEVELS


def _state_holds(ts, v, q, flat_us: int, *, declared: bool = False) -> dict:
    """A tag whose values are a few discrete levels (:func:`~historian.discrete.discrete_levels`,
    the rule ``diag unit build`` finds a discrete state by: a filter's 0/1/2) holding one for
    hours is a state, not a frozen sensor: its long runs are no flat line. Its levels
    (``state``, as ``0, 1 or 2``), the value of its longest run (``held``) and how long
    (``held_s``); ``flat`` and ``flat_s`` 0. A ``declared`` state (a tags CSV's role) is one
    on at most :data:`DECLARED_MAX_LEVELS` values whatever the rule says. Any other tag:
    :data:`NO_STATE`."""
    usable = (q < BAD) & np.isfinite(v)
    levels = discrete_levels(v[usable])
    if levels is None and declared:
        vals = np.unique(v[usable])
        levels = tuple(vals.tolist()) if 2 <= len(vals) <= DECLARED_MAX_LEVELS else None
    if levels is None:
        return NO_STATE
    value, dur = flat_runs(ts[usable], v[usable], flat_us)
    longest = int(np.argmax(dur))
    return {
        "state": levels_text(v[usable], levels),
        "held": float(value[longest]),
        "held_s": float(dur[longest]) / US,
        "flat": 0,
        "flat_s": 0.0,
    }


def _num(x):
    return None if x is None or (isinstance(x, float) and np.isnan(x)) else float(x)
