"""``diag explain`` on the blending line nobody here tuned on (issue 37's audit), on a seed other
than the benchmark's (7): the manual valve first, the header pressure flagged as a consequence;
and the coarse levels' node fit by conjugate gradients agreeing with the direct solve it
replaced."""

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

import diag_plugin.fuzzy.wang_mendel as wm
from diag_plugin.models.spec import Variable
from diag_plugin.rulebase.document import RuleBase
from diag_plugin.selection.consequence import consequence
from diag_plugin.selection.lags import default_max_lag
from diag_plugin.selection.scoring import cut_row
from diag_plugin.simulate.blendline import on_grid, simulate_blendline
from diag_plugin.training.chunked import train
from diag_plugin.workbench.explain import CUTS, explain
from diag_plugin.workbench.model_edit import new_model

INPUTS = ["FEED_A[k]", "FEED_B[k]", "LEVEL[k]", "TEMP[k]"]


@pytest.fixture(scope="module")
def line():
    """Ten days of the line (seed 11) on its 15 s grid, and the model a user makes of it:
    ``diag model new`` without options (shape and sets from the data), then ``diag train``."""
    import tempfile
    from pathlib import Path

    f = on_grid(simulate_blendline(10, seed=11))
    with tempfile.TemporaryDirectory() as d:
        rb = new_model(Path(d) / "line.toml", "line", "OUT_FLOW[k]", INPUTS, frame=f,
                       tag_info={}, period="15s", shape=None)  # fmt: skip
        a, b = f.index[0], f.index[-1] + pd.Timedelta("15s")
        res = train(rb, lambda x, y: f[(f.index >= x) & (f.index < y)], a, b)
        rb.apply_training(res.model)
        rb.save()
        yield f, RuleBase.load(rb.path)


def test_manual_valve_first_header_pressure_a_consequence(line):
    # a thin model (sets 41/21/15/15, the fine grid answering 1 %): minutes before issue 37's
    # third round, now the candidates whose grid the data cannot fill are not retrained at
    # the sets add-input writes (only their fewer sets are)
    f, rb = line
    e = explain(rb, f, tag_info={})
    top = e.candidates[0]
    assert top.input.startswith("HAND_VALVE[") and not top.consequence, e.as_dict(top=4)
    # it cuts the error as explain counts a cut (its tier)
    assert top.rmse_pct_if_added < CUTS * e.baseline_rmse_pct
    hp = [c for c in e.candidates if c.input.startswith("HEADER_P[")]
    assert hp and all(c.consequence for c in hp), e.as_dict(top=6)
    # what it offers for a grid the data cannot fill is the fewer sets it retrained
    unfilled = [c for c in e.candidates if any("cannot fill" in n for n in c.notes)]
    assert unfilled and all("--sets" in c.command for c in unfilled), e.as_dict()


def test_three_day_window_valve_seen_only_at_the_edge(tmp_path, monkeypatch):
    """Three days of the line (seed 16; the defect was found on seed 7): the manual valve's
    held-out values are reached only just before the cut, where the screen's out-of-fold
    correction cannot judge them; it is retrained anyway and leads."""
    import diag_plugin.workbench.explain as explain_mod

    f = on_grid(simulate_blendline(3, seed=16))
    rb = new_model(tmp_path / "line.toml", "line", "OUT_FLOW[k]", INPUTS, frame=f,
                   tag_info={}, period="15s", shape=None)  # fmt: skip
    a, b = f.index[0], f.index[-1] + pd.Timedelta("15s")
    rb.apply_training(train(rb, lambda x, y: f[(f.index >= x) & (f.index < y)], a, b).model)
    e = explain(rb, f, tag_info={})
    top = e.candidates[0]
    assert top.input.startswith("HAND_VALVE[") and not top.consequence, e.as_dict(top=4)
    assert top.rmse_pct_if_added < CUTS * e.baseline_rmse_pct
    # what this guards: on the screen's error alone the valve is not retrained
    monkeypatch.setattr(explain_mod, "UNJUDGED_EXTRA", 0)
    alone = explain(rb, f, tag_info={})
    assert not any(c.input.startswith("HAND_VALVE[") for c in alone.candidates)
    assert any(s["input"].startswith("HAND_VALVE[") for s in alone.screened)


@pytest.mark.parametrize(("days", "seed"), [(3, 13), (3, 23), (10, 15)])
def test_a_valve_moved_a_few_times_is_not_read_as_a_consequence(days, seed):
    """Windows where main flagged the manual valve as driven by the output: what the output
    leaves of the valve is a handful of levels (it is moved every 6-18 h), too few for the
    chain test to tell a cause from a consequence — it says so and flags nothing; the header
    pressure, which sags with the flow, stays a consequence in the same windows."""
    f = on_grid(simulate_blendline(days, seed=seed))
    y = f["OUT_FLOW"].to_numpy(float)
    inputs = [f[c.split("[")[0]].to_numpy(float) for c in INPUTS]
    cut, horizon = cut_row(f.index, 0.2), default_max_lag(f.index)
    valve = consequence(f["HAND_VALVE"].to_numpy(float), y, inputs, cut, horizon)
    assert not valve.likely, valve
    assert valve.unjudged and not valve.judged  # read as a chain, but the data cannot tell
    assert "cannot tell" in valve.unjudged_note("HAND_VALVE", "OUT_FLOW[k]")
    hp = consequence(f["HEADER_P"].to_numpy(float), y, inputs, cut, horizon)
    assert hp.chain and hp.judged and not hp.unjudged, hp


def test_header_pressure_flagged_where_the_held_out_output_is_new():
    """Three days of the line on seed 113 (not tuned on: the mend was made on 101-110): nine
    tenths of the held-out outputs lie in sets of the output the training part never
    visited. Main scored the header pressure there too (r²ᵧ −1.3: an unvisited set answers
    the training mean) and missed it; scored where the training rows saw the output it is a
    chain, and the manual valve is still not flagged."""
    from diag_plugin.selection.consequence import Y_SETS, _index

    f = on_grid(simulate_blendline(3, seed=113))
    y = f["OUT_FLOW"].to_numpy(float)
    inputs = [f[c.split("[")[0]].to_numpy(float) for c in INPUTS]
    cut, horizon = cut_row(f.index, 0.2), default_max_lag(f.index)
    ix = _index(y, cut, Y_SETS, clip=False)
    visited = np.bincount(ix[:cut][ix[:cut] >= 0], minlength=Y_SETS) > 0
    held = ix[cut:][np.isfinite(y[cut:])]
    assert np.mean((held < 0) | ~visited[np.maximum(held, 0)]) > 0.5  # what main missed on
    hp = consequence(f["HEADER_P"].to_numpy(float), y, inputs, cut, horizon)
    assert hp.chain and hp.likely, hp
    assert not consequence(f["HAND_VALVE"].to_numpy(float), y, inputs, cut, horizon).likely


def test_compare_table_says_cannot_tell_for_the_valve():
    """`diag compare`'s residual-vs-tag table uses the same test: on the 3-day seed-13 window
    the manual valve is marked "cannot tell" (not "likely"), the header pressure "likely"."""
    from diag_plugin.workbench.compare import residual_vs_tags

    f = on_grid(simulate_blendline(3, seed=13))
    y = f["OUT_FLOW"].to_numpy(float)
    x = np.column_stack([f[c.split("[")[0]].to_numpy(float) for c in INPUTS])
    res = y - np.nanmean(y)  # the flag reads the output and inputs, not the residual
    t = residual_vs_tags(f, f.index, res, {"OUT_FLOW"}, y, x).set_index("tag")
    assert not t.loc["HAND_VALVE", "likely_consequence"]
    assert t.loc["HAND_VALVE", "consequence_unjudged"]
    assert t.loc["HEADER_P", "likely_consequence"]
    assert not t.loc["HEADER_P", "consequence_unjudged"]


@pytest.mark.parametrize(("seed", "drift", "offered"), [(1, 0.0, False), (1, 6.0, True)])
def test_a_drift_is_offered_only_where_it_holds_across_the_window(tmp_path, seed, drift, offered):
    """Ten days of the line (seed 1, where issue 37's ``days()`` ranked second): on the
    held-out tail ``days()`` cuts the error 3.4 % — the last training days' valve offset
    carried forward; with each fifth of the window held out in turn it does not, so it is
    not offered and a note says why. The same window with a real drift (the outflow rising
    by 6 t/h over the ten days): offered."""
    f = on_grid(simulate_blendline(10, seed=seed))
    f["OUT_FLOW"] = f["OUT_FLOW"] + drift * np.linspace(0.0, 1.0, len(f))
    rb = new_model(tmp_path / "line.toml", "line", "OUT_FLOW[k]", INPUTS, frame=f,
                   tag_info={}, period="15s", shape=None)  # fmt: skip
    a, b = f.index[0], f.index[-1] + pd.Timedelta("15s")
    rb.apply_training(train(rb, lambda x, y: f[(f.index >= x) & (f.index < y)], a, b).model)
    e = explain(rb, f, tag_info={})
    days = [c for c in e.candidates if c.input.startswith("days()")]
    said = [n for n in e.notes if n.startswith("slow drift not offered") and "stretches" in n]
    if offered:
        assert days and days[0].rmse_pct_if_added < CUTS * e.baseline_rmse_pct, e.as_dict()
        assert not said
    else:
        assert not days and len(said) == 1, e.as_dict()


def _level_system(rb, f, monkeypatch):
    """A five-input model (the line's four and the manual valve) and its first coarse level's
    normal equations, as the node fit builds them."""
    cols = INPUTS + ["HAND_VALVE[k]"]
    X = np.column_stack([f[c.split("[")[0]].to_numpy() for c in cols])
    y = f["OUT_FLOW"].to_numpy()
    ok = np.isfinite(X).all(axis=1) & np.isfinite(y)
    hv = Variable("HAND_VALVE[k]", "HANDVALVE", "%", (30.0, 90.0), 21)
    spec = replace(rb.spec, inputs=list(rb.inputs) + [hv])
    m = rb.codec.new_estimator(spec).fit(X[ok], y[ok])
    got = {}
    solve = wm._solve_spd

    def keep(M, rhs):
        got["M"], got["rhs"] = M, rhs
        return solve(M, rhs)

    monkeypatch.setattr(wm, "_solve_spd", keep)
    _, outside, _ = wm._fit_nodes(m, 1)
    assert "M" not in got, "outside explain the node fit keeps the direct solve"
    with wm.iterative_node_fit():
        _, values, _ = wm._fit_nodes(m, 1)
    monkeypatch.setattr(wm, "_solve_spd", solve)
    assert "M" in got, "the level was not fitted by the sparse path"
    assert np.array_equal(outside, spsolve(sp.csc_matrix(got["M"]), got["rhs"]))
    return m, values, got["M"], got["rhs"]


def test_node_fit_by_conjugate_gradients_equals_the_direct_solve(line, monkeypatch):
    f, rb = line
    m, values, M, rhs = _level_system(rb, f, monkeypatch)
    direct = spsolve(sp.csc_matrix(M), rhs)
    scale = np.abs(direct).max()
    assert values.size > 1000  # a level big enough that the direct solve fills in
    assert np.abs(values - direct).max() <= 1e-8 * scale
    # where conjugate gradients do not converge, the direct solve answers (the same values)
    monkeypatch.setattr(wm, "CG_MAXITER", 1)
    assert np.array_equal(wm._solve_spd(M, rhs), spsolve(M.tocsc(), rhs))
