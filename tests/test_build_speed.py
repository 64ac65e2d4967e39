"""The build's fast paths give exactly what the slow ones gave (issue 34, speed).

Judged on plants the fast paths were not tuned on (the tour's small tank and heat exchanger,
:mod:`diag_plugin.simulate.smallplants`; the speed work was measured on the coupled process):
the unit built on two worker processes is the unit built on one; every candidate's dead times
screened in one product are :func:`~diag_plugin.selection.lags.lag_screen`'s, gaps included;
a model that fits its coarse levels only when a sample reaches them answers as one that
fitted them all; the occupied cells counted in a dense table are the unique keys; a coarse
level's corner weights are ``np.prod``'s to the bit; a selection step that takes the winning
variant's block fits is the step that fits them again; a coarse level's rules summed by the
compiled group-by are numpy's to the bit; the scoring node fit (normal equations per rule) is
the dense fit to rounding; a variant's bound never exceeds its error, and the candidates the
bounds pass over change no choice.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from diag_plugin.fuzzy.wang_mendel import WangMendelRegressor, corner_weight, pack, run_kernel
from diag_plugin.selection.lags import LagScreen, lag_screen
from diag_plugin.selection.scoring import BlockScorer, FrozenRuleBase
from diag_plugin.selection.sets import _occupied
from diag_plugin.simulate import smallplants as sp
from diag_plugin.unitbuild.build import _Context, _rulebase, _with_sets, build_unit


def _plant(kind: str, days: float, seed: int):
    sim = {"tank": sp.simulate_tank, "heatex": sp.simulate_heat_exchanger}[kind]
    return sp.export(sim(days, seed=seed, start="2026-03-02"), 60.0, timing="grid", seed=seed)


def _text(path) -> str:
    """A built file without the times it was written at."""
    return re.sub(r"(?m)^.*(_at|learned) = .*$", "", path.read_text(encoding="utf-8"))


@pytest.mark.parametrize("kind", ["tank", "heatex"])
def test_two_workers_build_the_unit_one_builds(tmp_path, kind):
    frame = _plant(kind, 3.0, 21)
    one = build_unit("u", frame, folder=tmp_path / "one", period="60s", far=0.05, workers=1)
    two = build_unit("u", frame, folder=tmp_path / "two", period="60s", far=0.05, workers=2)
    assert [t.as_dict() for t in one.tests] == [t.as_dict() for t in two.tests]
    assert one.learned.limits == two.learned.limits
    files = sorted(p.name for p in (tmp_path / "one").iterdir())
    assert files == sorted(p.name for p in (tmp_path / "two").iterdir())
    assert len(files) > 1
    for name in files:
        assert _text(tmp_path / "one" / name) == _text(tmp_path / "two" / name), name


def test_the_parent_reads_no_model_file_back(tmp_path, monkeypatch):
    """On two workers each model file is read back in the worker that wrote it (its model
    comes back in memory): the parent parses none, and the unit is the one-worker unit's
    (the test above)."""
    from diag_plugin.rulebase.document import RuleBase

    frame = _plant("tank", 3.0, 21)
    read: list[str] = []  # the parent's reads (a forked worker appends to its own copy)
    plain = RuleBase.load.__func__

    def load(cls, path):
        read.append(str(path))
        return plain(cls, path)

    monkeypatch.setattr(RuleBase, "load", classmethod(load))
    res = build_unit("u", frame, folder=tmp_path, period="60s", far=0.05, workers=2)
    assert len(res.tests) > 1 and res.learned.limits
    assert read == []


def test_all_candidates_screened_at_once_equal_one_by_one():
    frame = _plant("heatex", 2.0, 33)
    cols = {c: frame[c].to_numpy(float) for c in frame.columns}
    rng = np.random.default_rng(5)
    names = list(cols)
    gappy = names[0]
    cols[gappy] = cols[gappy].copy()
    cols[gappy][rng.choice(cols[gappy].size, 40, replace=False)] = np.nan  # gaps of its own
    w = rng.normal(0, 1.0, cols[gappy].size)  # a white input acting 7 samples late
    target = cols[names[-1]] + np.r_[np.zeros(7), w[:-7]] + rng.normal(0, 0.1, w.size)
    cols["w"] = w
    names.append("w")
    target[100:160] = np.nan  # a residual the model does not cover everywhere
    for max_lag in (0, 10, 80):  # the last beyond the direct product's horizon
        screen = LagScreen(cols, max_lag)
        got = screen.screen(target, names)
        assert list(got) == names or set(got) == set(names)
        for c in names:
            want = lag_screen(target, cols[c], max_lag)
            np.testing.assert_allclose(got[c], want, rtol=1e-9, atol=1e-12, err_msg=c)
    # the dead time the screen ranks first is the one built in
    assert np.argmax(LagScreen(cols, 10).screen(target, ["w"])["w"]) == 7


def _model(frame, inputs, out, sets):
    X = frame[inputs].to_numpy(float)
    y = frame[out].to_numpy(float)
    spans = [(np.nanmin(X[:, k]), np.nanmax(X[:, k])) for k in range(X.shape[1])]
    cut = len(y) // 2
    ok = np.isfinite(X[:cut]).all(axis=1) & np.isfinite(y[:cut])
    m = WangMendelRegressor(input_spans=spans, n_sets=sets).fit(X[:cut][ok], y[:cut][ok])
    return m, X


@pytest.mark.parametrize("kind", ["tank", "heatex"])
def test_coarse_levels_fitted_on_demand_answer_as_all_levels(kind):
    frame = _plant(kind, 2.0, 44)
    cols = list(frame.columns)
    out, inputs = cols[-1], cols[:2]
    for sets in (31, 9):
        m, X = _model(frame, inputs, out, sets)
        X = X.copy()
        X[5, 0] = np.nan
        X[6, 1] = X[:, 1].max() * 10  # beyond the span, clipped
        full = run_kernel(pack([m.inference_grid()], dense=True), np.empty(0, np.int64), X)
        lazy, _ = _model(frame, inputs, out, sets)
        got = lazy.predict_detail(X)
        for a, b in zip(
            (full.y, full.support, full.reason, full.level, full.spread),
            (got.y, got.support, got.reason, got.level, got.spread),
            strict=True,
        ):
            np.testing.assert_array_equal(a, b)
        assert (got.level > 0).any()  # coarse levels did answer some samples


@pytest.mark.parametrize("kind", ["tank", "heatex"])
def test_rows_asked_again_past_the_span_answer_as_all_levels(kind):
    """The rows the fine level leaves short are asked only the coarser levels (continuing
    the fine answer): past the span, the trend's move is added once, whether a coarse level
    answers or the fine answer holds."""
    frame = _plant(kind, 2.0, 44)
    cols = list(frame.columns)
    out, inputs = cols[-1], cols[:2]
    for sets in (31, 9):
        m, X = _model(frame, inputs, out, sets)
        # the box of the spans and 5 % past each end, at random: inside the data's range
        # and not, short of support on the fine grid and at the coarse levels
        rng = np.random.default_rng(3)
        lo = np.array([p.lo for p in m.partitions_])
        hi = np.array([p.lo + p.step * (p.n - 1) for p in m.partitions_])
        X = np.vstack([X, rng.uniform(lo - 0.05 * (hi - lo), hi + 0.05 * (hi - lo), (20000, 2))])
        full = run_kernel(pack([m.inference_grid()], dense=True), np.empty(0, np.int64), X)
        lazy, _ = _model(frame, inputs, out, sets)
        got = lazy.predict_detail(X)
        again = lazy.predict_detail(X)  # every level packed: the rows asked all at once
        for a, b, c in zip(
            (full.y, full.support, full.reason, full.level, full.spread),
            (got.y, got.support, got.reason, got.level, got.spread),
            (again.y, again.support, again.reason, again.level, again.spread),
            strict=True,
        ):
            np.testing.assert_array_equal(a, b)
            np.testing.assert_array_equal(a, c)
        assert ((got.reason == 3) & (got.level > 0)).any()  # coarse answers past the span
        # where no coarse level answers, the fine answer (its move past the span included)
        # holds as it is: coarse cells marked without data, the rows short on the fine grid
        packed = list(pack([m.inference_grid()], dense=True))
        packed[15] = np.zeros_like(packed[15])  # the data flags: no coarse cell answers
        none = np.empty(0, np.int64)
        fine = run_kernel(pack([m.inference_grid(0)], dense=True), none, X)
        short = (fine.support < 0.9) & (fine.reason != 1)
        ref = run_kernel(tuple(packed), none, X[short])
        assert ((ref.reason == 3) & (ref.level == 0)).any()
        prior = type(fine)(*(f[short] for f in (fine.y, fine.support, fine.reason,
                                                fine.level, fine.spread)))  # fmt: skip
        cont = run_kernel(tuple(packed), none, X[short], prior, first=1)
        for a, b in zip(
            (ref.y, ref.support, ref.reason, ref.level, ref.spread),
            (cont.y, cont.support, cont.reason, cont.level, cont.spread),
            strict=True,
        ):
            np.testing.assert_array_equal(a, b)


def test_no_coarse_level_fitted_where_the_fine_grid_answers_every_sample():
    frame = _plant("tank", 2.0, 45)
    cols = list(frame.columns)
    m, X = _model(frame, cols[:1], cols[-1], 7)
    fine = m.predict_detail(X)
    rows = np.flatnonzero((fine.level == 0) & (fine.support >= 0.9))
    assert rows.size > 100
    fresh, _ = _model(frame, cols[:1], cols[-1], 7)
    again = fresh.predict_detail(X[rows])
    np.testing.assert_array_equal(again.y, fine.y[rows])
    assert fresh.n_levels_ > 1 and not fresh._nodes  # nothing fitted beyond the fine grid


@pytest.mark.parametrize("d,sets", [(1, 31), (3, 31), (5, 31)])  # 31^5 > the dense table
def test_occupied_cells_counted_densely_are_the_unique_keys(d, sets):
    idx = np.random.default_rng(d).integers(0, sets, size=(2000, d)) // 3
    key = idx @ (sets ** np.arange(d, dtype=np.int64))
    assert _occupied(idx, sets) == np.unique(key).size


def test_corner_weights_are_np_prod_to_the_bit():
    rng = np.random.default_rng(8)
    for d in range(1, 7):
        upper = rng.random((300, d))
        upper[rng.random(upper.shape) < 0.2] = 0.0  # corners a rule gives no weight
        upper[rng.random(upper.shape) < 0.1] = 1.0
        for c in range(1 << d):
            up = np.array([(c >> k) & 1 for k in range(d)], bool)
            want = np.prod(np.where(up, upper, 1.0 - upper), axis=1)
            np.testing.assert_array_equal(corner_weight(upper, 1.0 - upper, up), want)


def test_the_winners_fits_reused_are_the_fits_made_again():
    """A step's scorer built from the winning variant's block fits (as select_inputs does)
    is the scorer that fits that variant again: the same pooled error, residual and
    per-block predictions."""
    frame = _plant("heatex", 3.0, 46)
    ctx = _Context(frame, {}, "60s")
    tags = list(ctx.vars)
    out, ins = tags[-1], [(tags[0], 0), (tags[1], 2)]
    y = ctx.column(out)
    cols = [ctx.column(t, g) for t, g in ins]
    variables = _with_sets([ctx.variable(t, g) for t, g in ins], cols, len(y))
    base = FrozenRuleBase(_rulebase("t", ctx.vars[out], [], "60s"))
    probe = BlockScorer(base, [], y, ctx.block)
    probe.score(variables, cols)
    fits = probe.fitted()
    assert fits is not None and len(fits) == len(probe.parts) > 1
    again = BlockScorer(FrozenRuleBase(base, variables), cols, y, ctx.block)
    reused = BlockScorer(FrozenRuleBase(base, variables), cols, y, ctx.block, fitted=fits)
    assert reused.base_rmse == again.base_rmse
    np.testing.assert_array_equal(reused.residual(cols), again.residual(cols))
    for a, b in zip(reused.parts, again.parts, strict=True):
        np.testing.assert_array_equal(a.base_pred, b.base_pred)
        assert (a.base_cov, a.base_fine, a.base_rows) == (b.base_cov, b.base_fine, b.base_rows)
    # the spec read once is the one the file gives for those inputs
    assert FrozenRuleBase(base, variables).spec == _rulebase("t", ctx.vars[out], variables,
                                                             "60s").spec  # fmt: skip


@pytest.mark.parametrize("d", [1, 2, 3])
@pytest.mark.parametrize("shape", ["trapezoidal", "triangular"])
def test_coarse_node_fit_compiled_equals_numpy_to_the_bit(monkeypatch, d, shape):
    """A coarse level's design made by the compiled loops (corners, nodes, smoothness
    Gram matrix) gives the node values numpy's loops give, bit for bit, on every level —
    dense and sparse fits, sets uneven per input, data on part of the grid only."""
    import diag_plugin.fuzzy.wang_mendel as W

    rng = np.random.default_rng(40 + d)
    n = 6000
    X = rng.uniform(0.0, 1.0, (n, d)) ** np.arange(1, d + 1)  # thin corners of the grid
    X[: n // 3, 0] *= 0.4  # a band the data leave empty
    y = np.sin(3 * X).sum(axis=1) + rng.normal(0, 0.05, n)
    sets = [31, 21, 11][:d] if d > 1 else [41]

    def fitted(loops):
        monkeypatch.setattr(W, "_design_loops", loops)
        m = WangMendelRegressor([(0.0, 1.0)] * d, (-3.0, 3.0), n_sets=sets, shape=shape)
        m.fit(X, y)
        return [m.level_nodes(lv) for lv in range(1, m.n_levels_)]

    compiled = fitted(lambda nsets: W.kernels())
    plain = fitted(lambda nsets: None)
    assert len(compiled) == len(plain) >= 2
    for (k1, v1, f1), (k2, v2, f2) in zip(compiled, plain, strict=True):
        assert np.array_equal(k1, k2) and np.array_equal(f1, f2)
        assert k1.size > 1
        assert np.array_equal(v1.view(np.int64), v2.view(np.int64))


@pytest.mark.parametrize("d", [1, 2, 3])
def test_sets_for_data_compiled_search_equals_numpy(monkeypatch, d):
    """The set count the compiled search finds is numpy's loop's, on data that fill a grid
    evenly, only a band of it, or sit on a few values (the count then falls to the bottom);
    rows with a gap are left out by both."""
    import sys

    from diag_plugin.fuzzy import _kernels  # noqa: F401 - loads numba: the compiled path
    from diag_plugin.selection.sets import sets_for_data

    rng = np.random.default_rng(7 + d)
    spans = [(0.0, 10.0)] * d
    cases = []
    for n in (40, 700, 5000, 30000):
        cases.append([rng.uniform(0, 10, n) for _ in range(d)])
        cases.append([rng.normal(5, 0.3 + k, n).clip(0, 10) for k in range(d)])
        cases.append([rng.integers(0, 3, n).astype(float) for _ in range(d)])
    cases[0][0][3] = np.nan
    got = [sets_for_data(c, spans) for c in cases]
    monkeypatch.delitem(sys.modules, "numba")
    want = [sets_for_data(c, spans) for c in cases]
    assert got == want
    assert len(set(want)) > 2


def _grid_data(d: int, seed: int, n: int = 6000):
    rng = np.random.default_rng(seed)
    X = rng.uniform(0.0, 1.0, (n, d)) ** np.arange(1, d + 1)  # thin corners of the grid
    X = X[(X[:, 0] < 0.45) | (X[:, 0] > 0.55)]  # a band the data leave empty
    return X, np.sin(3 * X).sum(axis=1) + rng.normal(0, 0.05, len(X))


@pytest.mark.parametrize("d", [1, 2, 3])
def test_coarse_rules_compiled_equal_numpy_to_the_bit(monkeypatch, d):
    """A coarse level's rules (keys, conclusions, counts, spreads) summed by the compiled
    group-by are numpy's, bit for bit, on every level of an averaged model."""
    import sys

    from diag_plugin.fuzzy import _kernels  # noqa: F401 - loads numba: the compiled path

    X, y = _grid_data(d, 60 + d)
    sets = [31, 21, 11][:d] if d > 1 else [41]

    def levels():
        m = WangMendelRegressor([(0.0, 1.0)] * d, (-3.0, 3.0), n_sets=sets).fit(X, y)
        return [m.level_rules(lv) for lv in range(1, m.n_levels_)]

    got = levels()
    monkeypatch.delitem(sys.modules, "numba")
    want = levels()
    assert len(got) == len(want) >= 2
    for a, b in zip(got, want, strict=True):
        for u, v in zip(a, b, strict=True):
            assert u.dtype == v.dtype and u.tobytes() == v.tobytes()


@pytest.mark.parametrize("d", [1, 2, 3])
def test_scoring_node_fit_equals_the_dense_fit_to_rounding(d):
    """Within scoring_node_fit a coarse level's normal equations summed over each rule's own
    corners give the dense product's node values to rounding (not to the bit), the rows a
    prediction asks again answer with the same levels, and outside it the dense fit's bits
    are back."""
    from diag_plugin.fuzzy.wang_mendel import scoring_node_fit

    X, y = _grid_data(d, 70 + d)
    sets = [31, 21, 11][:d] if d > 1 else [41]
    Xq = np.random.default_rng(d).uniform(-0.05, 1.05, (4000, d))

    def model():
        return WangMendelRegressor([(0.0, 1.0)] * d, (-3.0, 3.0), n_sets=sets).fit(X, y)

    dense = model()
    want = dense.predict_detail(Xq)
    with scoring_node_fit():
        sparse = model()
        got = sparse.predict_detail(Xq)
    assert (want.level > 0).any()
    np.testing.assert_array_equal(got.level, want.level)
    np.testing.assert_array_equal(got.reason, want.reason)
    np.testing.assert_allclose(got.y, want.y, rtol=1e-9, atol=1e-12)
    for lv in range(1, dense.n_levels_):
        np.testing.assert_allclose(sparse.level_nodes(lv)[1], dense.level_nodes(lv)[1],
                                   rtol=1e-9, atol=1e-12)  # fmt: skip
    again = model()
    for lv in range(1, dense.n_levels_):
        assert again.level_nodes(lv)[1].tobytes() == dense.level_nodes(lv)[1].tobytes()


@pytest.mark.parametrize("kind", ["tank", "heatex"])
def test_a_variants_bound_never_exceeds_its_error(kind):
    """BlockScorer.bound (the fine level's final answers alone) is at most the pooled error
    score() then gives the same variant from the bound's fits, which is the error of a
    fresh score()."""
    frame = _plant(kind, 3.0, 47)
    ctx = _Context(frame, {}, "60s")
    tags = list(ctx.vars)
    out = tags[-1]
    y = ctx.column(out)
    base = FrozenRuleBase(_rulebase("t", ctx.vars[out], [], "60s"))
    scorer = BlockScorer(base, [], y, ctx.block)
    seen = 0
    for t in tags[:-1]:
        for lag in (0, 3):
            cols = [ctx.column(t, lag)]
            ins = _with_sets([ctx.variable(t, lag)], cols, len(y))
            low, fits = scorer.bound(ins, cols)
            rmse, cov = scorer.score(ins, cols, fits)
            assert (rmse, cov) == scorer.score(ins, cols)
            if np.isfinite(rmse):
                assert 0.0 < low <= rmse
                seen += 1
    assert seen >= 4


@pytest.mark.parametrize("kind", ["tank", "heatex"])
def test_candidates_passed_over_by_their_bound_change_no_choice(monkeypatch, kind):
    """select_inputs with the bounds (candidates and dead times that cannot win not
    finished) chooses what it chooses with every variant scored in full."""
    import diag_plugin.unitbuild.build as B

    frame = _plant(kind, 3.0, 48)
    ctx = _Context(frame, {}, "60s")
    tags = list(ctx.vars)
    calls = {"full": 0}
    plain = BlockScorer.score

    def counted(self, variables, cols, prefit=None):
        calls["full"] += 1
        return plain(self, variables, cols, prefit)

    monkeypatch.setattr(BlockScorer, "score", counted)
    got = [B.select_inputs(ctx, t, tags, test=f"t{i}").as_dict() for i, t in enumerate(tags)]
    pruned = calls["full"]
    calls["full"] = 0
    monkeypatch.setattr(B, "BOUND_MARGIN", float("inf"))  # no bound ever passes one over
    want = [B.select_inputs(ctx, t, tags, test=f"t{i}").as_dict() for i, t in enumerate(tags)]
    assert got == want
    assert any(g["inputs"] for g in got)
    assert pruned < calls["full"]  # some variants were passed over


@pytest.mark.parametrize("kind", ["tank", "heatex"])
def test_no_candidate_finished_that_cannot_cut_the_error(monkeypatch, kind):
    """select_inputs finishes (fits the coarse levels of) only variants whose bound is within
    reach of a kept step: the candidates in the order of their bounds, none finished whose
    bound exceeds the cut by MIN_GAIN of the current error (a step that keeps no input
    finishes none it could not keep; main finished the best-screened candidate of every step)."""
    import diag_plugin.unitbuild.build as B
    from diag_plugin.selection.lags import TOLERANCE

    frame = _plant(kind, 3.0, 48)
    ctx = _Context(frame, {}, "60s")
    tags = list(ctx.vars)
    bound_of: dict[int, float] = {}
    finished: list[tuple[float, float]] = []  # (bound, the step's current error)
    plain_bound, plain_score = BlockScorer.bound, BlockScorer.score

    def bound(self, variables, cols):
        low, fits = plain_bound(self, variables, cols)
        bound_of[id(fits)] = low
        return low, fits

    def score(self, variables, cols, prefit=None):
        finished.append((bound_of[id(prefit)], self.base_rmse))
        return plain_score(self, variables, cols, prefit)

    monkeypatch.setattr(BlockScorer, "bound", bound)
    monkeypatch.setattr(BlockScorer, "score", score)
    got = [B.select_inputs(ctx, t, tags, test=f"t{i}") for i, t in enumerate(tags)]
    assert any(g.steps for g in got) and finished
    reach = (1 - B.MIN_GAIN) * (1 + TOLERANCE) * (1 + B.BOUND_MARGIN)
    assert all(low <= cur * reach for low, cur in finished)


def _historian(tmp_path, kind: str, seed: int) -> tuple[str, object, object]:
    """A historian of the plant's tags, each exported with irregular spacings, and one tag
    every 3 min (held between its samples on the 1 min grid)."""
    import pandas as pd

    from diag_plugin.simulate import smallplants
    from historian.store import Historian

    sim = {"tank": sp.simulate_tank, "heatex": sp.simulate_heat_exchanger}[kind]
    run = sim(3.0, seed=seed, start="2026-03-02")
    fast = smallplants.export(run, 60.0, timing="irregular", seed=seed)
    slow = smallplants.export(run, 180.0, timing="jitter", seed=seed)
    url = f"sqlite:///{tmp_path / 'h.db'}"
    with Historian.open(url) as h:
        h.write_samples(fast.iloc[:, 1:])
        h.write_samples(slow.iloc[:, :1])
    return url, fast.index[0], fast.index[-1] + pd.Timedelta("1min")


@pytest.mark.parametrize("kind", ["tank", "heatex"])
def test_the_window_read_in_shares_is_one_read(tmp_path, kind):
    """The tags' sampling and the window read in shares of the tags by worker processes are
    one read's, column for column and bit for bit (irregular and slow tags included)."""
    import pandas as pd

    from diag_plugin.unitbuild.parallel import map_tests
    from diag_plugin.unitbuild.read import read_sampling, read_window
    from historian.access import open_data, tag_sampling
    from historian.store import Historian

    url, a, b = _historian(tmp_path, kind, 31)
    with Historian.open(url) as h:
        tags = sorted(str(t) for t in h.tags()["name"])

    def mapper(fn, items, args):
        return map_tests(fn, items, args, workers=2)

    one, info = open_data(url, tags, a, b, "1min")
    one.attrs = {}
    for n in (2, 3, len(tags) + 1):
        assert read_sampling(url, tags, a, b, n, mapper) == tag_sampling(url, tags, a, b)
        got, got_info = read_window(url, tags, a, b, "1min", n, mapper)
        pd.testing.assert_frame_equal(got, one, check_exact=True)
        assert got_info == info and got.attrs == {}


def test_the_parent_reads_no_raw_sample_on_two_workers(tmp_path, monkeypatch):
    """``build_from_historian`` on two workers leaves every raw read to the workers (a forked
    worker records in its own copy), and builds the one-worker unit file for file."""
    from historian.store import Historian

    url, a, b = _historian(tmp_path, "heatex", 32)
    read: list[int] = []
    plain = Historian._read_raw

    def raw(self, tag_id, *args, **kw):
        read.append(tag_id)
        return plain(self, tag_id, *args, **kw)

    monkeypatch.setattr(Historian, "_read_raw", raw)
    from diag_plugin.unitbuild.build import build_from_historian

    one = build_from_historian(url, "u", a, b, folder=tmp_path / "one", far=0.05, workers=1)
    assert read  # one worker: the parent reads
    read.clear()
    two = build_from_historian(url, "u", a, b, folder=tmp_path / "two", far=0.05, workers=2)
    assert read == []
    assert one.period == two.period and len(two.tests) > 1
    files = sorted(p.name for p in (tmp_path / "one").iterdir())
    assert files == sorted(p.name for p in (tmp_path / "two").iterdir())
    for name in files:
        assert _text(tmp_path / "one" / name) == _text(tmp_path / "two" / name), name
