"""WangMendelStack: many fitted models in one call give each model's own predictions."""

from __future__ import annotations

import numpy as np
import pytest

from diag_plugin.fuzzy.stack import WangMendelStack
from diag_plugin.fuzzy.wang_mendel import WangMendelRegressor, _fields, pack


def _models(seed: int) -> list[WangMendelRegressor]:
    """Models of 1–3 inputs, both methods, both shapes, some with sparse rule coverage."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(12):
        d = 1 + i % 3
        n = 300 if i % 4 else 40  # few samples: many cells never trained
        X = rng.uniform(-1, 2, (n, d))
        y = np.sin(X).sum(axis=1) * (1 + i) + rng.normal(0, 0.05, n)
        m = WangMendelRegressor(
            n_sets=int(rng.integers(3, 12)),
            method="wm" if i % 2 else "wm-avg",
            shape="triangular" if i % 5 == 0 else "trapezoidal",
        )
        out.append(m.fit(X, y))
    return out


@pytest.mark.parametrize("seed", [3, 71])
def test_stacked_prediction_equals_each_models_own(seed):
    models = _models(seed)
    stack = WangMendelStack.from_models(models)
    rng = np.random.default_rng(seed + 1)
    n = 5000
    which = rng.integers(0, len(models), n)
    X = rng.uniform(-1.5, 2.5, (n, 3))  # beyond the spans too: clipped, reason "outside"
    X[rng.random((n, 3)) < 0.03] = np.nan
    got = stack.predict_detail(which, X)
    checked, levels = set(), set()
    for j, m in enumerate(models):
        rows = which == j
        want = m.predict_detail(X[rows, : m.n_features_in_])
        np.testing.assert_array_equal(got.y[rows], want.y)
        np.testing.assert_array_equal(got.support[rows], want.support)
        np.testing.assert_array_equal(got.reason[rows], want.reason)
        np.testing.assert_array_equal(got.level[rows], want.level)
        checked |= set(np.unique(want.reason).tolist())
        levels |= set(np.unique(want.level).tolist())
        # once every level's rules are packed (a replay's later pieces) the coarse levels are
        # asked in one call: the same bits
        last = m.n_levels_ - 1
        m.__dict__.setdefault("_packs", {})[last] = pack([m.inference_grid(last)], dense=True)
        again = m.predict_detail(X[rows, : m.n_features_in_])
        for a, b in zip(_fields(again), _fields(want), strict=True):
            np.testing.assert_array_equal(a, b)
    assert checked >= {0, 1, 2, 3}  # ok, NaN input, unsupported and outside all exercised
    assert levels >= {-1, 0, 1, 2}  # unanswered, the fine grid and coarser levels


def test_a_nan_in_a_column_the_model_does_not_read_is_ignored():
    models = _models(5)
    one_input = next(i for i, m in enumerate(models) if m.n_features_in_ == 1)
    stack = WangMendelStack.from_models(models)
    X = np.array([[0.5, np.nan, np.nan]])
    got = stack.predict_detail(np.array([one_input]), X)
    want = models[one_input].predict_detail(X[:, :1])
    np.testing.assert_array_equal(got.y, want.y)
    assert np.isfinite(got.y).all()


def test_bad_calls_are_refused():
    models = _models(9)
    stack = WangMendelStack.from_models(models)
    with pytest.raises(ValueError, match="index"):
        stack.predict(np.array([len(models)]), np.zeros((1, 3)))
    with pytest.raises(ValueError, match="columns"):
        stack.predict(np.array([2]), np.zeros((1, 1)))  # model 2 has 3 inputs
    with pytest.raises(RuntimeError, match="not trained"):
        WangMendelStack.from_models([WangMendelRegressor()])
    assert not WangMendelStack.accepts(WangMendelRegressor())
    assert WangMendelStack.accepts(models[0])


def test_rules_edited_after_stacking_need_a_new_stack():
    m = _models(11)[1]
    before = WangMendelStack.from_models([m])
    grid = m.inference_grid()
    m.set_rules(grid.keys[0], grid.conclusions[0] + 1.0, counts=m.count_)
    X = np.random.default_rng(0).uniform(0, 1, (50, m.n_features_in_))
    w = np.zeros(50, np.int64)
    after = WangMendelStack.from_models([m])
    np.testing.assert_array_equal(after.predict(w, X), m.predict(X))
    ok = np.isfinite(m.predict(X))
    np.testing.assert_allclose(before.predict(w, X)[ok] + 1.0, m.predict(X)[ok])
