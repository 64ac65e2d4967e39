"""ts-fcm: Takagi–Sugeno model with Fuzzy c-Means premises and weighted least-squares
consequents (Laukonen et al., eqs. 13–26), behind the model seam (estimator, codec, file, CLI)."""

import json

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

from diag_plugin.fuzzy import ts_fcm
from diag_plugin.fuzzy.ts_fcm import TakagiSugenoRegressor, fuzzy_c_means, memberships
from diag_plugin.models import Model
from diag_plugin.models.protocol import REASON_NAN, REASON_OK, REASON_OUTSIDE
from diag_plugin.rulebase.document import RuleBase, Variable

#: the method of the model files (the ``trained`` fixture of conftest.py reads it)
METHOD = "ts-fcm"


def blobs(centres, n=400, sd=0.05, seed=0):
    rng = np.random.default_rng(seed)
    centres = np.asarray(centres, float)
    label = np.repeat(np.arange(len(centres)), n)
    return centres[label] + rng.normal(0, sd, (label.size, centres.shape[1])), label


def match(found, want):
    """Largest distance from a wanted centre to its nearest found one (and vice versa)."""
    d = np.linalg.norm(found[:, None, :] - want[None, :, :], axis=2)
    return max(d.min(axis=0).max(), d.min(axis=1).max())


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fuzzy_c_means_recovers_well_separated_centres(seed):
    want = np.random.default_rng(100 + seed).uniform(0, 10, (4, 3))
    want[:, 0] += np.arange(4) * 12  # well separated
    X, _ = blobs(want, seed=seed)
    V, it = fuzzy_c_means(X, 4, m=2.0, eps=1e-4, max_iter=500, random_state=seed)
    assert 1 < it < 500
    assert match(V, want) < 0.05


def test_initial_centres_lie_within_the_data_range_and_are_seeded():
    lo, hi = np.array([0.0, 10.0]), np.array([1.0, 30.0])
    V = ts_fcm.initial_centres(lo, hi, 50, np.random.default_rng(3))  # eq. 18
    assert (V >= lo).all() and (V <= hi).all()
    X, _ = blobs([[0, 0], [3, 3]])
    a = fuzzy_c_means(X, 2, random_state=7)[0]
    np.testing.assert_array_equal(a, fuzzy_c_means(X, 2, random_state=7)[0])


def test_memberships_sum_to_one_and_a_centre_belongs_to_itself():
    V = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    Z = np.vstack([V, np.random.default_rng(0).uniform(-1, 2, (50, 2))])
    for m in (1.5, 2.0, 3.0):
        U = memberships(Z, V, m)
        np.testing.assert_allclose(U.sum(axis=1), 1.0)
        np.testing.assert_allclose(U[:3], np.eye(3), atol=1e-12)
    # eq. 26 at m = 2: inverse squared distances, normalised
    z = np.array([[0.25, 0.5]])
    w = 1 / ((z - V) ** 2).sum(axis=1)
    np.testing.assert_allclose(memberships(z, V, 2.0)[0], w / w.sum())


def piecewise_linear(seed=0):
    """Three separated operating regions, each with its own linear law."""
    centres = np.array([[10.0, 10.0], [50.0, 80.0], [90.0, 20.0]])
    laws = np.array([[1.0, 0.5, -2.0], [20.0, -0.3, 0.1], [-5.0, 0.2, 0.4]])  # const, slopes
    X, label = blobs(centres, n=500, sd=2.0, seed=seed)
    y = laws[label, 0] + np.einsum("ij,ij->i", laws[label, 1:], X)
    return X, y, centres, laws


def test_takagi_sugeno_reproduces_a_piecewise_linear_function():
    X, y, centres, laws = piecewise_linear()
    m = TakagiSugenoRegressor(n_clusters=3, m=1.5, eps=1e-5, input_spans=[(0, 100)] * 2)
    m.fit(X, y)
    assert isinstance(m, Model) and m.n_rules_ == 3
    assert match(m.centers_, centres) < 0.5
    order = [int(np.argmin(np.linalg.norm(centres - c, axis=1))) for c in m.centers_]
    np.testing.assert_allclose(m.intercept_, laws[order, 0], atol=1e-3)
    np.testing.assert_allclose(m.coef_, laws[order, 1:], atol=1e-4)
    assert np.abs(m.predict(X) - y).max() < 1e-3 * np.ptp(y)
    assert m.weight_.sum() == pytest.approx(len(y))
    assert m.output_mean_ == pytest.approx(y.mean())


def test_chunked_consequents_equal_one_weighted_least_squares(monkeypatch):
    """Eq. 24 with ``D_j²`` weights, solved over row chunks, against one direct solve."""
    rng = np.random.default_rng(4)
    X = rng.uniform(0, 1, (3000, 2))
    y = np.sin(3 * X[:, 0]) + X[:, 1] ** 2
    monkeypatch.setattr(ts_fcm, "CHUNK_ROWS", 512)
    m = TakagiSugenoRegressor(n_clusters=4, input_spans=[(0, 1)] * 2).fit(X, y)
    U = memberships(X, m.centers_, 2.0)
    A = np.column_stack([np.ones(len(X)), X])
    for j in range(4):
        c = np.linalg.lstsq(A * U[:, [j]], y * U[:, j], rcond=None)[0]
        np.testing.assert_allclose([m.intercept_[j], *m.coef_[j]], c, rtol=1e-8, atol=1e-10)


@pytest.mark.parametrize("power", [1.0, 2.0, 1.5])
def test_consequent_weights_follow_eq_23_or_eq_24(monkeypatch, power):
    """``weight_power`` p weights each rule's squared errors by μ^p: 1 is eq. 23's cost, 2 the
    ``D_j²`` of its stated solution eq. 24; chunked, against one direct weighted solve. The
    clustering is the same, the consequents differ (unless the data are exactly linear)."""
    rng = np.random.default_rng(5)
    X = rng.uniform(0, 1, (3000, 2))
    y = np.sin(3 * X[:, 0]) + X[:, 1] ** 2
    monkeypatch.setattr(ts_fcm, "CHUNK_ROWS", 512)
    m = TakagiSugenoRegressor(n_clusters=4, weight_power=power, input_spans=[(0, 1)] * 2)
    m.fit(X, y)
    U = memberships(X, m.centers_, 2.0)
    A = np.column_stack([np.ones(len(X)), X])
    for j in range(4):
        w = np.sqrt(U[:, j] ** power)
        c = np.linalg.lstsq(A * w[:, None], y * w, rcond=None)[0]
        np.testing.assert_allclose([m.intercept_[j], *m.coef_[j]], c, rtol=1e-8, atol=1e-10)
    other = TakagiSugenoRegressor(n_clusters=4, weight_power=3.0 - power, input_spans=[(0, 1)] * 2)
    other.fit(X, y)
    np.testing.assert_array_equal(other.centers_, m.centers_)
    if power != 1.5:
        assert np.abs(other.coef_ - m.coef_).max() > 1e-3
    assert TakagiSugenoRegressor().weight_power == 2.0  # eq. 24 stays the default
    with pytest.raises(ValueError, match="weight_power must be > 0"):
        TakagiSugenoRegressor(weight_power=0).fit(X, y)


def test_not_incremental_and_says_so():
    caps = TakagiSugenoRegressor.capabilities
    assert not caps.incremental and not caps.mergeable
    X, y, _, _ = piecewise_linear()
    m = TakagiSugenoRegressor(n_clusters=3).partial_fit(X, y)  # the first call fits
    with pytest.raises(NotImplementedError, match="not incremental"):
        m.partial_fit(X, y)
    with pytest.raises(NotImplementedError, match="cannot be merged"):
        m.merge(m)


def test_state_round_trips_through_json():
    X, y, _, _ = piecewise_linear(seed=2)
    m = TakagiSugenoRegressor(n_clusters=3, m=1.7, random_state=5).fit(X, y)
    back = TakagiSugenoRegressor.from_state(json.loads(json.dumps(m.to_state())))
    np.testing.assert_array_equal(back.predict(X), m.predict(X))
    assert back.get_params() == {
        **m.get_params(),
        "input_spans": m.spans_.tolist(),
        "output_span": list(m.output_span_),
    }
    assert back.output_mean_ == m.output_mean_ and back.n_samples_seen_ == m.n_samples_seen_


def test_reasons_for_missing_and_out_of_span_inputs():
    X, y, _, _ = piecewise_linear()
    m = TakagiSugenoRegressor(n_clusters=3, input_spans=[(0, 100)] * 2).fit(X, y)
    det = m.predict_detail([[50.0, 50.0], [np.nan, 1.0], [150.0, 50.0]])
    assert list(det.reason) == [REASON_OK, REASON_NAN, REASON_OUTSIDE]
    assert det.y[2] == pytest.approx(m.predict([[100.0, 50.0]])[0])
    assert m.extrapolate([[np.nan, 1.0]])[0] == pytest.approx(m.output_mean_)


def test_free_run_feeds_back_the_models_own_outputs():
    rng = np.random.default_rng(8)
    u = rng.uniform(0, 100, 800)
    yv = np.zeros(800)
    for k in range(1, 800):
        yv[k] = 0.5 * yv[k - 1] + (0.2 if u[k - 1] < 50 else 0.6) * u[k - 1]
    X, y = np.column_stack([yv[:-1], u[:-1]]), yv[1:]
    rb = RuleBase.new(
        "fr",
        Variable("Y[k]", "Y", "", (0.0, 150.0)),
        [Variable("Y[k-1]", "Y", "", (0.0, 150.0)), Variable("U[k-1]", "U", "", (0.0, 100.0))],
        method="ts-fcm",
    )
    m = rb.new_model().set_params(n_clusters=6).fit(X, y)
    assert m.capabilities.free_run and m.output_lags == [1, 0]
    sim = m.simulate(X)
    bad = X.copy()
    bad[1:, 0] = 0.0  # the measured lag is ignored after the first row
    np.testing.assert_allclose(m.simulate(bad), sim)
    assert np.abs(m.predict(bad) - m.predict(X)).max() > 1.0
    # the free-run error stays bounded (a stable model of a stable plant)
    assert np.sqrt(np.mean((sim - y) ** 2)) < 0.1 * np.ptp(y)
    assert not TakagiSugenoRegressor(output_lags=[0, 0]).capabilities.free_run


def test_model_file_lists_rules_round_trips_and_predicts_like_the_model(tmp_path):
    rb, res, f = trained_valve_file(tmp_path, METHOD)
    text = rb.path.read_text()
    for opt in ("n_clusters = 10", "m = 2.0", "eps = 0.01", "max_iter = 300", "random_state = 0"):
        assert f"\n{opt}\n" in text
    assert "\nweight_power = 2.0\n" in text  # eq. 24, the default, written out
    assert text.count("{ centre = [") == 10 and res.size == 10
    loaded = RuleBase.load(rb.path)
    assert loaded.dumps() == text
    loaded.save()
    assert rb.path.read_text() == text
    from diag_plugin.regressors import build_design

    d = build_design(f, [v.spec for v in rb.inputs], rb.output.spec)
    np.testing.assert_allclose(loaded.to_model().predict(d.X), res.model.predict(d.X), atol=1e-5)
    # the options in the file reach the estimator
    edited = text.replace("n_clusters = 10", "n_clusters = 4").replace("m = 2.0", "m = 1.5")
    edited = edited.replace("weight_power = 2.0", "weight_power = 1.0")
    (tmp_path / "o.toml").write_text(edited)
    est = RuleBase.load(tmp_path / "o.toml").new_model()
    assert (est.n_clusters, est.m, est.weight_power) == (4, 1.5, 1.0)
    # a file written before the option existed trains with eq. 24's weights
    (tmp_path / "old.toml").write_text(text.replace("weight_power = 2.0\n", ""))
    assert RuleBase.load(tmp_path / "old.toml").new_model().weight_power == 2.0


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("{ centre = [", "{ centre = [1.0, ", r"rule \d+: centre has 3 values for 2 inputs"),
        (", const = ", ', const = "x", z = ', r"rule \d+: unknown key\(s\) z"),
        ("m = 2.0", "m = 0.5", "m must be a number > 1"),
        ("eps = 0.01", "tol = 0.01", "unknown ts-fcm option 'tol'"),
        ("weight_power = 2.0", "weight_power = 0", r"weight_power must be a number > 0"),
    ],
)
def test_a_broken_edit_names_file_and_line(trained, tmp_path, old, new, message):
    broken_edit_is_named(trained[0].path, tmp_path, old, new, message)


def test_trains_compares_and_explains_through_the_seam(tmp_path):
    rb, res, f = trained_valve_file(tmp_path, METHOD, seed=7)
    assert res.validation["rmse_pct"] < 10.0
    # trained once on all rows after validation: as many samples as the design has
    assert res.samples == res.rows - sum(res.dropped.values())
    compares_and_explains(rb.path, f)


def test_cli_model_new_train_compare(cli_plant):
    plant = cli_plant
    _, text = cli_new_train_compare(plant, "ts", "ts-fcm")
    assert 'method = "ts-fcm"' in text and text.count("{ centre = [") == 10
    shown = run_diag(plant, "rules", "show", "ts")
    assert shown.returncode == 0 and "centre CV[k-1]" in shown.stdout, shown.stderr
    fcl = run_diag(plant, "rules", "export-fcl", "ts")
    assert fcl.returncode != 0 and "no IEC 61131-7 FCL form" in fcl.stderr


@pytest.mark.parametrize("m", [2.0, 1.7])
def test_the_compiled_free_run_is_the_row_by_row_one(m):
    free_run_is_the_reference(
        lambda lags, spans: TakagiSugenoRegressor(
            n_clusters=6, m=m, output_lags=lags, input_spans=spans
        )
    )
