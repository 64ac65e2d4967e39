"""Wang–Mendel models: partitions, training (eq. 2, eq. 5), chunking, merge, inference."""

import tracemalloc

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from diag_plugin.fuzzy.partition import UniformPartition
from diag_plugin.fuzzy.wang_mendel import (
    REASON_NAN,
    REASON_OK,
    REASON_OUTSIDE,
    REASON_UNSUPPORTED,
    WangMendelRegressor,
)


def plant(n, seed, d=2):
    rng = np.random.default_rng(seed)
    X = rng.uniform(0, 100, (n, d))
    y = 40 * (X[:, 0] / 100) ** 2 * np.sqrt(X[:, 1:].mean(axis=1) / 100) + rng.normal(0, 0.2, n)
    return X, y


@pytest.mark.parametrize("shape", ["triangular", "trapezoidal"])
def test_partition_is_ruspini_and_max_membership(shape):
    p = UniformPartition(-5.0, 15.0, 11, shape)
    x = np.linspace(-7, 17, 2001)
    mus = np.array([p.membership(x, i) for i in range(p.n)])
    np.testing.assert_allclose(mus.sum(axis=0), 1.0, atol=1e-12)
    # eq. 3: the fuzzified set is the one with maximal membership
    best = mus.argmax(axis=0)
    near = p.nearest(x)
    agree = mus[near, np.arange(x.size)] >= mus[best, np.arange(x.size)] - 1e-12
    assert agree.all()
    j, w = p.upper_weight(x)
    np.testing.assert_allclose(w, p.membership(x, j + 1), atol=1e-12)
    assert p.labels("U")[:2] == ["U00", "U01"]


def test_partition_rejects_bad_spans():
    with pytest.raises(ValueError, match="lo < hi"):
        UniformPartition(1.0, 1.0)
    with pytest.raises(ValueError, match="at least 2"):
        UniformPartition(0.0, 1.0, 1)


def test_averaged_method_is_mean_of_cell_outputs():
    """Modified Wang–Mendel (eq. 5): a cell's conclusion is the average output."""
    X = np.array([[10.0], [10.4], [9.8], [50.0]])
    y = np.array([1.0, 2.0, 6.0, 7.0])
    m = WangMendelRegressor([(0, 100)], (0, 10), n_sets=11).fit(X, y)
    assert m.n_rules_ == 2
    np.testing.assert_allclose(m.conclusions_, [3.0, 7.0], atol=1e-3)
    np.testing.assert_allclose(m.sd_[0], np.std([1.0, 2.0, 6.0]), atol=1e-3)
    np.testing.assert_array_equal(m.count_, [3, 1])


def test_classic_method_keeps_heaviest_rule():
    """Classic Wang–Mendel (eq. 2, step 4): the heaviest conflicting rule wins."""
    X = np.array([[10.0], [11.9], [10.0]])
    y = np.array([2.0, 8.0, 3.6])  # sample 1 is near the set centre, y near a set centre
    m = WangMendelRegressor([(0, 100)], (0, 10), n_sets=11, output_sets=11, method="wm")
    m.fit(X, y)
    assert m.n_rules_ == 1
    assert m.conclusions_[0] == pytest.approx(2.0)


@pytest.mark.parametrize("method", ["wm-avg", "wm"])
@pytest.mark.parametrize("seed", [3, 11])
def test_partial_fit_and_merge_equal_one_fit(method, seed):
    X, y = plant(50_000, seed)
    spans = [(0, 100), (0, 100)]
    full = WangMendelRegressor(spans, (0, 45), n_sets=17, method=method).fit(X, y)
    rng = np.random.default_rng(seed)
    cuts = np.sort(rng.choice(np.arange(1, len(y)), size=7, replace=False))
    chunked = WangMendelRegressor(spans, (0, 45), n_sets=17, method=method)
    parts = []
    for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(y)], strict=True):
        chunked.partial_fit(X[a:b], y[a:b])
        parts.append(
            WangMendelRegressor(spans, (0, 45), n_sets=17, method=method).fit(X[a:b], y[a:b])
        )
    merged = parts[0]
    for p in parts[1:]:
        merged.merge(p)
    for other in (chunked, merged):
        np.testing.assert_array_equal(full.keys_, other.keys_)
        np.testing.assert_array_equal(full.count_, other.count_)
        np.testing.assert_array_equal(full.conclusions_, other.conclusions_)
        np.testing.assert_array_equal(full.sd_, other.sd_)
        np.testing.assert_array_equal(full.predict(X[:1000]), other.predict(X[:1000]))


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 10_000), st.integers(1, 399))
def test_chunk_boundaries_property(seed, cut):
    X, y = plant(400, seed, d=3)
    a = WangMendelRegressor([(0, 100)] * 3, (0, 45), n_sets=7).fit(X, y)
    b = WangMendelRegressor([(0, 100)] * 3, (0, 45), n_sets=7)
    b.partial_fit(X[:cut], y[:cut]).partial_fit(X[cut:], y[cut:])
    np.testing.assert_array_equal(a.qsum_, b.qsum_)
    np.testing.assert_array_equal(a.qsq_, b.qsq_)


def truth(X):
    """The noise-free surface of :func:`plant`."""
    return 40 * (X[:, 0] / 100) ** 2 * np.sqrt(X[:, 1:].mean(axis=1) / 100)


@pytest.mark.parametrize(("shape", "vs_nearest"), [("triangular", 0.35), ("trapezoidal", 0.65)])
def test_inference_interpolates_a_smooth_function(shape, vs_nearest):
    X, y = plant(200_000, 5)
    m = WangMendelRegressor([(0, 100), (0, 100)], (0, 45), shape=shape).fit(X, y)
    Xt, _ = plant(20_000, 6)  # fresh points the model has not seen
    err = m.predict(Xt) - truth(Xt)
    assert np.isfinite(err).all()
    rmse = np.sqrt(np.mean(err**2))
    # the same rules without interpolation (each point takes its nearest rule's conclusion)
    # miss the noise-free surface by about 0.36 t/h RMS (0.8 % of span): a step of the
    # 31-set grid (3.3 % of the input span) times the slope
    near = np.rint(Xt / (100 / 30)).astype(np.int64)
    rules = dict(zip(m.keys_.tolist(), m.conclusions_, strict=True))
    step = np.array([rules[k] for k in m.cell_keys(near).tolist()]) - truth(Xt)
    rmse_step = np.sqrt(np.mean(step**2))
    assert rmse_step > 0.3, rmse_step
    # interpolation between the rules (all of it with triangular sets, between the plateaus
    # with trapezoidal ones) does much better; 0.09 and 0.19 t/h with these seeds
    assert rmse < vs_nearest * rmse_step, (rmse, rmse_step)
    assert rmse < (0.003 if shape == "triangular" else 0.005) * 45, rmse


def test_triangular_inference_reproduces_a_multilinear_function_exactly():
    """Rules sampled from f(x) = multilinear in x at the set centres: with triangular sets
    inference is multilinear interpolation over the rule grid, so it reproduces f
    everywhere in the span, not only at the centres (a step predictor misses by ~ slope·h/2)."""
    rng = np.random.default_rng(4)
    spans, sets = [(0.0, 10.0), (-20.0, 20.0), (100.0, 160.0)], [11, 5, 7]
    m = WangMendelRegressor(spans, (-1000, 1000), n_sets=sets, shape="triangular")
    m.fit(np.zeros((1, 3)), np.zeros(1))
    c = rng.uniform(-3, 3, 8)

    def f(X):
        u = (X - [lo for lo, _ in spans]) / [hi - lo for lo, hi in spans]  # 0..1 per input
        a, b, d = u[:, 0], u[:, 1], u[:, 2]
        terms = (1, a, b, d, a * b, a * d, b * d, a * b * d)
        return 100 * sum(ci * t for ci, t in zip(c, terms, strict=True))

    idx = np.array(np.meshgrid(*[np.arange(n) for n in sets], indexing="ij")).reshape(3, -1).T
    centres = np.column_stack(
        [lo + i * (hi - lo) / (n - 1) for (lo, hi), n, i in zip(spans, sets, idx.T, strict=True)]
    )
    m.set_rules(m.cell_keys(idx), f(centres))
    X = np.column_stack([rng.uniform(lo, hi, 5000) for lo, hi in spans])
    X[:10] = centres[rng.choice(len(centres), 10)]  # at the centres too
    np.testing.assert_allclose(m.predict(X), f(X), rtol=0, atol=1e-9 * 2000)


def test_triangular_inference_is_multilinear_interpolation():
    rng = np.random.default_rng(0)
    m = WangMendelRegressor([(0, 10), (0, 20)], (0, 100), n_sets=[11, 5], shape="triangular")
    m.fit(np.zeros((1, 2)), np.zeros(1))
    grid = np.array([[i, j] for i in range(11) for j in range(5)])
    vals = rng.uniform(0, 100, len(grid))
    m.set_rules(m.cell_keys(grid), vals)
    x = np.array([[3.25, 7.0]])  # between sets 3–4 of input 1 and 1–2 of input 2 (step 5)
    v = {tuple(g): vals[i] for i, g in enumerate(grid)}
    fx, fy = 0.25, 0.4
    expected = (
        v[(3, 1)] * (1 - fx) * (1 - fy)
        + v[(4, 1)] * fx * (1 - fy)
        + v[(3, 2)] * (1 - fx) * fy
        + v[(4, 2)] * fx * fy
    )
    assert m.predict(x)[0] == pytest.approx(expected)


@pytest.mark.parametrize("levels", [0, None])
def test_unsupported_samples_are_nan_with_reason(levels):
    X = np.c_[np.linspace(0, 40, 500), np.linspace(0, 40, 500)]
    m = WangMendelRegressor([(0, 100), (0, 100)], (0, 100), n_sets=11, levels=levels)
    m.fit(X, X[:, 0])
    pts = np.array([[20, 20], [90, 90], [np.nan, 5], [-10, -10], [20, 60], [35, 5]])
    det = m.predict_detail(pts)
    assert np.isfinite(det.y[0]) and det.reason[0] == REASON_OK and det.level[0] == 0
    assert np.isnan(det.y[1]) and det.reason[1] == REASON_UNSUPPORTED and det.level[1] == -1
    assert np.isnan(det.y[2]) and det.reason[2] == REASON_NAN and det.level[2] == -1
    assert np.isfinite(det.y[3]) and det.reason[3] == REASON_OUTSIDE and det.level[3] == 0
    # (20, 60): beyond the training data's range of the second input (0…40): no level answers
    assert np.isnan(det.y[4]) and det.level[4] == -1
    if levels == 0:  # the paper's fine grid alone: no rule fires at (35, 5) either
        assert np.isnan(det.y[5])
        assert det.coverage == pytest.approx(2 / 6)
        assert det.coverage_by_level() == {0: pytest.approx(2 / 6)}
    else:  # inside both ranges, off the diagonal the data lie on: only the coarsest cell
        # holding it (fine sets 0-7 of both inputs) has data, and it answers, saying so
        assert det.level[5] == m.n_levels_ - 1 == 3 and det.y[5] == pytest.approx(20, abs=1)
        assert det.coverage == pytest.approx(3 / 6)
        assert det.coverage_by_level() == {0: pytest.approx(2 / 6), 3: pytest.approx(1 / 6)}


def test_nan_training_rows_are_skipped_and_counted():
    X, y = plant(1000, 1)
    X[5, 0] = np.nan
    y[7] = np.nan
    m = WangMendelRegressor([(0, 100)] * 2, (0, 45)).fit(X, y)
    assert m.n_skipped_ == 2 and m.n_samples_seen_ == 998


def _peak_bytes(fn) -> int:
    """Peak of the memory allocated (and traced: numpy arrays are) while ``fn()`` runs."""
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


@pytest.mark.parametrize("d", [5, 6, 9])
def test_many_inputs_stay_sparse(d):
    """Seed 000's regression vectors have 8–10 entries: the 31^d rule grid (229 MB of
    float64 for 5 inputs, 7 GB for 6) must never be allocated, in fit or in predict."""
    rng = np.random.default_rng(d)
    n = 200_000
    X = rng.uniform(0, 1, (n, d))
    y = X @ np.linspace(1, 2, d)
    new = lambda: WangMendelRegressor([(0, 1)] * d, (0, 2 * d))  # noqa: E731
    new().fit(X[:100], y[:100]).predict(X[:100])  # compiled kernels loaded before measuring
    m = new()
    fit_peak = _peak_bytes(lambda: m.fit(X, y))
    assert m.n_cells_ == 31**d and m.keys_.size <= n
    pred = {}
    pred_peak = _peak_bytes(lambda: pred.setdefault("y", m.predict(X)))
    grid = 8 * 31**d
    # memory in proportion to the rows (fit about 80 bytes per row measured, predict about
    # 120), never to the grid: one dense table of it alone would be > 1000 bytes per row
    assert grid > 1000 * n
    assert fit_peak < 200 * n, (fit_peak, grid)
    assert pred_peak < 300 * n, (pred_peak, grid)
    # 200,000 samples in 31^d cells: the coarse levels' node fit would weigh too much, so the
    # fine grid answers alone, as before the levels (each training sample its own cell's rule)
    assert np.allclose(pred["y"][:200], y[:200], atol=0.05 * d)
    X, y = X[:20_000], y[:20_000]
    m = new().fit(X, y)
    merged = WangMendelRegressor([(0, 1)] * d, (0, 2 * d)).fit(X[:7000], y[:7000])
    merged.merge(WangMendelRegressor([(0, 1)] * d, (0, 2 * d)).fit(X[7000:], y[7000:]))
    np.testing.assert_array_equal(merged.qsum_, m.qsum_)


def test_merge_rejects_different_partitions():
    X, y = plant(100, 2)
    a = WangMendelRegressor([(0, 100)] * 2, (0, 45), n_sets=7).fit(X, y)
    b = WangMendelRegressor([(0, 100)] * 2, (0, 45), n_sets=9).fit(X, y)
    with pytest.raises(ValueError, match="different partitions"):
        a.merge(b)


def test_estimator_conventions():
    m = WangMendelRegressor(n_sets=5)
    assert not hasattr(m, "keys_")
    with pytest.raises(RuntimeError, match="not trained"):
        m.predict(np.zeros((1, 1)))
    X, y = plant(100, 4)
    assert m.fit(X, y) is m
    assert m.n_features_in_ == 2
    with pytest.raises(ValueError, match="2 inputs"):
        m.predict(np.zeros((3, 3)))


def test_eq5_as_printed_averages_the_centres_of_the_outputs_sets():
    """``conclusion="sets"`` (Kościelny et al., eq. 5 as printed): each sample's conclusion is
    the centre of its output's max-membership set (eq. 3 on y) and a cell averages those;
    the default averages the outputs. Chunks and merges stay exact; the two differ by at
    most half an output set."""
    rng = np.random.default_rng(11)
    X = rng.uniform(0, 100, (4000, 2))
    y = 0.3 * X[:, 0] + 0.2 * X[:, 1] + rng.normal(0, 1.5, 4000)
    kw = dict(input_spans=[(0, 100), (0, 100)], output_span=(0, 50), n_sets=7, levels=0)
    lit = WangMendelRegressor(conclusion="sets", **kw).fit(X, y)
    avg = WangMendelRegressor(**kw).fit(X, y)
    out = UniformPartition(0, 50, 31)
    centres = out.centers[out.nearest(y)]
    cells = lit.cell_indices()
    ix = np.stack([UniformPartition(0, 100, 7).nearest(X[:, k]) for k in range(2)], axis=1)
    for j, cell in enumerate(cells):
        mine = np.all(ix == cell, axis=1)
        assert lit.conclusions_[j] == pytest.approx(centres[mine].mean(), abs=1e-3)
        assert avg.conclusions_[j] == pytest.approx(y[mine].mean(), abs=1e-3)
    assert np.max(np.abs(lit.conclusions_ - avg.conclusions_)) <= out.step / 2 + 1e-3
    assert not np.allclose(lit.conclusions_, avg.conclusions_)
    parts = WangMendelRegressor(conclusion="sets", **kw)
    for s in range(0, 4000, 700):
        parts.partial_fit(X[s : s + 700], y[s : s + 700])
    np.testing.assert_array_equal(parts.conclusions_, lit.conclusions_)
    with pytest.raises(ValueError, match="different partitions or methods"):
        WangMendelRegressor(**kw).fit(X, y).merge(lit)
    with pytest.raises(ValueError, match="conclusion must be one of"):
        WangMendelRegressor(conclusion="median", **kw).fit(X, y)


def test_without_takes_out_exactly_the_samples_given_and_refuses_any_it_never_had():
    """``without`` (issue 38, bug 10): the model minus a part of its training equals the model
    trained on the rest, state and predictions; a part holding samples the model never had —
    other data, the same part twice, a sample repeated more often than it was trained — is
    refused, not silently clipped (unit learn would cross-fit from a damaged model)."""

    def new():
        return WangMendelRegressor([(0, 100)] * 2, (0, 45), n_sets=7)

    X, y = plant(600, 3)
    full = new().fit(X, y)
    before = full.to_state()
    part = new().fit(X[:200], y[:200])
    rest = new().fit(X[200:], y[200:])
    out = full.without(part)
    for k in ("keys_", "count_", "qsum_", "qsq_"):
        np.testing.assert_array_equal(getattr(out, k), getattr(rest, k), err_msg=k)
    assert out.n_samples_seen_ == rest.n_samples_seen_ == 400
    Xt, _ = plant(300, 4)
    np.testing.assert_array_equal(out.predict(Xt), rest.predict(Xt))
    for k, v in full.to_state().items():  # the model itself is left as it was
        np.testing.assert_array_equal(v, before[k], err_msg=k)

    repeated = new().fit(np.vstack([X, X[:1]]), np.r_[y, y[:1]])  # one sample once more
    low = X[:, 0] < 60  # a model that never saw the high half of the first input
    half = new().fit(X[low], y[low])
    one_new_cell = new().fit(np.vstack([X[low][:50], [[100.0, 50.0]]]), np.r_[y[low][:50], 20.0])
    cases = {
        "other data": (full, new().fit(*plant(200, 99))),
        "a sample more often than trained": (full, repeated),
        "the same part twice": (out, part),
        "one cell the model never had": (half, one_new_cell),
    }
    for what, (model, other) in cases.items():
        with pytest.raises(ValueError, match="never in this model"):
            model.without(other)
            pytest.fail(what)


def test_coarse_levels_and_stand_in_as_a_group_by_computes_them():
    """A coarse level's rules are the group-by of the fine cells' integer accumulators (as
    np.unique and np.add.at give them), and extrapolate with the prediction passed in answers
    as it does computing it (the build's scoring passes it)."""
    rng = np.random.default_rng(3)
    X = rng.uniform(0, 1, (3000, 3))
    y = np.sin(3 * X[:, 0]) + X[:, 1] * X[:, 2] + rng.normal(0, 0.05, 3000)
    m = WangMendelRegressor([(0, 1)] * 3, (-1, 3), n_sets=[21, 15, 9]).fit(X, y)
    for lv in range(1, m.n_levels_):
        has = m.count_ > 0
        keys = m._coarse_keys(m.keys_[has], lv)
        uk, inv = np.unique(keys, return_inverse=True)
        want = [np.zeros(uk.size, np.int64) for _ in range(3)]
        for w, a in zip(want, (m.count_, m.qsum_, m.qsq_), strict=True):
            np.add.at(w, inv, a[has])
        got = m.level_rules(lv)
        assert np.array_equal(got.keys, uk) and np.array_equal(got.count, want[0])
        mean = want[1] / want[0]
        assert np.array_equal(got.conclusions, m.output_partition_.lo + mean * m._yquant)
    # a fine grid alone on few samples: many cells without a rule, the nearest rule answers
    Q = rng.uniform(0, 1, (500, 3))
    Q[:5, 1] = np.nan  # an input missing: no answer either way
    thin = lambda: WangMendelRegressor([(0, 1)] * 3, (-1, 3), n_sets=15, levels=0)  # noqa: E731
    a, b = thin().fit(X[:200], y[:200]), thin().fit(X[:200], y[:200])
    pred = a.predict(Q)
    assert (~np.isfinite(pred)).sum() > 50
    got = a.extrapolate(Q, pred=pred)
    assert np.array_equal(got, b.extrapolate(Q), equal_nan=True)
    assert np.isfinite(got[5:]).all() and np.isnan(got[:5]).all()
