"""Valve tests and fixed set-points (issue 34, item 7) on a process cooler built by hand
(:mod:`tests.cooler`: its outlet temperature held at a fixed 45 °C, not a tag, by the
cooling-water valve; not tuned to the unit, written once from its physics).

The unit is built from 5 fault-free hours (600 samples at 30 s: a short window), with the loop
declared as ``--loop T_OUT=45:V_CW`` and, through ``diag unit build --loops-from``, in the tags
CSV's ``set_point`` column. Faults are scored on seeds never used to build (11, 12).
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from diag_plugin.diagnose.unit import Unit
from diag_plugin.regressors import InputSpec, SpecError, feature
from diag_plugin.unitbuild.build import build_unit
from diag_plugin.unitbuild.loops import Loop, loops_from_tags_csv, parse_loop
from historian.errors import UserError
from tests import cooler
from tests.test_any_plant_tour import diag, fmt, import_csv

ONSET = int(2 * 3600 / cooler.PERIOD_S)  # the faults start after 2 h
SEEDS = (11, 12)


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("cooler")
    frame = cooler.simulate(5.0, seed=1)
    res = build_unit("cool", frame, folder=tmp, period="30s", far=0.01,
                     loops=[parse_loop(cooler.LOOP)])  # fmt: skip
    unit = Unit.load(res.path, tmp)
    runs = {
        (fault, seed): unit.reset().evaluate(cooler.simulate(6.0, seed, fault))
        for fault in (None, "valve_capacity", "stiction", "cw_warm")
        for seed in SEEDS
    }
    return res, unit, runs


def _after(d, col: str) -> pd.Series:
    return d.symptoms[col].iloc[ONSET:]


def _top1(d) -> list[str]:
    top = d.top_tags["top1"].iloc[ONSET:]
    return top[top != ""].value_counts().index.tolist()


# ---------------------------------------------------------------- the fixed set-point
def test_a_fixed_set_point_is_parsed_and_its_errors_are_clear(tmp_path):
    lp = parse_loop("XMEAS9=120.4:XMV10")
    assert lp == Loop("XMEAS9", "120.4", "XMV10") and lp.fixed == 120.4
    assert parse_loop("T=-3e1").fixed == -30.0 and parse_loop("T=T_SP:V").fixed is None
    for bad, what in (("T=nan:V", "not a finite number"), ("12=T:V", "only the set-point"),
                      ("T=45:7", "only the set-point")):  # fmt: skip
        with pytest.raises(UserError, match=what) as e:
            parse_loop(bad)
        assert f"--loop {bad!r}" in str(e.value)
    p = tmp_path / "tags.csv"
    cooler.tags_csv().to_csv(p, index=False)
    assert loops_from_tags_csv(p) == [Loop("T_OUT", "45", "V_CW")]
    bad_rows = {
        "name,loop,role,set_point\nT,a,pv,warm\nV,a,out,\n": r"tags.csv:2: set_point 'warm' of T "
        r"\(loop a\) is not a number",
        "name,loop,role,set_point\nT,a,pv,\nV,a,out,45\n": r"tags.csv:3: set_point '45' on V "
        r"\(loop a, role out\): a fixed set-point goes on the loop's pv row",
        "name,loop,role,set_point\nT,a,pv,45\nS,a,sp,\n": r"tags.csv:3: loop a has a fixed "
        r"set_point \(45 on line 2\) and a set-point tag S",
        "name,loop,role,set_point\nT,,,45\n": r"tags.csv:2: set_point '45' of T without a loop",
    }
    for text, msg in bad_rows.items():
        p.write_text(text)
        with pytest.raises(UserError, match=msg):
            loops_from_tags_csv(p)


def test_a_const_input_spec_round_trips():
    s = InputSpec.parse("const(120.4)[k]")
    assert s.fn == "const" and s.param == 120.4 and not s.tags and str(s) == "const(120.4)[k]"
    idx = pd.date_range("2026-01-01", periods=3, freq="1min", tz="UTC")
    assert (feature(pd.DataFrame({"A": [1.0, 2, 3]}, index=idx), s) == 120.4).all()
    for bad in ("const()[k]", "const(A)[k]"):
        with pytest.raises(SpecError, match="const"):
            InputSpec.parse(bad)


def test_the_loop_with_a_fixed_set_point_is_built(built):
    res, unit, _ = built
    tests = {t.test: t for t in res.tests}
    pv = tests["T_OUT"]
    assert pv.method == "track" and pv.inputs == ["const(45)[k]"] and pv.tracks == "45"
    assert pv.actuator == "V_CW" and pv.declared
    spread = tests["T_OUT_spread"]
    assert spread.statistic == "spread" and spread.actuator == "V_CW"
    assert unit.file.test("T_OUT").set_point == "45"
    assert "45" not in unit.cmodel.tags  # a set-point is never a tag at fault


def test_the_valve_is_predicted_from_the_loads_that_drive_it(built):
    """Item 7: the controller output's test reads several process conditions (the process
    flow and both inlet temperatures set the cooling a steady state needs), never the
    outlet temperature its loop holds; a short window's other tests stop at two inputs."""
    res, *_ = built
    valve = {t.test: t for t in res.tests}["V_CW"]
    tags = {InputSpec.parse(i).tags[0] for i in valve.inputs}
    assert len(tags) >= 3 and "T_OUT" not in tags, valve.inputs
    assert {"F_PROC", "T_IN", "T_CW"} <= tags
    assert "controller output" in valve.why


# ---------------------------------------------------------------- detection and naming
def test_fault_free_runs_are_quiet(built):
    *_, runs = built
    for seed in SEEDS:
        assert (runs[(None, seed)].detected == 1).mean() < 0.02


def test_a_loss_of_valve_capacity_fires_the_valves_own_test_and_names_it(built):
    """The loop opens the valve further and holds the outlet at 45 °C: only the valve's
    position, against what the loads say it should be, shows the fault."""
    *_, runs = built
    for seed in SEEDS:
        d = runs[("valve_capacity", seed)]
        assert (_after(d, "V_CW") != 0).mean() > 0.8
        assert (_after(d, "T_OUT") != 0).mean() < 0.05  # the loop's error stays in its band
        assert _top1(d)[0] == "V_CW"


def test_a_sticking_valve_is_seen_and_named_on_the_valve(built):
    *_, runs = built
    for seed in SEEDS:
        d = runs[("stiction", seed)]
        assert (d.detected.iloc[ONSET:] == 1).mean() > 0.05
        assert _top1(d)[0] == "V_CW"


def test_warmer_cooling_water_is_named_on_the_water_not_on_the_valve(built):
    """Issues 34 items 4/7: the cooling water comes 6 °C warmer than the 5 h window saw; the
    loop opens the valve and holds the outlet, and the valve's own test fires (its linear
    model does not know the cooler there). Every test in alarm is explained by the water's
    excursion beyond what the unit learned (its residual within twice the water's excess
    times the valve's gain on it), so the water is named, not the valve that absorbs it
    (``Excursions``); on main the valve was named first on 70 % and 89 % of the alarm
    samples. The valve's own faults above keep the valve."""
    res, unit, runs = built
    for seed in SEEDS:
        d = runs[("cw_warm", seed)]
        assert (_after(d, "V_CW") != 0).mean() > 0.5  # the valve's test fires
        top = d.top_tags["top1"].iloc[ONSET:]
        top = top[top != ""]
        assert _top1(d)[0] == "T_CW"
        assert (top == "T_CW").mean() > 0.7, top.value_counts()


def test_the_fixed_set_point_loop_is_built_through_the_commands(tmp_path):
    """``diag import`` + ``diag unit build --loops-from`` with the tags CSV's ``set_point``,
    and ``--loop`` with a number; a bad number is refused naming the option."""
    g = ["--db", f"sqlite:///{tmp_path / 'h.db'}", "--rulebases", str(tmp_path / "rb")]
    frame = cooler.simulate(5.0, seed=1)
    cooler.tags_csv().to_csv(tmp_path / "tags.csv", index=False)
    import_csv(g, frame, tmp_path / "c.csv", tags=tmp_path / "tags.csv")
    t0, t1 = fmt(frame.index[0]), fmt(frame.index[-1] + pd.Timedelta("30s"))
    rc, text = diag(g, "unit", "build", "c", "--from", t0, "--to", t1, "--json",
                    "--loops-from", str(tmp_path / "tags.csv"))  # fmt: skip
    assert rc == 0, text
    tests = {t["test"]: t for t in json.loads(text)["tests"]}
    assert tests["T_OUT"]["tracks"] == "45" and tests["T_OUT"]["actuator"] == "V_CW"
    rc, text = diag(g, "unit", "build", "d", "--from", t0, "--to", t1, "--loop", "T_OUT=inf:V_CW")
    assert rc == 2 and "--loop 'T_OUT=inf:V_CW'" in text, text
    assert np.isfinite(parse_loop("T_OUT=45:V_CW").fixed)
