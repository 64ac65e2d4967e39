"""A measured disturbance is a cause, never a test (issue 34, item 4; docs/how-to/unit-loops.md,
"A measured disturbance").

The acceptance pass on an aeration basin (docs/explanation/acceptance-aeration.md) found the
build testing what drives the plant: the influent "predicted" from an air valve alarmed
FAILURE through a storm, the water temperature "predicted" from the blower's power. Here the
steam heater (:mod:`tests.heater`, written once, not tuned) built with its inlet temperature
and process flow declared disturbances: neither is tested — without the declaration both are,
from the outlet that follows them (``T_IN = f(T_OUT[k-28], …)``, a relation the wrong way
round) — both stay inputs; the steam meter's bias is still found and named on seeds never
used to build. The 7-tag line (:mod:`tests.line7`) declares its supply pressure in a tags CSV
with the role ``driver`` through the CLI; a declaration the build cannot use names the tag
and where.
"""

from __future__ import annotations

import pandas as pd
import pytest

from diag_plugin.diagnose.unit import Unit
from diag_plugin.status import NE107
from tests import heater, line7
from tests.test_any_plant_tour import diag, fmt, import_csv

SEEDS = (101, 102, 103)
ON = int(86400 / heater.PERIOD_S)


@pytest.fixture(scope="module")
def heaters(tmp_path_factory):
    from diag_plugin.unitbuild.build import build_unit

    frame = heater.simulate(5.0, 1)
    out = {}
    for key, driven in (("plain", ()), ("declared", ("T_IN", "F_PROC"))):
        folder = tmp_path_factory.mktemp(key)
        res = build_unit("heater", frame, folder=folder, period="20s", far=0.01,
                         manual=["STEAM_V"], disturbances=list(driven))  # fmt: skip
        out[key] = res, Unit.load(res.path, folder)
    return out


def test_a_declared_disturbance_is_an_input_never_a_test(heaters):
    plain, _ = heaters["plain"]
    res, unit = heaters["declared"]
    assert {"T_IN", "F_PROC"} <= {ch.tag for ch in plain.tests}  # the build's own choice
    assert not {"T_IN", "F_PROC"} & {ch.tag for ch in res.tests}
    for tag in ("T_IN", "F_PROC"):
        assert res.skipped[tag].startswith("a measured disturbance (declared"), res.skipped
    read = {i.split("[")[0] for name in unit.tests for i in unit.models[name].inputs}
    assert {"T_IN", "F_PROC"} <= read, read  # still what the outlet is modelled from


def test_the_steam_meter_bias_is_still_found_and_named(heaters):
    _, unit = heaters["declared"]
    for seed in SEEDS:
        clean = unit.reset().evaluate(heater.simulate(2.0, seed)).status.to_numpy()
        alarm = (clean == NE107.FAILURE) | (clean == NE107.OFF_SPEC)
        assert alarm[ON:].mean() < 0.01, seed
        d = unit.reset().evaluate(heater.simulate(2.0, seed, "steam_bias"))
        st = d.status.to_numpy()[ON:]
        on = (st == NE107.FAILURE) | (st == NE107.OFF_SPEC)
        assert on.mean() > 0.6, (seed, on.mean())
        named = pd.Series(d.top["top1"].to_numpy()[ON:][on]).value_counts(normalize=True)
        assert named.index[0] == "F_STEAM" and named.iloc[0] > 0.85, named


def _tags_csv(tmp, rows: dict[str, tuple[str, str]]):
    tc = line7.tags_csv()
    for tag, (loop, role) in rows.items():
        tc.loc[tc["name"] == tag, ["loop", "role"]] = [loop, role]
    tc.to_csv(tmp / "tags.csv", index=False)
    return tmp / "tags.csv"


@pytest.fixture(scope="module")
def line(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("line")
    g = ["--db", f"sqlite:///{tmp / 'h.db'}", "--rulebases", str(tmp / "rb")]
    frame = line7.simulate(3.0, seed=1)
    tags = _tags_csv(tmp, {"SUPPLY_P": ("", "driver"), "HAND_VALVE": ("", "manual")})
    import_csv(g, frame, tmp / "line.csv", tags=tags)
    return g, tmp, frame, tags


def test_a_tags_csv_declares_a_disturbance_by_its_role(line):
    g, tmp, frame, tags = line
    t0, t1 = frame.index[0], frame.index[-1] + pd.Timedelta("15s")
    rc, text = diag(g, "unit", "build", "line", "--from", fmt(t0), "--to", fmt(t1),
                    "--loops-from", str(tags), "--far", "0.01")  # fmt: skip
    assert rc == 0, text
    assert "not tested: SUPPLY_P: a measured disturbance (declared" in text, text
    unit = Unit.load("line", tmp / "rb")
    assert not any(unit.models[t].output.startswith("SUPPLY_P") for t in unit.tests)


def test_a_declaration_the_build_cannot_use_names_the_tag_and_where(line, tmp_path):
    g, tmp, frame, _ = line
    base = ["unit", "build", "x", "--from", fmt(frame.index[0]),
            "--to", fmt(frame.index[0] + pd.Timedelta(days=2))]  # fmt: skip
    rc, text = diag(g, *base, "--disturbance", "NOPE")
    assert (
        rc == 2 and "--disturbance NOPE: disturbance NOPE (disturbance) is not in the data" in text
    )
    rc, text = diag(g, *base, "--disturbance", "VALVE_A", "--loop", line7.LOOP)
    assert rc == 2 and "disturbance VALVE_A (disturbance) is a tag of loop FEED_FLOW=" in text
    rc, text = diag(g, *base, "--disturbance", "HAND_VALVE", "--manual", "HAND_VALVE")
    assert rc == 2 and "HAND_VALVE is declared a hand valve and a measured disturbance" in text
    bad = _tags_csv(tmp_path, {"SUPPLY_P": ("feed", "exogenous")})
    rc, text = diag(g, *base, "--loops-from", str(bad))
    assert rc == 2, text
    assert f"{bad}:2: SUPPLY_P is a measured disturbance (role exogenous) and in loop feed" in text
    typo = _tags_csv(tmp_path, {"SUPPLY_P": ("", "disturbence")})
    rc, text = diag(g, *base, "--loops-from", str(typo))
    assert rc == 2, text
    assert f"{typo}:2: role 'disturbence' of SUPPLY_P without a loop: a row without a loop" in text
    assert not (tmp / "rb" / "x.unit.toml").exists()
