"""``diag benchmark --plant chemplant``: a unit built from fault-free runs beside PCA and DPCA.

One ``--quick`` run (2 training seeds × 6 days at 3 min, seeds 9101 / 9151 never used while
building or tuning, three faults) through the real CLI, its JSON checked.
"""

from __future__ import annotations

import json

import pytest

from diag_plugin import cli

FAR = 0.01  # alarms per hour: a 2-day fault-free run expects about 0.5 episode


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    import io
    from contextlib import redirect_stdout

    out = tmp_path_factory.mktemp("unit")
    buf = io.StringIO()
    with redirect_stdout(buf):
        rc = cli.main(
            ["benchmark", "--plant", "chemplant", "--quick", "--far", str(FAR),
             "--out", str(out), "--json"]
        )  # fmt: skip
    return rc, json.loads(buf.getvalue()), out


def test_the_cli_runs_and_prints_json_with_the_expected_keys(result):
    rc, out, folder = result
    assert rc == 0
    for key in ("plant", "period_s", "far_per_hour", "budget", "training", "scoring",
                "methods", "fault_free", "faults", "summary", "seconds"):  # fmt: skip
        assert key in out
    assert out["methods"] == ["unit", "PCA", "DPCA"]
    assert out["far_per_hour"] == FAR
    assert set(out["training"]["seeds"]).isdisjoint(out["scoring"]["fault_seeds"])
    assert {r["fault"] for r in out["faults"]} == {"fi109_bias", "tv103_stuck", "feed_comp_step"}
    for r in out["faults"]:
        for m in out["methods"]:
            assert set(r[m]) >= {"detection_rate", "delay_s", "in_top3", "runs"}
            assert 0 <= r[m]["detection_rate"] <= 1
    for m in out["methods"]:
        assert set(out["fault_free"][m]) >= {"share", "per_hour"}
    assert set(out["summary"]["goal"]) == {
        "detection_above_pca", "false_alarms_no_higher", "top3_80pct", "holds"
    }  # fmt: skip
    assert (folder / "chemplant.unit.toml").exists()  # --out keeps the built unit


def test_a_big_sensor_bias_is_detected_and_named(result):
    _, out, _ = result
    row = next(r for r in out["faults"] if r["fault"] == "fi109_bias")
    assert row["size"] == 1.5
    assert row["unit"]["detection_rate"] > 0.5
    assert row["unit"]["in_top3"] == row["unit"]["runs"]
    assert all("FI109" in x["top3"] for x in row["unit"]["per_seed"])


def test_fault_free_false_alarms_stay_near_the_budget_on_an_unseen_seed(result):
    _, out, _ = result
    fa = out["fault_free"]["unit"]
    assert fa["per_hour"] <= 3 * FAR  # at most one episode in the 48 h run
    assert fa["share"] < 0.02


def test_a_training_seed_cannot_score(capfd):
    rc = cli.main(["benchmark", "--plant", "chemplant", "--quick", "--seed", "2"])
    assert rc == 2
    assert "both train and score" in capfd.readouterr().err
