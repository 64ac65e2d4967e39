"""Two chillers sharing a building's load, the second staged on by day only (issue 34, item 5:
a stop is not a blackout): written once from the physics below for the equipment run
condition's tests, not a simulator of the package and not tuned for the unit.

Tags, at 1 min (a 10 s simulation, spot samples):

- ``LOAD`` the building's load, kW: 300 at night, 1,100 by day (06:00–19:00, a smooth
  ramp), plus a 2 h Ornstein–Uhlenbeck walk of σ 60 kW (a measured disturbance)
- ``B_RUN`` chiller B's run feedback: 1 from 07:00 to 19:00 (chiller A alone at night), and
  0 throughout the days of a maintenance (``stop_days``)
- ``A_SP``, ``B_SP`` the leaving-water set-points, 7 °C
- ``A_T``, ``B_T`` the leaving water, °C: each tends in 3 min to ``13 + 7·q/800 − 0.12·cap``
  (``q`` its share of the load: all of it alone, half with both running); stopped, B's warms
  to the plant room's 21 °C in 90 min
- ``A_CAP``, ``B_CAP`` the capacity valves, %: a PI each on the leaving water (gain 6 %/K,
  integral 1 %/K per 10 s step; 0 … 100); B's 0 while stopped
- ``A_KW``, ``B_KW`` the powers, kW: ``20 + 0.2·q``; B's 0 while stopped

Noise 0.03 K on the temperatures, 2 kW on the powers, 0.3 % on the valves. Faults from
``onset_days``: ``a_bias`` A's leaving-water sensor reads +1 K (inside its loop); ``b_bias``
B's reads +1 K (inside its loop, while B runs: a fault right after B's start).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.signal import lfilter

PERIOD_S = 60.0
STEP_S = 10.0


def _ou(
    rng: np.random.Generator, n: int, sd: float, tau_s: float, step_s: float = STEP_S
) -> np.ndarray:
    a = np.exp(-step_s / tau_s)
    return lfilter([1], [1, -a], rng.standard_normal(n) * sd * np.sqrt(1 - a * a))


def simulate(
    days: float, seed: int, fault: str | None = None, onset_days: float = 0.0,
    stop_days: tuple[float, float] | None = None, start: str = "2026-06-01",
    period_s: float = PERIOD_S, step_s: float = STEP_S,
) -> pd.DataFrame:  # fmt: skip
    """``days`` of 1 min samples from ``start`` (UTC), ``fault`` from ``onset_days`` on,
    chiller B stopped over ``stop_days`` (days from the start); ``period_s``, ``step_s``: the
    samples' period and the simulation's step (the PI's integral 1 %/K per 10 s either way)."""
    rng = np.random.default_rng(seed)
    sub = int(period_s / step_s)
    n = int(days * 86400 / period_s) * sub
    t = pd.Timestamp(start, tz="UTC") + pd.to_timedelta(np.arange(n) * step_s, unit="s")
    hour = (t.hour + t.minute / 60.0).to_numpy()
    day = np.arange(n) * step_s / 86400.0
    occ = np.clip((hour - 6.0), 0, 1) * np.clip(19.0 - hour, 0, 1)
    load = np.maximum(300.0 + 800.0 * occ + _ou(rng, n, 60.0, 7200.0, step_s), 100.0)
    b_run = ((hour >= 7.0) & (hour < 19.0)).astype(float)
    if stop_days is not None:
        b_run[(day >= stop_days[0]) & (day < stop_days[1])] = 0.0
    bias = np.where((fault == "a_bias") & (day >= onset_days), 1.0, 0.0)
    b_bias = np.where((fault == "b_bias") & (day >= onset_days), 1.0, 0.0)
    if fault not in (None, "a_bias", "b_bias"):
        raise ValueError(fault)
    a_t = np.empty(n)
    b_t = np.empty(n)
    a_cap = np.empty(n)
    b_cap = np.empty(n)
    noise = rng.standard_normal((n, 2)) * 0.03
    ta, tb, ua, ub = 7.0, 7.0, 50.0, 50.0
    ia, ib = 50.0, 50.0
    f = step_s / 180.0
    ki = step_s / 10.0  # the integral's 1 %/K per 10 s
    for i in range(n):
        both = b_run[i] > 0
        q = load[i] / 2 if both else load[i]
        ta += f * (13 + 7 * q / 800 - 0.12 * ua - ta)
        ea = 7.0 - (ta + bias[i] + noise[i, 0])
        ia = min(100.0, max(0.0, ia - ki * ea))
        ua = min(100.0, max(0.0, ia - 6.0 * ea))
        if both:
            tb += f * (13 + 7 * q / 800 - 0.12 * ub - tb)
            eb = 7.0 - (tb + b_bias[i] + noise[i, 1])
            ib = min(100.0, max(0.0, ib - ki * eb))
            ub = min(100.0, max(0.0, ib - 6.0 * eb))
        else:
            tb += step_s / 5400.0 * (21.0 - tb)
            ib, ub = 50.0, 0.0
        a_t[i], b_t[i], a_cap[i], b_cap[i] = ta, tb, ua, ub
    qa = np.where(b_run > 0, load / 2, load)
    frame = pd.DataFrame(
        {
            "LOAD": load + rng.standard_normal(n) * 10.0,
            "B_RUN": b_run,
            "A_SP": np.full(n, 7.0),
            "B_SP": np.full(n, 7.0),
            "A_T": a_t + bias + noise[:, 0],
            "B_T": b_t + b_bias + noise[:, 1],
            "A_CAP": a_cap + rng.standard_normal(n) * 0.3,
            "B_CAP": b_cap + rng.standard_normal(n) * 0.3 * b_run,
            "A_KW": 20 + 0.2 * qa + rng.standard_normal(n) * 2.0,
            "B_KW": (20 + 0.2 * load / 2) * b_run + rng.standard_normal(n) * 2.0,
        },
        index=t,
    )
    return frame.iloc[::sub]
