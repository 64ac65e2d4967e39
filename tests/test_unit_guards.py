"""Guards of a unit's combined test, its threshold learning and ``diag unit build`` (issue 38).

Each test was shown to fail on the bug it names (planted by hand, one at a time) and to pass
on the code as it is; docs/reference/testing.md, "Issue 38 — diagnosis", lists them.

* the combined statistic keeps its false-alarm level when some tests are unknown (χ² of the
  known count mapped to ``T`` degrees of freedom) and is unknown with fewer than half known;
* its threshold is calibrated on T² of blocks the parameters were not learned on (out of
  sample: higher than an in-sample one);
* a thin rule level is pooled with the coarser ones, never ends the calibration;
* set-points are never tags a unit can blame — by name, and by the description the historian
  gives them (``diag unit build`` records them in the unit file);
* ``diag unit build`` skips a set-point known only by its description, tests the tag its
  controller holds as the loop's own relation, and keeps 30 s of on/off delay at any rate.

The rest close survivors of the mutation check (docs/reference/testing.md): a tag's direction is the
move a bias of its sensor makes, the ranking's invariances, the learning window's runs and
training range, a window where the plant stood still, the thresholds as calibrated.
"""

from __future__ import annotations

import math
import re
import shutil

import numpy as np
import pandas as pd
import pytest
from scipy import signal, stats

from diag_plugin.diagnose.unit import Unit
from diag_plugin.diagnose.unitfile import UnitFile
from diag_plugin.diagnose.unittags import (
    MIN_KNOWN_SHARE,
    CombinedModel,
    derived_matrix,
    describe_top,
    top_tags,
)
from diag_plugin.examples.coupled import DAY, TESTS, build, process
from diag_plugin.examples.rigs import held_levels
from diag_plugin.learn.budget import episodes
from diag_plugin.learn.thresholds import (
    MIN_LEVEL_SAMPLES,
    RUN_GAP,
    SETTLE_SAMPLES,
    LearnError,
    fuzzy_sets,
    learn_combined,
    learn_thresholds,
    level_scales,
    settled,
)
from diag_plugin.unitbuild.build import build_unit, evaluation_for, loop_lags
from historian.taginfo import TagInfo


def _correlated(n: int, T: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``n`` draws of ``T`` scaled residuals ~ N(0, S), S a random correlation matrix."""
    rng = np.random.default_rng([seed, 38])
    a = rng.standard_normal((T, T))
    s = a @ a.T + T * np.eye(T)
    d = np.sqrt(np.diag(s))
    s = s / np.outer(d, d)
    return rng.multivariate_normal(np.zeros(T), s, size=n), s


@pytest.fixture(scope="module")
def learned(tmp_path_factory):
    """The coupled process's unit (``combined = true``, ``isolation = "tags"``), models
    trained and thresholds learned on 3 fault-free days of seed 1."""
    folder = tmp_path_factory.mktemp("coupled")
    window = process(3 * DAY, 1)
    path = build(folder, window, {"combined": True, "isolation": "tags"})
    got = learn_thresholds(Unit.load(path), [window], far=0.05)
    uf = UnitFile.load(path)
    uf.set_learned(got)
    uf.save()
    unit = Unit.load(path)
    unit.learned_result = got  # what learn_thresholds returned, for the tests below
    return unit


def _model(cov: np.ndarray) -> CombinedModel:
    T = cov.shape[0]
    return CombinedModel([], np.zeros(T), np.ones(T), cov, np.zeros((T, 0)), None)


# ---------------------------------------------------------------- the combined statistic
@pytest.mark.parametrize("T, unknown", [(4, 1), (6, 2), (5, 2)])
def test_the_combined_statistic_keeps_its_false_alarm_level_with_tests_unknown(T, unknown):
    """Fault-free scaled residuals (correlated, the covariance the model holds): the share of
    samples beyond the χ²_T quantile of 1 % and 5 % is that level whether all tests are known
    or some are (the statistic over the known ones mapped to T degrees of freedom)."""
    n = 40_000
    z, cov = _correlated(n, T, seed=T * 10 + unknown)
    model = _model(cov)
    full = model.evaluate(z)[0]
    some = z.copy()
    some[:, :unknown] = np.nan  # those tests unknown (their models' inputs missing)
    part = model.evaluate(some)[0]
    assert np.isfinite(part).all()
    for level in (0.01, 0.05):
        limit = stats.chi2.isf(level, T)
        for t2 in (full, part):
            assert abs((t2 > limit).mean() - level) < 0.25 * level, (level, (t2 > limit).mean())
    # and the same quantiles: the mapped statistic is χ²_T, not χ² of the known count
    for q in (0.5, 0.9, 0.99):
        assert np.quantile(part, q) == pytest.approx(stats.chi2.ppf(q, T), rel=0.05)


@pytest.mark.parametrize("T, unknown", [(4, 1), (7, 2), (40, 20)])
def test_a_large_combined_statistic_with_tests_unknown_stays_finite_and_ordered(T, unknown):
    """Far out in the tail (a fault) the χ² survival of the known tests' statistic underflows
    to 0 and its χ²_T quantile was infinite: every large deviation read ``inf`` and none
    ranked above another. Mapped in logarithms it stays finite, grows with the deviation, and
    joins the exact mapping where that is still finite; with every test known it is T² itself."""
    model = _model(np.eye(T))
    size = np.geomspace(1.0, 1e4, 200)
    z = np.outer(size, np.ones(T)) / math.sqrt(T - unknown)
    some = z.copy()
    some[:, :unknown] = np.nan
    part = model.evaluate(some)[0]
    assert np.isfinite(part).all() and np.all(np.diff(part) > 0)
    q = size**2  # T² over the known tests
    exact = stats.chi2.isf(stats.chi2.sf(q, T - unknown), T)
    ok = np.isfinite(exact)
    assert ok.any() and not ok.all()
    np.testing.assert_allclose(part[ok], exact[ok], rtol=1e-12)
    last = int(np.flatnonzero(ok)[-1])  # across the switch: the same slope as just before it
    before = (part[last] - part[last - 1]) / (q[last] - q[last - 1])
    after = (part[last + 1] - part[last]) / (q[last + 1] - q[last])
    assert after == pytest.approx(before, rel=0.05)
    np.testing.assert_allclose(model.evaluate(z)[0], (z**2).sum(axis=1), rtol=1e-9)


@pytest.mark.parametrize("T", [2, 3, 4, 5, 7])
def test_the_combined_statistic_is_unknown_with_fewer_than_half_the_tests_known(T):
    z, cov = _correlated(10, T, seed=T)
    model = _model(cov)
    need = max(1, math.ceil(MIN_KNOWN_SHARE * T))
    for known in range(1, T + 1):
        x = z.copy()
        x[:, known:] = np.nan
        t2 = model.evaluate(x)[0]
        if known < need:
            assert np.isnan(t2).all(), (T, known)
        else:
            assert np.isfinite(t2).all(), (T, known)


def test_a_unit_with_most_tests_unknown_publishes_the_combined_test_unknown(learned):
    """D and F missing: only rA and rC (of five) known — the combined test says nothing, and
    with one tag missing (four tests known) it still judges."""
    f = process(600, 41)
    f[["D", "F"]] = np.nan
    d = learned.reset().evaluate(f)
    assert d.combined["T2"].isna().all()
    f = process(600, 41)
    f["F"] = np.nan
    d = learned.reset().evaluate(f)
    assert d.combined["T2"].iloc[300:].notna().all()


# ---------------------------------------------------------------- the combined threshold
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_combined_threshold_is_calibrated_out_of_sample(learned, seed):
    """Fault-free filtered residuals of five tests whose level wanders between periods (as a
    plant's does): the threshold learned with the centre, scale and covariance fitted without
    the block they score is above the one fitted on all the data (in-sample T² is smaller)."""
    n, T = 5000, len(TESTS)
    rng = np.random.default_rng([seed, 381])
    e = rng.standard_normal((n, T)) @ np.linalg.cholesky(_correlated(1, T, seed)[1]).T
    x = signal.sosfilt(signal.butter(2, 0.05, output="sos"), e, axis=0) * 3.0
    block = np.repeat(np.arange(5), n // 5)
    x += rng.normal(0.0, 0.4, (5, T))[block]  # each period its own small offset
    body = pd.DataFrame(x, columns=list(TESTS))
    cross = learn_combined(learned, body, block, 0.01, {}).high
    inside = learn_combined(learned, body, np.zeros(n, np.int64), 0.01, {}).high
    assert cross > 1.1 * inside, (cross, inside)


# ---------------------------------------------------------------- rule levels
def test_a_thin_rule_level_is_pooled_with_the_coarser_ones():
    """Level 1 answered a handful of samples, level 2 many: both get the pool's scale, and
    level 2's answers stay calibrated (a thin level used to end the list); a thin level at the
    end, never filled, stays out."""
    rng = np.random.default_rng(7)
    level = np.r_[np.zeros(600), np.ones(MIN_LEVEL_SAMPLES // 3), np.full(300, 2), np.full(5, 3)]
    level = level.astype(np.int64)
    raw = rng.standard_normal(level.size) * np.array([1.0, 1.5, 2.0, 3.0])[level]
    got = level_scales(raw, level)
    assert len(got) == 3, got
    assert got[0] == 1.0 and got[1] == got[2] and 1.5 < got[2] < 2.5, got
    # two thin levels in a row between full ones: pooled until full, then the next level
    level = np.r_[np.zeros(600), np.ones(10), np.full(10, 2), np.full(200, 3)].astype(np.int64)
    raw = rng.standard_normal(level.size)
    got = level_scales(raw, level)
    assert len(got) == 4 and got[1] == got[2] == got[3], got


def test_a_thin_fine_grid_is_pooled_into_the_reference():
    """A model whose fine grid answers only a few samples (many inputs, few rows per cell):
    the finest levels that together answer enough are the reference (scale 1), the coarser
    ones are scaled against it — the test is not left unknown everywhere (a 12-tag coupled
    plant's unit build failed: "only 0 known filtered residual values")."""
    rng = np.random.default_rng(11)
    level = np.r_[np.zeros(5), np.ones(400), np.full(300, 2)].astype(np.int64)
    raw = rng.standard_normal(level.size) * np.array([1.0, 1.0, 2.0])[level]
    got = level_scales(raw, level)
    assert len(got) == 3 and got[0] == got[1] == 1.0 and 1.6 < got[2] < 2.4, got
    # no level at all answers enough: nothing is calibrated beyond the fine grid
    assert level_scales(raw[:20], level[:20]) == [1.0]


# ---------------------------------------------------------------- set-points are never blamed
def test_a_set_point_is_never_a_tag_the_unit_names(tmp_path):
    """The model tag B read as plant tag FIC1.SP (``[tags]``): the derived matrix, the ranking
    and the combined model leave it out; the other tags stay."""
    path = build(tmp_path, process(2 * DAY, 1), {"isolation": "tags", "combined": True})
    path.write_text(path.read_text() + '\n[tags]\nB = "FIC1.SP"\n')
    unit = Unit.load(path)
    faults = derived_matrix(unit).faults
    assert "FIC1.SP" not in faults and faults == ["A", "C", "D", "E", "F"]
    rough = CombinedModel.of(unit)  # before diag unit learn: the matrix's 0/1 columns
    assert rough.tags == faults
    assert rough.xi.tolist() == (derived_matrix(unit).entries == "1").astype(float).tolist()


# ---------------------------------------------------------------- diag unit build
PERIOD = "10s"


def _loop_plant(n: int, seed: int) -> tuple[pd.DataFrame, dict[str, TagInfo]]:
    """A flow loop at 10 s: FLOW_TARGET (the operator's entry, a set-point only its
    description says so) held 20–60 min, FI101 following it (first-order, 3 samples), the
    valve VALVE moving with the flow and a pressure disturbance, a temperature TI201 and a
    pressure PI301 downstream."""
    rng = np.random.default_rng([seed, 382])
    sp = held_levels(rng, n, 20.0, 80.0, (120, 360))
    a = math.exp(-1 / 3)
    fi = signal.lfilter([1 - a], [1, -a], sp, zi=[a * sp[0]])[0]
    dist = signal.lfilter([0.02], [1, -0.98], rng.standard_normal(n))
    valve = 0.8 * fi + 60.0 * dist + 5.0
    ti = 40.0 + 0.3 * np.r_[np.full(4, fi[0]), fi[:-4]]
    pi = 2.0 + 0.02 * valve - 0.01 * fi
    idx = pd.date_range("2026-03-02 00:00:03", periods=n, freq=PERIOD, tz="UTC", name="ts")
    f = pd.DataFrame(
        {
            "FLOW_TARGET": sp,
            "FI101": fi + 0.3 * rng.standard_normal(n),
            "VALVE": valve + 0.5 * rng.standard_normal(n),
            "TI201": ti + 0.2 * rng.standard_normal(n),
            "PI301": pi + 0.01 * rng.standard_normal(n),
        },
        idx,
    )
    info = {
        "FLOW_TARGET": TagInfo("FLOW_TARGET", "m3/h", 0, 100, "feed flow set-point"),
        "FI101": TagInfo("FI101", "m3/h", 0, 100, "feed flow"),
        "VALVE": TagInfo("VALVE", "%", 0, 100, "feed valve position"),
        "TI201": TagInfo("TI201", "degC", 0, 100, "reactor temperature"),
        "PI301": TagInfo("PI301", "bar", 0, 5, "header pressure"),
    }
    return f, info


@pytest.fixture(scope="module")
def loop_built(tmp_path_factory):
    folder = tmp_path_factory.mktemp("loop")
    frame, info = _loop_plant(2400, 1)
    res = build_unit("loop", frame, folder=folder, period=PERIOD, tag_info=info, far=0.05)
    return res, Unit.load(res.path, folder)


def test_a_set_point_known_by_its_description_is_not_tested(loop_built):
    res, _ = loop_built
    assert "set-point" in res.skipped.get("FLOW_TARGET", ""), res.skipped
    assert "FLOW_TARGET" not in {t.tag for t in res.tests}
    # the flow its controller holds is tested as the loop's own relation, at that set-point
    (fi,) = [t for t in res.tests if t.tag == "FI101"]
    assert fi.tracks == "FLOW_TARGET" and fi.method == "track", fi


def test_a_set_point_known_by_its_description_is_never_blamed(loop_built, tmp_path):
    """The loop test reads FLOW_TARGET (its set-point); the unit never names it at fault —
    not in the derived matrix, not in the ranking, not in an alarm's tags."""
    res, unit = loop_built
    assert any("FLOW_TARGET" in s for t in unit.tests for s in unit.models[t].inputs)
    assert "FLOW_TARGET" not in unit.matrix.faults
    assert "FLOW_TARGET" not in unit.cmodel.tags
    assert "FLOW_TARGET" in UnitFile.load(res.path).build["set_points"]
    # a unit built before [build] set_points was written: the loop test's set-point counts
    old = tmp_path / "old"
    shutil.copytree(res.path.parent, old)
    text = (old / res.path.name).read_text()
    (old / res.path.name).write_text(text.replace('set_points = ["FLOW_TARGET"]\n', ""))
    assert "FLOW_TARGET" not in Unit.load(old / res.path.name, old).matrix.faults
    # a described set-point no loop test names (read by other models only): [build] alone
    sp_only = re.sub(r',? ?(tracks|set_point) = "FLOW_TARGET"', "", text)
    assert "FLOW_TARGET" in sp_only and '"FLOW_TARGET"' in sp_only.split("set_points =")[1]
    (old / res.path.name).write_text(sp_only)
    assert "FLOW_TARGET" not in Unit.load(old / res.path.name, old).matrix.faults
    # a bias on the flow sensor: the unit names tags, never the set-point
    frame, _ = _loop_plant(1500, 2)
    frame.iloc[700:, frame.columns.get_loc("FI101")] += 8.0
    d = unit.reset().evaluate(frame)
    named = set(d.top_tags[["top1", "top2", "top3"]].to_numpy().ravel()) - {""}
    assert named and "FLOW_TARGET" not in named, named
    assert not d.faults.str.contains("FLOW_TARGET").any()


@pytest.mark.parametrize("period", ["250ms", "1s", "2s", "5s", "10s", "1min", "15min"])
def test_the_on_off_delays_keep_30_seconds_at_any_rate(period):
    """30 s of delay (the example unit's 30 samples at 1 s) at every rate, never under 3
    samples nor over 30."""
    s = pd.Timedelta(period).total_seconds()
    ev = evaluation_for(period)
    assert ev["on_delay"] == ev["off_delay"]
    if s < 1.0:
        assert ev["on_delay"] == 30  # at most 30 samples
    elif s <= 10.0:
        assert ev["on_delay"] * s == pytest.approx(30.0, rel=0.2)
    else:
        assert ev["on_delay"] == 3  # at least 3 samples


def test_a_built_unit_at_10_s_has_3_samples_of_delay(loop_built):
    _, unit = loop_built
    assert unit.ev["on_delay"] == 3  # 30 s
    assert unit.ev["off_delay"] >= 3  # at least the on-delay (alarm_settings: ISA-18.2)


def test_a_loop_actuator_no_other_test_reads_takes_its_loop_axis_whatever_the_sign():
    """A controller output read by no test but its loop's (``--tags`` left it out): its
    direction is empty, so its contribution is its loop test's axis alone, ``(S⁻¹z)_j² /
    S⁻¹_jj`` — all of a deviation of that test alone, up or down."""
    xi = np.array([[1.0, 0.0], [0.0, 0.0], [-0.8, 0.0]])  # PV: loop test and a reader
    cm = CombinedModel(["PV", "OUT"], np.zeros(3), np.ones(3), np.eye(3), xi, 10.0,
                       np.array([-1, 0]))  # fmt: skip
    t2, share = cm.evaluate(np.array([[5.0, 0.0, 0.0], [-5.0, 0.0, 0.0], [-5.0, 1.0, 0.0]]))
    assert t2[:2] == pytest.approx([25.0, 25.0])
    assert share[0, 1] == pytest.approx(1.0) and share[1, 1] == pytest.approx(1.0)
    assert share[2, 1] == pytest.approx(25.0 / 26.0)
    assert share[0, 0] == pytest.approx(1.0 / 1.64)  # PV's own direction explains less


def test_a_tags_share_does_not_depend_on_the_length_of_its_direction():
    """RBC (Alcala & Qin, 2009, eq. 13) is a projection: directions 1000 times shorter or
    longer give the same shares, for any deviation."""
    z, cov = _correlated(50, 4, seed=9)
    xi = np.random.default_rng(9).standard_normal((4, 3))
    shares = []
    for f in (1e-3, 1.0, 1e3):
        cm = CombinedModel(["X", "Y", "W"], np.zeros(4), np.ones(4), cov, xi * f, 10.0)
        shares.append(cm.evaluate(z * 3.0)[1])
    np.testing.assert_allclose(shares[0], shares[1], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(shares[2], shares[1], rtol=1e-9, atol=1e-12)


def test_an_alarm_names_only_tags_that_explain_some_of_it():
    share = np.array([[0.9, 0.0, 0.4], [0.0, 0.0, 0.0], [0.5, np.nan, 0.7]])
    top = top_tags(share, ["X", "Y", "W"], np.array([True, True, False]))
    assert top["top1"].tolist() == ["X", "", ""] and top["top2"].tolist() == ["W", "", ""]
    assert top["top3"].tolist() == ["", "", ""]  # Y explains nothing: never named
    assert describe_top(top.iloc[0]) == "tags: X 0.90, W 0.40"
    assert describe_top(top.iloc[1]) == ""


@pytest.mark.parametrize("scale", ["span", "max"])
def test_a_tags_direction_is_the_move_a_bias_of_its_sensor_makes(tmp_path, scale):
    """Eq. 6 of the module doc: a bias ``b`` of D's sensor moves the test modelling D by
    ``b · 100 / span`` (``ymax`` with ``scale = "max"``) over its scale ``s``, exactly (its
    model does not read D), and the tests that neither read nor model D not at all."""
    window = process(3 * DAY, 1)
    path = build(tmp_path, window, {"combined": True, "isolation": "tags", "scale": scale})
    uf = UnitFile.load(path)
    uf.set_learned(learn_thresholds(Unit.load(path), [window], far=0.05, spread=False))
    uf.save()
    unit = Unit.load(path)
    f = process(1500, 51)
    g = f.copy()
    g["D"] += 3.0
    before = unit.reset().evaluate(f).residuals
    after = unit.reset().evaluate(g).residuals
    cm, tests = unit.cmodel, list(unit.tests)
    dz = ((after - before) / cm.scale).iloc[800:]  # the low-pass has settled
    col = cm.tags.index("D")
    moved = dz["rD"].dropna()
    assert len(moved) > 300
    want = 3.0 * cm.xi[tests.index("rD"), col]
    # where the fine grid answered (a coarser level divides the residual by its scale)
    assert (np.abs(moved - want) < 0.01 * abs(want)).mean() > 0.3, moved.describe()
    for t in ("rA", "rC"):  # neither reads nor models D
        assert cm.xi[tests.index(t), col] == 0.0
        assert dz[t].abs().max() < 1e-9


# ---------------------------------------------------------------- the learning window
def test_each_run_of_a_window_waits_for_the_filter_to_settle():
    """Two runs of data with a gap longer than RUN_GAP: the first SETTLE_SAMPLES of each are
    left out (the filter starts from rest in each); a run of under 4 × that loses a quarter."""
    long = 5 * SETTLE_SAMPLES
    data = np.r_[np.zeros(7, bool), np.ones(long, bool), np.zeros(RUN_GAP + 5, bool),
                 np.ones(long, bool), np.zeros(RUN_GAP + 5, bool), np.ones(400, bool)]  # fmt: skip
    keep = settled(data)
    starts = [7, 7 + long + RUN_GAP + 5, 7 + 2 * (long + RUN_GAP + 5)]
    for a in starts[:2]:
        assert not keep[a : a + SETTLE_SAMPLES].any()
        assert keep[a + SETTLE_SAMPLES : a + long].all()
    assert not keep[starts[2] : starts[2] + 100].any() and keep[starts[2] + 100 :].all()
    # a gap no longer than RUN_GAP does not restart the filter
    data = np.r_[np.ones(long, bool), np.zeros(RUN_GAP, bool), np.ones(long, bool)]
    assert settled(data)[SETTLE_SAMPLES:].all()


def test_a_window_overlapping_the_training_range_is_cross_fitted(tmp_path):
    """Models trained on days 2–4: a window of days 1–4 overlaps their training data and is
    cross-fitted; a window of day 1 alone lies before it and uses the models' own residuals."""
    frame = process(4 * DAY, 3)
    path = build(tmp_path, frame.iloc[DAY:], {"combined": True})
    unit = Unit.load(path)
    got = learn_thresholds(unit, [frame], far=0.05)
    assert all(s.startswith("cross-fitted") for s in got.sources.values()), got.sources
    got = learn_thresholds(unit.reset(), [frame.iloc[:DAY]], far=0.05)
    assert all("trained outside the window" in s for s in got.sources.values()), got.sources


def test_a_window_where_the_plant_stood_still_is_refused_with_what_to_do(tmp_path):
    """Every tag held at one value (a plant at a standstill, or a frozen historian): each
    test's residual is a constant, its filtered residual too once the filter settles — no
    false-alarm rate can be read from it, and the message names the tests and what to do."""
    path = build(tmp_path, process(2 * DAY, 1), {"lowpass": 0.2})
    still = process(2000, 7)
    still.iloc[:] = still.iloc[[1000]].to_numpy()
    with pytest.raises(LearnError) as exc:
        learn_thresholds(Unit.load(path), [still], far=0.05)
    got = "\n".join(exc.value.problems)
    named = [t for t in TESTS if f"test {t}: its filtered residual is constant" in got]
    assert named and "learn over a window where its output varies" in got, got


def test_a_window_where_the_tests_are_never_known_together_gives_a_loadable_unit(learned, tmp_path):
    """Each row has one test unknown (a tag dropping out in turn): no covariance can be
    estimated, so the scaled residuals are taken as independent — identity, shrinkage 1 —
    and the unit file written from it loads."""
    T = len(TESTS)
    x = np.random.default_rng(5).standard_normal((2000, T))
    x[np.arange(2000), np.arange(2000) % T] = np.nan
    body = pd.DataFrame(x, columns=list(TESTS))
    spec = learn_combined(learned, body, np.repeat(np.arange(5), 400), None, {})
    assert np.array_equal(spec.cov, np.eye(T)) and spec.shrinkage == 1.0
    for f in learned.file.path.parent.glob("p*.toml"):
        shutil.copy(f, tmp_path / f.name)
    uf = UnitFile.load(tmp_path / "p.unit.toml")
    uf.set_combined(spec)
    uf.save()
    assert UnitFile.load(tmp_path / "p.unit.toml").combined.shrinkage == 1.0


def test_the_thresholds_written_are_the_ones_the_budget_calibrated(learned):
    """However small a test's residual (thresholds under 1 % of span), its limits are the
    calibrated ones (only a band of ±1e-4 % around 0 is enforced), in the file as learned."""
    got = learned.learned_result
    for t in TESTS:
        b = got.budgets[t]
        assert got.limits[t] == pytest.approx((b.low, b.high)), t  # none near 0 here
        spec = learned.file.test(t)
        assert (spec.low, spec.high) == pytest.approx(got.limits[t], rel=1e-3)
    assert min(got.limits[t][1] for t in TESTS) < 1.0  # a small threshold is kept small


def test_fuzzy_sets_without_residuals_are_crisp_at_the_thresholds():
    """No fault-free residual to measure the ramps by: zero-width ramps at the thresholds (the
    crisp evaluation), never ramps turned inside out."""
    assert fuzzy_sets(np.array([np.nan, np.nan]), -2.0, 3.0) == (-2.0, -2.0, 3.0, 3.0)
    n1, n0, p0, p1 = fuzzy_sets(np.random.default_rng(3).standard_normal(500), -2.0, 3.0)
    assert n1 < -2.0 < n0 <= 0.0 <= p0 < 3.0 < p1


def test_episodes_without_delays_count_every_run_above_the_level():
    """``episodes`` by default: no delay (one sample on, one sample back inside ends it)."""
    x = np.array([0.0, 1.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0])
    assert episodes(x, np.array([0.5, 2.0])).tolist() == [3, 0]
    assert episodes(x, np.array([0.5]), 1, 2).tolist() == [2]  # a 1-sample dip bridged
    assert episodes(np.ones(6), np.array([0.5])).tolist() == [1]  # one run, one episode


@pytest.mark.parametrize("missing", ["--from", "--to"])
def test_unit_learn_needs_both_ends_of_its_window(tmp_path, capsys, missing):
    from diag_plugin.cli import main

    args = {"--from": "2026-05-04T00:00:00Z", "--to": "2026-05-05T00:00:00Z"}
    args.pop(missing)
    cmd = ["--db", f"sqlite:///{tmp_path / 'h.db'}", "--rulebases", str(tmp_path)]
    cmd += ["unit", "learn", "p", *[x for kv in args.items() for x in kv]]
    with pytest.raises(SystemExit) as exc:
        main(cmd)
    assert exc.value.code == 2
    assert f"required: {missing}" in capsys.readouterr().err


@pytest.mark.parametrize("max_lag", [1, 2, 5, 60, 360])
def test_a_loops_response_times_reach_the_dead_time_horizon(max_lag):
    """0 and up to 12 response times spaced geometrically to the horizon, whatever it is —
    one sample included (a coarse grid, a loop answering within one period)."""
    lags = loop_lags(max_lag)
    assert lags[0] == 0 and lags[-1] == max_lag and len(lags) <= 13
    assert all(a < b for a, b in zip(lags, lags[1:], strict=False))
    assert loop_lags(0) == [0]


def test_set_points_that_are_not_a_list_of_tags_are_a_file_line_error(tmp_path):
    from diag_plugin.diagnose.unitfile import UnitError, new_unit_text

    path = tmp_path / "u.unit.toml"
    text = new_unit_text("u", {"r1": "m.toml"}) + '\n[build]\nperiod = "10s"\n'
    path.write_text(text + 'set_points = ["FLOW_TARGET"]\n')
    assert UnitFile.load(path).build["set_points"] == ["FLOW_TARGET"]
    path.write_text(text + 'set_points = "FLOW_TARGET"\n')
    with pytest.raises(UnitError) as exc:
        UnitFile.load(path)
    n = len(text.splitlines()) + 1
    assert f"u.unit.toml:{n}: set_points must be a list of tags" in "\n".join(exc.value.problems)
