"""The model seam (issue 7): a method is an estimator and a codec behind the registry, and
training, compare and explain reach it only through the protocol. A toy method proves it."""

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from helpers import valve_frame

from diag_plugin.models import METHODS, Capabilities, Method, Model, Prediction
from diag_plugin.rulebase.document import RuleBase, RuleBaseError, Variable
from diag_plugin.training.chunked import train
from diag_plugin.workbench.compare import compare
from diag_plugin.workbench.explain import explain


class MeanModel:
    """Predicts the training mean of the output, whatever the inputs."""

    capabilities = Capabilities(incremental=True, mergeable=True)

    def __init__(self):
        self.n_samples_seen_ = 0
        self.sum_ = 0.0

    def fit(self, X, y):
        self.n_samples_seen_, self.sum_ = 0, 0.0
        return self.partial_fit(X, y)

    def partial_fit(self, X, y):
        self.n_samples_seen_ += len(y)
        self.sum_ += float(np.sum(y))
        return self

    def predict_detail(self, X):
        X = np.asarray(X, float).reshape(len(X), -1)
        y = np.full(len(X), self.sum_ / self.n_samples_seen_ if self.n_samples_seen_ else np.nan)
        y[np.isnan(X).any(axis=1)] = np.nan
        return Prediction(y, np.isfinite(y).astype(float), np.where(np.isfinite(y), 0, 1))

    def predict(self, X):
        return self.predict_detail(X).y

    @property
    def output_mean_(self):
        return self.sum_ / self.n_samples_seen_ if self.n_samples_seen_ else float("nan")

    def extrapolate(self, X, pred=None):
        y = self.predict(X) if pred is None else np.array(pred, float)
        return np.where(np.isfinite(y), y, self.output_mean_)

    def merge(self, other):
        self.n_samples_seen_ += other.n_samples_seen_
        self.sum_ += other.sum_
        return self

    def to_state(self):
        return {"n": self.n_samples_seen_, "sum": self.sum_}

    @classmethod
    def from_state(cls, state):
        m = cls()
        m.n_samples_seen_, m.sum_ = state["n"], state["sum"]
        return m


class MeanCodec:
    """Its file part: ``[rules] list = [{ then = MEAN, n = N }]``."""

    def __init__(self, method):
        self.method = method

    def new_estimator(self, spec):
        return MeanModel()

    def to_model(self, rb):
        return MeanModel.from_state(rb.rules[0] if rb.rules else {"n": 0, "sum": 0.0})

    def predictor(self, rb, model):
        return model

    def apply_training(self, rb, model):
        return [model.to_state()]

    def size(self, model):
        return 1

    def read_rules(self, rb, items, positions):
        out = []
        for (line, _, _), item in zip(positions, items, strict=False):
            if not isinstance(item.get("then"), float):
                rb.error(line, "then must be a number")
                continue
            out.append({"n": item.get("n", 1), "sum": item["then"] * item.get("n", 1)})
        return out

    def format_rules(self, rb):
        rows = [
            f"    {{ then = {r['sum'] / max(r['n'], 1)!r}, n = {r['n']} }},\n" for r in rb.rules
        ]
        return "list = [\n" + "".join(rows) + "]\n"


@pytest.fixture
def mean_method(monkeypatch):
    """The toy method, registered the way a real one is: one line in the registry."""
    import sys
    import types

    mod = types.ModuleType("toy_mean_method")
    mod.MeanCodec = MeanCodec
    monkeypatch.setitem(sys.modules, "toy_mean_method", mod)
    monkeypatch.setitem(METHODS, "mean", Method("mean", "toy_mean_method", "MeanCodec", "mean"))


def test_a_new_method_trains_compares_and_explains_through_the_seam(tmp_path, mean_method):
    f = valve_frame(3, seed=12)
    rb = RuleBase.new(
        "m",
        Variable("F[k]", "F", "t/h", (0.0, 40.0), 31),
        [Variable("CV[k-1]", "CV", "%", (0.0, 100.0), 31)],
        method="mean",
        path=tmp_path / "m.toml",
    )
    assert isinstance(rb.new_model(), Model)
    a, b = f.index[0], f.index[-1] + pd.Timedelta("10s")
    res = train(rb, lambda s, e: f[(f.index >= s) & (f.index < e)], a, b, chunk=pd.Timedelta("9h"))
    cut = f.index >= res.validation_range[0]
    want = (f["F"][cut] - f["F"][~cut].iloc[1:].mean()).pow(2).mean() ** 0.5 / 40 * 100
    assert res.validation["rmse_pct"] == pytest.approx(want, rel=1e-3)
    rb.apply_training(res.model, {"samples": res.samples})
    rb.save()
    loaded = RuleBase.load(rb.path)
    assert loaded.rules[0]["n"] == res.samples
    c = compare(loaded, f)
    assert c.metrics["coverage"] > 0.99 and len(c.regions) == 0  # no rule regions declared
    e = explain(loaded, f, max_lag=2)
    assert e.candidates and math.isfinite(e.baseline_rmse_pct)
    # its own file errors come with the line
    bad = loaded.text.replace("then = ", 'then = "x", z = ')
    (tmp_path / "bad.toml").write_text(bad)
    with pytest.raises(RuleBaseError, match=r"bad\.toml:\d+: then must be a number"):
        RuleBase.load(tmp_path / "bad.toml")


def test_an_unknown_method_is_a_file_line_error(tmp_path):
    text = (Path(__file__).parents[1] / "rulebases" / "valve_b.toml").read_text()
    (tmp_path / "x.toml").write_text(text.replace('method = "wm-avg"', 'method = "ts-xyz"'))
    with pytest.raises(RuleBaseError, match=r"x\.toml:\d+: method must be one of wm-avg, wm"):
        RuleBase.load(tmp_path / "x.toml")


@pytest.mark.parametrize("method", [m for m, v in METHODS.items() if v.identifies])
def test_every_method_extrapolates_from_the_prediction_it_is_given(method):
    """The seam's ``extrapolate(X, pred)``: every method takes the prediction the caller has
    (the held-out scorer passes it always) and answers as when it computes it; a ``pred``
    shifted by one moves the answer by one where it has a value (so it is used, not
    recomputed)."""
    f = valve_frame(1, seed=3)
    f = f.dropna()
    X, y = f[["CV", "P1"]].to_numpy(float)[:3000], f["F"].to_numpy(float)[:3000]
    rb = RuleBase.new(
        "m",
        Variable("F[k]", "F", "t/h", (0.0, 40.0), 7),
        [
            Variable("CV[k]", "CV", "%", (0.0, 100.0), 7),
            Variable("P1[k]", "P1", "kPa", (300.0, 700.0), 7),
        ],
        method=method,
    )
    m = rb.codec.new_estimator(rb.spec).fit(X[:2000], y[:2000])
    Q = X[2000:].copy()
    Q[:5, 0] = np.nan  # no value: the stand-in
    Q[5:10, 0] = 250.0  # far outside the window: no rule, for a grid
    pred = m.predict(Q)
    want = m.extrapolate(Q)
    assert np.isfinite(want[5:]).all()
    assert np.array_equal(m.extrapolate(Q, pred=pred), want, equal_nan=True)
    has = np.isfinite(pred)
    assert has.any()
    moved = m.extrapolate(Q, pred=pred + 1.0)
    assert np.array_equal(moved[has], want[has] + 1.0)
    assert np.array_equal(moved[~has], want[~has], equal_nan=True)
