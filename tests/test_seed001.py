"""Seed 001's figures on the simulated valve (docs/explanation/seed001.md): Fig. 4 / eq. 7,
the "±5 %" of Models A and B, Figs. 7 and 8. The docs' figures use seeds 11/12 (lab), 1 and 43;
these tests run other seeds and shorter runs."""

import xml.etree.ElementTree as ET

import numpy as np
import pandas as pd
import pytest

from diag_plugin.examples import seed001


def test_the_lab_model_of_eq_7_is_within_the_papers_1_to_2_percent(tmp_path):
    """Sect. 4.3: with complete training data (a rig, steady pressures, every opening) a static
    F = f(U) with 31 sets models the valve within 1–2 % — beside HistGradientBoosting."""
    res = seed001.lab_model(days=1.0, train_seed=31, test_seed=32)
    for conclusion in ("sets", "mean"):
        m = res["models"][conclusion]
        assert m["rmse_pct"] < 2.0 and m["coverage"] == 1.0, m
        assert m["rmse_pct"] < 1.5 * res["models"]["hgb"]["rmse_pct"], res["models"]
    assert res["ranges"]["P1"][1] - res["ranges"]["P1"][0] < 150  # steady: noise only
    root = ET.parse(seed001.plot_fig4(res, tmp_path / "f4.svg")).getroot()
    ns = {"s": "http://www.w3.org/2000/svg"}
    assert len(root.findall(".//s:g[@class='panel']", ns)) == 2


def test_model_a_meets_the_band_where_its_one_pressure_carries_the_pressure_drop():
    """Sect. 4.4's "±5 %": on the default plant the outlet pressure wanders as much as the
    inlet, Model A (P1 alone) misses the band and the pressure drop brings it in; with a steady
    outlet Model A is within it and B is not."""
    # 8 training days: the gaps the test checks are as clear as with 20 (A 6.5 % vs A' 2.5 %;
    # steady outlet A 2.2 % vs B 4.7 %), at two fifths of the time
    res = seed001.accuracy(days=8, test_days=2, seed=5, test_seed=44)
    plant = res["default"]
    assert plant["A"]["test"]["rmse_pct"] > 5.0
    assert plant["A'"]["test"]["rmse_pct"] < 5.0 and plant["A'"]["test"]["within_band"] > 0.9
    steady = res["steady outlet"]
    assert steady["A"]["test"]["rmse_pct"] < 5.0 and steady["A"]["test"]["within_band"] > 0.95
    assert steady["B"]["test"]["rmse_pct"] > 1.5 * steady["A"]["test"]["rmse_pct"]
    for p in res.values():  # beside the baseline on the same data
        for m in ("A", "A'", "B"):
            assert p[m]["test"]["rmse_pct"] < 2.0 * p[m]["hgb_test"]["rmse_pct"], (m, p[m])


def test_fig8_model_b_is_blind_to_p_and_model_a_answers_in_steps(tmp_path):
    """Fig. 8 on a week never seen: B's residual ignores P1, A's moves more for each larger
    change, and the share of changed pressures A was trained on falls as the change grows."""
    res = seed001.fig8(test_days=3, test_seed=44)
    a, b = res["changes"]["valve_a"], res["changes"]["valve_b"]
    for g in ("1.1", "1.2", "1.3"):
        assert b["P1"][g]["mean_pct"] == 0.0 and b["P1"][g]["max_abs_pct"] == 0.0
    shift = [abs(a["P1"][g]["mean_pct"]) for g in ("1.1", "1.2", "1.3")]
    assert shift[0] > 1.0 and shift[0] < shift[1] < shift[2], shift
    inside = [a["P1"][g]["inside_trained_p1"] for g in ("1.1", "1.2", "1.3")]
    assert inside[0] >= inside[1] >= inside[2] and inside[2] < 1.0, inside
    start = pd.Timestamp(res["start"])
    assert pd.Timestamp(res["from"]) == start - pd.Timedelta(hours=12)
    root = ET.parse(seed001.plot_fig8(res, tmp_path / "f8.svg")).getroot()
    ns = {"s": "http://www.w3.org/2000/svg"}
    assert len(root.findall(".//s:g[@class='panel']", ns)) == 4


def test_fig7_shows_a_b_and_b2_on_a_week_they_never_saw(tmp_path):
    """Fig. 7: A, B.1 and B.2 in normal operation; B.2 answers as B.1 wherever the controller
    output stays off the sets the edit changed (CV00-CV09, CV28-CV30)."""
    res = seed001.fig7(test_days=2, test_seed=44)
    fr = res["frames"]
    b1, b2 = fr["residuals"]["valve_b"]["r"], fr["residuals"]["valve_b2"]["r"]
    u = fr["test"]["CV"].shift(1).reindex(b1.index)
    mid = (u >= 40) & (u <= 85)
    assert mid.mean() > 0.3
    np.testing.assert_allclose(b2[mid], b1[mid])
    assert not np.allclose(b2[~mid], b1[~mid])
    for name in ("valve_a", "valve_b", "valve_b2"):
        assert res[name]["coverage"] == 1.0 and res[name]["rmse_pct"] > 0
    root = ET.parse(seed001.plot_fig7(res, tmp_path / "f7.svg")).getroot()
    ns = {"s": "http://www.w3.org/2000/svg"}
    titles = "".join(root.itertext())
    assert "B.2" in titles and len(root.findall(".//s:g[@class='panel']", ns)) == 3


def test_quietest_and_trained_range():
    idx = pd.date_range("2026-01-01", periods=6 * 360, freq="10s", tz="UTC")
    r = pd.Series(np.where((idx >= idx[0] + pd.Timedelta("2h")) & (idx < idx[0]
                  + pd.Timedelta("4h")), 0.1, 3.0), index=idx)  # fmt: skip
    assert seed001.quietest(r, pd.Timedelta("2h")) == idx[0] + pd.Timedelta("2h")
    rb = seed001._shipped(("valve_a",))["valve_a"]
    lo, hi = seed001.trained_range(rb, 1)  # P1: within the transducer's 0-4000 kPa
    assert 0.0 <= lo < 3000.0 < hi <= 4000.0


def test_quietest_needs_a_stretch_that_fits():
    idx = pd.date_range("2026-01-01", periods=6 * 360, freq="10s", tz="UTC")
    with pytest.raises(ValueError, match="no stretch"):
        seed001.quietest(pd.Series(1.0, index=idx), pd.Timedelta("7h"))
