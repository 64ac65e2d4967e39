"""Plant data read off the grid as a plant export gives it (issue 34, items 3/5/6): readings
every period at the period's time ±20 % of it, local times with an offset (``+02:00``), one
row repeated; and the pumping station of :mod:`tests.test_unit_statesettle` written in
seconds, at 1 s. For ``diag import`` → ``diag unit build`` → ``diag diagnose`` as a user runs
them (tests/test_unit_statesettle.py, benchmarks/settle_offgrid.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

#: a reading's time: its period's ± this share of the period
JITTER = 0.2
#: the export's local offset
OFFSET = "+02:00"


def station_1s(days: float, seed: int, bias_at_s: float | None = None) -> pd.DataFrame:
    """tests/test_unit_statesettle.py's pumping station written in seconds at 1 s: a demand
    with a daily cycle, a slow walk and noise; pump 2 on above 260 m3/h, off below 200; at a
    start the header pressure overshoots (5 min), pump 2's current runs up (4 min); at a stop
    the pressure dips. ``bias_at_s``: pump 1's current meter +3 A from then."""
    rng = np.random.default_rng(seed)
    n = int(days * 86400)
    t = np.arange(n) / 86400.0
    walk = np.cumsum(rng.normal(0, 0.002 / np.sqrt(60), n))
    demand = 220 + 80 * np.sin(2 * np.pi * (t - 0.3)) + 20 * walk + rng.normal(0, 5, n)
    slow = pd.Series(demand).rolling(60, min_periods=1).mean().to_numpy()  # the pump's switch
    run2 = np.zeros(n)
    on = False
    for k in range(n):
        on = slow[k] > 260 or (on and slow[k] > 200)
        run2[k] = float(on)
    over, runup = np.zeros(n), np.zeros(n)
    for k in np.flatnonzero(np.diff(run2) != 0) + 1:
        d = np.arange(min(n - k, 3600))
        up = run2[k] == 1
        over[k : k + d.size] += (1.0 if up else -0.5) * np.exp(-d / 300.0)
        if up:
            runup[k : k + d.size] += 4.0 * np.exp(-d / 240.0)
    share = demand / (1 + run2)
    press = 5.0 - 2.5e-5 * share**2 + over + rng.normal(0, 0.01, n)
    i1 = 5 + 0.002 * share**2 / 0.8 + rng.normal(0, 0.3, n)
    i2 = run2 * (5 + 0.002 * share**2 / 0.8 + runup + rng.normal(0, 0.3, n))
    if bias_at_s is not None:
        i1[int(bias_at_s) :] += 3.0
    idx = pd.date_range("2026-06-01", periods=n, freq="1s", tz="UTC")
    return pd.DataFrame(
        {"FLOW": demand + rng.normal(0, 2, n), "PRESS": press, "I1": i1, "I2": i2,
         "RUN2": run2}, index=idx)  # fmt: skip


def off_grid(run: pd.DataFrame, period_s: float, seed: int) -> pd.DataFrame:
    """Readings every ``period_s`` of a 1 s run, each at its period's time ±20 % (the
    reading the value of the nearest 1 s sample), one row repeated."""
    rng = np.random.default_rng([seed, 20])
    count = int((len(run) - 1) // period_s)
    t = np.arange(count) * period_s + rng.uniform(-JITTER, JITTER, count) * period_s
    t = t[(t >= 0) & (t <= len(run) - 1)]
    out = run.iloc[np.round(t).astype(np.int64)].copy()
    out.index = run.index[0] + pd.to_timedelta(np.round(t * 1e3).astype(np.int64), unit="ms")
    k = len(out) // 3
    return pd.concat([out.iloc[: k + 1], out.iloc[k : k + 1], out.iloc[k + 1 :]])


def write_csv(frame: pd.DataFrame, path: Path) -> None:
    """The frame as a plant export: local times with their offset, millisecond stamps."""
    out = frame.copy()
    local = out.index.tz_convert("Etc/GMT-2")
    out.index = [t.strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + OFFSET for t in local]
    out.index.name = "time"
    out.to_csv(path)


def stamps_off_grid(frame: pd.DataFrame, seed: int) -> pd.DataFrame:
    """A regular ``frame``'s rows each stamped at its grid time ±20 % of the spacing (the
    values those of the grid time: the stamp alone moves), one row repeated — a run that
    exists only at its own rate (:mod:`tests.line7` at 15 s, its 1-min means) exported as
    :func:`off_grid` exports a 1 s run."""
    rng = np.random.default_rng([seed, 21])
    step = frame.index[1] - frame.index[0]
    shift = rng.uniform(-JITTER, JITTER, len(frame)) * step.total_seconds()
    out = frame.copy()
    out.index = frame.index + pd.to_timedelta(np.round(shift * 1e3).astype(np.int64), unit="ms")
    k = len(out) // 3
    return pd.concat([out.iloc[: k + 1], out.iloc[k : k + 1], out.iloc[k + 1 :]])
