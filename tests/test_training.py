"""Chunked training with a time-ordered held-out block (issue 3, training jobs)."""

import numpy as np
import pandas as pd
import pytest

from diag_plugin.rulebase import RuleBase, Variable
from diag_plugin.training import ErrorStats, train


def plant_frame(days, seed):
    rng = np.random.default_rng(seed)
    n = int(days * 8640)
    idx = pd.date_range("2026-01-01", periods=n, freq="10s", tz="UTC", name="ts")
    cv = np.clip(50 + np.cumsum(rng.normal(0, 1.5, n)) % 100, 0, 100)
    p1 = 500 + 150 * np.sin(np.arange(n) / 8640 * 2 * np.pi) + rng.normal(0, 5, n)
    f = np.r_[0, 30 * (cv[:-1] / 100) ** 2 * np.sqrt(p1[1:] / 650)] + rng.normal(0, 0.1, n)
    frame = pd.DataFrame({"CV": cv, "P1": p1, "F": f}, index=idx)
    frame.iloc[rng.choice(n, 50, replace=False), 0] = np.nan
    return frame


def rulebase(tmp_path, inputs=("CV[k-1]",)):
    spans = {"CV": (0.0, 100.0), "P1": (0.0, 1000.0)}
    return RuleBase.new(
        "m",
        Variable("F[k]", "F", "t/h", (0.0, 40.0), 31),
        [Variable(s, s[0], "", spans[s.split("[")[0]], 31) for s in inputs],
        path=tmp_path / "m.toml",
    )


def reader(frame):
    return lambda a, b: frame[(frame.index >= a) & (frame.index < b)]


def test_chunked_training_equals_one_pass(tmp_path):
    f = plant_frame(6, seed=21)
    rb = rulebase(tmp_path, ("CV[k-1]", "P1[k]"))
    a, b = f.index[0], f.index[-1] + pd.Timedelta("10s")
    one = train(rb, reader(f), a, b, chunk=pd.Timedelta(days=30))
    many = train(rb, reader(f), a, b, chunk=pd.Timedelta(hours=7))
    np.testing.assert_array_equal(one.model.keys_, many.model.keys_)
    np.testing.assert_array_equal(one.model.conclusions_, many.model.conclusions_)
    assert one.validation == pytest.approx(many.validation, rel=1e-12)
    # one row of lag history and the 50 rows whose CV[k-1] is missing
    assert one.samples == many.samples == len(f) - 51
    assert one.dropped == many.dropped == {"history for the lags": 1, "CV missing or bad": 50}
    assert one.rows == many.rows == len(f)


def test_validation_is_out_of_sample_and_in_percent_of_span(tmp_path):
    f = plant_frame(6, seed=5)
    a, b = f.index[0], f.index[-1] + pd.Timedelta("10s")
    with_p = train(rulebase(tmp_path, ("CV[k-1]", "P1[k]")), reader(f), a, b)
    without_p = train(rulebase(tmp_path, ("CV[k-1]",)), reader(f), a, b)
    assert with_p.validation_range[0] == a + (b - a) * 0.8
    v = with_p.validation
    assert 0 < v["rmse_pct"] < 2 and v["coverage"] > 0.99
    assert without_p.validation["rmse_pct"] > 2 * v["rmse_pct"]
    # the reported error is computed on the held-out block only
    n_val = v["samples"]
    assert n_val == pytest.approx(0.2 * len(f), rel=0.01)


def test_locked_rules_are_used_in_validation(tmp_path):
    f = plant_frame(3, seed=8)
    a, b = f.index[0], f.index[-1] + pd.Timedelta("10s")
    rb = rulebase(tmp_path)
    rb.apply_training(train(rb, reader(f), a, b).model)
    for r in rb.rules:
        r.lock, r.then = True, 0.0  # an expert pins every rule to zero flow
    res = train(rb, reader(f), a, b)
    mean_f = f["F"].iloc[int(0.8 * len(f)) :].mean()
    assert res.validation["bias_pct"] == pytest.approx(mean_f / 40 * 100, rel=0.02)


def test_error_stats_merge():
    y = np.arange(10.0)
    a, b, c = ErrorStats(10.0), ErrorStats(10.0), ErrorStats(10.0)
    a.update(y[:4], y[:4] + 1)
    b.update(y[4:], y[4:] - 1)
    c.update(y, np.r_[y[:4] + 1, y[4:] - 1])
    assert a.merge(b).result() == c.result()
    assert c.result()["rmse_pct"] == pytest.approx(10.0)
