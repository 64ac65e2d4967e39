"""A supply fan holding duct pressure, switched off at night and at weekends (issue 34, items 5
and 6: a unit judged only while it runs): written once from the physics below for the
run-condition tests, not a simulator of the package and not tuned for the unit.

Tags, at 5 min (spot samples of a 10 s simulation):

- ``FAN_RUN`` the fan's run feedback, 1 running / 0 stopped: Monday–Friday 06:00–19:00
- ``DP_SP`` the duct pressure set-point, Pa: 250, 200 on Fridays (an operator's setback)
- ``DP`` the duct static pressure, Pa (±3 Pa transmitter noise): the fan at speed ``n``
  (0 … 1) against the duct, ``DP = P0 · (s·n)² / (1 + K · v²)``, ``P0`` 600 Pa, ``K`` 1.5, ``s``
  the belt's transmission (1 healthy)
- ``FAN_SPD`` the speed command, % (a PI on ``DP_SP − DP``, 0.0005 per Pa and 10 s, starting
  from 0 at each start with a ramp of 1 % a step; 0 while stopped)
- ``VAV`` the terminal boxes' mean openness, % (a daily occupancy cycle and a slow walk)
- ``FLOW`` supply air flow, m³/s: ``Cv · v · √DP``, ``Cv`` 0.5
- ``FAN_KW`` fan power, kW: ``DP · FLOW / (1000 · 0.6)`` plus 0.15 kW of losses while running
- ``T_OUT`` the outside air, °C (the weather: a daily cycle and a 3-day walk)
- ``T_MOT`` the motor's winding temperature, °C: the outside air plus 12 K per kW, a 30 min lag

While stopped the fan, the flow and the power are 0, the duct pressure 0 plus its noise, the
speed command 0, the terminal boxes closed (0 %) and the winding cools to the outside air.

Faults from ``onset`` on (running hours only show them): ``belt_slip`` the belt transmits
0.9 of the motor's speed (the speed command rises to hold the pressure and saturates at 100 %
on the busy hours, the pressure then below its set-point); ``flow_bias`` the flow meter reads
+0.4 m³/s.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.signal import lfilter

PERIOD_S = 300.0
STEP_S = 10.0
TAGS = ("FAN_RUN", "DP_SP", "DP", "FAN_SPD", "VAV", "FLOW", "FAN_KW", "T_OUT", "T_MOT")
P0, K, CV = 600.0, 1.5, 0.5


def _ou(rng: np.random.Generator, n: int, sd: float, tau_s: float, dt: float) -> np.ndarray:
    a = np.exp(-dt / tau_s)
    return lfilter([1], [1, -a], rng.standard_normal(n) * sd * np.sqrt(1 - a * a))


def simulate(
    days: float, seed: int, fault: str | None = None, onset_days: float = 0.0,
    start: str = "2026-03-02",
) -> pd.DataFrame:  # fmt: skip
    """``days`` of 5 min samples from ``start`` (a Monday, UTC), ``fault`` from
    ``onset_days`` on."""
    rng = np.random.default_rng(seed)
    sub = int(PERIOD_S / STEP_S)
    n = int(days * 86400 / PERIOD_S) * sub
    t = pd.Timestamp(start, tz="UTC") + pd.to_timedelta(np.arange(n) * STEP_S, unit="s")
    hour = (t.hour + t.minute / 60.0).to_numpy()
    weekday = t.day_of_week.to_numpy()
    run = ((weekday < 5) & (hour >= 6.0) & (hour < 19.0)).astype(float)
    sp = np.where(weekday == 4, 200.0, 250.0)
    days_ = np.arange(n) * STEP_S / 86400.0
    t_out = 6.0 + 5.0 * np.sin(2 * np.pi * (hour - 9.0) / 24.0)
    t_out = t_out + _ou(rng, n, 3.0, 3 * 86400, STEP_S)
    occ = 0.55 + 0.25 * np.sin(np.pi * np.clip((hour - 6.0) / 13.0, 0, 1))
    vav = np.clip(occ + _ou(rng, n, 0.08, 3 * 3600, STEP_S), 0.2, 1.0) * run
    s = np.ones(n)
    bias = np.zeros(n)
    at = days_ >= onset_days
    if fault == "belt_slip":
        s[at] = 0.9
    elif fault == "flow_bias":
        bias[at] = 0.4
    elif fault is not None:
        raise ValueError(fault)
    spd = np.zeros(n)
    dp = np.zeros(n)
    noise = rng.standard_normal(n) * 3.0
    u = 0.0
    for i in range(n):
        if run[i] == 0.0:
            u = 0.0
        else:
            p = P0 * (s[i] * u) ** 2 / (1.0 + K * vav[i] ** 2)
            e = sp[i] - (p + noise[i])
            u = min(1.0, max(0.0, u + min(0.01, max(-0.01, 0.0005 * e))))
        spd[i] = u
        dp[i] = P0 * (s[i] * u) ** 2 / (1.0 + K * vav[i] ** 2)
    flow = CV * vav * np.sqrt(dp)
    kw = (dp * flow / 600.0 + 0.15) * run
    a = np.exp(-STEP_S / 1800.0)
    heat = t_out + 12.0 * kw
    t_mot = lfilter([1 - a], [1, -a], heat, zi=[a * heat[0]])[0]
    frame = pd.DataFrame(
        {
            "FAN_RUN": run,
            "DP_SP": sp,
            "DP": dp + noise,
            "FAN_SPD": 100.0 * spd,
            "VAV": 100.0 * vav,
            "FLOW": flow + bias * run + rng.standard_normal(n) * 0.01,
            "FAN_KW": kw + rng.standard_normal(n) * 0.005,
            "T_OUT": t_out + rng.standard_normal(n) * 0.1,
            "T_MOT": t_mot + rng.standard_normal(n) * 0.1,
        },
        index=t,
    )
    return frame.iloc[::sub]


def tags_csv(running: bool = True) -> pd.DataFrame:
    """The plant's tags CSV (``diag import --tags``, ``diag unit build --loops-from``): the
    pressure loop, the outside air a measured disturbance, and (``running``) the run
    feedback the role ``running``."""
    rows = [
        ("FAN_RUN", "", 0, 1, "fan run feedback", "", "running" if running else ""),
        ("DP_SP", "Pa", 0, 500, "duct pressure set-point", "dsp", "sp"),
        ("DP", "Pa", 0, 500, "duct static pressure", "dsp", "pv"),
        ("FAN_SPD", "%", 0, 100, "supply fan speed command", "dsp", "out"),
        ("VAV", "%", 0, 100, "terminal boxes' mean openness", "", ""),
        ("FLOW", "m3/s", 0, 15, "supply air flow", "", ""),
        ("FAN_KW", "kW", 0, 10, "supply fan power", "", ""),
        ("T_OUT", "degC", -20, 40, "outside air temperature", "", "disturbance"),
        ("T_MOT", "degC", -20, 120, "fan motor winding temperature", "", ""),
    ]
    cols = ["name", "unit", "lo", "hi", "description", "loop", "role"]
    return pd.DataFrame(rows, columns=cols)
