"""Tests of the mean-value engine simulator (diag_plugin.simulate.engine, seed 000's plant)."""

from __future__ import annotations

import math
import time

import numpy as np
import pandas as pd
import pytest

from diag_plugin.simulate.engine import (
    ENGINE_TAGS,
    EngineFault,
    EngineParams,
    im240_like_trace,
    simulate_engine,
    simulate_engine_open_loop,
)

QUIET = {c: 0.0 for c in ("omega", "omega_dy", "m_a", "p_m", "T_L")}
#: a dynamometer rotor so heavy that the speed stays put (speed-controlled dyno)
STIFF = EngineParams(j_dy=1e5)
SEED_SIGNALS = ("omega", "m_a", "alpha", "m_f", "T_L", "omega_dy")  # eqs. 7–11


@pytest.fixture(scope="module")
def cycle() -> pd.DataFrame:
    return simulate_engine(seed=3, internals=True)


# ---------------------------------------------------------------- shape, determinism, speed


def test_default_length_index_and_columns(cycle):
    assert len(cycle) == 7000
    assert isinstance(cycle.index, pd.DatetimeIndex)
    assert str(cycle.index.tz) == "UTC"
    assert cycle.index.is_monotonic_increasing
    start = pd.Timestamp("2026-01-01", tz="UTC")
    assert start < cycle.index[0] < start + pd.Timedelta(seconds=0.2)
    for c in list(ENGINE_TAGS) + ["rev"]:
        assert c in cycle.columns
    assert (cycle["rev"].to_numpy() == np.arange(7000)).all()
    assert not cycle[list(ENGINE_TAGS)].isna().any().any()
    # once per revolution: the time step is one revolution at the current speed
    dt = np.diff((cycle.index - start).total_seconds().to_numpy())
    rev_time = 60.0 / cycle["omega_true"].to_numpy()[1:]
    np.testing.assert_allclose(dt, rev_time, rtol=0, atol=2e-9)  # ns time stamps
    assert dt.max() > 3 * dt.min()  # irregular: varies with speed


def test_every_signal_of_the_seed_regression_vectors_exists(cycle):
    for c in SEED_SIGNALS:
        assert cycle[c].dtype == np.float64
        assert cycle[c].std() > 0


def test_same_seed_same_data_other_seed_other_data():
    a = simulate_engine(1500, seed=5, start="2026-03-01T12:00")
    b = simulate_engine(1500, seed=5, start="2026-03-01T12:00")
    pd.testing.assert_frame_equal(a, b)
    assert a.index[0] > pd.Timestamp("2026-03-01T12:00", tz="UTC")
    c = simulate_engine(1500, seed=6, start="2026-03-01T12:00")
    assert not np.allclose(a["alpha"], c["alpha"])
    assert not np.allclose(a["omega"], c["omega"])


def test_n_rev_is_a_parameter_and_a_prefix_is_stable():
    short = simulate_engine(800, seed=2)
    long = simulate_engine(1600, seed=2)
    assert len(short) == 800 and len(long) == 1600
    # 800 is a whole number of 4-revolution excitation holds: the first 800 coincide
    pd.testing.assert_frame_equal(short, long.iloc[:800])
    with pytest.raises(ValueError):
        simulate_engine(0)


def test_fast_after_compile():
    simulate_engine(200, seed=0)
    t0 = time.perf_counter()
    simulate_engine(7000, seed=1)
    assert time.perf_counter() - t0 < 1.0


# ---------------------------------------------------------------- physical plausibility


def test_physical_ranges_over_the_cycle(cycle):
    w = cycle["omega_true"]
    assert 650 < w.min() and w.max() < 4300
    assert abs(np.percentile(w, 1) - 800) < 100  # idle about 800 rpm
    assert w.max() > 3800  # the top of the cycle near 4000 rpm
    pm = cycle["p_m_true"]
    assert 12 < pm.min() and pm.max() < 101.3
    assert 20 < pm.median() < 60
    ma = cycle["m_ath"]
    assert 1.5 < ma.min() < 6 and 35 < ma.max() < 120  # g/s of a 3.0 L engine
    assert 0 <= cycle["alpha"].min() and cycle["alpha"].max() <= 100
    mf = cycle["m_f"]
    assert 5 < mf.min() and mf.max() < 120  # mg per revolution
    lam = cycle["lambda"]
    assert 0.95 < lam.median() < 1.05
    assert np.percentile(lam, 1) > 0.85 and np.percentile(lam, 99) < 1.2
    # the cycle is followed: speed error rms well under 100 rpm
    err = cycle["omega_true"] - cycle["omega_ref"]
    assert np.sqrt((err**2).mean()) < 60
    # air and fuel in the stoichiometric ratio on average
    air_per_rev = cycle["m_ap"] * 60.0 / cycle["omega_true"]  # g/rev
    ratio = (air_per_rev * 1e3 / cycle["m_fc"]).median()
    assert 14.0 < ratio < 15.4


def test_trace_has_the_im240_shape():
    t, n = im240_like_trace()
    assert t[0] == 0 and t[-1] == 240
    assert n[0] == 800 and n[-1] == 800 and n.max() == pytest.approx(4000)
    stop = (t > 60) & (t < 110) & (n == 800)
    assert stop.any()  # the stop between the two hills
    assert n[t < 90].max() < n[t > 100].max()  # the second hill is the higher


# ---------------------------------------------------------------- steady state


def _steady(alpha: float, load: float) -> pd.Series:
    df = simulate_engine_open_loop(np.full(800, alpha), load, noise=QUIET)
    tail = df.iloc[-100:]
    assert tail["omega"].std() < 0.5, "constant throttle and load must give a constant speed"
    return tail.mean()


def test_constant_inputs_give_a_constant_speed_and_more_throttle_more_of_everything():
    lo = _steady(8.0, 30.0)
    hi = _steady(14.0, 30.0)
    assert 900 < lo["omega"] < hi["omega"] < 4500
    assert hi["m_a"] > lo["m_a"] * 1.3
    assert hi["p_m"] > lo["p_m"]
    # in a steady state the load cell reads the dynamometer load, λ = 1
    assert lo["T_L"] == pytest.approx(30.0, abs=0.05)
    assert lo["lambda"] == pytest.approx(1.0, abs=1e-3)
    # and the MAF equals the port flow (manifold in balance)
    assert lo["m_a"] == pytest.approx(lo["m_ap"], rel=1e-3)
    # more load at the same throttle: slower
    slow = _steady(8.0, 45.0)
    assert slow["omega"] < lo["omega"] - 100


def test_torque_converter_slips_by_its_k_factor_and_passes_the_load():
    """With the automatic transmission on (an open torque converter at gear ratio 1) the
    dynamometer turns slower than the engine: in a steady state above the coupling point
    the pump torque ``(n/K)² (1 − SR)/(1 − SR_c)`` equals the load the turbine passes to the
    dynamometer, which the load cell reads. Without it (the default) ω_dy is ω."""
    conv = EngineParams(converter=True)
    for load in (20.0, 40.0):
        df = simulate_engine_open_loop(np.full(1200, 12.0), load, noise=QUIET, params=conv)
        tail = df.iloc[-100:].mean()
        assert df.iloc[-100:]["omega"].std() < 0.5
        assert tail["T_L"] == pytest.approx(load, abs=0.05)
        sr = tail["omega_dy"] / tail["omega"]
        pump = (tail["omega"] / conv.k_converter) ** 2 * (1 - sr) / (1 - conv.sr_coupling)
        assert conv.sr_coupling < sr < 1 and pump == pytest.approx(load, rel=0.02)
        assert tail["T_e"] == pytest.approx(load, rel=0.02)  # the engine's brake torque
    rigid = simulate_engine_open_loop(np.full(800, 12.0), 40.0, noise=QUIET)
    np.testing.assert_array_equal(rigid["omega_dy"], rigid["omega"])
    cycle = simulate_engine(3000, seed=4, params=conv, noise=QUIET, internals=True)
    slip = 1 - cycle["omega_dy"] / cycle["omega"]
    assert 0.005 < slip.median() < 0.05 and slip.max() > 0.05  # more slip when accelerating


# ---------------------------------------------------------------- manifold filling


def test_throttle_step_fills_the_manifold_first_order_with_the_filling_time_constant():
    n0 = 60
    alpha = np.full(160, 5.0)
    alpha[n0:] = 8.0
    df = simulate_engine_open_loop(alpha, 30.0, noise=QUIET, params=STIFF, omega0_rpm=1500)
    assert df["omega"].std() < 1.0  # speed held
    pm = df["p_m_true"].to_numpy()
    p0, p1 = pm[n0 - 1], pm[-1]
    assert p1 > p0 + 3  # more throttle, higher pressure (kPa)
    rel = (pm[n0:] - p0) / (p1 - p0)
    assert (np.diff(rel) > -1e-9).all() and rel.max() < 1.01  # monotone, no overshoot
    # the 63 % point, in revolutions after the step (revolution means: + 0.5)
    k63 = np.interp(1 - math.exp(-1), rel, np.arange(len(rel)) + 1.0)
    # theory: tau = 4π V_m / (λ_l V_d ω), i.e. 2 V_m / (λ_l V_d) revolutions,
    # with the volumetric efficiency λ_l of the final state (choked throttle)
    end = df.iloc[-1]
    w = end["omega_true"] / 60 * 2 * math.pi
    p = STIFF
    lam_l = end["m_ap"] * 1e-3 * 4 * math.pi * p.R * p.T_m / (end["p_m_true"] * 1e3 * p.v_d_m3 * w)
    assert 0.5 < lam_l < 1.0
    tau_rev = 2 * p.v_m_m3 / (lam_l * p.v_d_m3)
    assert 0.6 * tau_rev < k63 < 1.4 * tau_rev
    tau_s = k63 * 60 / end["omega_true"]
    assert 0.05 < tau_s < 0.3  # a tenth of a second at 1500 rpm
    # three time constants later: within 10 % of the end value
    assert rel[int(math.ceil(3 * tau_rev))] > 0.9


def test_larger_manifold_fills_slower():
    alpha = np.full(160, 5.0)
    alpha[60:] = 8.0
    k = []
    for vm in (2e-3, 8e-3):
        p = EngineParams(j_dy=1e5, v_m_m3=vm)
        pm = simulate_engine_open_loop(alpha, 30.0, noise=QUIET, params=p, omega0_rpm=1500)
        pm = pm["p_m_true"].to_numpy()
        rel = (pm[60:] - pm[59]) / (pm[-1] - pm[59])
        k.append(np.interp(0.632, rel, np.arange(len(rel)) + 1.0))
    assert k[1] > 2.5 * k[0]


# ---------------------------------------------------------------- fuel film


def _fuel_step(x_film: float) -> pd.DataFrame:
    fuel = np.full(140, 25.0)
    fuel[50:] = 30.0
    p = EngineParams(j_dy=1e5, x_film=x_film)
    return simulate_engine_open_loop(
        np.full(140, 5.0), 30.0, fuel_mg=fuel, noise=QUIET, params=p, omega0_rpm=1500
    )


def test_fuel_step_reaches_the_cylinders_with_the_film_lag():
    df = _fuel_step(0.25)
    inj = df["m_f_inj"].to_numpy()
    fc = df["m_fc"].to_numpy()
    assert inj[49] == pytest.approx(25.0) and inj[50] == pytest.approx(30.0)  # at once
    frac = (fc[50:] - 25.0) / 5.0
    # first revolution: the (1 - X) direct part plus a little evaporation
    assert 0.7 < frac[0] < 0.9
    assert (np.diff(frac) > 0).all() and frac[-1] > 0.999
    # the film deficit decays with tau_f: ratio per revolution exp(-Δt/τ_f)
    dt_rev = 60.0 / df["omega_true"].iloc[-1]
    deficit = 1 - frac[1:15]
    tau_fit = -dt_rev / np.log(deficit[1:] / deficit[:-1]).mean()
    assert tau_fit == pytest.approx(EngineParams().tau_film_s, rel=0.05)
    # without a film the cylinders get the step at once
    frac0 = (_fuel_step(0.0)["m_fc"].to_numpy()[50:] - 25.0) / 5.0
    assert frac0[0] == pytest.approx(1.0, abs=1e-6)


# ---------------------------------------------------------------- faults


@pytest.mark.parametrize(
    ("signal", "gain"), [("omega", 1.2), ("m_a", 1.2), ("omega_dy", 1.2), ("T_L", 0.9)]
)
def test_sensor_fault_multiplies_only_its_column_exactly_after_onset(signal, gain):
    nominal = simulate_engine(2000, seed=4, internals=True)
    faulty = simulate_engine(
        2000, seed=4, internals=True, faults=[EngineFault(signal, gain, onset=1200)]
    )
    others = [c for c in nominal.columns if c != signal]
    pd.testing.assert_frame_equal(nominal[others], faulty[others])
    np.testing.assert_array_equal(faulty[signal].iloc[:1200], nominal[signal].iloc[:1200])
    np.testing.assert_array_equal(faulty[signal].iloc[1200:], nominal[signal].iloc[1200:] * gain)
    assert faulty.attrs["faults"] == [
        {"signal": signal, "gain": gain, "onset": 1200, "kind": "sensor"}
    ]


def test_command_recorded_fault_is_the_seeds_data_multiplication():
    nominal = simulate_engine(1500, seed=4)
    faulty = simulate_engine(1500, seed=4, faults=[EngineFault("alpha", 1.2, 500, "sensor")])
    np.testing.assert_array_equal(faulty["alpha"].iloc[500:], nominal["alpha"].iloc[500:] * 1.2)
    pd.testing.assert_frame_equal(faulty.drop(columns="alpha"), nominal.drop(columns="alpha"))


def test_throttle_actuator_fault_changes_the_dynamics_not_the_past():
    onset = 3000
    nominal = simulate_engine(5000, seed=8, internals=True)
    faulty = simulate_engine(
        5000, seed=8, internals=True, faults=[EngineFault("alpha", 1.2, onset)]
    )
    pd.testing.assert_frame_equal(nominal.iloc[:onset], faulty.iloc[:onset])
    after = slice(onset, None)
    # the engine gets 1.2 × the command
    np.testing.assert_allclose(
        faulty["alpha_act"].iloc[after], np.clip(1.2 * faulty["alpha"].iloc[after], 0, 100)
    )
    # the same command now lets in more air: the throttle flow per command rises
    first = slice(onset, onset + 3)
    assert (faulty["m_ath"].to_numpy()[first] > nominal["m_ath"].to_numpy()[first] * 1.05).all()
    # the speed controller answers with less throttle; the recorded command drops
    ratio = faulty["alpha"].iloc[onset + 500 :].mean() / nominal["alpha"].iloc[onset + 500 :].mean()
    assert 0.75 < ratio < 0.95
    assert not np.allclose(faulty["omega"].iloc[after], nominal["omega"].iloc[after])


def test_fuel_actuator_fault_without_trim_makes_the_engine_run_rich_unseen_in_the_command():
    onset = 3000
    p = EngineParams(lambda_trim_gain=0.0)
    nominal = simulate_engine(4000, seed=9, internals=True, params=p)
    faults = [EngineFault("m_f", 1.4, onset)]
    faulty = simulate_engine(4000, seed=9, internals=True, params=p, faults=faults)
    pd.testing.assert_frame_equal(nominal.iloc[:onset], faulty.iloc[:onset])
    late = slice(onset + 200, None)
    np.testing.assert_allclose(faulty["m_f_inj"].iloc[late], 1.4 * faulty["m_f"].iloc[late])
    assert faulty["lambda"].iloc[late].median() == pytest.approx(1 / 1.4, abs=0.03)
    # the recorded command stays near its nominal level; the engine's speed differs
    cmd_ratio = faulty["m_f"].iloc[late].mean() / nominal["m_f"].iloc[late].mean()
    assert 0.95 < cmd_ratio < 1.2
    assert not np.allclose(faulty["omega"].iloc[late], nominal["omega"].iloc[late])


def test_fuel_actuator_fault_with_the_lambda_trim_pulls_the_command_down():
    onset = 3000
    nominal = simulate_engine(4500, seed=9, internals=True)
    faulty = simulate_engine(4500, seed=9, internals=True, faults=[EngineFault("m_f", 1.4, onset)])
    pd.testing.assert_frame_equal(nominal.iloc[:onset], faulty.iloc[:onset])
    first = slice(onset + 5, onset + 30)
    assert faulty["lambda"].iloc[first].median() < 0.8  # rich at first
    late = slice(onset + 1200, None)  # after a few trim time constants
    assert faulty["lambda"].iloc[late].median() == pytest.approx(1.0, abs=0.03)
    cmd_ratio = faulty["m_f"].iloc[late].mean() / nominal["m_f"].iloc[late].mean()
    assert cmd_ratio == pytest.approx(1 / 1.4, abs=0.04)
    assert nominal["lambda"].median() == pytest.approx(1.0, abs=0.01)


def test_fault_spec_is_checked():
    with pytest.raises(ValueError, match="unknown engine signal"):
        EngineFault("speed", 1.2, 0)
    with pytest.raises(ValueError, match="gain"):
        EngineFault("omega", 0.0, 0)
    with pytest.raises(ValueError, match="onset"):
        EngineFault("omega", 1.2, -1)
    with pytest.raises(ValueError, match="only alpha and m_f"):
        EngineFault("m_a", 1.2, 0, "actuator")
    assert EngineFault("m_f", 1.4, 10).kind == "actuator"
    assert EngineFault("omega", 1.2, 10).kind == "sensor"
    with pytest.raises(TypeError):
        simulate_engine(100, faults=[("omega", 1.2, 0)])  # type: ignore[list-item]


def test_registered_lazily_in_the_simulate_package():
    import diag_plugin.simulate as sim

    assert sim.simulate_engine is simulate_engine
    assert sim.EngineFault is EngineFault
    assert "simulate_engine" in sim.__all__ and "EngineFault" in sim.__all__
