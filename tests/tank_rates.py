"""The tank of tests/test_unit_build.py (``_tank``) at another rate, off the grid and with a
valve transmitter that reads its limit with noise (tests/test_unit_pinned_rates.py).

:func:`tank_at` simulates the same 1 s run as ``_tank`` (the same draws, the same seed) and
reads it every ``period_s``: each reading is the mean of the 1 s samples of the period that
starts at its stamp; on the grid the stamps are the period's (``_tank``'s 1-min means at
60 s, to the bit); off it each stamp is shifted by a random 0 … ``jitter`` of the period
(the readings then cover the shifted periods), and :func:`regrid` puts them back on the grid
as the historian does (:func:`historian.window.align`, at the period
:func:`historian.sampling.model_period` finds from the stamps). ``noise``: the valve's
reading (``LIC101.OUT``) as a position transmitter gives it, each 1 s sample plus white
noise of that standard deviation (% of span), quantised to ``quantum`` where given — at its
limit it reads 99.96, 100.0, 99.98 ….
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from diag_plugin.simulate import smallplants as sp


def tank_1s(days: float, seed: int, set_points, surge: float = 0.0) -> pd.DataFrame:
    """``_tank``'s 1 s run before its 1-min means (the same draws in the same order)."""
    idx = sp._seconds(days, "2026-03-02")
    n = len(idx)
    rng = np.random.default_rng([seed, 7])
    fin = 38.0 + sp._ou(rng, n, 4.0, 2 * 3600.0) + sp._ou(rng, n, 0.8, 20.0)
    fin[n // 2 :] += surge
    hold = np.repeat(rng.choice(set_points, n // 14400 + 1), 14400)[:n].astype(float)
    return sp.tank_run(idx, np.clip(fin, 5, 200), hold, rng)


def tank_at(
    days: float,
    seed: int,
    set_points,
    period_s: int,
    surge: float = 0.0,
    jitter: float = 0.0,
    noise: float = 0.0,
    quantum: float = 0.0,
) -> pd.DataFrame:
    """The tank read every ``period_s`` (see module doc): stamps on the grid (``jitter`` 0)
    or each shifted by a random 0 … ``jitter`` of the period (sorted, not regridded)."""
    run = tank_1s(days, seed, set_points, surge)
    if noise > 0:
        rng = np.random.default_rng([seed, 34])
        v = run["LIC101.OUT"].to_numpy() + rng.normal(0.0, noise, len(run))
        run["LIC101.OUT"] = np.round(v / quantum) * quantum if quantum > 0 else v
    p = int(period_s)
    if jitter <= 0:
        return run.resample(f"{p}s").mean()  # _tank's means (at 60 s, to the bit)
    count = len(run) // p - 1  # the last period's shifted window reaches past the run
    rng = np.random.default_rng([seed, 40])
    shift = np.floor(rng.uniform(0.0, jitter, count) * p * 1000).astype(np.int64)  # ms
    start_ms = np.arange(count, dtype=np.int64) * p * 1000 + shift
    first = -(-start_ms // 1000)  # the first 1 s sample at or after the stamp
    x = run.to_numpy(float)
    rows = first[:, None] + np.arange(p)[None, :]
    values = x[rows].mean(axis=1)
    index = run.index[0] + pd.to_timedelta(start_ms, unit="ms")
    return pd.DataFrame(values, index=pd.DatetimeIndex(index, name="ts"), columns=run.columns)


def found_period(frame: pd.DataFrame) -> str:
    """The grid period the historian's build takes from these stamps (every tag sampled at
    them): :func:`historian.sampling.model_period`, as ``diag unit build`` reads it."""
    from historian.sampling import format_period, model_period, sampling_of

    us = frame.index.as_unit("us").asi8
    return format_period(model_period([sampling_of(c, us) for c in frame.columns]))


def regrid(frame: pd.DataFrame, period_s: int) -> pd.DataFrame:
    """``frame``'s readings on the grid ``k · period_s`` (from the epoch) by the historian's
    one rule (:func:`historian.window.align`, the mean within half a period)."""
    from historian.window import align

    us = frame.index.as_unit("us").asi8
    p = int(period_s) * 1_000_000
    t0 = -(-(int(us[0]) - p // 2) // p) * p  # the first grid point whose bin holds a reading
    n = (int(us[-1]) - t0 + p // 2) // p + 1
    q = np.zeros(len(us), np.int64)
    cols = {c: align(us, frame[c].to_numpy(float), q, t0, p, n) for c in frame.columns}
    index = pd.DatetimeIndex(pd.to_datetime(t0 + np.arange(n) * p, unit="us", utc=True))
    return pd.DataFrame(cols, index=index.rename("ts"))
