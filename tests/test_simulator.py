"""Tests of the DAMADICS servomotor–valve assembly simulator (diag_plugin.simulate)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from helpers import DAMADICS_HOW, damadics_file, require

from diag_plugin.simulate import (
    FAULTS,
    TAGS,
    FaultSpec,
    ValveParams,
    fault_truth,
    parse_fault,
    simulate_valve,
)
from diag_plugin.simulate import physics as ph

START = pd.Timestamp("2026-01-01", tz="UTC")
ONSET = pd.Timestamp("2026-01-01T06:00", tz="UTC")
QUIET = ValveParams(noise_scale=0.0)


@pytest.fixture(scope="module")
def base() -> pd.DataFrame:
    return simulate_valve(0.5, seed=3, internals=True)


@pytest.fixture(scope="module")
def three_days() -> pd.DataFrame:
    return simulate_valve(3, seed=11, internals=True)


# ---------------------------------------------------------------- shape and determinism


def test_shape_index_and_period():
    df = simulate_valve(1, period_s=10, start="2026-02-01T00:00")
    assert len(df) == 8640
    assert isinstance(df.index, pd.DatetimeIndex)
    assert df.index.name == "ts"
    assert str(df.index.tz) == "UTC"
    assert df.index[0] == pd.Timestamp("2026-02-01", tz="UTC")
    steps = df.index[1:] - df.index[:-1]
    assert (steps == pd.Timedelta(seconds=10)).all()
    assert list(df.columns) == list(TAGS)
    assert all(df[c].dtype == np.float64 for c in df.columns)
    assert not df.isna().any().any()
    assert df.attrs["faults"] == []
    short = simulate_valve(0.1, period_s=1)
    assert len(short) == 8640
    assert short.index[1] - short.index[0] == pd.Timedelta(seconds=1)


def test_deterministic_for_a_seed_and_seeds_differ():
    a = simulate_valve(0.3, seed=5)
    b = simulate_valve(0.3, seed=5)
    pd.testing.assert_frame_equal(a, b)
    c = simulate_valve(0.3, seed=6)
    assert (a["P1"] - c["P1"]).abs().mean() > 10.0
    assert (a["CV"] - c["CV"]).abs().mean() > 1.0


def test_shorter_run_is_a_prefix_of_a_longer_one():
    a = simulate_valve(0.5, seed=2)
    b = simulate_valve(1.2, seed=2)
    pd.testing.assert_frame_equal(a, b.iloc[: len(a)])


def test_values_inside_transducer_ranges(three_days):
    for tag, meta in TAGS.items():
        lo, hi = meta.span
        assert three_days[tag].between(lo, hi).all(), tag


def test_cv_and_pressures_cover_the_operating_range(three_days):
    cv = three_days["CV"]
    assert cv.quantile(0.95) - cv.quantile(0.05) > 35.0
    dp = three_days["P1"] - three_days["P2"]
    assert dp.std() > 0.02 * 4000  # several % of the pressure span


# ---------------------------------------------------------------- physics


def test_flow_rises_with_opening_and_with_sqrt_dp():
    x = np.linspace(0.05, 1.0, 20)
    f = ph.valve_flow_th(x, 3400.0, 2450.0, 100.0, 16.0, 50.0, 0.8, 0.2)
    assert (np.diff(f) > 0).all()
    assert ph.valve_flow_th(0.0, 3400.0, 2450.0, 100.0, 16.0, 50.0, 0.8, 0.2) == 0.0
    # F ∝ sqrt(ΔP) while the flow is not choked
    f1 = ph.valve_flow_th(0.6, 3400.0, 3200.0, 100.0, 16.0, 50.0, 0.8, 0.2)
    f4 = ph.valve_flow_th(0.6, 3400.0, 2600.0, 100.0, 16.0, 50.0, 0.8, 0.2)
    assert f4 / f1 == pytest.approx(2.0, rel=1e-9)
    # equal percentage: the same step in X multiplies Kv by the same factor
    kv = ph.kv_relative(np.array([0.6, 0.7, 0.8, 0.9]), 50.0)
    ratios = kv[1:] / kv[:-1]
    assert ratios == pytest.approx(np.full(3, 50.0**0.1), rel=0.03)


def test_choked_flow_stops_depending_on_p2():
    p2 = np.linspace(3000.0, 0.0, 61)
    f = ph.valve_flow_th(0.7, 3400.0, p2, 100.0, 16.0, 50.0, 0.8, 0.2)
    dp_all = ph.allowed_pressure_drop_kpa(0.7, 3400.0, 100.0, 0.8, 0.2)
    choked = 3400.0 - p2 > dp_all
    assert choked.any() and (~choked).any()
    assert np.ptp(f[choked]) < 1e-9  # flat once choked
    assert (np.diff(f[~choked]) > 0).all()
    # hotter water chokes earlier (vapour pressure rises with T)
    hot = ph.allowed_pressure_drop_kpa(0.7, 3400.0, 220.0, 0.8, 0.2)
    assert hot < dp_all
    assert ph.vapour_pressure_kpa(100.0) == pytest.approx(101.3, rel=0.02)
    assert ph.water_density(100.0) == pytest.approx(958.4, rel=0.01)


def test_simulated_flow_follows_sqrt_dp_and_opening(three_days):
    d = three_days
    m = (d["X_true"] > 40) & (d["X_true"] < 95)
    dp = (d["P1"] - d["P2"])[m]
    A = np.column_stack([np.ones(m.sum()), d["X_true"][m], np.log(dp)])
    coef, *_ = np.linalg.lstsq(A, np.log(d["F_true"][m]), rcond=None)
    assert coef[1] > 0.03  # flow rises with X (equal %: ln(50)/100 ≈ 0.039)
    assert coef[2] == pytest.approx(0.5, abs=0.08)


def test_simulated_flow_chokes_when_outlet_pressure_falls():
    d = simulate_valve(0.2, seed=4, internals=True, faults=[FaultSpec("f17", 0.95, None)])
    p = ValveParams()
    rho = ph.water_density(d["T1"].to_numpy())
    kv = p.kvs * ph.kv_relative(d["X_true"].to_numpy() / 100.0, p.rangeability)
    unchoked = ph.liquid_flow_th(kv, (d["P1"] - d["P2"]).to_numpy(), rho)
    assert (d["F_true"] < 0.9 * unchoked).mean() > 0.95


def test_pressure_explains_flow_much_better_than_cv_alone(three_days):
    """Model B F_k = f(U_{k-1}) against model A F_k = f(U_{k-1}, P_k) (seed paper)."""
    d = three_days
    u = d["CV"].to_numpy()[:-1] / 100.0
    y = d["F"].to_numpy()[1:]
    sdp = np.sqrt((d["P1"] - d["P2"]).to_numpy()[1:] / 1000.0)
    basis = np.column_stack([u**j for j in range(8)])

    def rmse(A):
        c, *_ = np.linalg.lstsq(A, y, rcond=None)
        return float(np.sqrt(np.mean((y - A @ c) ** 2)))

    err_b = rmse(basis)
    err_a = rmse(basis * sdp[:, None])
    assert err_b > 3.0 * err_a


def _travel_direction_gap(d: pd.DataFrame) -> float:
    cv = d["CV"].to_numpy()
    e = d["X"].to_numpy() - cv
    dcv = np.r_[0.0, np.diff(cv)]
    return float(e[dcv < -0.3].mean() - e[dcv > 0.3].mean())


def test_hysteresis_visible_and_set_by_friction():
    d = simulate_valve(1, seed=7, params=QUIET)
    gap = _travel_direction_gap(d)
    assert gap > 0.5  # X lags behind CV in the direction of travel
    strong = simulate_valve(1, seed=7, params=ValveParams(noise_scale=0.0, hysteresis=0.4))
    assert _travel_direction_gap(strong) > 2.0 * gap
    none = simulate_valve(1, seed=7, params=ValveParams(noise_scale=0.0, hysteresis=0.0))
    assert abs(_travel_direction_gap(none)) < 0.35 * gap  # what is left is the ~1 s lag


def _best_lag(d: pd.DataFrame, max_lag: int = 12) -> int:
    cv = np.diff(d["CV"].to_numpy())
    x = np.diff(d["X"].to_numpy())
    corr = [np.corrcoef(cv[: len(cv) - k], x[k:])[0, 1] for k in range(max_lag)]
    return int(np.argmax(corr))


def test_x_lags_cv_by_about_a_second_plus_dead_time():
    d = simulate_valve(0.1, period_s=1, seed=1, params=QUIET)
    assert _best_lag(d) == 1
    slow = simulate_valve(0.1, period_s=1, seed=1, params=ValveParams(noise_scale=0, dead_time_s=5))
    assert _best_lag(slow) in (5, 6)


# ---------------------------------------------------------------- faults

#: tags each fault must visibly change (mean |Δ| > 0.3 % of span after the onset)
EXPECTED = {
    "f1": ("X", "F", "CV"),
    "f2": ("X", "CV"),
    "f3": ("X", "CV"),
    "f4": ("X", "P0"),
    "f5": ("X", "CV"),
    "f6": ("X", "CV"),
    "f7": ("T1", "F"),
    "f8": ("P0",),
    "f9": ("P0",),
    "f10": ("P0", "X"),
    "f11": ("P0",),
    "f12": ("P0",),
    "f13": ("X",),
    "f14": ("P0",),
    "f15": ("X",),
    "f16": ("X", "F"),
    "f17": ("P2",),
    "f18": ("X", "CV"),
    "f19": ("F", "CV"),
}
STRENGTH = {"f12": -0.5, "f14": -0.5, "f19": -0.5}


@pytest.mark.parametrize("name", sorted(FAULTS, key=lambda n: int(n[1:])))
def test_each_fault_acts_from_its_onset_and_not_before(base, name):
    spec = FaultSpec(name, STRENGTH.get(name, 0.5), ONSET)
    d = simulate_valve(0.5, seed=3, internals=True, faults=[spec])
    before = d.index < ONSET
    pd.testing.assert_frame_equal(d[before], base[before], check_exact=True)
    diff = (d[~before] - base[~before]).abs().mean()
    for tag in EXPECTED[name]:
        lo, hi = TAGS[tag].span
        assert diff[tag] > 0.003 * (hi - lo), (name, tag, diff[tag])
    # process conditions only change where the fault is a process condition
    for tag in ("P1", "P2", "T1"):
        if tag not in EXPECTED[name]:
            assert diff[tag] == 0.0, (name, tag)
    if name == "f14":  # a pure measurement fault
        assert (diff.drop("P0") == 0.0).all()
    assert d.attrs["faults"][0]["name"] == name
    assert d.attrs["faults"][0]["onset"] == ONSET.isoformat()


def test_abrupt_and_incipient_development(base):
    ramp = 3 * 3600.0
    ab = simulate_valve(0.5, seed=3, internals=True, faults=[FaultSpec("f18", 0.6, ONSET)])
    inc = simulate_valve(
        0.5,
        seed=3,
        internals=True,
        faults=[FaultSpec("f18", 0.6, ONSET, "incipient", ramp)],
    )
    early = (base.index >= ONSET) & (base.index < ONSET + pd.Timedelta("30min"))
    late = base.index >= ONSET + pd.Timedelta(seconds=ramp)
    d_ab = (ab["X"] - base["X"]).abs()
    d_inc = (inc["X"] - base["X"]).abs()
    assert d_ab[early].mean() > 5.0 * d_inc[early].mean()
    assert d_inc[late].mean() > 0.5 * d_ab[late].mean()
    # the truth follows DABLib's FGEN profile
    truth = fault_truth(inc.index, [FaultSpec("f18", 0.6, ONSET, "incipient", ramp)])
    t = truth["f18"]
    assert t[t.index < ONSET].eq(0).all()
    assert t[ONSET + pd.Timedelta(hours=1.5)] == pytest.approx(0.3)
    assert t[late].eq(0.6).all()


def test_fault_without_onset_starts_at_the_start_and_strengths_are_checked():
    d = simulate_valve(0.05, faults=[FaultSpec("f19", -0.3)])
    assert d.attrs["faults"][0]["onset"] is None
    with pytest.raises(ValueError, match="limits"):
        FaultSpec("f1", -0.5)
    with pytest.raises(ValueError, match="unknown fault"):
        FaultSpec("f20", 0.5)


def test_f13_measurement_mode_leaves_the_process_alone(base):
    p = ValveParams(f13_mode="measurement")
    ok = simulate_valve(0.5, seed=3, internals=True, params=p)
    d = simulate_valve(0.5, seed=3, internals=True, params=p, faults=[FaultSpec("f13", 0.2, ONSET)])
    after = d.index >= ONSET
    assert (d["F"] == ok["F"]).all() and (d["CV"] == ok["CV"]).all()
    assert (d["X"][after] - ok["X"][after]).abs().mean() > 3.0


def test_without_positioner_the_chain_is_open():
    """``positioner_gain=0``: CV drives the E/P converter, so P0 depends on CV alone and
    an E/P or spring fault is not compensated (the plant of Kościelny et al.'s Table 4)."""
    p = ValveParams(positioner_gain=0.0, hysteresis=0.03, noise_scale=0.0)
    ok = simulate_valve(0.5, seed=3, internals=True, params=p)
    # healthy: the calibration still puts X near CV, within the friction band
    assert (ok["X"] - ok["CV"]).abs().median() < 3.0
    # P0 is a straight function of the (filtered) CV: no feedback from X
    slope, icpt = np.polyfit(ok["CV"], ok["P0"], 1)
    assert np.abs(ok["P0"] - (slope * ok["CV"] + icpt)).quantile(0.99) < 5.0
    after = ok.index >= ONSET
    for fault in ("f12", "f11"):
        d = simulate_valve(
            0.5, seed=3, internals=True, params=p, faults=[FaultSpec(fault, 0.2, ONSET)]
        )
        if fault == "f12":  # the E/P output falls for the same CV: ~20 % less pressure
            ratio = d["P0"][after] / (slope * d["CV"][after] + icpt)
            assert 0.75 < ratio.median() < 0.85
        else:  # a weaker spring: more travel for the same chamber pressure
            x_for_p0 = np.polyfit(ok["P0"], ok["X"], 1)
            excess = d["X"][after] - np.polyval(x_for_p0, d["P0"][after])
            assert excess.median() > 5.0
    # with the positioner (default) the same E/P fault is compensated: P0(CV) barely moves
    closed = ValveParams(noise_scale=0.0)
    c_ok = simulate_valve(0.5, seed=3, params=closed)
    c = simulate_valve(0.5, seed=3, params=closed, faults=[FaultSpec("f12", 0.2, ONSET)])
    assert (c["X"] - c_ok["X"])[after].abs().median() < 1.0


# ---------------------------------------------------------------- parse_fault


@pytest.mark.parametrize(
    "text, expected",
    [
        ("f17:0.5@2026-03-01T10:00", ("f17", 0.5, "2026-03-01T10:00Z", "abrupt", 86400.0)),
        ("f2:1@2026-03-01/incipient=6h", ("f2", 1.0, "2026-03-01T00:00Z", "incipient", 21600.0)),
        ("F19:-0.2", ("f19", -0.2, None, "abrupt", 86400.0)),
        (
            "f6:0.8@2026-01-02T00:00/incipient",
            ("f6", 0.8, "2026-01-02T00:00Z", "incipient", 86400.0),
        ),
        (
            "f3:0.25@2026-01-02T01:00+01:00/abrupt",
            ("f3", 0.25, "2026-01-02T00:00Z", "abrupt", 86400.0),
        ),
        ("f9:0.1/incipient=900", ("f9", 0.1, None, "incipient", 900.0)),
    ],
)
def test_parse_fault_good(text, expected):
    spec = parse_fault(text)
    name, strength, onset, dev, ramp = expected
    assert spec.name == name
    assert spec.strength == strength
    assert spec.onset == (None if onset is None else pd.Timestamp(onset))
    assert spec.development == dev
    assert spec.ramp_s == ramp


@pytest.mark.parametrize(
    "text, message",
    [
        ("", "expected NAME:STRENGTH"),
        ("f17", "expected NAME:STRENGTH"),
        ("f20:0.5", "unknown fault"),
        ("f17:abc", "not a number"),
        ("f17:0.5@yesterday", "not an ISO 8601 time"),
        ("f17:2", "outside its limits"),
        ("f1:-0.5", "outside its limits"),
        ("f17:0.5/sudden", "abrupt/incipient"),
        ("f17:0.5/abrupt=1h", "only goes with /incipient"),
        ("f17:0.5/incipient=soon", "bad duration"),
    ],
)
def test_parse_fault_bad(text, message):
    with pytest.raises(ValueError, match=message):
        parse_fault(text)


# ---------------------------------------------------------------- CLI


def test_cli_writes_csv_and_parquet(tmp_path, capsys):
    from diag_plugin.cli import main

    csv = tmp_path / "sim.csv"
    rc = main(
        ["simulate", "--days", "0.1", "--out", str(csv), "--seed", "4"]
        + ["--fault", "f17:0.5@2026-01-01T01:00", "--fault", "f4:0.2@2026-01-01T02:00/incipient=1h"]
    )
    assert rc == 0
    back = pd.read_csv(csv)
    assert list(back.columns) == ["ts", *TAGS]
    assert back["ts"].iloc[1] == "2026-01-01T00:00:10+00:00"
    ref = simulate_valve(0.1, seed=4, faults=[parse_fault("f17:0.5@2026-01-01T01:00")])
    assert len(back) == len(ref)
    assert np.allclose(back["P1"].to_numpy()[:300], ref["P1"].to_numpy()[:300], rtol=1e-5)
    truth = json.loads((tmp_path / "sim.csv.faults.json").read_text())
    assert [f["name"] for f in truth] == ["f17", "f4"]

    pq = tmp_path / "sim.parquet"
    assert main(["simulate", "--days", "0.05", "--out", str(pq), "--period", "5"]) == 0
    d = pd.read_parquet(pq)
    assert list(d.columns) == list(TAGS)
    assert str(d.index.tz) == "UTC" and d.index.name == "ts"
    assert len(d) == 864
    pd.testing.assert_frame_equal(
        d, simulate_valve(0.05, period_s=5), check_index_type=False, check_freq=False
    )


def test_cli_rejects_bad_input(tmp_path, capsys):
    from diag_plugin.cli import main

    assert (
        main(["simulate", "--days", "1", "--out", str(tmp_path / "x.csv"), "--fault", "f99:1"]) == 2
    )
    assert "unknown fault" in capsys.readouterr().err
    assert main(["simulate", "--days", "1", "--out", str(tmp_path / "x.txt")]) == 2
    assert (
        main(["simulate", "--days", "1", "--out", str(tmp_path / "x.csv"), "--period", "0.33"]) == 2
    )
    assert not (tmp_path / "x.csv").exists()


# ---------------------------------------------------------------- real data (plausibility)


def test_lag_and_ranges_match_the_real_actuator():
    """The Lublin hour: X follows CV about 1 s later; P1, P2, T1, F inside our spans."""
    real_file = damadics_file()
    require("real DAMADICS data", real_file is not None, DAMADICS_HOW)
    from scipy.io import loadmat

    m = loadmat(real_file)["OneHourTestData_ExampleII"]
    real = pd.DataFrame({"CV": m[5], "X": m[6]})
    assert _best_lag(real, 6) == 1
    # the simulated CV is far smoother than the real one (6 %/s jitter), so compare
    # without transducer noise, which would otherwise hide the 1 s lag
    sim = simulate_valve(0.1, period_s=1, seed=0, params=QUIET)
    assert _best_lag(sim, 6) == 1
    for row, tag in ((1, "P1"), (2, "P2"), (3, "T1"), (4, "F")):
        lo, hi = TAGS[tag].span
        assert lo <= m[row].min() and m[row].max() <= hi, tag
