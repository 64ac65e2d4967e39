"""Chunked training with a time-ordered held-out block (issue 3, training jobs)."""

import numpy as np
import pandas as pd
import pytest
from helpers import valve_frame as plant_frame

from diag_plugin.metrics import ErrorStats, residual_pct
from diag_plugin.rulebase.document import RuleBase, Variable
from diag_plugin.training.chunked import train


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
    a, b, c = ErrorStats(), ErrorStats(), ErrorStats()
    a.update(residual_pct(y[:4], y[:4] + 1, 10.0))
    b.update(residual_pct(y[4:], y[4:] - 1, 10.0))
    c.update(residual_pct(y, np.r_[y[:4] + 1, y[4:] - 1], 10.0))
    assert a.merge(b).result() == c.result()
    assert c.result()["rmse_pct"] == pytest.approx(10.0)


def test_dask_training_equals_in_process(tmp_path):
    """The Dask engine on a LocalCluster gives exactly the in-process rule base."""
    from distributed import LocalCluster

    from diag_plugin.training.dask_engine import dask_fitter

    f = plant_frame(4, seed=33)
    f.iloc[::997, 1] = np.nan
    path = tmp_path / "frame.parquet"
    f.to_parquet(path)
    rb = rulebase(tmp_path, ("CV[k-1]", "P1[k]"))
    a, b = f.index[0], f.index[-1] + pd.Timedelta("10s")
    chunk = pd.Timedelta(hours=9)
    local = train(rb, reader(f), a, b, chunk=chunk, keep_rows=True)
    with LocalCluster(
        n_workers=2, threads_per_worker=1, host="127.0.0.1", dashboard_address=None, processes=True
    ) as cluster:
        fitter = dask_fitter(cluster.scheduler_address, ParquetReader(str(path)))
        remote = train(rb, reader(f), a, b, chunk=chunk, fit_chunks=fitter, keep_rows=True)
    for attr in ("keys_", "count_", "qsum_", "qsq_"):
        np.testing.assert_array_equal(getattr(local.model, attr), getattr(remote.model, attr))
    rb_local = rulebase(tmp_path, ("CV[k-1]", "P1[k]"))
    rb_remote = rulebase(tmp_path, ("CV[k-1]", "P1[k]"))
    rb_local.apply_training(local.model)
    rb_remote.apply_training(remote.model)
    assert rb_local.dumps() == rb_remote.dumps()
    assert local.samples == remote.samples and local.dropped == remote.dropped
    assert local.validation == pytest.approx(remote.validation)
    # the rows a baseline is fitted and scored on: the same whichever engine trained
    assert len(local.design[1]) == local.training["samples"]
    assert len(local.design[3]) == local.validation["samples"]
    for x, y in zip(local.design, remote.design, strict=True):
        np.testing.assert_array_equal(x, y)


class ParquetReader:
    """A picklable reader a Dask worker can run: the worker reads the data itself."""

    def __init__(self, path):
        self.path = path

    def __call__(self, a, b):
        f = pd.read_parquet(self.path)
        return f[(f.index >= a) & (f.index < b)]
