"""A 5-tag jacketed vessel built by hand (issue 34 item 6): a reactor's temperature held by a
PI controller on its jacket's coolant valve, the coolant flow metered after the valve (as the
chemical plant's jacket: TIC104, its valve, FI105). Not a simulator of the package: written
once from the physics below, for the sticking valve's alarms.

Tags:

- ``FEED_T`` feed temperature, °C (slow random swings)
- ``TEMP_TARGET`` the temperature set-point, °C (operators move it every 3–8 h)
- ``TEMP`` the reactor temperature, °C (``C dT/dt = Q + w (T_feed − T) − k F (T − T_cw)``)
- ``COOL_OUT`` the controller's output, % (PI, reverse acting: more cooling when hot)
- ``COOL_FLOW`` the coolant flow, m³/h (``F = 0.3 · position``, the valve linear)

The reaction's heat ``Q`` wanders (unmeasured). ``stiction``: from ``onset`` the valve moves
only when the output is more than 3 % away from its position, then jumps to it.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from tests.line7 import operator_steps, tags_frame

PERIOD_S = 15.0
TAGS = ("FEED_T", "TEMP_TARGET", "TEMP", "COOL_OUT", "COOL_FLOW")


def simulate(
    days: float, seed: int, fault: str | None = None, onset_days: float = 1.0
) -> pd.DataFrame:
    """The vessel's 15 s samples over ``days`` (``fault`` from ``onset_days`` on)."""
    n, onset = (int(d * 86400 / PERIOD_S) for d in (days, onset_days))
    rng = np.random.default_rng(seed)
    dt = PERIOD_S / 60.0  # minutes
    sp = operator_steps(rng, n, PERIOD_S, (3, 8), 60.0, 1.5, (55.0, 65.0))
    cap, w, kf, t_cw = 20.0, 0.5, 0.08, 20.0  # per minute: heat capacity, feed, coolant
    kp, ti = 4.0, 8.0  # %/K, minutes
    temp, feed, q, pos = 60.0, 30.0, 40.0, 50.0
    integ = pos
    out = np.empty((n, len(TAGS)))
    for i in range(n):
        feed = 30.0 + 0.999 * (feed - 30.0) + 0.05 * rng.standard_normal()
        q = 40.0 + 0.998 * (q - 40.0) + 0.3 * rng.standard_normal()
        meas_t = temp + 0.03 * rng.standard_normal()
        e = meas_t - sp[i]  # reverse acting: hot → open the coolant valve
        integ = float(np.clip(integ + kp * e * dt / ti, 0.0, 100.0))
        op = float(np.clip(kp * e + integ, 0.0, 100.0))
        stick = fault == "stiction" and i >= onset
        if not stick or abs(op - pos) > 3.0:
            pos = op
        flow = 0.3 * pos
        temp += dt * (q + w * (feed - temp) - kf * flow * (temp - t_cw)) / cap
        out[i] = (feed + 0.05 * rng.standard_normal(), sp[i], meas_t, op,
                  flow + 0.05 * rng.standard_normal())  # fmt: skip
    idx = pd.date_range("2026-03-02", periods=n, freq=f"{int(PERIOD_S)}s", tz="UTC")
    return pd.DataFrame(out, index=idx, columns=list(TAGS))


def tags_csv() -> pd.DataFrame:
    """The vessel's tags CSV, the loop declared in its ``loop`` and ``role`` columns."""
    return tags_frame([
        ("FEED_T", "degC", "feed temperature", "", ""),
        ("TEMP_TARGET", "degC", "reactor temperature target", "temp", "sp"),
        ("TEMP", "degC", "reactor temperature", "temp", "pv"),
        ("COOL_OUT", "%", "jacket coolant valve output", "temp", "out"),
        ("COOL_FLOW", "m3/h", "jacket coolant flow", "", ""),
    ])  # fmt: skip
