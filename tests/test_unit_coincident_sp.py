"""A tag whose numbers coincide with another loop's declared set-point (issue 34, item 3).

Acceptance pass on a distillation column (docs/explanation/acceptance-column.md): the operators
set the reboiler's steam-flow set-point in proportion to the feed, 1 t/h of steam per
kmol/min of feed, so the two read the same numbers. The steam loop was declared
(``steam_flow`` held at ``STEAM_SETPT`` by ``StmValve``), yet `diag unit build` took the
feed, which no controller holds, for a measurement held at ``STEAM_SETPT`` (its RMS
difference from it under half its spread: ``FeedFlow = f(STEAM_SETPT[k]) (its control loop,
track; actuator None)``). A declared set-point belongs to its loop; the guess is for loops
nobody declared. The plant here is written for this test.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from diag_plugin.unitbuild.build import build_unit
from diag_plugin.unitbuild.loops import Loop


def _column(days: float, seed: int) -> pd.DataFrame:
    """1-min samples: the feed stepped by the operators every 4-12 h between 8 and 12; the
    steam set-point entered 2 min later at the same number (a ratio of 1); the steam flow
    held there by its valve (a first-order loop of 2 min), the valve's opening from the
    flow it passes; a tray temperature falling with the boil-up per feed."""
    rng = np.random.default_rng(seed)
    n = int(days * 1440)
    feed = np.empty(n)
    i, level = 0, 10.0
    while i < n:
        j = min(n, i + int(rng.uniform(240, 720)))
        level = float(rng.choice([v for v in (8.0, 9.0, 10.0, 11.0, 12.0) if v != level]))
        feed[i:j] = level
        i = j
    sp = np.r_[np.full(2, feed[0]), feed[:-2]]
    flow = np.empty(n)
    f = sp[0]
    for k in range(n):
        f += (1 - np.exp(-0.5)) * (sp[k] - f)
        flow[k] = f
    valve = 5.0 * flow + rng.normal(0, 0.3, n)
    walk = np.cumsum(rng.normal(0, 0.01, n))
    temp = 100 - 8 * flow / feed + 0.5 * walk + rng.normal(0, 0.05, n)
    idx = pd.date_range("2026-06-01", periods=n, freq="60s", tz="UTC")
    return pd.DataFrame({"FEED": feed + rng.normal(0, 0.04, n), "STEAM_SP": sp,
                         "FLOW_S": flow + rng.normal(0, 0.04, n), "V_S": valve, "TEMP": temp},
                        index=idx)  # fmt: skip


def test_a_tag_beside_another_loops_declared_set_point_is_not_held_at_it(tmp_path):
    """Fails on main: there the feed's test is the steam loop's relation (``tracks`` =
    ``STEAM_SP``), as if a controller held the feed."""
    train = _column(3, 1)
    # the coincidence the guess reads: the feed is within half its spread of the set-point
    rms = float(np.sqrt(np.mean((train["FEED"] - train["STEAM_SP"]) ** 2)))
    assert rms < 0.5 * float(train["FEED"].std())
    res = build_unit("col", train, folder=tmp_path, period="60s", far=0.01,
                     loops=[Loop("FLOW_S", "STEAM_SP", "V_S")], workers=1)  # fmt: skip
    by_tag = {t.tag: t for t in res.tests if t.statistic == "level"}
    assert by_tag["FLOW_S"].tracks == "STEAM_SP"  # the declared loop keeps its set-point
    assert by_tag["FEED"].tracks is None
    assert "track" not in by_tag["FEED"].method
