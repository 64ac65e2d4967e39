"""A coarse level's node fit chooses dense arrays by what they cost (issue 37): a trained model
of three inputs and some thousand rules fits every level without scipy.sparse (whose import
cost a ``diag train`` process 0.2 s), the dense and sparse solves agree to rounding, the
dense fit holds BLAS to one thread, and numpy's smoothness Gram matrix is the compiled one's.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

import diag_plugin.fuzzy.wang_mendel as wm
from diag_plugin.fuzzy import _kernels as K

#: a three-input model on a band of its input space, as a trained process model is: 1,280
#: fine rules, 286 nodes at level 1 (rules × nodes above the old dense bound of 2^17)
MODEL = textwrap.dedent(
    """
    import numpy as np
    from diag_plugin.fuzzy.wang_mendel import WangMendelRegressor

    def band_model():
        rng = np.random.default_rng(3)
        x1 = rng.uniform(0, 100, 100_000)
        x2 = 50 + 35 * np.sin(x1 / 16) + rng.normal(0, 3, x1.size)
        x3 = 80 - 0.6 * x1 + rng.normal(0, 3, x1.size)
        X = np.column_stack([x1, x2, x3])
        y = 0.3 * x1 + 0.5 * x2 + 0.2 * x3 + rng.normal(0, 1, x1.size)
        m = WangMendelRegressor(input_spans=[(0, 100)] * 3, output_span=(0, 100), n_sets=[31] * 3)
        return m.fit(X, y)
    """
)
PROBE = MODEL + textwrap.dedent(
    """
    import json, sys
    m = band_model()
    n_rules = int((m.count_ > 0).sum())
    sizes = [int(m.level_nodes(level)[0].size) for level in range(1, m.n_levels_)]
    print(json.dumps({"rules": n_rules, "nodes": sizes, "sparse": "scipy.sparse" in sys.modules}))
    """
)


@pytest.fixture(scope="module")
def band_model():
    space: dict = {}
    exec(MODEL, space)
    return space["band_model"]()


def test_a_trained_three_input_model_fits_its_levels_without_scipy_sparse():
    res = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    assert out["rules"] * out["nodes"][0] > 1 << 17  # the old bound sent level 1 to scipy
    assert out["sparse"] is False, out


def _values(m, level: int, dense: bool, monkeypatch) -> np.ndarray:
    monkeypatch.setattr(wm, "dense_node_fit", lambda n, k: dense)
    return wm._fit_nodes(m, level)[1]


@pytest.mark.parametrize("level", [1, 2, 3])
def test_dense_and_sparse_node_fits_agree_to_rounding(band_model, level, monkeypatch):
    dense = _values(band_model, level, True, monkeypatch)
    sparse = _values(band_model, level, False, monkeypatch)
    assert dense.size == sparse.size > 1
    assert np.abs(dense - sparse).max() <= 1e-12 * np.abs(sparse).max()


def test_dense_fit_holds_blas_to_one_thread(band_model, monkeypatch):
    seen = []
    solve = np.linalg.solve

    def spy(M, rhs):
        seen.extend(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas")
        return solve(M, rhs)

    monkeypatch.setattr(wm.np.linalg, "solve", spy)
    monkeypatch.setattr(wm, "dense_node_fit", lambda n, k: True)
    with threadpool_limits(2, user_api="blas"):  # the tests run at one thread (conftest)
        wm._fit_nodes(band_model, 2)
        after = [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
    assert seen and set(seen) == {1}
    assert set(after) == {2}  # the caller's setting is given back


def _dense_gram(nodes: np.ndarray, radix: np.ndarray, nsets: np.ndarray) -> np.ndarray:
    """``P.T @ P`` with ``P`` formed: a row of 1, -2, 1 per second difference along an input
    where both neighbours are nodes."""
    k, rows = nodes.size, []
    where = {int(v): i for i, v in enumerate(nodes)}
    for j in range(radix.size):
        for i, v in enumerate(nodes):
            idx = (v // radix[j]) % nsets[j]
            lo, hi = where.get(int(v - radix[j])), where.get(int(v + radix[j]))
            if 0 < idx < nsets[j] - 1 and lo is not None and hi is not None:
                row = np.zeros(k)
                row[[lo, i, hi]] = 1.0, -2.0, 1.0
                rows.append(row)
    P = np.array(rows).reshape(-1, k)
    return P.T @ P


@pytest.mark.parametrize("seed", range(6))
def test_numpy_smooth_gram_is_the_dense_product_and_the_compiled_one_bit_for_bit(seed):
    rng = np.random.default_rng(seed)
    d = 1 + seed % 4
    nsets = rng.integers(2, 9, d).astype(np.int64)
    radix = wm._radix(nsets)
    total = int(np.prod(nsets))
    nodes = np.sort(rng.choice(total, int(rng.integers(1, total + 1)), replace=False))
    got = wm._smooth_gram(nodes.astype(np.int64), d, radix, nsets)
    for want in (_dense_gram(nodes, radix, nsets), K.smooth_gram(nodes, radix, nsets)):
        assert np.array_equal(got.view(np.int64), want.view(np.int64))
