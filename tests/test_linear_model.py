"""The ``linear`` method (a short window's PCA-like test): least squares that merge exactly,
past the span it learned an answer only while the line moves little, a file that
round-trips with any tag name."""

from __future__ import annotations

import numpy as np
import pytest

from diag_plugin.models.linear import EDGE_MOVE, LinearRegressor
from diag_plugin.models.protocol import REASON_OUTSIDE
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


def test_past_its_span_it_answers_only_while_the_lines_move_is_small():
    """Past an input's span the test answers along the line while the line's move beyond
    the edge is within EDGE_MOVE of the output's span; further out it has no support (the
    prediction at the edge)."""
    X, y = _data()
    m = LinearRegressor(input_spans=[(0.0, 5.0), (10.0, 20.0)]).fit(X, y)
    lo, hi = m.output_span_
    room = EDGE_MOVE * (hi - lo)  # about 0.25 * 22
    b = m.coef_[1:]
    near = 5.0 + 0.9 * room / abs(b[0])  # the first input past its span, a move of 0.9 room
    far = 5.0 + 1.1 * room / abs(b[0])  # … of 1.1 room
    rows = np.array([[2.0, 15.0], [near, 15.0], [far, 15.0], [2.0, 10.0 - 1.1 * room / abs(b[1])],
                     [np.nan, 15.0]])  # fmt: skip
    p = m.predict_detail(rows)
    assert p.support.tolist() == [1.0, 1.0, 0.0, 0.0, 0.0]
    assert (p.reason[1:4] == REASON_OUTSIDE).all()
    line = m.coef_[0] + rows[:, :2] @ b
    assert p.y[1] == pytest.approx(line[1], rel=1e-9)  # along the line, not at the edge
    edge = m.coef_[0] + np.array([5.0, 15.0]) @ b
    assert p.y[2] == pytest.approx(edge, rel=1e-9)  # unknown: the edge's value, as before
    assert np.isfinite(p.y[:4]).all()


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


def test_the_allowance_past_the_span_is_a_share_of_the_output_s_learned_range():
    """``[rules] learned_output`` (a short window's output range where its span is a meter's,
    issue 34 item 3): the line's move past an input's span is held to EDGE_MOVE of that range,
    not of the meter's; the file keeps it, and a malformed one is refused."""
    from diag_plugin.rulebase.document import RuleBaseError

    X, y = _data()
    ins = [Variable("a[k]", "a", "", (0.0, 5.0)), Variable("b[k]", "b", "", (10.0, 20.0))]
    rb = RuleBase.new("m", Variable("y[k]", "y", "", (-200.0, 200.0)), ins, method="linear")
    rb.doc["rules"]["learned_output"] = [-37.0, -15.0]  # about what y spans over the data
    rb.edited()
    rb.apply_training(rb.new_model().fit(X, y), {"source": "test"})
    text = rb.dumps()
    back = RuleBase(text, "m.toml")
    assert back.options["learned_output"] == [-37.0, -15.0]
    meter = RuleBase(text.replace("learned_output = [-37.0, -15.0]\n", ""), "n.toml")
    assert "learned_output" not in meter.options
    m = back.to_model()
    room = EDGE_MOVE * 22.0
    mid = 5.0 + 2.0 * room / abs(m.coef_[1])  # twice the learned allowance, within the meter's
    rows = np.array([[2.0, 15.0], [mid, 15.0]])
    assert m.predict_detail(rows).support.tolist() == [1.0, 0.0]
    assert meter.to_model().predict_detail(rows).support.tolist() == [1.0, 1.0]
    for bad in ("[-15.0, -37.0]", "[1.0]", '"x"'):
        with pytest.raises(RuleBaseError, match="learned_output must be"):
            RuleBase(text.replace("[-37.0, -15.0]", bad), "bad.toml")
    with pytest.raises(RuleBaseError, match="takes no option 'learned_input'"):
        RuleBase(text.replace("learned_output", "learned_input"), "o.toml")


def test_the_within_merge_is_the_fixed_effects_fit_of_the_points():
    """``within_merge``: one line over operating points with an intercept each, exact on the
    QR factors — the slopes of a least-squares fit of every point's rows about its own means,
    the intercept through the grand means; ``merge`` (one line through every point) bends
    its slopes to cover an offset between the points that no input carries."""
    from diag_plugin.models.linear import LinearRegressor, within_merge

    rng = np.random.default_rng(7)
    spans = [(0.0, 12.0), (0.0, 5.0)]

    def point(n, offset, shift):
        X = rng.uniform(0, 1, (n, 2)) * [10.0, 5.0]
        X[:, 0] += shift  # the points also differ in an input: the slopes must not take it
        y = 2.0 + 1.5 * X[:, 0] - 0.7 * X[:, 1] + offset + rng.normal(0, 0.1, n)
        return X, y

    parts = [point(400, 0.0, 0.0), point(150, 3.0, 1.5), point(90, -2.0, 0.5)]
    fits = [LinearRegressor(input_spans=spans).fit(X, y) for X, y in parts]
    pooled = LinearRegressor(input_spans=spans).fit(
        np.vstack([X for X, _ in parts]), np.concatenate([y for _, y in parts])
    )
    got = within_merge(fits)
    Xd = np.vstack([X - X.mean(axis=0) for X, _ in parts])
    yd = np.concatenate([y - y.mean() for _, y in parts])
    slopes = np.linalg.lstsq(Xd, yd, rcond=None)[0]
    np.testing.assert_allclose(got.coef_[1:], slopes, rtol=1e-9)
    X_all = np.vstack([X for X, _ in parts])
    y_all = np.concatenate([y for _, y in parts])
    assert got.coef_[0] == pytest.approx(y_all.mean() - slopes @ X_all.mean(axis=0), rel=1e-9)
    assert got.output_mean_ == pytest.approx(y_all.mean())
    assert abs(got.coef_[1] - 1.5) < 0.02 and abs(pooled.coef_[1] - 1.5) > 0.1, pooled.coef_


def test_input_noise_corrects_the_slope_least_squares_shrink():
    """A noisy input's least-squares slope is shrunk towards 0 by var(x) / (var(x) + σ²)
    (regression dilution; the 7-tag line's tank rate: 1,069 for its 1,200). Given the
    input's noise variance (``[rules] input_noise``, one per input), the fit subtracts it
    from the normal equations and finds the slope; the file carries it, its folds too
    (``rb.new_model()``), and a variance per input, not negative, is all it takes."""
    rng = np.random.default_rng(5)
    n = 20000
    true = rng.normal(0.0, 1.0, n)
    z = rng.uniform(0.0, 5.0, n)
    x = np.column_stack([z, true + rng.normal(0.0, 0.5, n)])  # noise var 0.25: shrink 0.8
    y = 1.0 + 0.5 * z + 2.0 * true + rng.normal(0.0, 0.05, n)
    spans = [(0.0, 5.0), (-4.0, 4.0)]
    ols = LinearRegressor(input_spans=spans).fit(x, y)
    assert ols.coef_[2] == pytest.approx(1.6, abs=0.05)  # 2 × 1 / 1.25
    eiv = LinearRegressor(input_spans=spans, input_noise=(0.0, 0.25)).fit(x, y)
    assert np.allclose(eiv.coef_, [1.0, 0.5, 2.0], atol=0.05)
    half = LinearRegressor(input_spans=spans, input_noise=(0.0, 0.25)).fit(x[: n // 2], y[: n // 2])
    rest = LinearRegressor(input_spans=spans, input_noise=(0.0, 0.25)).fit(x[n // 2 :], y[n // 2 :])
    assert np.allclose(half.merge(rest).coef_, eiv.coef_, rtol=1e-9, atol=1e-9)
    ins = [Variable("Z[k]", "Z", "", spans[0]), Variable("X[k]", "X", "", spans[1])]
    rb = RuleBase.new("m", Variable("y[k]", "y", "", (-10, 20)), ins, method="linear")
    rb.doc["rules"]["input_noise"] = [0.0, 0.25]
    rb.edited()
    rb.apply_training(rb.new_model().fit(x, y), {"source": "test"})
    back = RuleBase(rb.dumps(), "m.toml")
    assert not back.problems
    assert np.allclose(back.to_model().coef_, eiv.coef_, rtol=1e-6)
    assert np.allclose(back.new_model().fit(x, y).coef_, eiv.coef_, rtol=1e-9)
    bad = back.dumps().replace("input_noise = [0.0, 0.25]", "input_noise = [-1.0, 0.25]")
    with pytest.raises(Exception, match="input_noise must be one variance"):
        RuleBase(bad, "bad.toml")
