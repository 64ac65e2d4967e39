"""Residual post-processing and symptom evaluation (issue 9; seeds 000 and 001)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from diag_plugin.diagnose.residuals import Latch, LowPass, MaxScaler, residual_pct
from diag_plugin.diagnose.symptoms import (
    FixedThresholds,
    FuzzyThreeValued,
    LearnedThresholds,
    OnOffDelay,
    is_unknown,
)
from diag_plugin.models.series import effective_samples


def _chunks(n: int, k: int, rng: np.random.Generator) -> list[slice]:
    cuts = np.sort(rng.choice(np.arange(1, n), size=k - 1, replace=False))
    b = np.r_[0, cuts, n]
    return [slice(b[i], b[i + 1]) for i in range(k)]


def test_residual_pct_reused_from_metrics():
    from diag_plugin import metrics

    assert residual_pct is metrics.residual_pct
    np.testing.assert_allclose(residual_pct([55.0], [50.0], 200.0), [2.5])


def test_lowpass_chunked_equals_one_pass():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(2000, 3)) + np.linspace(0, 5, 2000)[:, None]
    one = LowPass().transform(x)
    f = LowPass()
    chunked = np.vstack([f.transform(x[s]) for s in _chunks(len(x), 37, rng)])
    np.testing.assert_allclose(chunked, one, rtol=1e-12)
    g = LowPass()
    single = np.vstack([g.transform(x[i : i + 1]) for i in range(len(x))])
    np.testing.assert_allclose(single, one, rtol=1e-12)
    # A state round trip through JSON mid-stream changes nothing either.
    h = LowPass()
    first = h.transform(x[:700])
    h2 = LowPass.from_state(json.loads(json.dumps(h.to_state())))
    np.testing.assert_allclose(np.vstack([first, h2.transform(x[700:])]), one, rtol=1e-12)
    # Not trivially equal to the input: the filter does smooth.
    assert np.std(np.diff(one[:, 0])) < 0.1 * np.std(np.diff(x[:, 0]))


def test_lowpass_dataframe_roundtrip():
    idx = pd.date_range("2026-01-01", periods=50, freq="s")
    df = pd.DataFrame({"r1": np.ones(50), "r2": np.zeros(50)}, index=idx)
    out = LowPass().transform(df)
    assert isinstance(out, pd.DataFrame)
    assert list(out.columns) == ["r1", "r2"] and out.index.equals(idx)


def _gain(w: float) -> float:
    n = 40000
    t = np.arange(n)
    x = np.sin(np.pi * w * t)  # w in scipy units: π·w rad/sample
    y = LowPass().transform(x)  # default cut-off: π/100 rad/sample
    tail = slice(n // 2, n)
    return float(np.sqrt(np.mean(y[tail] ** 2) / np.mean(x[tail] ** 2)))


def test_lowpass_minus_3db_at_cutoff():
    g_cut = _gain(0.01)  # π/100 rad/sample
    g_stop = _gain(0.1)
    assert 20 * np.log10(g_cut) == pytest.approx(-3.01, abs=0.2)
    # 4th order: −80 dB per decade.
    assert 20 * np.log10(g_stop) < -70
    assert _gain(0.001) == pytest.approx(1.0, abs=0.01)


def test_lowpass_nan_holds_state_and_restarts_after_long_gap():
    rng = np.random.default_rng(2)
    x = rng.normal(size=600) + 3.0
    xn = x.copy()
    xn[200:205] = np.nan
    f = LowPass(max_gap=10)
    y = f.transform(xn)
    assert np.isnan(y[200:205]).all()
    assert np.isfinite(y[:200]).all() and np.isfinite(y[205:]).all()
    # Short gap: state held, i.e. equal to filtering the series with the NaNs cut out.
    ref = LowPass().transform(np.r_[x[:200], x[205:]])
    np.testing.assert_allclose(np.r_[y[:200], y[205:]], ref, rtol=1e-12)
    # Chunked with the gap crossing a chunk boundary gives the same.
    g = LowPass(max_gap=10)
    yc = np.r_[g.transform(xn[:202]), g.transform(xn[202:])]
    np.testing.assert_allclose(yc, y, rtol=1e-12, equal_nan=True)
    # Long gap (> max_gap, split over chunks): restart from rest as on a fresh filter.
    xl = x.copy()
    xl[300:320] = np.nan
    h = LowPass(max_gap=10)
    yl = np.r_[h.transform(xl[:310]), h.transform(xl[310:])]
    np.testing.assert_allclose(yl[320:], LowPass().transform(x[320:]), rtol=1e-12)


def test_max_scaler_and_latch():
    y_ref = pd.DataFrame({"a": [1.0, -4.0, 2.0], "b": [10.0, np.nan, 5.0]})
    sc = MaxScaler().fit(y_ref)
    np.testing.assert_allclose(sc.max_, [4.0, 10.0])
    r = pd.DataFrame({"a": [2.0], "b": [-1.0]})
    np.testing.assert_allclose(sc.transform(r).to_numpy(), [[0.5, -0.1]])
    with pytest.raises(ValueError):
        MaxScaler().fit(np.zeros((3, 1)))

    lt = Latch({"a": 0.3, "b": 0.1})
    r = pd.DataFrame({"a": [0.1, np.nan, -0.4, 0.0, np.nan], "b": [0.0, np.nan, 0.05, 0, 0]})
    out = lt.transform(r)
    np.testing.assert_array_equal(out["a"].to_numpy(), [0, np.nan, 1, 1, 1])
    np.testing.assert_array_equal(out["b"].to_numpy(), [0, np.nan, 0, 0, 0])
    # Carried across calls until reset.
    assert lt.transform(pd.DataFrame({"a": [0.0], "b": [0.0]}))["a"].iloc[0] == 1.0
    lt2 = Latch.from_state(json.loads(json.dumps(lt.to_state())), {"a": 0.3, "b": 0.1})
    assert lt2.transform(pd.DataFrame({"a": [0.0], "b": [0.0]}))["a"].iloc[0] == 1.0
    lt.reset()
    assert lt.transform(pd.DataFrame({"a": [0.0], "b": [0.0]}))["a"].iloc[0] == 0.0


def test_fixed_thresholds_signed_unsigned_and_asymmetric():
    r = np.array([[-2.0, 0.5], [0.0, np.nan], [2.0, -0.5], [1.0, 3.0]])
    s = FixedThresholds(high=1.0).transform(r)
    np.testing.assert_array_equal(s, [[-1, 0], [0, np.nan], [1, 0], [0, 1]])
    u = FixedThresholds(high=1.0, signed=False).transform(r)
    np.testing.assert_array_equal(u, [[1, 0], [0, np.nan], [1, 0], [0, 1]])
    a = FixedThresholds(high=[1.0, 0.4], low=[-3.0, -0.4]).transform(r)
    np.testing.assert_array_equal(a, [[0, 1], [0, np.nan], [1, -1], [0, 1]])


@pytest.mark.parametrize("phi", [0.0, 0.5, 0.9, 0.98])
def test_effective_samples_of_an_ar1_series(phi):
    """AR(1) x_k = φ x_{k-1} + e_k has integrated autocorrelation time (1 + φ) / (1 − φ)."""
    from scipy import signal

    n = 400_000
    e = np.random.default_rng(int(phi * 100) + 3).normal(size=n)
    x = signal.lfilter([1.0], [1.0, -phi], e)
    want = n * (1 - phi) / (1 + phi)
    assert effective_samples(x) == pytest.approx(want, rel=0.1)


def test_effective_samples_of_a_filtered_residual_and_edge_cases():
    # the unit's residual filter (4th-order Butterworth at 0.01 of Nyquist) leaves about one
    # independent value per 110 samples of white noise (τ measured on three seeds: 110–113)
    n = 200_000
    white = np.random.default_rng(4).normal(size=n)
    filtered = LowPass(0.01, 4).transform(white)
    got = effective_samples(filtered)
    assert n / 150 < got < n / 80
    # NaNs are left out; constant or tiny series give their count; thresholds report it
    with_nan = white.copy()
    with_nan[::7] = np.nan
    assert effective_samples(with_nan) == pytest.approx(np.isfinite(with_nan).sum(), rel=0.05)
    assert effective_samples(np.ones(50)) == 50.0
    assert effective_samples([1.0, np.nan]) == 1.0
    frame = pd.DataFrame({"white": white, "filtered": filtered})
    lt = LearnedThresholds().fit(frame)
    assert lt.n_independent_["white"] > 20 * lt.n_independent_["filtered"]


def test_learned_thresholds_false_rate_and_detection():
    n = 200_000
    idx = pd.date_range("2026-01-01", periods=n, freq="s")
    train = pd.DataFrame(
        np.random.default_rng(10).normal(scale=[1.0, 2.0], size=(n, 2)),
        index=idx,
        columns=["r1", "r2"],
    )
    lt = LearnedThresholds().fit(train)
    assert lt.window_ == (idx[0], idx[-1])
    np.testing.assert_allclose(lt.thresholds_.to_numpy(), 1.2 * 3.29 * np.array([1, 2]), rtol=0.05)
    state = json.loads(json.dumps(lt.to_state()))
    assert state["window"][0].startswith("2026-01-01T00:00:00")
    lt2 = LearnedThresholds.from_state(state)

    fresh = pd.DataFrame(
        np.random.default_rng(11).normal(scale=[1.0, 2.0], size=(n, 2)), columns=["r1", "r2"]
    )
    on_delay = 3
    delay = OnOffDelay(on_delay=on_delay, off_delay=3)
    s = delay.transform(lt2.transform(fresh))
    false_rate = (s.to_numpy() != 0).mean(axis=0)
    assert np.all(false_rate <= 0.001), false_rate
    raw_rate = (lt.transform(fresh).to_numpy() != 0).mean(axis=0)
    assert np.all(raw_rate <= 0.001), raw_rate

    # A step of 3× the threshold is detected within on_delay samples.
    k0 = 1000
    step = fresh.iloc[: 2 * k0].copy()
    step.iloc[k0:] += 3 * lt.thresholds_.to_numpy()
    d = OnOffDelay(on_delay=on_delay, off_delay=3).transform(lt.transform(step)).to_numpy()
    for j in range(2):
        first = k0 + int(np.argmax(d[k0:, j] != 0))
        assert d[first, j] == 1.0
        assert first - k0 <= on_delay - 1
        assert (d[first:, j] == 1).all()


def test_fuzzy_memberships_sum_to_one_and_monotone():
    fz = FuzzyThreeValued(threshold=2.0, width=1.0)
    r = np.linspace(-5, 5, 2001)
    mn, mz, mp = fz.transform(r)
    np.testing.assert_allclose(mn + mz + mp, 1.0, atol=1e-12)
    assert np.all(np.diff(mp) >= 0) and np.all(np.diff(mn) <= 0)
    assert np.all((mn >= 0) & (mz >= 0) & (mp >= 0))
    # Zero is trapezoidal: increasing then flat then decreasing.
    assert mz[np.abs(r) <= 1.5].min() == 1.0
    assert mp[r >= 2.5].min() == 1.0 and mp[r <= 1.5].max() == 0.0
    assert mp[np.argmin(np.abs(r - 2.0))] == pytest.approx(0.5)
    # Width 0 is the crisp threshold.
    _, _, mp0 = FuzzyThreeValued(2.0, 0.0).transform(r)
    np.testing.assert_array_equal(mp0, FixedThresholds(2.0, signed=False).transform(r) * (r > 0))
    # Unknown stays unknown.
    mn, mz, mp = fz.transform(np.array([np.nan, 0.0]))
    assert np.isnan([mn[0], mz[0], mp[0]]).all() and mz[1] == 1.0
    with pytest.raises(ValueError):
        FuzzyThreeValued(1.0, 3.0).transform(r)


def test_on_off_delay_basic_and_unknown():
    d = OnOffDelay(on_delay=3, off_delay=2)
    nan = np.nan
    raw = np.array([0, 1, 1, 0, 1, 1, nan, 1, 1, 0, nan, 0, 0, -1, -1, -1, 1], float)
    out = d.transform(raw)
    exp = np.array([0, 0, 0, 0, 0, 0, nan, 1, 1, 1, nan, 0, 0, 0, 0, -1, -1], float)
    np.testing.assert_array_equal(out, exp)
    assert is_unknown(out).sum() == 2
    # All unknown: never a symptom.
    np.testing.assert_array_equal(is_unknown(OnOffDelay(1, 1).transform(np.full(5, nan))), True)


def test_on_off_delay_chunked_equals_one_pass():
    rng = np.random.default_rng(5)
    raw = rng.choice([-1.0, 0.0, 0.0, 1.0, np.nan], p=[0.2, 0.3, 0.2, 0.2, 0.1], size=(3000, 4))
    one = OnOffDelay(3, 4).transform(raw)
    d = OnOffDelay(3, 4)
    chunked = np.vstack([d.transform(raw[s]) for s in _chunks(len(raw), 37, rng)])
    np.testing.assert_array_equal(chunked, one)
    e = OnOffDelay(3, 4)
    parts = [e.transform(raw[:1000])]
    e = OnOffDelay.from_state(json.loads(json.dumps(e.to_state())))
    parts.append(e.transform(raw[1000:]))
    np.testing.assert_array_equal(np.vstack(parts), one)
    assert (one != 0).any() and (one == 0).any()


@pytest.mark.parametrize("n", [600, 2000, 7000])
def test_effective_samples_stop_summing_at_the_first_lag_not_positive(n):
    """Sokal's window ends at the first lag whose ρ_k is not positive, whatever follows: a
    residual that alternates (ρ_1 < 0) over a slow swing (ρ_2 ≈ 0.9) counts every sample; a
    window running on to the next such lag would count ρ_1 + ρ_2 and give about n / 2.8."""
    t = np.arange(n)
    x = (-1.0) ** t + 1.28 * np.sin(2 * np.pi * t / (n / 2) + 0.3)
    from scipy import signal

    a = x - x.mean()
    rho = signal.correlate(a, a, mode="full", method="direct")[n - 1 :]
    rho = rho / rho[0]
    assert rho[1] <= 0 < rho[2] and rho[1] + rho[2] > 0.5  # the case is the one described
    assert effective_samples(x) == pytest.approx(n)


def test_lowpass_in_place_gives_the_same_bits_and_no_new_array():
    rng = np.random.default_rng(5)
    x = rng.normal(size=(400, 3)) + 2.0
    x[50:60, 1] = np.nan
    x[70, 2] = np.inf  # non-finite: NaN out, in place as in a new array
    ref = LowPass(max_gap=5).transform(x)
    mine = x.copy()
    got = LowPass(max_gap=5).transform(mine, overwrite=True)
    assert got is mine
    np.testing.assert_array_equal(got, ref)
    assert np.isnan(got[70, 2])
    # a frame (the caller's values) or a column-major array is never written
    f = pd.DataFrame(x.copy())
    LowPass().transform(f, overwrite=True)
    np.testing.assert_array_equal(f.to_numpy(), x)
    col = np.asfortranarray(x)
    out = LowPass().transform(col, overwrite=True)
    assert out is not col
    np.testing.assert_array_equal(col, x)
