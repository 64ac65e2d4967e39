"""A steam heater whose steam valve an operator sets by hand (issue 34, item 5): written once
from the physics below for the hand-valve tests, not a simulator of the package and not tuned
for the unit. Unlike :mod:`tests.line7` it has no control loop and no tank: the hand valve
sets a heat input, and its reading is noisy (a position transmitter).

Tags, at 20 s:

- ``F_PROC`` process water, t/h (wanders around 200)
- ``T_IN`` its inlet temperature, °C (a daily cycle and slow swings)
- ``P_STEAM`` steam header pressure, bar (wanders around 8)
- ``STEAM_V`` the steam valve, % open, set by hand every 4–12 h at 30–50 %; read by a
  position transmitter (±0.1 %)
- ``F_STEAM`` steam flow, t/h: ``0.08 · STEAM_V · √P_STEAM``, a 60 s lag
- ``T_OUT`` the outlet temperature, °C: ``T_IN + 2200 · F_STEAM · η / (4.19 · F_PROC)``, a
  5 min lag (η = 1 clean)

Faults from ``onset`` on: ``steam_bias`` the steam flow meter reads +0.6 t/h, ``fouling`` η
falls 1 → 0.9 over a day, ``valve_moved`` the hand valve set to 70 %, a position never seen.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.signal import lfilter

PERIOD_S = 20.0
TAGS = ("F_PROC", "T_IN", "P_STEAM", "STEAM_V", "F_STEAM", "T_OUT")
#: the tag at fault of each fault, as an operator would want it named
AT_FAULT = {"steam_bias": "F_STEAM", "fouling": "T_OUT"}


def _ou(rng: np.random.Generator, n: int, sd: float, tau_s: float) -> np.ndarray:
    a = np.exp(-PERIOD_S / tau_s)
    return lfilter([1], [1, -a], rng.standard_normal(n) * sd * np.sqrt(1 - a * a))


def _lag(x: np.ndarray, tau_s: float) -> np.ndarray:
    a = np.exp(-PERIOD_S / tau_s)
    return lfilter([1 - a], [1, -a], x, zi=[a * x[0]])[0]


def simulate(
    days: float, seed: int, fault: str | None = None, onset_days: float = 1.0,
    start: str = "2026-05-04",
) -> pd.DataFrame:  # fmt: skip
    """The heater's 20 s samples over ``days`` from ``start`` (``fault`` from ``onset_days``)."""
    rng = np.random.default_rng(seed)
    n = int(days * 86400 / PERIOD_S)
    onset = int(onset_days * 86400 / PERIOD_S)
    hours = np.arange(n) * PERIOD_S / 3600.0
    f_proc = 200.0 + _ou(rng, n, 12.0, 7200.0)
    t_in = 15.0 + 3.0 * np.sin(2 * np.pi * hours / 24.0) + _ou(rng, n, 0.6, 10800.0)
    p = 8.0 + _ou(rng, n, 0.4, 3600.0)
    hv = np.empty(n)
    i = 0
    while i < n:  # the operators' moves
        k = int(rng.uniform(4, 12) * 3600 / PERIOD_S)
        hv[i : i + k] = round(float(rng.uniform(30, 50)), 1)
        i += k
    if fault == "valve_moved":
        hv[onset:] = 70.0
    f_steam = _lag(0.08 * hv * np.sqrt(np.maximum(p, 0.1)), 60.0)
    eta = np.ones(n)
    if fault == "fouling":
        eta[onset:] = 1.0 - 0.1 * np.minimum((np.arange(n - onset)) * PERIOD_S / 86400.0, 1.0)
    t_out = _lag(t_in + 2200.0 * f_steam * eta / (4.19 * f_proc), 300.0)
    meas_steam = f_steam + rng.normal(0, 0.05, n)
    if fault == "steam_bias":
        meas_steam[onset:] += 0.6
    idx = pd.date_range(start, periods=n, freq=f"{int(PERIOD_S)}s", tz="UTC")
    return pd.DataFrame(
        {
            "F_PROC": f_proc + rng.normal(0, 0.5, n),
            "T_IN": t_in + rng.normal(0, 0.05, n),
            "P_STEAM": p + rng.normal(0, 0.02, n),
            "STEAM_V": hv + rng.normal(0, 0.1, n),
            "F_STEAM": meas_steam,
            "T_OUT": t_out + rng.normal(0, 0.05, n),
        },
        index=idx,
    )
