"""A blending line nobody here tuned on (issue 37's audit): the explain benchmark's stranger.

``OUT_FLOW = (0.6 FEED_A + 0.5 FEED_B) · sqrt(LEVEL / 2) · (0.5 + HAND_VALVE / 110)
+ 0.05 (TEMP − 60) + noise``: four measured inputs that wander (Ornstein–Uhlenbeck), a
manual valve ``HAND_VALVE`` moved by hand every 6–18 hours (the hidden cause a model of the
four inputs misses) and a header pressure ``HEADER_P`` that sags with the outflow (a
consequence of the output, not a cause). Sampled every 15 s with ±2 s of jitter, 0.2 % of
the rows missing — the audit's generator (``/work/brief/data/blend_gen.py``) with its seed a
parameter (the audit's is 7).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.signal import lfilter


def simulate_blendline(days: float, seed: int = 7) -> pd.DataFrame:
    """The line's export as a historian gives it: a row every 15 s ± 2 s (naive UTC times,
    index ``timestamp``), 0.2 % of the rows missing, values rounded as the audit's CSV."""
    rng = np.random.default_rng(seed)
    n = int(days * 86400 / 15)

    def ou(sd: float, tau: float) -> np.ndarray:
        a = np.exp(-1 / tau)
        return lfilter([1], [1, -a], rng.standard_normal(n) * sd * np.sqrt(1 - a * a))

    t0 = pd.Timestamp("2026-01-05 00:00:00")
    ts = t0 + pd.to_timedelta(np.arange(n) * 15 + rng.uniform(-2, 2, n), unit="s")
    fa, fb = 40 + ou(8, 2000), 25 + ou(5, 3000)
    lv, tp = 2.0 + ou(0.4, 5000), 60 + ou(4, 8000)
    hv = np.empty(n)  # the manual valve, moved every 6-18 h
    i, v = 0, 55.0
    while i < n:
        k = int(rng.uniform(6, 18) * 240)
        hv[i : i + k] = v
        v, i = rng.uniform(30, 90), i + k
    y = (0.6 * fa + 0.5 * fb) * np.sqrt(lv / 2) * (0.5 + hv / 110) + 0.05 * (tp - 60)
    y = y + rng.normal(0, 0.6, n)
    hp = 6.0 - 0.03 * y + rng.normal(0, 0.03, n)
    df = pd.DataFrame(
        {
            "FEED_A": fa.round(3),
            "FEED_B": fb.round(3),
            "LEVEL": lv.round(4),
            "TEMP": tp.round(2),
            "HAND_VALVE": hv.round(1),
            "HEADER_P": hp.round(4),
            "OUT_FLOW": y.round(3),
        },
        index=pd.DatetimeIndex(ts.floor("s"), name="timestamp"),
    )
    return df[rng.random(n) > 0.002]  # 0.2 % of the rows missing


def on_grid(df: pd.DataFrame, period: str = "15s") -> pd.DataFrame:
    """``df`` on its period's grid as the historian aligns it (each sample at the nearest grid
    point; a missing row a row of NaN), times in UTC."""
    g = df.copy()
    g.index = g.index.round(period).tz_localize("UTC")
    g = g[~g.index.duplicated(keep="first")]
    full = pd.date_range(g.index[0], g.index[-1], freq=period)
    return g.reindex(full)
