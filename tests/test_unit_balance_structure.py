"""Which flow gets a balance test follows the plant's structure (issue 34 item 4, H3's finding):
a two-tank line written here. Tank A's level is held by a declared loop on the transfer pump's
speed; the pump's flow Q_AB drains A and fills B; the feed FEED (a disturbance) fills A; tank
B drains by gravity (DRAIN). Only Q_AB is manipulated (the pump's moves precede and explain
its own); FEED leads the pump (the loop answers it) and DRAIN follows it minutes later
through B's inventory. So Q_AB gets a balance test, against tank A's level with FEED, and
FEED and DRAIN get none, at 10 s and at 1 min alike."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from diag_plugin.unitbuild.build import build_unit
from diag_plugin.unitbuild.loops import Loop

INFO = {
    "LVL_A": {"unit": "m", "lo": 0, "hi": 4, "description": "level of tank A"},
    "A_SP": {"unit": "m", "lo": 0, "hi": 4, "description": "level set-point tank A"},
    "PUMP_SPD": {"unit": "%", "lo": 0, "hi": 100, "description": "transfer pump speed"},
    "Q_AB": {"unit": "m3/h", "lo": 0, "hi": 80, "description": "transfer flow A to B"},
    "FEED": {"unit": "m3/h", "lo": 0, "hi": 80, "description": "feed into tank A"},
    "LVL_B": {"unit": "m", "lo": 0, "hi": 6, "description": "level of tank B"},
    "DRAIN": {"unit": "m3/h", "lo": 0, "hi": 80, "description": "drain out of tank B"},
}


def two_tanks(hours: float, dt: float, seed: int) -> pd.DataFrame:
    """The line on a ``dt``-second grid (1 s steps inside), set-point moves every 5 h."""
    rng = np.random.default_rng([seed, 34])
    n, sub = int(hours * 3600 / dt), max(1, int(dt))
    h = dt / sub
    a, b, integ, sp, wander = 2.0, 1.2, 0.0, 2.0, 0.0
    rows = np.empty((n, 7))
    for k in range(n):
        if k and k % int(5 * 3600 / dt) == 0:
            sp = float(np.clip(sp + rng.normal(0, 0.3), 1.4, 2.6))
        for j in range(sub):
            t = k * dt + j * h
            wander += -wander / 2400.0 * h + rng.normal(0, 0.06) * np.sqrt(h)
            feed = 28.0 + 5.0 * np.sin(2 * np.pi * t / 5400.0) + 3.0 * wander
            err = a - sp
            integ += 0.03 * err * h
            u = float(np.clip(40.0 + 25.0 * err + integ, 0, 100))
            q = 0.7 * u
            drain = 16.0 * np.sqrt(max(b, 0.0))
            a = max(a + (feed - q) / 3600.0 / 3.0 * 6.0 * h, 0.05)
            b = max(b + (q - drain) / 3600.0 / 2.5 * 6.0 * h, 0.05)
        rows[k] = (a, sp, u, q, feed, b, drain)
    noise = np.array([0.005, 0.0, 0.1, 0.2, 0.2, 0.005, 0.2])
    rows += rng.normal(size=rows.shape) * noise
    idx = pd.date_range("2026-05-04", periods=n, freq=f"{dt:g}s", tz="UTC")
    return pd.DataFrame(rows, index=idx, columns=list(INFO))


@pytest.mark.parametrize(("dt", "hours"), [(10.0, 30.0), (60.0, 120.0)])
def test_the_pumped_flow_gets_the_balance_test_not_the_feed_nor_the_drain(tmp_path, dt, hours):
    frame = two_tanks(hours, dt, seed=3)
    res = build_unit("line", frame, folder=tmp_path, period=f"{dt:g}s", tag_info=INFO,
                     loops=[Loop("LVL_A", "A_SP", "PUMP_SPD")], far=0.05)  # fmt: skip
    bal = {t.tag: t for t in res.tests if t.balance}
    assert set(bal) == {"Q_AB"}, (set(bal), res.notes)
    # tank A's balance: its feed and its level's rate; never tank B's flows or level
    read = {i.split("[")[0] for i in bal["Q_AB"].inputs}
    assert "FEED" in read and any(r.startswith("rate(LVL_A") for r in read), read
    assert not read & {"DRAIN", "LVL_B", "PUMP_SPD", "A_SP", "LVL_A"}, read
    assert not any(r.startswith("rate(LVL_B") for r in read), read
    said = [n for n in res.notes if n.startswith("Q_AB: driven by PUMP_SPD")]
    assert said and "balanced against LVL_A" in said[0], res.notes
