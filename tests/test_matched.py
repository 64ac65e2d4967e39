"""Matched false-alarm scoring (diag_plugin.bench.matched): the yardstick of issue 34."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from diag_plugin.bench.matched import (
    FaultRun,
    Scored,
    calibrate,
    calibrate_leaving_out,
    curve,
    delayed_score,
    episode_count,
    episode_interval,
    method_score,
    rates,
    side_ratio,
    split_spread,
)
from diag_plugin.diagnose.symptoms import OnOffDelay


def _ar1(rng, n, phi=0.8):
    e = rng.standard_normal(n)
    x = np.empty(n)
    x[0] = e[0]
    for i in range(1, n):
        x[i] = phi * x[i - 1] + np.sqrt(1 - phi**2) * e[i]
    return x


@pytest.mark.parametrize(("on", "off"), [(1, 1), (3, 1), (1, 4), (3, 3), (5, 2)])
def test_delayed_score_is_the_delayed_alarm_at_every_limit(on, off):
    rng = np.random.default_rng(on * 10 + off)
    x = _ar1(rng, 600, 0.6)
    x[rng.random(600) < 0.05] = np.nan  # unknown samples: never over
    d = delayed_score(x, on, off)
    for lam in (-0.5, 0.0, 0.7, 1.3, 2.0):
        raw = np.where(np.isfinite(x), x > lam, False).astype(float)
        ref = OnOffDelay(on, off).transform(raw[:, None])[:, 0] > 0
        got = np.where(np.isfinite(d), d, -np.inf) > lam
        np.testing.assert_array_equal(got, ref)


def test_side_ratio_and_method_score():
    r = np.array([[2.0, -1.0], [-4.0, 0.5], [np.nan, np.nan]])
    s = side_ratio(r, low=np.array([-2.0, -0.5]), high=np.array([4.0, 1.0]))
    np.testing.assert_allclose(s[:2], [[0.5, 2.0], [2.0, 0.5]])
    assert np.isnan(s[2]).all()
    m = method_score(s, 1, 1)
    np.testing.assert_allclose(m[:2], [2.0, 2.0])
    assert np.isnan(m[2])


def test_episodes_counted_per_run_and_per_hour():
    a = np.array([0, 1, 1, 0, 1, 0, 0, 1], bool)
    assert episode_count(a) == 3
    assert episode_count(np.array([1, 1, 0], bool)) == 1
    # two runs of 3 min samples: an alarm at the end of one and the start of the next are two
    runs = [np.array([0.0, 0, 2]), np.array([2.0, 2, 0])]
    share, per_h = rates(runs, 1.0, 180.0)
    assert share == pytest.approx(3 / 6)
    assert per_h == pytest.approx(2 / (6 * 180 / 3600))
    # unknown samples are not in alarm and stay in the denominators
    share, _ = rates([np.array([np.nan, np.nan, 2.0, 0.0])], 1.0, 1.0)
    assert share == pytest.approx(0.25)


@pytest.mark.parametrize("target", [0.01, 0.05])
def test_calibrated_limit_holds_on_held_out_runs(target):
    rng = np.random.default_rng(1)
    cal = [_ar1(rng, 5000) for _ in range(4)]
    held = [_ar1(rng, 5000) for _ in range(4)]
    lim = calibrate(cal, target, 60.0, "sample")
    assert lim.share <= target and lim.supported
    share, _ = rates(held, lim.limit, 60.0)
    n_eff = 20000 * (1 - 0.8) / (1 + 0.8)  # AR(1) effective sample size
    assert abs(share - target) < 4 * np.sqrt(target * (1 - target) / n_eff)


def test_calibrated_episode_rate_holds_on_held_out_runs():
    rng = np.random.default_rng(2)
    period = 60.0
    cal = [_ar1(rng, 20000, 0.9) for _ in range(3)]
    held = [_ar1(rng, 20000, 0.9) for _ in range(3)]
    target = 1.0  # episodes per hour
    lim = calibrate(cal, target, period, "hour")
    assert lim.per_hour <= target
    _, ph = rates(held, lim.limit, period)
    hours = 60000 * period / 3600
    assert abs(ph - target) < 4 * np.sqrt(target / hours) + 0.15


def test_episode_interval_is_garwoods_and_covers():
    lo, hi = episode_interval(10, 2.0)
    # the tabulated exact 95 % interval of a Poisson count of 10: 4.795 to 18.39
    assert lo == pytest.approx(4.795 / 2, abs=1e-3) and hi == pytest.approx(18.39 / 2, abs=1e-2)
    assert episode_interval(0, 5.0)[0] == 0.0
    # it covers the true rate about 95 % of the time (counts from a known rate)
    rng = np.random.default_rng(11)
    k = rng.poisson(3.0 * 4.0, 2000)
    cover = np.mean([lo <= 3.0 <= hi for lo, hi in (episode_interval(int(x), 4.0) for x in k)])
    assert 0.93 <= cover <= 0.995
    with pytest.raises(ValueError):
        episode_interval(1, 0.0)


def test_split_spread_pairs_methods_and_centres_on_the_target():
    rng = np.random.default_rng(12)
    pieces = [_ar1(rng, 400, 0.7) for _ in range(24)]
    got = split_spread(
        {"a": pieces, "same": [p.copy() for p in pieces], "scaled": [3 * p + 1 for p in pieces]},
        8, 0.02, 60.0, draws=300, seed=4,
    )  # fmt: skip
    # the same split for every method: the same scores give the same rates, and so does any
    # increasing transform of them (a limit is a quantile)
    np.testing.assert_array_equal(got["a"], got["same"])
    np.testing.assert_allclose(got["a"], got["scaled"])
    # exchangeable pieces: the held-out share spreads about the target (a limit read off a
    # finite calibration set is a little optimistic, never far)
    assert 0.5 * 0.02 < np.median(got["a"]) < 1.5 * 0.02
    assert np.quantile(got["a"], 0.95) > np.quantile(got["a"], 0.05)
    # a method whose pieces differ (half of them noisier) spreads wider than one whose do not
    mixed = [p * (1.6 if i % 2 else 1.0) for i, p in enumerate(pieces)]
    wide = split_spread({"m": mixed}, 8, 0.02, 60.0, draws=300, seed=4)["m"]
    assert np.std(wide) > np.std(got["a"])
    with pytest.raises(ValueError):
        split_spread({"a": pieces, "b": pieces[:-1]}, 8, 0.02, 60.0)
    with pytest.raises(ValueError):
        split_spread({"a": pieces}, 24, 0.02, 60.0)


def test_thin_calibration_is_flagged():
    rng = np.random.default_rng(3)
    lim = calibrate([rng.standard_normal(500)], 0.001, 180.0)
    assert not lim.supported
    assert calibrate([rng.standard_normal(5000)], 0.01, 180.0).supported


def _plant(rng, n_runs=6, n=400, onset=200, gain=(1.0, 0.3)):
    """Fault runs where the fault raises method A's statistic by gain[0] and B's by gain[1]
    (noise the same): A is truly better."""
    runs, a, b = [], [], []
    for i in range(n_runs):
        step = np.r_[np.zeros(onset), np.ones(n - onset)]
        a.append(Scored(_ar1(rng, n, 0.5) + 2.0 * gain[0] * step))
        b.append(Scored(_ar1(rng, n, 0.5) + 2.0 * gain[1] * step))
        runs.append(FaultRun("f", f"r{i}", onset, ()))
    return runs, a, b


def test_alarming_more_does_not_win():
    """B is A on another scale: at a fixed limit of 1 it alarms far more, and
    detects more; at matched false alarms it is exactly A."""
    rng = np.random.default_rng(4)
    runs, a, _ = _plant(rng)
    cal = [_ar1(rng, 3000, 0.5) for _ in range(3)]
    free = [_ar1(rng, 3000, 0.5) for _ in range(2)]

    def inflate(x):
        return 0.5 * x + 0.8

    b = [Scored(inflate(s.score)) for s in a]
    naive_a = np.mean([(s.score[200:] > 1).mean() for s in a])
    naive_b = np.mean([(s.score[200:] > 1).mean() for s in b])
    assert naive_b > naive_a  # what an unmatched comparison would credit
    methods = {
        "A": {"calibration": cal, "free": free, "faults": a},
        "B": {"calibration": [inflate(c) for c in cal], "free": [inflate(f) for f in free],
              "faults": b},
    }  # fmt: skip
    out = curve(methods, [0.01, 0.05], 60.0, "sample", runs)
    for p in out["points"]:
        ma, mb = p["methods"]["A"], p["methods"]["B"]
        assert ma["mean_detection"] == pytest.approx(mb["mean_detection"])
        assert ma["free_share"] == pytest.approx(mb["free_share"])
        # the episodes behind the held-out rate, and an interval that holds it
        assert ma["free_episodes"] == mb["free_episodes"] > 0
        lo, hi = ma["free_per_hour_95"]
        assert lo < ma["free_per_hour"] < hi
        assert ma["free_per_hour"] == pytest.approx(ma["free_episodes"] / (6000 / 60))


def test_truly_better_method_ranks_first_and_names_its_tag():
    rng = np.random.default_rng(5)
    runs, a, b = _plant(rng, gain=(1.0, 0.4))
    tags = ["X", "Y", "Z"]
    idx = pd.RangeIndex(400)
    runs = [FaultRun("f", r.run, r.onset, ("Y",)) for r in runs]
    for s in a:  # A's contributions point at Y, B's at X
        s.contributions = pd.DataFrame(
            rng.random((400, 3)) + np.array([0.0, 1.0, 0.0]), index=idx, columns=tags
        )
    for s in b:
        s.contributions = pd.DataFrame(
            rng.random((400, 3)) + np.array([1.0, 0.0, 0.0]), index=idx, columns=tags
        )
    cal = [_ar1(rng, 3000, 0.5) for _ in range(3)]
    methods = {
        "A": {"calibration": cal, "free": [], "faults": a},
        "B": {"calibration": cal, "free": [], "faults": b},
    }
    out = curve(methods, [0.005, 0.02, 0.05], 60.0, "sample", runs)
    for p in out["points"]:
        ma, mb = p["methods"]["A"], p["methods"]["B"]
        assert ma["mean_detection"] > mb["mean_detection"] + 0.1
        assert ma["in_top"] == ma["named_runs"] == 6
        assert mb["faults"]["f"]["per_run"][0]["top"][0] == "X"


def test_infinite_statistic_is_over_every_limit_and_unknown_never():
    s = method_score(np.array([[np.inf, np.nan], [np.nan, np.nan], [0.5, 0.2]]), 1, 1)
    assert s[0] == np.inf and np.isnan(s[1])
    share, per_h = rates([s], 10.0, 3600.0)
    assert share == pytest.approx(1 / 3) and per_h == pytest.approx(1 / 3)
    lim = calibrate([np.r_[s, np.zeros(97)]], 0.02, 60.0)
    assert lim.share <= 0.02 and lim.limit < np.inf


@pytest.mark.slow
def test_a_built_units_score_at_one_is_its_own_alarm(tmp_path):
    """The unit's score (tests over their thresholds, combined T² over its limit, each after
    the unit's delays, its oscillation hold's, then the maximum) is over 1 exactly where the
    unit itself alarms, on a run it never saw, with a fault and without."""
    from diag_plugin.bench.publicbench import unit_score
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.simulate import coupled
    from diag_plugin.status import NE107
    from diag_plugin.unitbuild.build import build_unit

    train, _ = coupled.simulate(4.0, n_tags=10, seed=1, structure_seed=0)
    res = build_unit("u", train, folder=tmp_path, period="3min", far=0.05)
    unit = Unit.load(res.path, tmp_path)
    run, _ = coupled.simulate(2.0, n_tags=10, seed=9, structure_seed=0)
    faulty = run.copy()
    tag = res.tests[0].tag
    faulty.iloc[len(run) // 2 :, faulty.columns.get_loc(tag)] += 3 * run[tag].std()
    on, off = int(unit.ev["on_delay"]), int(unit.ev["off_delay"])
    seen = 0
    for frame in (run, faulty):
        s, contrib = unit_score(unit, frame, on, off)
        d = unit.reset().evaluate(frame)
        st = d.status.to_numpy()
        native = (st != NE107.NORMAL) & (st != NE107.CHECK_FUNCTION)
        mine = np.where(np.isnan(s), -np.inf, s) > 1.0
        np.testing.assert_array_equal(mine, native)
        seen += int(native.sum())
        assert list(contrib.columns) == unit.cmodel.tags
    assert seen > 0  # the fault raised alarms: the comparison compared something


def test_a_run_is_scored_at_a_limit_its_own_tail_did_not_set():
    """SKAB's tuning runs calibrate too: a fault's alarm held into the run's normal samples
    after it is the calibration's largest score, so at a low target the common limit sits on
    that tail and the fault under it is never seen; left out, the run meets the limit the other
    runs set (the scoring runs' situation), and SKAB's metrics take one limit per run."""
    from diag_plugin.bench.publicbench import skab_metrics

    rng = np.random.default_rng(7)
    runs = {f"free{k}": rng.standard_normal(1000) for k in range(3)}
    fault = np.r_[rng.standard_normal(300), np.full(200, 40.0), np.full(40, 50.0)]
    labels = np.r_[np.zeros(300), np.ones(200), np.zeros(40)]
    runs["tuning"] = fault[labels == 0]  # its normal samples, the held tail among them
    common = calibrate(list(runs.values()), 0.005, 1.0).limit
    assert common >= 40.0  # the tail sets it: the fault is under it
    alone = calibrate_leaving_out(runs, ["tuning", "free0"], 0.005, 1.0)
    assert (
        alone["tuning"].limit == calibrate([runs[f"free{k}"] for k in range(3)], 0.005, 1.0).limit
    )
    assert alone["tuning"].limit < 5.0
    assert alone["free0"].limit >= 40.0  # the tail stays for every other run
    sk_common = skab_metrics([Scored(fault)], [labels], common)
    sk_alone = skab_metrics([Scored(fault)], [labels], [alone["tuning"].limit])
    assert sk_common["MAR"] == 1.0 and sk_alone["MAR"] == 0.0
    other = np.r_[np.zeros(50), np.full(50, 3.0)]
    lab2 = np.r_[np.zeros(50), np.ones(50)]
    both = skab_metrics(
        [Scored(fault), Scored(other)], [labels, lab2], [alone["tuning"].limit, 4.0]
    )
    assert both["MAR"] == pytest.approx(50 / 250)  # each run at its own limit: the 3s under 4


def test_a_labelled_run_calibrates_with_its_samples_before_the_anomaly_only():
    """A labelled run's fault-free operation is what precedes its anomaly: the label-0 samples
    after it are the recovery, where a method that saw the fault still holds its alarm (the
    off-delay's plateau at the fault's level). Counted as fault-free they set a low target's
    limit on the largest fault seen to its end (SKAB until 2026-12-02: every method's limit
    at 0.001–0.02); taken before the onset, the limit is the fault-free scores' and the fault
    under the old limit is seen."""
    from diag_plugin.bench.publicbench import before_onset

    rng = np.random.default_rng(5)
    free = [rng.random(1000) for _ in range(3)]  # fault-free runs: scores under 1
    x = np.r_[rng.random(300), np.full(200, 40.0), np.full(170, 40.0)]  # the held plateau
    labels = np.r_[np.zeros(300), np.ones(200), np.zeros(170)]
    pre = before_onset(x, labels)
    assert len(pre) == 300 and np.array_equal(pre, x[:300])
    old = calibrate([*free, x[labels == 0]], 0.01, 1.0).limit
    new = calibrate([*free, pre], 0.01, 1.0).limit
    assert old >= 40.0 and new < 1.0  # the plateau no longer sets the limit
    other = np.r_[rng.random(100), np.full(100, 20.0)]  # another run's smaller fault
    assert np.mean(other[100:] > old) == 0.0 and np.mean(other[100:] > new) == 1.0
    # a run with no anomaly is all fault-free; a list of labels works as an array does
    assert np.array_equal(before_onset(x[:50], np.zeros(50)), x[:50])
    assert len(before_onset(x, list(labels))) == 300
    # the mask the tuning scripts calibrate with: the same prefix, or every label 0
    from diag_plugin.bench.publicbench import fault_free_mask

    assert np.array_equal(x[fault_free_mask(labels)], pre)
    assert np.array_equal(fault_free_mask(labels, recovery=True), labels == 0)


def test_tail_levels_count_a_held_plateau_as_one_value_and_one_episode():
    """A fault's alarm held by the off-delay over a run's normal samples after it is one value
    of the score for all of them: the calibration's largest 2 % are then a handful of such
    plateaus (SKAB's tuning runs: two values), and a limit matched there can only be one of
    them. ``tail_levels`` says which values, how many samples and episodes each holds, and in
    which runs; ties at the cut-off are all in."""
    from diag_plugin.bench.matched import tail_levels

    rng = np.random.default_rng(11)
    on, off = 3, 240
    free = [0.5 * rng.random(1000) for _ in range(3)]  # the fault-free runs: under 0.5
    x = np.r_[0.5 * rng.random(300), np.linspace(5.0, 40.0, 200), 0.5 * rng.random(170)]
    held = delayed_score(x, on, off)[500:]  # the normal samples after the fault
    assert np.all(held == held[0]) and held[0] > 30.0  # one plateau: 170 samples, one value
    runs = [*free, held]
    levels = tail_levels(runs, 0.02)  # 64 of 3,170 samples: all inside the plateau
    assert len(levels) == 1
    (top,) = levels
    assert (top.value, top.samples, top.episodes, top.runs) == (held[0], 170, 1, (3,))
    # a target under the plateau's share can only be matched at it (or above everything)
    assert calibrate(runs, 0.01, 1.0).limit == held[0]
    # a wider share reaches the fault-free runs' own values: each a level of its own
    wide = tail_levels(runs, 0.1)
    assert wide[0] == top and len(wide) > 100
    assert {r for lv in wide[1:] for r in lv.runs} <= {0, 1, 2}
    # ties at the cut-off: every sample at that value is in, counted once per run
    tied = tail_levels([np.r_[np.full(4, 2.0), np.zeros(96)], np.r_[2.0, 0.0, 2.0]], 0.01)
    assert [(lv.value, lv.samples, lv.episodes, lv.runs) for lv in tied] == [(2.0, 6, 3, (0, 1))]
    with pytest.raises(ValueError):
        tail_levels(runs, 0.0)


def test_the_oscillation_score_is_the_hold_s_own_rule_at_every_level():
    """``oscillation_score`` over ``λ`` (or either side over it) exactly where the unit's
    :class:`OscillationHold` of the alarms at ``λ`` is on, for every ``λ``: random swings,
    windows and side changes asked (the hold arms on ``K`` changes within ``K`` windows and
    is kept while on or both sides are within one). A single + then − (a twin stopping and
    restarting) is held at no positive level; + − + is, until a side is quiet a window."""
    from diag_plugin.bench.matched import oscillation_score
    from diag_plugin.diagnose.unitloops import OscillationHold

    rng = np.random.default_rng(5)
    checked = held = 0
    for _ in range(120):
        n, w, k = int(rng.integers(5, 90)), int(rng.integers(1, 12)), int(rng.integers(1, 4))
        up = rng.normal(0.4, 1.0, (n, 2))
        down = -up * rng.uniform(0.5, 2.0, (n, 2))  # one side or the other: r/high, r/low
        score = np.where(np.isnan(o := oscillation_score(up, down, 1, 1, w, k)), -np.inf, o)
        for c in range(2):
            for lam in np.quantile(np.r_[up[:, c], down[:, c]], [0.5, 0.7, 0.85]):
                lam = max(lam, 0.0)
                s = np.where(up[:, c] > lam, 1.0, np.where(down[:, c] > lam, -1.0, 0.0))
                unit = OscillationHold(np.array([w]), k).transform(s[:, None].copy())[:, 0]
                mine = (score[:, c] > lam) | (s != 0)
                np.testing.assert_array_equal(unit != 0, mine)
                checked += 1
                held += int(((unit != 0) & (s == 0)).sum())
    assert checked == 720 and held > 100  # the hold held: the comparison compared something
    r = np.r_[np.zeros(5), np.full(20, 3.0), np.full(20, -3.0), np.zeros(200)]  # + then −
    assert np.nanmax(oscillation_score(r, -r, 3, 3, 100)) <= 0.0  # over no positive level
    r2 = np.r_[r[:45], np.full(20, 3.0), np.zeros(180)]  # + − +: a swing there and back
    o = oscillation_score(r2, -r2, 3, 3, 100)
    assert np.all(o[70:140] == 3.0) and np.nanmax(o[170:]) <= 0.0  # held, then off


def test_the_oscillation_score_applies_the_hold_s_settle_rule_at_every_level():
    """Issue 34 H2 (a): where settles open (an operator's step, a hand valve's move, a
    piece's start), ``oscillation_score`` with the openings and the quiet time is over ``λ``
    exactly where the unit's :class:`OscillationHold` of the alarms at ``λ``, given the same
    openings, is on, for every ``λ``: a settle opening on a test off for the quiet time at
    ``λ`` disarms the hold and its swings pass unseen until the bound; one opening on a test
    on (a fault in progress) at ``λ`` is not seen at that level. Without the openings the
    score (main's) holds swings the unit does not."""
    from diag_plugin.bench.matched import oscillation_score
    from diag_plugin.diagnose.unitloops import OscillationHold

    rng = np.random.default_rng(7)
    checked = held = differs = 0
    for _ in range(150):
        n, w, k = int(rng.integers(5, 120)), int(rng.integers(1, 12)), int(rng.integers(1, 4))
        up = rng.normal(0.4, 1.0, (n, 2))
        down = -up * rng.uniform(0.5, 2.0, (n, 2))
        opens = np.where(rng.random((n, 2)) < 0.05, rng.integers(1, 30, (n, 2)), 0)
        quiet = int(rng.integers(1, 10))
        o = oscillation_score(up, down, 1, 1, w, k, opens=opens, quiet=quiet)
        score = np.where(np.isnan(o), -np.inf, o)
        plain = np.where(np.isnan(p := oscillation_score(up, down, 1, 1, w, k)), -np.inf, p)
        for c in range(2):
            for lam in np.quantile(np.r_[up[:, c], down[:, c]], [0.3, 0.5, 0.7, 0.85]):
                lam = max(lam, 0.0)
                s = np.where(up[:, c] > lam, 1.0, np.where(down[:, c] > lam, -1.0, 0.0))
                hold = OscillationHold(np.array([w]), k, quiet=quiet)
                unit = hold.transform(s[:, None].copy(), opens[:, c : c + 1])[:, 0]
                np.testing.assert_array_equal(unit != 0, (score[:, c] > lam) | (s != 0))
                differs += int(((plain[:, c] > lam) != (score[:, c] > lam)).sum())
                checked += 1
                held += int(((unit != 0) & (s == 0)).sum())
    assert checked == 1200 and held > 1000 and differs > 500  # the settles changed the hold


# ---------------------------------------------------------------- the tag named first, per episode


def _named_runs():
    """Two runs of 40 samples, fault from sample 10, tags W, X, Y, Z, Y at fault; scores 1 in
    alarm and 0 elsewhere, so any limit matched on all-zero calibration runs is 0. Run 1:
    an alarm before the onset (not counted) and three episodes after it, Y largest over the
    first (4 samples), X over the other two (2 + 8 samples): over the run X is named first,
    Y second; per episode Y, X, X. Run 2: one episode, Y largest throughout."""
    tags = ["W", "X", "Y", "Z"]
    s1 = np.zeros(40)
    s1[[3, 4, *range(12, 16), 20, 21, *range(30, 38)]] = 1.0
    c1 = np.tile([0.0, 2.0, 1.0, 0.5], (40, 1))  # X, Y, Z: X first
    c1[12:16] = [0.0, 1.0, 3.0, 0.5]  # Y, X, Z
    c1[3:5] = [9.0, 0.0, 0.0, 0.0]  # W, before the onset: never named
    s2 = np.zeros(40)
    s2[25:33] = 1.0
    c2 = np.tile([0.1, 1.0, 5.0, 0.5], (40, 1))  # Y, X, Z
    idx = pd.RangeIndex(40)
    scored = [Scored(s, pd.DataFrame(c, index=idx, columns=tags)) for s, c in ((s1, c1), (s2, c2))]
    runs = [FaultRun("f", "r1", 10, ("Y",)), FaultRun("f", "r2", 10, ("Y",))]
    return runs, scored


def test_the_tag_named_first_and_each_episode_s_name_are_counted_per_run_fault_and_method():
    runs, scored = _named_runs()
    # a third run without a faulted tag: scored, never counted in the naming
    runs.append(FaultRun("g", "r3", 10, ()))
    scored.append(Scored(scored[0].score.copy(), scored[0].contributions))
    zero = [np.zeros(200)]
    methods = {"M": {"calibration": zero, "free": [], "faults": scored}}
    for per, target in (("sample", 0.01), ("hour", 0.5)):
        out = curve(methods, [target], 60.0, per, runs)
        m = out["points"][0]["methods"]["M"]
        assert m["limit"]["limit"] == 0.0
        f = m["faults"]["f"]
        r1, r2 = f["per_run"]
        assert r1["top"] == ["X", "Y", "Z"] and r1["in_top"]  # Y in the top 3, not first
        assert not r1["first_right"]
        assert r1["episodes"] == 3 and r1["episode_tags"] == ["Y", "X", "X"]
        assert r1["episodes_right"] == 1 and r1["episode_share"] == pytest.approx(1 / 3)
        assert r1["name_changed"]
        assert r2["top"][0] == "Y" and r2["first_right"]
        assert r2["episode_tags"] == ["Y"] and r2["episode_share"] == 1.0
        assert not r2["name_changed"]
        # the keys the lead's scripts read stay, the new counts beside them
        assert (f["in_top"], f["named_runs"], f["named_first"]) == (2, 2, 1)
        assert (f["episodes_right"], f["episodes_named"], f["name_changed_runs"]) == (2, 4, 1)
        g = m["faults"]["g"]
        assert g["named_runs"] == 0 and g["named_first"] == 0 and g["episodes_named"] == 0
        assert not g["per_run"][0]["first_right"] and g["per_run"][0]["episode_tags"]
        assert (m["in_top"], m["named_runs"], m["named_first"]) == (2, 2, 1)
        assert (m["episodes_right"], m["episodes_named"], m["name_changed_runs"]) == (2, 4, 1)


def test_a_run_without_alarms_or_contributions_names_nothing():
    runs, scored = _named_runs()
    quiet = Scored(np.zeros(40), scored[0].contributions)
    blind = Scored(scored[0].score, None)
    methods = {"M": {"calibration": [np.zeros(200)], "free": [], "faults": [quiet, blind]}}
    out = curve(methods, [0.01], 60.0, "sample", runs)
    f = out["points"][0]["methods"]["M"]["faults"]["f"]
    for r in f["per_run"]:
        assert r["top"] == [] and not r["first_right"] and r["episode_tags"] == []
        assert r["episode_share"] is None and not r["name_changed"]
    assert f["per_run"][1]["episodes"] == 3  # alarms, but nothing to name them with
    assert (f["named_first"], f["episodes_named"]) == (0, 0)


def test_episode_names_are_ranked_tags_of_each_episode_s_rows_ties_included():
    """Each episode's name is :func:`ranked_tags`' first tag over that episode's rows alone,
    ties of count and mean rank broken as it breaks them (small integer contributions with
    NaN make many)."""
    from diag_plugin.bench.matched import episode_ids, episode_names, ranked_tags

    rng = np.random.default_rng(3)
    episodes = ties = 0
    for trial in range(400):
        n, m = int(rng.integers(5, 60)), int(rng.integers(2, 9))
        c = rng.integers(0, 4, (n, m)).astype(float)
        c[c == 0] = np.nan if trial % 2 else 0.0
        frame = pd.DataFrame(c, columns=[f"T{i}" for i in rng.permutation(m)])
        rows = np.flatnonzero(rng.random(n) < 0.6)
        ep = episode_ids(rows)
        assert (ep[-1] + 1 if rows.size else 0) == episode_count(np.isin(np.arange(n), rows))
        got = episode_names(frame, rows, 3)
        want = [ranked_tags(frame, rows[ep == e], 3) for e in range(ep[-1] + 1 if rows.size else 0)]
        assert got == [w[0] if w else "" for w in want]
        episodes += len(got)
        ties += sum(len(w) > 1 and len(rows[ep == e]) == 2 for e, w in enumerate(want))
    assert episodes > 3000 and ties > 300


def test_the_page_shows_first_and_episodes_right_beside_top_3():
    from diag_plugin.bench.publicbench import render_page

    runs, scored = _named_runs()
    res = curve({"unit": {"calibration": [np.zeros(200)], "free": [], "faults": scored}},
                [0.01], 60.0, "sample", runs)  # fmt: skip
    out = {"title": "t", "per": "sample", "period_s": 60.0, "delays": [1, 1], "pca_share": 0.9,
           "source": "s", "split": [], "methods": ["unit"], "fault_tags": {"f": ["Y"]},
           "unit": {"rows": 1, "tests": 1, "seconds": 1.0, "commands": []},
           "curve": res, "curve_hour": None, "fault_info": {}, "seconds": {}}  # fmt: skip
    text = render_page(out, "diag benchmark")
    assert "| unit detection | unit top 3 | unit first | unit episodes right |" in text
    assert "| 2/2 | 1/2 | 2/4; 1 changed |" in text  # the curve's row
    assert "| top 3 | first | episodes right | named |" in text
    assert "| 2/2 | 1/2 | 2/4; 1 changed | X, Y, Z |" in text  # the fault's row


def test_a_sample_with_no_known_contribution_names_no_tag():
    """Where a method's contributions are unknown (a unit whose ``T²`` is unknown: most of
    its tests outside what it learned) the bench names no tag there, neither over the run
    nor over an episode: ranked as −inf, such samples named the first columns (tep-studio
    IDV13, seed 301: XMEAS11, XMEAS13, XMEAS10 over the 349 samples naming XMV6). Over a
    run the ranking is that of the samples with contributions; an episode with none names
    ``""`` and counts as an episode not named right."""
    from diag_plugin.bench.matched import episode_names, ranked_tags
    from diag_plugin.bench.plant import top_from_contributions

    tags = ["W", "X", "Y", "Z"]
    c = np.tile([0.1, 0.5, 2.0, np.nan], (40, 1))  # Y, X, W named; Z unknown
    c[10:25] = np.nan  # the alarm's first 15 samples: nothing known
    c[30:34] = np.nan  # the second episode: nothing known
    frame = pd.DataFrame(c, columns=tags)
    top = top_from_contributions(frame.iloc[[0, 12]], 3)
    assert top.iloc[0].tolist() == ["Y", "X", "W"] and top.iloc[1].tolist() == ["", "", ""]
    one = pd.DataFrame([[np.nan, np.nan, 1.0, np.nan]], columns=tags)
    assert top_from_contributions(one, 3).iloc[0].tolist() == ["Y", "", ""]
    rows = np.r_[10:28, 30:34]
    assert ranked_tags(frame, rows) == ["Y", "X", "W"]
    assert episode_names(frame, rows, 3) == ["Y", ""]
    score = np.zeros(40)
    score[rows] = 1.0
    run = FaultRun("f", "r1", 10, ("Y",))
    m = {"M": {"calibration": [np.zeros(200)], "free": [],
               "faults": [Scored(score, frame)]}}  # fmt: skip
    f = curve(m, [0.01], 60.0, "sample", [run])["points"][0]["methods"]["M"]["faults"]["f"]
    r = f["per_run"][0]
    assert r["top"] == ["Y", "X", "W"] and r["first_right"]
    assert r["episode_tags"] == ["Y", ""] and r["episodes_right"] == 1
    assert (f["episodes_right"], f["episodes_named"]) == (1, 2)
