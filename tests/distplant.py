"""A small plant with measured disturbances (issue 34, item 4): written once for the naming
of a declared disturbance against a tested tag, not a simulator of the package and not tuned
for the unit. Tags, at 60 s:

- ``T_AMB`` a room temperature, °C (a daily cycle and slow swings): a measured disturbance
- ``F_LOAD`` the load, m³/h (wanders around 100): a measured disturbance
- ``H_AMB`` the room's humidity, % (wanders around 50): a measured disturbance
- ``P_DEW`` a dew point, °C: ``0.3 · T_AMB`` (a 10 min lag) ``+ 0.2 · H_AMB``, a precise
  transmitter (±0.05)
- ``T_X`` a regeneration temperature, °C: ``50 + 0.5 · F_LOAD`` (a 5 min lag) ``+ P_DEW`` as
  read (set from the dew point's transmitter), and a wander of its own (±1, 1 h)
- ``T_Y`` a purge temperature, °C: ``60 − 0.3 · F_LOAD + 0.8 · P_DEW`` as read, ±0.25
- ``T_Z`` downstream of ``T_X``: ``20 + 0.6 · T_X``, and a wander of its own (±1.5, 2 h)

So ``T_AMB`` and ``H_AMB`` are read by one test, ``P_DEW``'s; ``F_LOAD`` and ``P_DEW`` by
the tests of ``T_X`` and ``T_Y``. A bias of ``P_DEW``'s transmitter moves ``T_X`` and
``T_Y`` as their models expect (quiet tests), and ``T_Z`` with them. Faults from ``onset``:
``dew_bias`` ``P_DEW`` reads +0.6 °C, ``load_bias`` ``F_LOAD`` reads +12 m³/h.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from tests import heater

PERIOD_S = 60.0
AT_FAULT = {"dew_bias": "P_DEW", "load_bias": "F_LOAD"}


def _ou(rng: np.random.Generator, n: int, sd: float, tau_s: float) -> np.ndarray:
    """:func:`tests.heater._ou` at this plant's period (the same filter, ``τ`` rescaled)."""
    return heater._ou(rng, n, sd, tau_s * heater.PERIOD_S / PERIOD_S)


def _lag(x: np.ndarray, tau_s: float) -> np.ndarray:
    return heater._lag(x, tau_s * heater.PERIOD_S / PERIOD_S)


def simulate(days: float, seed: int, fault: str | None = None, onset_days: float = 1.0,
             start: str = "2026-05-04") -> pd.DataFrame:  # fmt: skip
    """The plant's 60 s samples over ``days`` from ``start`` (``fault`` from ``onset_days``)."""
    rng = np.random.default_rng(seed)
    n = int(days * 86400 / PERIOD_S)
    onset = int(onset_days * 86400 / PERIOD_S)
    hours = np.arange(n) * PERIOD_S / 3600.0
    t_amb = 20.0 + 4.0 * np.sin(2 * np.pi * hours / 24.0) + _ou(rng, n, 3.0, 10800.0)
    f_load = 100.0 + _ou(rng, n, 10.0, 7200.0)
    h_amb = 50.0 + _ou(rng, n, 8.0, 5400.0)
    p_dew = -8.0 + 0.3 * _lag(t_amb, 600.0) + 0.2 * h_amb
    p_dew = p_dew + rng.normal(0, 0.05, n)  # the transmitter's reading
    if fault == "dew_bias":
        p_dew[onset:] += 0.6
    elif fault not in (None, "load_bias"):
        raise ValueError(fault)
    # set from the dew point's reading: a bias of it moves them as their models expect
    t_x = 50.0 + 0.5 * _lag(f_load, 300.0) + p_dew + _ou(rng, n, 1.0, 3600.0)
    t_y = 60.0 - 0.3 * f_load + 0.8 * p_dew + rng.normal(0, 0.25, n)
    t_z = 20.0 + 0.6 * t_x + _ou(rng, n, 1.5, 7200.0)
    if fault == "load_bias":
        f_load = f_load.copy()
        f_load[onset:] += 12.0
    idx = pd.date_range(start, periods=n, freq=f"{int(PERIOD_S)}s", tz="UTC")
    return pd.DataFrame(
        {
            "T_AMB": t_amb,
            "H_AMB": h_amb,
            "F_LOAD": f_load,
            "P_DEW": p_dew,
            "T_X": t_x,
            "T_Y": t_y,
            "T_Z": t_z,
        },
        index=idx,
    )
