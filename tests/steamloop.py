"""A steam heater under temperature control, for the same-measurement screen's tests (issue 34,
items 4 and 7): written once from the physics below, not a simulator of the package and not
tuned for the unit. Unlike :mod:`tests.heater` (a hand valve, no loop) a PI controller holds
the outlet at its set-point by moving the steam valve; the steam header's pressure is held by
another controller, so the steam flow is nearly a monotone function of the valve's position
(``|r|`` above the build's ``SAME_CORR``), as an air flow through a DO loop's valve is.

Tags, at 20 s:

- ``F_PROC_A``, ``F_PROC_B`` the process water flow, t/h, read by two transmitters (a
  redundant pair: each its own noise; wanders around 200)
- ``T_IN`` its inlet temperature, °C (a daily cycle and slow swings)
- ``T_SP`` the outlet temperature's set-point, °C (an operator moves it every 8–24 h among
  60, 63, 66 and 70 °C)
- ``T_OUT`` the outlet temperature, °C, held at ``T_SP`` (``T_IN + 2200 · F_STEAM · η /
  (4.19 · F_PROC)``, a 5 min lag, the probe a 30 s lag)
- ``STEAM_V`` the temperature controller's output, % (PI at 5 s, its working set-point
  ramped to ``T_SP`` at 0.5 °C/min as a DCS's set-point ramp does; the valve follows it)
- ``F_STEAM`` steam flow, t/h: ``0.45 · STEAM_V · √(P_STEAM / 8)``, the valve's 5 s stroke
- ``P_STEAM`` steam header pressure, bar, held near 8 by the header's own controller

Faults from ``onset_days`` on: ``steam_bias`` the steam flow meter reads +0.6 t/h (as
:mod:`tests.heater`'s); ``probe_drift`` the outlet probe drifts +8 °C over a day (a sensor
inside the loop, a failing thermocouple: the loop holds the wrong temperature, the valve
closes, the steam falls); ``fouling`` the heater's η falls 1 → 0.85 over a day (the loop
opens the valve to hold the outlet, the steam flow follows the valve: only the valve's
position says it).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.signal import lfilter

from tests.line7 import pi_valve

PERIOD_S = 20.0
TAGS = ("F_PROC_A", "F_PROC_B", "T_IN", "T_SP", "T_OUT", "STEAM_V", "F_STEAM", "P_STEAM")
LOOP = "T_OUT=T_SP:STEAM_V"
#: the tag at fault of each fault, as an operator would want it named
AT_FAULT = {"steam_bias": "F_STEAM", "probe_drift": "T_OUT", "fouling": "STEAM_V"}
#: the outlet temperatures an operator chooses, °C
SET_POINTS = (60.0, 63.0, 66.0, 70.0)


def _ou(rng: np.random.Generator, n: int, sd: float, tau_s: float, dt: float) -> np.ndarray:
    a = np.exp(-dt / tau_s)
    return lfilter([1], [1, -a], rng.standard_normal(n) * sd * np.sqrt(1 - a * a))


def simulate(
    days: float, seed: int, fault: str | None = None, onset_days: float = 1.0
) -> pd.DataFrame:
    """The heater's 20 s samples over ``days`` (``fault`` from ``onset_days`` on), after an
    hour's warm-up that is not returned; the loop runs at 5 s."""
    rng = np.random.default_rng(seed)
    sub = 4
    dt = PERIOD_S / sub
    warm = int(3600 / PERIOD_S)
    n = int(days * 86400 / PERIOD_S) + warm
    m = n * sub
    onset = int((onset_days * 86400 + 3600) / dt)
    hours = np.arange(m) * dt / 3600.0
    f_proc = 200.0 + _ou(rng, m, 15.0, 7200.0, dt)
    t_in = 15.0 + 3.0 * np.sin(2 * np.pi * hours / 24.0) + _ou(rng, m, 0.6, 10800.0, dt)
    p = 8.0 + _ou(rng, m, 0.03, 600.0, dt)
    sp = np.empty(m)
    i, v = 0, 66.0
    while i < m:  # the operators' moves
        k = int(rng.uniform(8, 24) * 3600 / dt)
        v = float(rng.choice([x for x in SET_POINTS if x != v]))
        sp[i : i + k] = v
        i += k
    kp, ti, ramp = 3.0, 240.0, 0.5 / 60.0 * dt  # %/°C, s, °C per step
    a_flow, a_out, a_probe = (np.exp(-dt / tau) for tau in (5.0, 300.0, 30.0))
    flow, t_true, probe, integ, pos, w = 20.0, sp[0], sp[0], 40.0, 40.0, sp[0]
    out = np.empty((n, 8))
    for i in range(m):
        drift = 0.0
        if fault == "probe_drift" and i >= onset:
            drift = 8.0 * min((i - onset) * dt / 86400.0, 1.0)
        w += float(np.clip(sp[i] - w, -ramp, ramp))
        e = w - (probe + drift)  # too cold opens the steam valve
        op, integ, pos = pi_valve(e, integ, pos, kp, dt, ti, None)
        target = 0.45 * pos * np.sqrt(max(p[i], 0.1) / 8.0)
        flow = a_flow * flow + (1 - a_flow) * target
        eta = 1.0
        if fault == "fouling" and i >= onset:
            eta = 1.0 - 0.15 * min((i - onset) * dt / 86400.0, 1.0)
        heat = t_in[i] + 2200.0 * flow * eta / (4.19 * f_proc[i])
        t_true = a_out * t_true + (1 - a_out) * heat
        probe = a_probe * probe + (1 - a_probe) * t_true
        if (i + 1) % sub == 0:
            out[i // sub] = (f_proc[i], f_proc[i], t_in[i], sp[i], probe + drift, op, flow, p[i])
    noise = np.array([0.5, 0.5, 0.05, 0.0, 0.05, 0.0, 0.05, 0.005])
    out += noise * rng.standard_normal(out.shape)
    after = np.arange(n) >= onset // sub
    if fault == "steam_bias":
        out[after, 6] += 0.6
    out = out[warm:]
    idx = pd.date_range("2026-06-01", periods=len(out), freq=f"{int(PERIOD_S)}s", tz="UTC")
    return pd.DataFrame(out, index=idx, columns=list(TAGS))
