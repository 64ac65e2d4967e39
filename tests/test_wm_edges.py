"""A Wang–Mendel model with an input past its span follows the data's slope (issue 34): the
answer moves along the model's linear trend (derived from the fine rules) for up to a quarter
span past the span's end; inside the spans the answer is the rules' weighted mean as before.
The stack, numpy's and the compiled loops agree bit for bit, and the trend comes back from a
rule-base file with the rules."""

from __future__ import annotations

import numpy as np
import pytest

from diag_plugin.fuzzy import _kernels as K
from diag_plugin.fuzzy import _numpy_kernels as N
from diag_plugin.fuzzy.stack import WangMendelStack
from diag_plugin.fuzzy.wang_mendel import WangMendelRegressor, pack
from diag_plugin.rulebase.document import RuleBase, Variable


def _line(seed: int = 0) -> WangMendelRegressor:
    """y = 2x learned on x in [0, 1], the span [0, 1.5] (room past the data)."""
    x = np.random.default_rng(seed).uniform(0, 1, 2000)
    return WangMendelRegressor(input_spans=[(0.0, 1.5)], n_sets=31).fit(x[:, None], 2 * x)


def _diagonal(seed: int = 1) -> tuple[WangMendelRegressor, np.ndarray, np.ndarray]:
    """y = 3·x1 − x2 on two inputs that move together (x2 = x1 + noise), as a plant's
    coupled temperatures do; and samples at and past the two ends of that diagonal."""
    rng = np.random.default_rng(seed)
    x1 = rng.uniform(0, 1, 3000)
    X = np.column_stack([x1, x1 + rng.normal(0, 0.05, x1.size)])
    m = WangMendelRegressor(n_sets=31).fit(X, 3 * X[:, 0] - X[:, 1])
    Q = np.array([[0.9, 1.05], [1.0, 1.08], [0.95, 1.06], [0.1, -0.05], [0.05, -0.08]])
    return m, Q, 3 * Q[:, 0] - Q[:, 1]


def test_inside_the_data_with_every_fired_rule_trained_the_answer_is_the_rules_mean():
    m = _line()
    x = np.linspace(0.05, 0.95, 200)
    d = m.predict_detail(x[:, None])
    assert (d.level == 0).all() and (d.support == 1.0).all()
    p = m.partitions_[0]
    j, w = p.upper_weight(x)
    v = dict(zip(m.keys_.tolist(), m.conclusions_.tolist(), strict=True))
    vj = np.array([v[i] for i in j])
    vk = np.array([v[i] for i in j + 1])
    want = ((1.0 - w) * vj + w * vk) / ((1.0 - w) + w)  # the kernel's sums, in its order
    np.testing.assert_array_equal(d.y, want)


def test_an_edited_rule_moves_the_trend():
    m = _line()
    before = m.trend_.copy()
    m.set_rules(m.keys_, m.conclusions_ + 1.0, counts=m.count_)
    assert m.trend_[0] == pytest.approx(before[0] + 1.0)
    assert m.trend_[1] == pytest.approx(before[1])


def test_stack_numpy_and_compiled_loops_agree_at_the_edges_bit_for_bit():
    m, Q, _ = _diagonal()
    rng = np.random.default_rng(5)
    X = np.vstack([Q, rng.uniform(-0.5, 1.5, (3000, 2))])
    one = _line()
    stack = WangMendelStack.from_models([m, one])
    which = np.zeros(X.shape[0], np.int64)
    got = stack.predict_detail(which, X)
    own = m.predict_detail(X)  # the dense fine table, then the levels
    n = X.shape[0]
    out = {}
    for name, loops in (("compiled", K), ("numpy", N)):
        o = [np.empty(n), np.empty(n), np.empty(n, np.int8), np.empty(n, np.int8), np.empty(n)]
        loops.infer_levels(np.empty(0, np.int64), X, *pack([m.inference_grid()], True), *o)
        out[name] = o
    fields = ("y", "support", "reason", "level", "spread")
    for i, f in enumerate(fields):
        a, b, c, e = getattr(got, f), getattr(own, f), out["compiled"][i], out["numpy"][i]
        for u in (b, c, e):
            assert np.array_equal(np.asarray(a).view(np.uint8), np.asarray(u).view(np.uint8))
    assert (own.reason == 3).sum() > 100 and (own.level >= 1).sum() > 10  # past spans, levels
    x1 = np.linspace(-0.2, 1.6, 50)[:, None]
    np.testing.assert_array_equal(
        stack.predict(np.ones(50, np.int64), np.hstack([x1, x1])), one.predict(x1)
    )


def test_the_trend_comes_back_from_the_rule_base_file(tmp_path):
    rb = RuleBase.new(
        "line",
        Variable("Y[k]", "Y", "", (0.0, 3.0), 31),
        [Variable("X[k]", "X", "", (0.0, 1.5), 31)],
        period="60s",
    )
    x = np.random.default_rng(2).uniform(0, 1.5, 3000)
    rb.apply_training(rb.new_model().fit(x[:, None], 2 * x), {"source": "test"})
    path = rb.save(tmp_path / "line.toml")
    back = RuleBase.load(path)
    m = back.to_model()
    assert "trend" not in path.read_text()  # derived from the rules, not stored
    q = np.array([[1.6], [1.7]])  # past the span's end, 1.5
    assert m.predict(q) == pytest.approx([3.2, 3.4], abs=0.05)  # the edge rule's 3.0 before
    again = RuleBase.load(back.save(tmp_path / "again.toml")).to_model()
    np.testing.assert_array_equal(again.trend_, m.trend_)
    np.testing.assert_array_equal(again.predict(q), m.predict(q))


def test_past_the_span_the_answer_moves_along_the_trend_a_quarter_span_at_most():
    x = np.random.default_rng(3).uniform(0, 1, 2000)
    m = WangMendelRegressor(n_sets=31).fit(x[:, None], 2 * x)  # span: the range seen
    lo, hi = m.partitions_[0].lo, m.partitions_[0].hi
    q = np.array([[hi + 0.1], [hi + 0.25 * (hi - lo)], [hi + 5.0], [lo - 0.1], [0.5]])
    d = m.predict_detail(q)
    edge = m.predict(np.array([[hi], [lo]]))
    b = m.trend_[1]
    assert d.reason.tolist() == [3, 3, 3, 3, 0]  # still said: outside the span
    np.testing.assert_allclose(d.y[:2], edge[0] + b * (q[:2, 0] - hi), rtol=0, atol=1e-12)
    assert d.y[2] == pytest.approx(d.y[1], abs=1e-12)  # beyond the reach the answer holds
    assert d.y[3] == pytest.approx(edge[1] - 0.1 * b, abs=1e-12)
    assert d.y[0] == pytest.approx(2 * q[0, 0], abs=0.03)  # was the edge rule's ≈ 2.0
