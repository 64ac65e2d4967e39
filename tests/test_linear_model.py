"""The ``linear`` method (a short window's PCA-like test): least squares that merge exactly,
no support outside the span it learned, a file that round-trips with any tag name."""

from __future__ import annotations

import numpy as np
import pytest

from diag_plugin.models.linear import LinearRegressor
from diag_plugin.models.spec import Variable
from diag_plugin.rulebase.document import RuleBase


def _data(n=500, seed=0):
    rng = np.random.default_rng(seed)
    X = rng.uniform([0, 10], [5, 20], (n, 2))
    return X, 3.0 + 0.5 * X[:, 0] - 2.0 * X[:, 1] + rng.normal(0, 0.01, n)


def test_coefficients_and_the_merge_of_parts_is_the_fit_of_all():
    X, y = _data()
    spans = [(0.0, 5.0), (10.0, 20.0)]
    whole = LinearRegressor(input_spans=spans).fit(X, y)
    assert np.allclose(whole.coef_, [3.0, 0.5, -2.0], atol=0.01)
    a = LinearRegressor(input_spans=spans).fit(X[:200], y[:200])
    b = LinearRegressor(input_spans=spans).fit(X[200:], y[200:])
    assert np.allclose(a.merge(b).coef_, whole.coef_, rtol=1e-9, atol=1e-9)
    back = LinearRegressor.from_state(whole.to_state())
    assert np.allclose(back.predict(X), whole.predict(X))


def test_no_support_outside_the_span_it_learned():
    X, y = _data()
    m = LinearRegressor(input_spans=[(0.0, 5.0), (10.0, 20.0)]).fit(X, y)
    p = m.predict_detail(np.array([[2.0, 15.0], [7.0, 15.0], [np.nan, 15.0]]))
    assert p.support.tolist() == [1.0, 0.0, 0.0]
    assert np.isfinite(p.y[:2]).all()


def test_the_file_round_trips_a_quoted_tag_and_refuses_products():
    X, y = _data()
    ins = [Variable('"Flow rate"[k]', "F", "", (0.0, 5.0)), Variable("T[k]", "T", "", (10, 20))]
    rb = RuleBase.new("m", Variable("y[k]", "y", "", (-40, 10)), ins, method="linear")
    rb.apply_training(rb.new_model().fit(X, y), {"source": "test"})
    back = RuleBase(rb.dumps(), "m.toml")
    assert not back.problems
    assert np.allclose(back.to_model().predict(X), rb.new_model().fit(X, y).predict(X))
    bad = back.dumps().replace(
        '{ term = "1",', '{ term = "T[k]^2", coef = 1.0 },\n    { term = "1",'
    )
    with pytest.raises(Exception, match="a linear model has only"):
        RuleBase(bad, "bad.toml").to_model()
