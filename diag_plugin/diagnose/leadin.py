"""The lead-in: the history a unit reads before a time so that its carried state there is the
running plug-in's.

A :class:`~diag_plugin.diagnose.unit.Unit` carries state from sample to sample (its models'
lags, the Butterworth low-pass filter of Laukonen et al., Sec. IV, the on/off delays of
Kościelny et al., Sec. 5, spread windows, alarm and isolation holds). A replay from a time T0
(``diag diagnose --from``), a live restart's catch-up and a fresh live start's warm-up
(:mod:`diag_plugin.live.catchup`) therefore evaluate :func:`lead_in` samples before T0 and
keep only the diagnosis from T0 on (:func:`since`). A library module: the commands and the
live plug-in both use it.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pandas as pd

#: the longest lead-in ``diag diagnose --from`` reads (the default chunk: one more read at most)
LEAD_CAP = "7D"
#: what is left of a cold start's transient in the low-pass filter after its settling time
SETTLED = 1e-6


def lead_in(unit: Any) -> int:
    """Samples a replay from ``--from`` reads before it: the sum of :func:`lead_in_parts`,
    capped at :data:`LEAD_CAP` of data."""
    n = sum(lead_in_parts(unit).values())
    return min(n, int(pd.Timedelta(LEAD_CAP) / pd.Timedelta(unit.period)))


def lead_in_parts(unit: Any) -> dict[str, int]:
    """What a replay from ``--from`` reads before it, in samples, so that at ``--from`` the
    unit's carried state is what the live plug-in, running since earlier, had there: ``lags``,
    the longest lag its models read (``rate`` one more); ``spread``, a spread test's two
    windows (the running median, then the median of the deviations from it); ``filter``, the
    low-pass filter's settling — the samples after which a cold start's transient is below
    :data:`SETTLED` of it, ``ln(SETTLED) / ln|p|`` for the filter's slowest pole ``p`` (1 150
    samples at the default cut-off 0.01); ``delays``, the on/off delays (with the unit's own
    off-delay, that once more; with a re-alarm hold, its window and its long hold each
    time). State that depends on all history (a latch, a held isolation,
    ``dir()`` inputs) starts at the lead-in's start."""
    from diag_plugin.diagnose.butterworth import sos_poles

    ev = unit.ev
    out = {"lags": max((b.history for b in unit.builders.values()), default=0)}
    out["spread"] = 2 * unit.spread.window if unit.spread_cols.size else 0
    out["filter"] = 0
    if unit.lowpass is not None:
        poles = sos_poles(unit.lowpass.sos_)  # scipy.signal.sos2zpk's
        slowest = float(np.abs(poles).max())
        if 0 < slowest < 1:
            out["filter"] = math.ceil(math.log(SETTLED) / math.log(slowest))
    # the re-alarm hold (unitloops.AlarmHold): an alarm raised again within its window of
    # the last end is held long, so the window and the long hold before it too
    off = ev["off_delay"]
    if ev.get("realarm_window", 0) > 0:
        off = ev["realarm_window"] + max(off, ev["realarm_off"])
    alarm = off if unit.alarm_hold else 0
    out["delays"] = ev["on_delay"] + off + alarm
    return out


def since(d: Any, start: pd.Timestamp | None) -> Any:
    """The diagnosis ``d`` (a :class:`~diag_plugin.diagnose.unit.Diagnosis`) from ``start`` on
    (all of it when ``start`` is None): the lead-in's rows dropped."""
    if start is None or not len(d) or d.status.index[0] >= start:
        return d
    keep = d.status.index >= start
    cut = {
        f.name: v[keep]
        for f in dataclasses.fields(d)
        if isinstance(v := getattr(d, f.name), pd.Series | pd.DataFrame)
    }
    return dataclasses.replace(d, **cut)
