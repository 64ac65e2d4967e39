"""The sets' shape chosen on held-out data by ``diag model new`` (issue 37).

With the paper's trapezoidal sets only one rule fires on the plateau around each set centre,
so the model's output is a staircase between the rule centres; triangular sets give the
multilinear interpolation. On surfaces the change was not tuned on (a known smooth function
of two slowly moving inputs, two seeds) the shape chosen on the training part's own tail cuts
the error on a later period the choice never saw; on a surface that *is* a staircase aligned
with the sets the paper's shape is kept.
"""

from __future__ import annotations

import copy

import numpy as np
import pandas as pd
import pytest

from diag_plugin.selection.scoring import HeldOutScorer, cut_row
from diag_plugin.selection.setsearch import choose_shape
from diag_plugin.workbench.model_edit import new_model

INFO = {"A": {"lo": 0, "hi": 100}, "B": {"lo": 0, "hi": 100}, "Y": {"lo": -10, "hi": 80}}


def _ou(rng, n, tau):
    a = np.exp(-1.0 / tau)
    e = rng.normal(0, np.sqrt(1 - a * a), n)
    out = np.empty(n)
    out[0] = 0.0
    for i in range(1, n):
        out[i] = a * out[i - 1] + e[i]
    return out


def surface(seed: int, stair: bool = False, n: int = 30_000) -> pd.DataFrame:
    """Y of two inputs moving slowly over most of their span, 1-minute samples: a smooth
    known function, or (``stair``) a staircase constant on each 31-set cell."""
    rng = np.random.default_rng(seed)
    idx = pd.date_range("2026-01-01", periods=n, freq="60s", tz="UTC")
    slow = _ou(rng, n, 200)
    a = np.clip(50 + 25 * slow + rng.uniform(-20, 20, n // 500 + 1).repeat(500)[:n], 0, 100)
    b = np.clip(50 + 25 * _ou(rng, n, 400), 0, 100)
    if stair:
        y = 0.5 * np.round(a * 0.3) / 0.3 + 0.3 * np.round(b * 0.3) / 0.3
    else:
        y = 40 * np.sin(a / 100 * 3) * (0.5 + b / 200) + 20
    y = y + rng.normal(0, 0.02, n)
    return pd.DataFrame({"A": a, "B": b, "Y": y}, index=idx)


def _fit_later(tmp_path, f: pd.DataFrame):
    """The model ``new_model`` writes from the first 80 % (31 sets, shape chosen there), and
    the error of each shape trained on those rows, scored on the last 20 %."""
    cut = cut_row(f.index, 0.2)
    notes: list[str] = []
    rb = new_model(tmp_path / "m.toml", "m", "Y[k]", ["A[k]", "B[k]"], frame=f.iloc[:cut],
                   tag_info=INFO, period="60s", sets=31, shape=None, notes=notes)  # fmt: skip
    cols, y = [f["A"].to_numpy(), f["B"].to_numpy()], f["Y"].to_numpy()
    err = {}
    for shape in ("trapezoidal", "triangular"):
        probe = copy.copy(rb)
        probe.shape = shape
        err[shape] = HeldOutScorer(probe, cols, y, cut).base_rmse
    return rb, err, notes


@pytest.mark.parametrize("seed", [5, 6])
def test_smooth_surface_gets_triangular_sets_and_a_lower_later_error(tmp_path, seed):
    rb, err, notes = _fit_later(tmp_path, surface(seed))
    assert rb.shape == "triangular", notes  # the old diag model new wrote trapezoidal sets
    assert err["triangular"] < 0.8 * err["trapezoidal"], err
    assert any("set shape chosen on held-out data: triangular" in n for n in notes)


def test_staircase_on_the_cells_keeps_the_papers_trapezoidal_sets(tmp_path):
    rb, err, notes = _fit_later(tmp_path, surface(5, stair=True))
    assert rb.shape == "trapezoidal", notes
    assert err["trapezoidal"] < err["triangular"], err


def test_no_choice_without_enough_data(tmp_path):
    f = surface(5, n=200)
    rb = new_model(tmp_path / "m.toml", "m", "Y[k]", ["A[k]", "B[k]"], frame=f.iloc[:30],
                   tag_info=INFO, period="60s", sets=31, shape=None)  # fmt: skip
    assert rb.shape == "trapezoidal"
    cols = [f["A"].to_numpy(), f["B"].to_numpy()]
    assert choose_shape(rb, cols, f["Y"].to_numpy(), 190) is None
    given = new_model(tmp_path / "g.toml", "g", "Y[k]", ["A[k]", "B[k]"], frame=f,
                      tag_info=INFO, period="60s", sets=31, shape="triangular")  # fmt: skip
    assert given.shape == "triangular"


def test_a_method_without_fuzzy_sets_has_no_shape_to_choose(tmp_path):
    """The codec's estimator class says whether the method takes a shape (no model built)."""
    f = surface(5, n=2000)
    cols = [f["A"].to_numpy(), f["B"].to_numpy()]
    for method, expect_choice in (("narmax2", False), ("wm-avg", True)):
        path = tmp_path / f"{method}.toml"
        rb = new_model(path, method, "Y[k]", ["A[k]", "B[k]"], frame=None, tag_info=INFO,
                       period="60s", method=method, shape=None)  # fmt: skip
        choice = choose_shape(rb, cols, f["Y"].to_numpy(), 1500)
        assert (choice is not None) == expect_choice, (method, choice)
