"""Three sand filters washed in rotation, each a piece of equipment (issue 34, items 4-5: a
piece's test never reads another piece's tags): written once from the physics below for the
build's input choice, not a simulator of the package and not tuned for the unit.

Tags, at 1 min (a 20 s simulation, spot samples):

- ``TOTAL_FLOW`` the bank's inflow, m³/h: ``600 + 150·sin(2π(h − 9)/24)`` plus a 2 h
  Ornstein–Uhlenbeck walk of σ 40 (a measured disturbance), shared by the filters in service
- ``RAW_TURB`` the raw water's turbidity, NTU: 5 plus a 6 h walk of σ 1.5 (unit-wide)
- ``Fn_STATE`` (n = 1–3) 0 filtering, 1 backwash: filter n washed for 12 min every 24 h, at
  02:00, 10:00 and 18:00 (a fixed rotation: each filter's time since its wash is its
  neighbour's shifted by 8 h, the coincidence the acceptance pass's filter bank showed)
- ``Fn_FLOW`` its flow: the bank's inflow over the filters in service, 0 while washed
- ``Fn_HL`` its head loss, m: ``(0.4 + 0.05·h)·(q/200)²``, ``h`` the hours since its last
  wash (the bed clogs), ``q`` its flow
- ``Fn_TURB`` its effluent, NTU: ``0.05 + 0.002·h + 0.01·RAW_TURB`` plus 0.3 decaying in
  20 min after a wash (ripening)

Noise 4 m³/h on the flows, 0.01 m on the head losses, 0.005 NTU on the turbidities, 0.05
NTU on the raw water. Faults from ``onset_days``: ``f1_flow_bias`` filter 1's flow meter reads
10 % high, ``f2_hl_bias`` filter 2's head-loss transmitter reads +0.25 m (measurements only:
the filters' flows and head losses are unchanged).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.signal import lfilter

PERIOD_S = 60.0
STEP_S = 20.0
WASH_H = (2.0, 10.0, 18.0)
WASH_MIN = 12.0
FILTERS = (1, 2, 3)


def _ou(rng: np.random.Generator, n: int, sd: float, tau_s: float) -> np.ndarray:
    a = np.exp(-STEP_S / tau_s)
    return lfilter([1], [1, -a], rng.standard_normal(n) * sd * np.sqrt(1 - a * a))


def running(n: int) -> str:
    """Filter ``n``'s declaration, ``--running 'Fn:Fn_STATE=0:Fn_FLOW,Fn_HL,Fn_TURB'``."""
    return f"F{n}:F{n}_STATE=0:F{n}_FLOW,F{n}_HL,F{n}_TURB"


def simulate(
    days: float, seed: int, fault: str | None = None, onset_days: float = 0.0,
    start: str = "2026-03-02",
) -> pd.DataFrame:  # fmt: skip
    """``days`` of 1 min samples from ``start`` (UTC), ``fault`` from ``onset_days`` on."""
    if fault not in (None, "f1_flow_bias", "f2_hl_bias"):
        raise ValueError(fault)
    rng = np.random.default_rng(seed)
    sub = int(PERIOD_S / STEP_S)
    n = int(days * 86400 / PERIOD_S) * sub
    secs = np.arange(n) * STEP_S
    t = pd.Timestamp(start, tz="UTC") + pd.to_timedelta(secs, unit="s")
    hour = (secs / 3600.0) % 24.0
    total = np.maximum(600 + 150 * np.sin(2 * np.pi * (hour - 9) / 24) + _ou(rng, n, 40, 7200),
                       100.0)  # fmt: skip
    raw = np.maximum(5.0 + _ou(rng, n, 1.5, 6 * 3600), 0.5)
    washing = np.stack([(hour >= w) & (hour < w + WASH_MIN / 60) for w in WASH_H])
    in_service = (~washing).sum(axis=0)
    cols: dict[str, np.ndarray] = {"TOTAL_FLOW": total + rng.standard_normal(n) * 4.0,
                                   "RAW_TURB": raw + rng.standard_normal(n) * 0.05}  # fmt: skip
    day = secs / 86400.0
    for k, f in enumerate(FILTERS):
        # hours since the end of its last wash (the first day: as if washed the day before)
        end = WASH_H[k] + WASH_MIN / 60
        h = (hour - end) % 24.0
        q = np.where(washing[k], 0.0, total / in_service)
        hl = (0.4 + 0.05 * h) * (q / 200.0) ** 2
        if fault == "f2_hl_bias" and f == 2:
            hl = hl + np.where(day >= onset_days, 0.25, 0.0)
        meter = 1.1 if fault == "f1_flow_bias" and f == 1 else 1.0
        q_read = q * np.where(day >= onset_days, meter, 1.0)
        turb = 0.05 + 0.002 * h + 0.01 * raw + 0.3 * np.exp(-h * 60 / 20.0)
        cols[f"F{f}_STATE"] = washing[k].astype(float)
        cols[f"F{f}_FLOW"] = q_read + rng.standard_normal(n) * 4.0
        cols[f"F{f}_HL"] = hl + rng.standard_normal(n) * 0.01
        cols[f"F{f}_TURB"] = turb + rng.standard_normal(n) * 0.005
    return pd.DataFrame(cols, index=t).iloc[::sub]
