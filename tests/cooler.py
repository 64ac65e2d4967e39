"""A process cooler built by hand for the valve tests (issue 34, item 7): not a simulator of
the package and not tuned for the unit; written once from the physics below.

A process stream (``F_PROC`` t/h at ``T_IN`` °C) is cooled by cooling water (inlet ``T_CW``
°C); a PI controller holds the outlet ``T_OUT`` at a **fixed** set-point of 45 °C (the
set-point is not a tag: ``--loop T_OUT=45:V_CW``) by moving the cooling-water valve ``V_CW``
(%, its output). The cooling-water flow is not measured. Heat transfer by the effectiveness
of a cooler, ``T_target = T_IN − ε (T_IN − T_CW)``, ``ε = 1 − exp(−k F_cw / F_PROC)``, the
outlet answering with a first-order lag: the valve a steady state needs,
``F_cw = −F_PROC / k · ln(1 − (T_IN − 45) / (T_IN − T_CW))``, depends on all three loads.

Faults from ``onset`` on: ``valve_capacity`` (the cooling-water supply loses 30 % of its
pressure: less flow per % of opening; the loop opens the valve further and holds the
outlet at 45 °C, so only the valve's position shows it), ``stiction`` (the valve moves only
when the output is 3 % away from its position: the loop cycles), ``cw_warm`` (a measured
disturbance, not a fault of the cooler: the cooling-water supply comes 6 °C warmer, beyond
what a short window saw; the loop opens the valve further and holds the outlet).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from tests.line7 import pi_valve

PERIOD_S = 30.0
SET_POINT = 45.0
TAGS = ("F_PROC", "T_IN", "T_CW", "T_OUT", "V_CW")
LOOP = f"T_OUT={SET_POINT:g}:V_CW"
#: the cooling-water supply's rise in fault ``cw_warm``, °C
CW_WARM = 6.0


def _ou(rng: np.random.Generator, n: int, sd: float, tau: float) -> np.ndarray:
    a = np.exp(-1.0 / tau)
    x = np.empty(n)
    v = rng.normal(0, sd)
    for i in range(n):
        v = a * v + np.sqrt(1 - a * a) * sd * rng.standard_normal()
        x[i] = v
    return x


def simulate(hours: float, seed: int, fault: str | None = None, onset_h: float = 2.0):
    """The cooler's 30 s samples over ``hours`` (``fault`` from ``onset_h`` on), after an
    hour's warm-up that is not returned; the loop runs at 5 s."""
    rng = np.random.default_rng(seed)
    sub = 6  # 5 s steps per sample
    warm = int(3600 / PERIOD_S)
    n = int(hours * 3600 / PERIOD_S) + warm
    m = n * sub
    dt = PERIOD_S / sub
    onset = int((onset_h + 1.0) * 3600 / dt)
    f = np.clip(30.0 + _ou(rng, m, 4.0, 3600 / dt), 15.0, 45.0)
    tin = 90.0 + _ou(rng, m, 3.0, 5400 / dt)
    tcw = 20.0 + 2.0 * np.sin(2 * np.pi * np.arange(m) * dt / 86400) + _ou(rng, m, 1.5, 7200 / dt)
    if fault == "cw_warm":
        tcw[onset:] += CW_WARM
    k, cap = 1.0, 1.2  # transfer per (t/h of water / t/h of process); water t/h per % open
    kp, ti = 2.0, 300.0  # %/°C, s
    y, pos, integ = SET_POINT, 40.0, 40.0
    out = np.empty((n, 5))
    for i in range(m):
        faulty = fault is not None and i >= onset
        e = y - SET_POINT  # too hot opens the cooling valve
        op, integ, pos = pi_valve(e, integ, pos, kp, dt, ti,
                                  3.0 if faulty and fault == "stiction" else None)  # fmt: skip
        flow_cw = cap * pos * (np.sqrt(0.7) if faulty and fault == "valve_capacity" else 1.0)
        eps = 1.0 - np.exp(-k * max(flow_cw, 0.1) / f[i])
        target = tin[i] - eps * (tin[i] - tcw[i])
        y += (target - y) * (1 - np.exp(-dt / 180.0))
        if (i + 1) % sub == 0:
            out[i // sub] = (f[i], tin[i], tcw[i], y, op)
    noise = np.array([0.2, 0.1, 0.1, 0.05, 0.0])
    out += noise * rng.standard_normal(out.shape)
    out = out[warm:]
    idx = pd.date_range("2026-05-04", periods=len(out), freq=f"{int(PERIOD_S)}s", tz="UTC")
    return pd.DataFrame(out, index=idx, columns=list(TAGS))


def tags_csv() -> pd.DataFrame:
    """The cooler's tags CSV, its loop declared with a fixed set-point (``set_point``)."""
    rows = [
        ("F_PROC", "t/h", "process flow", "", "", ""),
        ("T_IN", "degC", "process inlet temperature", "", "", ""),
        ("T_CW", "degC", "cooling-water inlet temperature", "", "", ""),
        ("T_OUT", "degC", "process outlet temperature", "outlet", "pv", f"{SET_POINT:g}"),
        ("V_CW", "%", "cooling-water valve (controller output)", "outlet", "out", ""),
    ]
    return pd.DataFrame(rows, columns=["name", "unit", "description", "loop", "role", "set_point"])
