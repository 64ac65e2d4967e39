"""A set-point schedule whose steps lie within the loop test's band: the build says so
(diagnose/settle.py; unitbuild/loops.py ``_under_band``).

The fourth acceptance pass (docs/explanation/acceptance-aeration.md): an aeration basin's
dissolved-oxygen set-points follow a day/night schedule (2.0 by day, 1.5 by night). Built at
1 s, the loop tests' bands (their smaller threshold, 0.52 and 0.85 mg/l) were wider than the
schedule's 0.5 mg/l steps, so the settle guard took none of them for a step and each
fault-free day alarmed at 06:02 and 22:02; the build said only "no set-point step settled in
the window". A small aerated tank written here: one DO loop at 1 s whose set-point a schedule
steps by 0.1 mg/l (within any band its noise allows), an air valve, an air flow.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from diag_plugin.diagnose.settle import settle_guard
from diag_plugin.diagnose.unit import Unit
from diag_plugin.unitbuild.build import build_unit
from diag_plugin.unitbuild.loops import parse_loop

#: the schedule's set-points by day and by night, mg/l, and its steps (hours)
DAY, NIGHT = 2.0, 1.9
SWITCH_H = (2.0, 5.0, 8.0, 11.0)


def _aerated_tank(hours: float, seed: int) -> pd.DataFrame:
    """1 s samples: DO (mg/l) in a tank whose oxygen uptake follows a slow cycle, held by a PI
    on the air valve (%), the air flow through it (Nm³/h); ``dDO/dt = kLa(air)(9 − DO) −
    OUR``, ``kLa = 0.004 · air`` per hour, the valve moving in 10 s."""
    rng = np.random.default_rng(seed)
    n = int(hours * 3600)
    t = np.arange(n) / 3600.0
    sp = np.where(np.searchsorted(SWITCH_H, t, side="right") % 2 == 0, DAY, NIGHT)
    our = 30.0 + 8.0 * np.sin(2 * np.pi * t / 6.0)  # mg/l/h
    do, integ, pos = 2.0, 40.0, 40.0
    rows = np.empty((n, 4))
    for k in range(n):
        meas = do + 0.03 * rng.standard_normal()
        e = sp[k] - meas
        integ = min(max(integ + 10.0 * e / 300.0, 0.0), 100.0)
        out = min(max(integ + 10.0 * e, 0.0), 100.0)
        pos += (out - pos) / 10.0
        air = 40.0 * pos
        do += (0.004 * air * (9.0 - do) - our[k]) / 3600.0
        rows[k] = (meas, sp[k], out, air * (1 + 0.01 * rng.standard_normal()))
    idx = pd.date_range("2026-03-02", periods=n, freq="1s", tz="UTC")
    return pd.DataFrame(rows, index=idx, columns=["DO", "DO_SP", "AIR_VLV", "AIR_FLOW"])


def test_set_point_moves_within_the_band_are_named_by_the_build(tmp_path):
    window = _aerated_tank(12.0, 1)
    res = build_unit("tank", window, folder=tmp_path, period="1s", far=0.01,
                     loops=[parse_loop("DO=DO_SP:AIR_VLV")], force=True)  # fmt: skip
    unit = Unit.load(res.path, tmp_path)
    guard = settle_guard(unit)
    assert guard is not None and [lp.sp for lp in guard.loops] == ["DO_SP"]
    band = guard.loops[0].band
    assert band > abs(DAY - NIGHT), band  # the premise: every step within the band
    sp = window[["DO_SP"]].to_numpy(float)
    assert guard.steps(sp) == []  # the guard takes none of them for a step
    note = next(n for n in res.notes if n.startswith("settle_max_s"))
    moves = int(np.count_nonzero(np.diff(window["DO_SP"].to_numpy())))
    assert moves == len(SWITCH_H)
    said = f"{moves} set-point move(s) within their loop test's band are not steps"
    assert said in note, note
    assert f"DO_SP {NIGHT:g} → {DAY:g}, its loop's band {band:.4g}" in note or (
        f"DO_SP {DAY:g} → {NIGHT:g}, its loop's band {band:.4g}" in note
    ), note
    assert unit.file.build["settle"] == note
