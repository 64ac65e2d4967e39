"""The numpy loops of Wang–Mendel training and one model's inference (issue 37) give the same
bits as the compiled ones, so a ``diag train`` that runs without numba saves the same model.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from diag_plugin.fuzzy import _kernels as K
from diag_plugin.fuzzy import _numpy_kernels as N
from diag_plugin.fuzzy.wang_mendel import WangMendelRegressor, pack


def _data(rng, n: int, d: int, lo: float = -10, hi: float = 110):
    """Inputs over and beyond a 0..100 span with NaN holes, a smooth noisy output."""
    X = rng.uniform(lo, hi, (n, d)) * np.r_[1.0, 0.5, 0.7, 0.9][:d]
    X[rng.random((n, d)) < 0.01] = np.nan
    y = np.sin(X.sum(axis=1) / 30) * 40 + 50 + rng.normal(0, 2, n)
    y[rng.random(n) < 0.01] = np.nan
    y[:50] = 1e6  # beyond the clip of the output quantum
    return X, y


def _model(d: int, shape: str, sets: int) -> WangMendelRegressor:
    return WangMendelRegressor(
        input_spans=[(0, 100)] * d, output_span=(0, 100), n_sets=[sets] * d, shape=shape
    ).init(d)


@pytest.mark.parametrize(
    "d, shape, sets", [(1, "triangular", 31), (2, "trapezoidal", 15), (3, "triangular", 31)]
)
def test_accumulation_is_the_compiled_ones_bit_for_bit(d, shape, sets):
    X, y = _data(np.random.default_rng(d), 50_000, d)
    m = _model(d, shape, sets)
    lo, step, nsets, _, _ = m._arrays()
    got = []
    for loops in (K, N):
        arrays = [np.zeros(m.n_cells_, np.int64) for _ in range(3)]
        skipped = loops.accumulate_dense(X, y, lo, step, nsets, m.radix_, 0.0, m._yquant, *arrays)
        got.append((skipped, arrays))
    (s1, a1), (s2, a2) = got
    assert s1 == s2 > 0
    for u, v in zip(a1, a2, strict=True):
        assert np.array_equal(u, v)


def test_accumulation_of_large_squares_stays_exact():
    """Sums of squares past float64's exact integers take the integer path."""
    n = 2_000_000
    key = np.zeros(n, np.int64)
    q = np.full(n, 131_072, np.int64)
    assert N._sums(key, q * q, 1)[0] == n * 131_072**2


@pytest.mark.parametrize(
    "d, shape, sets, rows",
    [(1, "triangular", 31, 12), (2, "trapezoidal", 15, 60), (3, "triangular", 31, 4000)],
)
def test_inference_at_every_level_is_the_compiled_ones_bit_for_bit(d, shape, sets, rows):
    rng = np.random.default_rng(10 + d)
    X, y = _data(rng, 30_000, d)
    m = _model(d, shape, sets).fit(X[:rows], y[:rows])  # sparse: coarse levels answer
    assert m.n_levels_ > 2
    Xt, _ = _data(rng, 30_000, d, -20, 120)
    n = Xt.shape[0]
    levels = set()
    for depth in range(m.n_levels_):
        packed = pack([m.inference_grid(depth)], dense=depth % 2 == 0)  # tables and searches
        got = []
        for loops in (K, N):
            o = [np.empty(n), np.empty(n), np.empty(n, np.int8), np.empty(n, np.int8)]
            o.append(np.empty(n))
            loops.infer_levels(np.empty(0, np.int64), Xt, *packed, *o)
            got.append(o)
        for u, v in zip(*got, strict=True):
            assert np.array_equal(u.view(np.uint8), v.view(np.uint8))
        levels |= set(np.unique(got[1][3]).tolist())
    assert {-1, 0, 1, 2} <= levels  # no answer, the fine grid and coarse levels all met


PROBE = textwrap.dedent(
    """
    import json, sys
    import numpy as np
    from diag_plugin.fuzzy.wang_mendel import WangMendelRegressor
    rng = np.random.default_rng(0)
    X = rng.uniform(0, 100, (20_000, 2))
    m = WangMendelRegressor(input_spans=[(0, 100)] * 2, output_span=(0, 200), n_sets=[31] * 2)
    y = m.fit(X, X.sum(axis=1)).predict(X)
    print(json.dumps({"numba": "numba" in sys.modules, "y": float(np.nansum(y))}))
    """
)


def test_training_and_predicting_one_model_do_not_load_numba():
    res = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    assert out["numba"] is False
    assert out["y"] > 0


@pytest.mark.parametrize(
    "d, shape, sets, rows",
    [(1, "triangular", 31, 12), (2, "trapezoidal", 15, 60), (3, "triangular", 31, 4000)],
)
def test_prediction_by_numpy_loops_is_the_fine_kernels_bit_for_bit(
    d, shape, sets, rows, monkeypatch
):
    """Without numba (numpy's loops, no ``infer_fine``) ``predict_detail`` searches the levels;
    with it the fine level comes from its dense table: the same answers, bit for bit."""
    from diag_plugin.fuzzy import wang_mendel

    rng = np.random.default_rng(20 + d)
    X, y = _data(rng, 30_000, d)
    Xt, _ = _data(rng, 20_000, d, -20, 120)
    fast = _model(d, shape, sets).fit(X[:rows], y[:rows]).predict_detail(Xt)
    monkeypatch.setattr(wang_mendel, "kernels", lambda rows=None: N)
    slow = _model(d, shape, sets).fit(X[:rows], y[:rows]).predict_detail(Xt)
    assert {-1, 0, 1} <= set(np.unique(fast.level).tolist())  # fine, coarse and no answer met
    for f in ("y", "support", "reason", "level", "spread"):
        a, b = getattr(fast, f), getattr(slow, f)
        assert np.array_equal(a.view(np.uint8), b.view(np.uint8)), f


@pytest.mark.parametrize("plateau", [0.3, 0.5, 0.75, 0.6])  # 1 − p: 0.7, 0.5, 0.25, 0.4
def test_fine_kernel_without_divisions_is_the_searched_levels_bit_for_bit(plateau, monkeypatch):
    """``infer_fine`` multiplies by ``1 / (1 − p)`` where ``1 − p`` is a power of two (0.5,
    0.25) and divides otherwise (0.7, 0.4), and takes a total weight of exactly 1 as the
    average: the same bits as the searched levels (numpy's loops) at every plateau."""
    from diag_plugin.fuzzy import wang_mendel
    from diag_plugin.fuzzy.partition import UniformPartition

    rng = np.random.default_rng(7)
    X, y = _data(rng, 30_000, 2)
    Xt, _ = _data(rng, 20_000, 2, -20, 120)
    # the models' partitions at this plateau (a model's own is DEFAULT_PLATEAU)
    monkeypatch.setattr(
        wang_mendel, "UniformPartition", lambda *a: UniformPartition(*a, plateau=plateau)
    )

    def model() -> WangMendelRegressor:  # the fine grid answers most rows
        return _model(2, "trapezoidal", 15).fit(X[:20_000], y[:20_000])

    assert np.all(model()._arrays()[3] == plateau)
    fast = model().predict_detail(Xt)
    monkeypatch.setattr(wang_mendel, "kernels", lambda rows=None: N)
    slow = model().predict_detail(Xt)
    assert (fast.level == 0).mean() > 0.5
    assert (fast.support == 1.0).any() and ((fast.support > 0) & (fast.support < 1)).any()
    for f in ("y", "support", "reason", "level", "spread"):
        a, b = getattr(fast, f), getattr(slow, f)
        assert np.array_equal(a.view(np.uint8), b.view(np.uint8)), f
