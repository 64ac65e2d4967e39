"""A manipulated flow's balance test (issue 34, items 4 and 7; :mod:`diag_plugin.unitbuild.
balance`) on the tour's tank (:func:`diag_plugin.simulate.smallplants.tank_run`: the level held
by LIC101 on the outflow valve, outflow FI102 through that valve, inflow FI101 a disturbance),
with a leak no meter sees: liquid lost from the tank.

The leak breaks the tank's mass balance and nothing else: the level loop closes the valve and
the outflow falls as the valve says, so the outflow's own test (from the valve and the level)
holds. The unit is built from 6 fault-free days of seed 1 and scored on seeds 2 and 3.
"""

from __future__ import annotations

import tempfile
import tomllib

import numpy as np
import pandas as pd
import pytest

from diag_plugin.diagnose.unit import Unit
from diag_plugin.regressors import InputSpec
from diag_plugin.simulate import smallplants as sp
from diag_plugin.unitbuild.balance import tag_kind
from diag_plugin.unitbuild.build import build_unit
from historian.taginfo import TagInfo

FAR = 0.05  # per hour: six days show the tail the thresholds rest on
SET_POINTS = (40.0, 45.0, 50.0, 55.0)
LEAK = 8.0  # m³/h lost from the tank from the run's middle (a fifth of the mean inflow)


def _tank(days: float, seed: int, leak: float = 0.0) -> pd.DataFrame:
    """The tank with the operators' set-points every 4 h; ``leak`` m³/h lost from the tank
    over the run's second half. 1-min means."""
    idx = sp._seconds(days, "2026-03-02")
    n = len(idx)
    rng = np.random.default_rng([seed, 7])
    fin = 38.0 + sp._ou(rng, n, 4.0, 2 * 3600.0) + sp._ou(rng, n, 0.8, 20.0)
    hold = np.repeat(rng.choice(SET_POINTS, n // 14400 + 1), 14400)[:n].astype(float)
    lost = np.zeros(n)
    lost[n // 2 :] = leak
    return sp.tank_run(idx, np.clip(fin, 5, 200), hold, rng, leak=lost).resample("60s").mean()


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("balance")
    res = build_unit("tank", _tank(6, 1), folder=tmp, period="60s", far=FAR)
    return res, Unit.load(res.path, tmp)


def test_the_outflow_gets_a_balance_test_without_its_valve(built):
    res, unit = built
    (bal,) = [t for t in res.tests if t.balance]
    assert (bal.test, bal.tag, bal.method) == ("FI102_balance", "FI102", "linear")
    # the inflow (a dead time later) and the level's rate: the tank's mass balance; never the
    # valve, its loop's set-point and measurement (the relation the leak does not break)
    assert bal.inputs[-1] == "rate(LT101)[k]", bal.inputs
    read = {i.split("[")[0] for i in bal.inputs}
    assert "FI101" in read and not read & {"LIC101.OUT", "LIC101.SP", "LT101"}, bal.inputs
    assert bal.steps[-1].rmse_pct <= 3.0
    # the flow's own test still reads its valve; the balance is a second test of the tag
    own = next(t for t in res.tests if t.test == "FI102")
    assert any(i.startswith("LIC101.OUT") for i in own.inputs)
    doc = tomllib.loads(res.path.read_text())
    assert doc["tests"]["FI102_balance"]["balance"] is True
    assert doc["build"]["tests"]["FI102_balance"]["balance"] is True
    assert "kept out: LIC101.OUT, LIC101.SP, LT101" in doc["build"]["tests"]["FI102_balance"]["why"]
    assert unit.file.test("FI102_balance").balance and not unit.file.test("FI102").balance
    assert unit.file.test("FI102_balance").high is not None  # its own thresholds


def test_a_bad_balance_key_is_a_file_line_error(built, tmp_path):
    from diag_plugin.diagnose.unitfile import UnitError

    res, _ = built
    text = res.path.read_text().replace("balance = true", 'balance = "yes"', 1)
    bad = tmp_path / "bad.unit.toml"
    bad.write_text(text)
    with pytest.raises(UnitError) as err:
        Unit.load(bad, res.path.parent)
    assert any("FI102_balance" in p and "balance must be true or false" in p
               for p in err.value.problems), err.value.problems  # fmt: skip


@pytest.mark.parametrize("seed", [2, 3])
def test_a_leak_fires_the_balance_test_and_names_the_outflow(built, seed):
    _, unit = built
    quiet = unit.reset().evaluate(_tank(2, seed))
    assert (quiet.symptoms.fillna(0) != 0).to_numpy().mean() < 0.01
    run = _tank(2, seed, LEAK)
    d = unit.reset().evaluate(run)
    late = slice(len(run) // 2 + 60, None)  # an hour after the onset
    s = d.symptoms.iloc[late].fillna(0) != 0
    assert s["FI102_balance"].mean() > 0.5, s.mean()
    # no other test sees it: the valve relation holds under the leak
    assert s.drop(columns="FI102_balance").to_numpy().mean() < 0.02, s.mean()
    # named: the outflow, the flow the balance models, in the top two of nearly every alarm
    # sample (an inflow meter reading high moves the same two tests the same way; docs)
    top = d.top_tags.iloc[late]
    alarm = top["top1"].fillna("") != ""
    two = top.loc[alarm, ["top1", "top2"]].apply(lambda r: "FI102" in set(r), axis=1)
    assert alarm.mean() > 0.5 and two.mean() > 0.9, top.loc[alarm, "top1"].value_counts()


def test_no_balance_test_where_no_controller_output_drives_a_flow(tmp_path):
    """The valve's output not recorded: nothing says a controller drives the outflow, and
    the build makes one test per tag, as before."""
    frame = _tank(6, 1).drop(columns="LIC101.OUT")
    res = build_unit("tank", frame, folder=tmp_path, period="60s", far=FAR)
    assert not [t for t in res.tests if t.balance or t.test.endswith("_balance")]
    assert sorted(t.tag for t in res.tests if t.statistic == "level") == ["FI101", "FI102", "LT101"]
    assert not any("balance" in n for n in res.notes)


@pytest.mark.parametrize(
    ("tag", "info", "kind"),
    [
        ("FI109", None, "flow"),
        ("LT101", None, "level"),
        ("PI101", None, "pressure"),
        ("TI104", None, None),
        ("LIC101.OUT", TagInfo("LIC101.OUT", "%", 0, 100, "level controller output"), None),
        ("LIC101.SP", None, None),
        ("XMEAS14", TagInfo("XMEAS14", "m³/h", None, None, "separator underflow"), "flow"),
        ("XMEAS1", TagInfo("XMEAS1", "kscmh", None, None, "A feed (stream 1)"), "flow"),
        ("XMEAS12", TagInfo("XMEAS12", "%", None, None, "product separator level"), "level"),
        ("XMEAS7", TagInfo("XMEAS7", "kPa", None, None, "reactor pressure"), "pressure"),
        ("XMEAS20", TagInfo("XMEAS20", "kW", None, None, "compressor work"), None),
        ("XMV7", TagInfo("XMV7", "%", None, None, "separator pot liquid flow (stream 10)"), None),
        ("Pressure", TagInfo("Pressure", "bar", None, None, "pressure after the pump"), "pressure"),
    ],
)
def test_what_a_tag_measures(tag, info, kind):
    assert tag_kind(tag, info) == kind


def test_a_balance_reads_no_set_point_and_no_levels_value():
    """A balance's terms are flows and a level's change (``rate``): a set-point (an
    operator's choice) or a level's value (held at one by its loop) relates the flow to what
    the operators chose over the window, and breaks at their next choices (the chemical plant
    at 1 s: ``FI102 = f(LI103)`` on 55 % and 100 % of two fault-free tuning runs,
    docs/explanation/chemplant-benchmark.md "At 1 s"). On its 12 days at 3 min (two seeds)
    main's balances read set-points in 5 of 9 (``FI102_balance = f(TIC103.SP, AI101)``)."""
    from diag_plugin.simulate.chemplant import CHEMPLANT_TAGS, sample, simulate_chemplant
    from diag_plugin.unitbuild.balance import balance_term

    info = {t: TagInfo(t, unit=u, lo=lo, hi=hi, description=d)
            for t, (u, lo, hi, d, _) in CHEMPLANT_TAGS.items()}  # fmt: skip
    assert balance_term("FI102", info["FI102"]) and balance_term("TI103", info["TI103"])
    assert not balance_term("LIC103.SP", info["LIC103.SP"])
    assert not balance_term("LI103", info["LI103"]) and not balance_term("LT101")
    runs, start = [], pd.Timestamp("2026-01-01", tz="UTC")
    for seed in (1, 2):
        run = sample(simulate_chemplant(6.0, seed, start=start), 180)
        runs.append(run)
        start = run.index[-1] + pd.Timedelta("1h")
    frame = pd.concat(runs)
    frame = frame.reindex(pd.date_range(frame.index[0], frame.index[-1], freq="180s"))
    with tempfile.TemporaryDirectory() as tmp:
        res = build_unit("cp", frame, folder=tmp, period="180s", tag_info=info, workers=1)
    balances = [t for t in res.tests if t.balance]
    assert len(balances) >= 6, [t.test for t in balances]
    for t in balances:
        terms = [tag for spec in map(InputSpec.parse, t.inputs) if spec.fn != "rate"
                 for tag in spec.tags]  # fmt: skip
        assert all(balance_term(tag, info.get(tag)) for tag in terms), (t.test, t.inputs)
    assert any(i.startswith("rate(") for t in balances for i in t.inputs)
