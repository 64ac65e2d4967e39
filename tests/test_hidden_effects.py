"""The user story on data with a hidden effect (issue 4).

Months of simulated valve data (seeds not used while developing: 7 was),
a model that misses one physical effect, ``explain`` must rank that effect
first and adding it must cut the held-out error.
"""

import numpy as np
import pandas as pd
import pytest
from helpers import DAMADICS_HOW, damadics_file, requires

from diag_plugin.examples.damadics import TAGS as DAMADICS_TAGS
from diag_plugin.examples.damadics import load_hour
from diag_plugin.regressors import build_design
from diag_plugin.rulebase.document import RuleBase
from diag_plugin.simulate.valve import TAGS, ValveParams, simulate_valve
from diag_plugin.training.chunked import train
from diag_plugin.workbench.explain import explain
from diag_plugin.workbench.model_edit import add_input, new_model

INFO = dict(TAGS)
#: what a plant historian usually records around a control valve (no positioner internals)
PLANT_TAGS = ["CV", "P1", "P2", "T1", "X", "F"]


def fit(rb, frame):
    a, b = frame.index[0], frame.index[-1] + pd.Timedelta(rb.period)
    res = train(rb, lambda x, y: frame[(frame.index >= x) & (frame.index < y)], a, b)
    rb.apply_training(res.model)
    rb.save()
    return RuleBase.load(rb.path), res.validation["rmse_pct"]


def story(tmp_path, frame, output, inputs, info):
    rb = new_model(tmp_path / "m.toml", "m", output, inputs, frame=frame, tag_info=info)
    rb, before = fit(rb, frame)
    e = explain(rb, frame, tag_info=info)
    best = e.candidates[0]
    assert e.baseline_rmse_pct == pytest.approx(before, rel=0.02)
    words = best.command.split()  # follow the command as explain prints it
    sets = int(words[words.index("--sets") + 1]) if "--sets" in words else None
    rb = add_input(rb, best.input, frame=frame, tag_info=info, replace=best.replaces, sets=sets)
    rb, after = fit(rb, frame)
    assert after == pytest.approx(best.rmse_pct_if_added, rel=0.05)
    return e, before, after


@pytest.mark.parametrize("seed", [5, 17])
def test_pressure_drop_is_found_and_cuts_the_error_threefold(tmp_path, seed):
    f = simulate_valve(60, seed=seed)[PLANT_TAGS]
    e, before, after = story(tmp_path, f, "F[k]", ["CV[k-1]"], INFO)
    top = e.candidates[0]
    assert top.input.startswith(("diff(P1,P2)", "P1[", "P2[")), e.as_dict(top=3)
    assert "pressure" in top.effect
    assert before / after >= 3, (before, after)


@pytest.mark.parametrize("seed", [13, 29])
def test_hidden_dead_time_is_found(tmp_path, seed):
    f = simulate_valve(30, seed=seed, params=ValveParams(dead_time_s=40.0))[PLANT_TAGS]
    e, before, after = story(tmp_path, f, "X[k]", ["CV[k]"], INFO)
    top = e.candidates[0]
    assert (top.input, top.kind, top.replaces) == ("CV[k-4]", "dead time", "CV[k]"), e.as_dict(
        top=3
    )
    assert top.command == "diag model add-input m 'CV[k-4]' --replace 'CV[k]'"
    assert before / after >= 2, (before, after)


@pytest.mark.parametrize("seed", [11, 23])
def test_hidden_hysteresis_is_found(tmp_path, seed):
    params = ValveParams(hysteresis=0.3, positioner_gain=5.0)
    f = simulate_valve(30, seed=seed, params=params)[["CV", "P1", "P2", "T1", "X"]]
    e, before, after = story(tmp_path, f, "X[k]", ["CV[k-1]"], INFO)
    top = e.candidates[0]
    assert (top.input, top.kind) == ("dir(CV,0.5)[k-1]", "direction"), e.as_dict(top=3)
    assert "hysteresis" in top.effect
    assert after < 0.85 * before, (before, after)


REAL = damadics_file()
real = requires("real DAMADICS data", REAL is not None, DAMADICS_HOW)


@real
def test_real_valve_flow_model_gets_the_pressure(tmp_path):
    """DAMADICS actuator 3, averaged to 10 s: F = f(X) misses the pressure."""
    f = load_hour(REAL, "10s")
    rb = new_model(tmp_path / "f.toml", "f", "F[k]", ["X[k]"], frame=f, tag_info=DAMADICS_TAGS)
    e = explain(rb, f, tag_info=DAMADICS_TAGS)
    # with the transducer's 0–100 % span for X, the model is also too coarse where this
    # valve works (54–72 %): resolution may rank above; among the missing effects, pressure
    effects = [c for c in e.candidates if c.kind != "resolution"]
    top2 = [c.input for c in effects[:2]]
    hit = [c for c in effects[:2] if c.input.startswith(("P1[", "diff(P1,P2)"))]
    assert hit, top2
    assert hit[0].rmse_pct_if_added < e.baseline_rmse_pct
    # X and the pressures correlate on this valve: explain says so for every candidate
    # whose own correlation with X is strong, and for no other
    for c in e.candidates:
        if c.kind not in ("tag", "difference"):
            continue
        d = build_design(f, [c.input, "X[k]"], None)
        r = abs(np.corrcoef(d.X[:, 0], d.X[:, 1])[0, 1])
        noted = any("correlated with X[k]" in n for n in c.notes)
        assert noted == (r > 0.6), (c.input, r, c.notes)


@real
def test_real_positioner_lag_is_suggested(tmp_path):
    """X = f(CV[k]) at 1 s: CV[k-1] (the positioner lag) must be suggested."""
    f = load_hour(REAL)
    info = dict(DAMADICS_TAGS)
    rb = new_model(tmp_path / "x.toml", "x", "X[k]", ["CV[k]"], frame=f, tag_info=info, period="1s")
    e = explain(rb, f, tag_info=info)
    cv = [c for c in e.candidates[:3] if c.input == "CV[k-1]"]
    assert cv, e.as_dict(top=3)
    assert cv[0].rmse_pct_if_added < e.baseline_rmse_pct
    assert np.isfinite(e.baseline_rmse_pct)
