"""narmax2: the second-order polynomial model of Laukonen et al. (eq. 12) by batch least squares,
behind the model seam (estimator, codec, file, CLI)."""

import itertools
import json
import re

import numpy as np
import pytest
from helpers import (
    broken_edit_is_named,
    cli_new_train_compare,
    compares_and_explains,
    free_run_is_the_reference,
    run_diag,
    trained_valve_file,
)

from diag_plugin.models import Model
from diag_plugin.models.narmax import Narmax2Regressor, parse_term, term_pairs
from diag_plugin.models.protocol import REASON_NAN, REASON_OK, REASON_OUTSIDE
from diag_plugin.rulebase.document import RuleBase, Variable

SPANS = [(0.0, 100.0), (200.0, 1800.0), (-5.0, 5.0)]


#: the method of the model files (the ``trained`` fixture of conftest.py reads it)
METHOD = "narmax2"


def poly_data(n=3000, seed=0):
    """Inputs over engineering spans and an exact second-order polynomial of them."""
    rng = np.random.default_rng(seed)
    X = np.column_stack([rng.uniform(lo, hi, n) for lo, hi in SPANS])
    terms = term_pairs(3)
    coef = rng.normal(0, 1, len(terms)) / np.array(
        [np.prod([max(abs(SPANS[i][0]), abs(SPANS[i][1])) for i in t]) for t in terms]
    )
    y = sum(c * np.prod([X[:, i] for i in t], axis=0) for c, t in zip(coef, terms, strict=True))
    return X, y, coef


def test_least_squares_recovers_an_exact_second_order_polynomial():
    X, y, coef = poly_data()
    m = Narmax2Regressor(input_spans=SPANS).fit(X, y)
    assert isinstance(m, Model)
    np.testing.assert_allclose(m.coef_, coef, rtol=1e-8, atol=1e-12)
    assert np.abs(m.predict(X) - y).max() < 1e-8 * np.abs(y).max()
    assert m.n_samples_seen_ == len(y) and m.output_mean_ == pytest.approx(y.mean())
    # spans from the data give the same coefficients (scaling is internal)
    np.testing.assert_allclose(Narmax2Regressor().fit(X, y).coef_, coef, rtol=1e-8, atol=1e-12)


def test_a_missing_term_is_not_invented():
    X, y, _ = poly_data()
    lin = 3.0 + 0.5 * X[:, 0] - 0.01 * X[:, 1]
    c = Narmax2Regressor(input_spans=SPANS).fit(X, lin).coef_
    np.testing.assert_allclose(c[:3], [3.0, 0.5, -0.01], rtol=1e-9)
    assert np.abs(c[3:]).max() < 1e-10


def test_partial_fit_and_merge_equal_one_fit():
    assert Narmax2Regressor.capabilities.incremental and Narmax2Regressor.capabilities.mergeable
    X, y, _ = poly_data(seed=1)
    y = y + np.random.default_rng(2).normal(0, 0.1, y.size)  # not exact: residuals matter
    whole = Narmax2Regressor(input_spans=SPANS).fit(X, y)
    parts = Narmax2Regressor(input_spans=SPANS)
    for a in range(0, len(y), 700):
        parts.partial_fit(X[a : a + 700], y[a : a + 700])
    np.testing.assert_allclose(parts.coef_, whole.coef_, rtol=1e-9)
    left = Narmax2Regressor(input_spans=SPANS).fit(X[:1000], y[:1000])
    right = Narmax2Regressor(input_spans=SPANS).fit(X[1000:], y[1000:])
    merged = left.merge(right)
    np.testing.assert_allclose(merged.coef_, whole.coef_, rtol=1e-9)
    assert merged.n_samples_seen_ == whole.n_samples_seen_
    assert merged.qr_.rss == pytest.approx(whole.qr_.rss, rel=1e-6)
    with pytest.raises(ValueError, match="different input spans"):
        Narmax2Regressor().fit(X[:50], y[:50]).merge(right)


def test_state_round_trips_through_json():
    X, y, _ = poly_data(seed=3)
    m = Narmax2Regressor(input_spans=SPANS, output_lags=[0, 0, 0]).fit(X, y)
    back = Narmax2Regressor.from_state(json.loads(json.dumps(m.to_state())))
    np.testing.assert_array_equal(back.predict(X), m.predict(X))
    # the statistics survive too: training can continue on the restored model
    more = Narmax2Regressor.from_state(m.to_state()).partial_fit(X[:100], y[:100])
    assert more.n_samples_seen_ == m.n_samples_seen_ + 100


def test_reasons_for_missing_and_out_of_span_inputs():
    X, y, _ = poly_data(seed=4)
    m = Narmax2Regressor(input_spans=SPANS).fit(X, y)
    Q = np.array([[50.0, 1000.0, 0.0], [np.nan, 1000.0, 0.0], [150.0, 1000.0, 0.0]])
    det = m.predict_detail(Q)
    assert list(det.reason) == [REASON_OK, REASON_NAN, REASON_OUTSIDE]
    assert np.isnan(det.y[1]) and np.isfinite(det.y[[0, 2]]).all()
    assert det.y[2] == pytest.approx(m.predict([[100.0, 1000.0, 0.0]])[0])  # clipped
    assert m.extrapolate(Q)[1] == pytest.approx(m.output_mean_)


def arx_data(n=600, seed=5):
    """y[k] = 0.6 y[k-1] + 0.3 u[k-1] + 0.002 u[k-1]² (exact, nonlinear, with feedback)."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(0, 100, n)
    y = np.zeros(n)
    for k in range(1, n):
        y[k] = 0.6 * y[k - 1] + 0.3 * u[k - 1] + 0.002 * u[k - 1] ** 2
    X = np.column_stack([y[:-1], u[:-1]])  # rows k = 1 … n-1: y[k-1], u[k-1]
    return X, y[1:]


def test_free_run_feeds_back_the_models_own_outputs():
    X, y = arx_data()
    rb = RuleBase.new(
        "arx",
        Variable("Y[k]", "Y", "", (0.0, 200.0)),
        [Variable("Y[k-1]", "Y", "", (0.0, 200.0)), Variable("U[k-1]", "U", "", (0.0, 100.0))],
        method="narmax2",
    )
    m = rb.new_model().fit(X, y)
    assert m.capabilities.free_run and m.output_lags == [1, 0]
    sim = m.simulate(X)
    np.testing.assert_allclose(sim, y, rtol=1e-9, atol=1e-9)
    # measured lags spoilt after the first row: the free run does not look at them ...
    bad = X.copy()
    bad[1:, 0] += 5.0
    np.testing.assert_allclose(m.simulate(bad), sim, rtol=1e-12)
    # ... while the one-step-ahead prediction does
    assert np.abs(m.predict(bad) - y)[1:].min() > 1.0
    static = RuleBase.new(
        "s",
        Variable("Y[k]", "Y", "", (0.0, 200.0)),
        [Variable("U[k-1]", "U", "", (0.0, 100.0))],
        method="narmax2",
    )
    assert not static.new_model().capabilities.free_run
    assert Narmax2Regressor.capabilities.free_run  # what the method can do


def test_terms_parse_in_any_order_and_reject_higher_orders():
    specs = ["CV[k-1]", "diff(P1,P2)[k]"]
    assert parse_term("1", specs) == ()
    assert parse_term("diff(P1,P2)[k]*CV[k-1]", specs) == (0, 1)
    assert parse_term("CV[k - 1]^2", specs) == (0, 0)
    with pytest.raises(ValueError, match="order 3"):
        parse_term("CV[k-1]^2*CV[k-1]", specs)
    with pytest.raises(ValueError, match="not an input"):
        parse_term("P1[k]", specs)
    assert len(term_pairs(4)) == 1 + 4 + 10
    assert all(len(t) <= 2 for t in itertools.chain(term_pairs(3)))


def test_model_file_lists_terms_round_trips_and_predicts_like_the_model(tmp_path):
    rb, res, f = trained_valve_file(tmp_path, METHOD)
    text = rb.path.read_text()
    assert 'method = "narmax2"' in text
    for term in ("1", "CV[k-1]", "CV[k-1]^2", "CV[k-1]*P1[k]", "P1[k]^2"):
        assert re.search(r'\{ term = "' + re.escape(term) + r'", coef = [-0-9.e]+ \}', text), term
    loaded = RuleBase.load(rb.path)
    assert loaded.dumps() == text  # unedited: the same bytes
    loaded.save()
    assert rb.path.read_text() == text
    # the file's coefficients (12 digits) predict like the trained model
    from diag_plugin.regressors import build_design

    d = build_design(f, [v.spec for v in rb.inputs], rb.output.spec)
    np.testing.assert_allclose(loaded.to_model().predict(d.X), res.model.predict(d.X), atol=1e-6)
    # a term deleted by the expert counts 0, and a comment stays with its term
    lines = text.splitlines()
    i = next(k for k, ln in enumerate(lines) if '"P1[k]^2"' in ln)
    edited = lines[:i] + lines[i + 1 :]
    j = next(k for k, ln in enumerate(edited) if '"CV[k-1]"' in ln)
    edited[j] += "  # slope of the valve"
    (tmp_path / "e.toml").write_text("\n".join(edited) + "\n")
    e = RuleBase.load(tmp_path / "e.toml")
    assert len(e.rules) == len(res.model.terms_) - 1
    e.apply_training(res.model)
    assert "# slope of the valve" in e.dumps() and '"P1[k]^2"' in e.dumps()


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ('term = "CV[k-1]^2"', 'term = "P9[k]^2"', r"'P9\[k\]' is not an input"),
        (
            'term = "CV[k-1]", coef = ',
            'term = "CV[k-1]", coef = "x", z = ',
            "coef must be a number",
        ),
        ('term = "CV[k-1]^2"', 'term = "CV[k-1]"', "duplicate term"),
    ],
)
def test_a_broken_edit_names_file_and_line(trained, tmp_path, old, new, message):
    broken_edit_is_named(trained[0].path, tmp_path, old, new, r"term \d+: " + message)


def test_trains_compares_and_explains_through_the_seam(tmp_path):
    rb, res, f = trained_valve_file(tmp_path, METHOD, seed=7)
    assert res.validation["rmse_pct"] < 5.0 and res.size == 6
    assert len(compares_and_explains(rb.path, f).regions) == 0


def test_cli_model_new_train_compare(cli_plant):
    plant = cli_plant
    _, text = cli_new_train_compare(plant, "nx", "narmax2")
    assert text.count("{ term = ") == 3  # 1, CV[k-1], CV[k-1]^2
    shown = run_diag(plant, "rules", "show", "nx")
    assert shown.returncode == 0 and "CV[k-1]^2" in shown.stdout, shown.stderr
    fcl = run_diag(plant, "rules", "export-fcl", "nx")
    assert fcl.returncode != 0 and "no IEC 61131-7 FCL form" in fcl.stderr


def test_the_compiled_free_run_is_the_row_by_row_one():
    free_run_is_the_reference(
        lambda lags, spans: Narmax2Regressor(output_lags=lags, input_spans=spans)
    )
