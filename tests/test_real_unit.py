"""A diagnostic unit on the real Lublin hour, set up the plain way a user would (issue 9).

The DAMADICS hour (actuator 3, fault-free, 1 s) is written as a CSV of timestamps and values
with no tag metadata, imported, and two models are trained on its first half hour:

    rf: F = f(X[k], P1[k])      (the valve: flow from travel and inlet pressure)
    rx: X = f(CV[k-1])          (the servomotor: travel from the controller output)

Thresholds are learned on 00:30–00:45 and the unit replays 00:45–01:00. The data are
fault-free, so every symptom is a false one. What it shows (measured when this test was
written): the flow test stays quiet throughout; the travel test raises OFF_SPEC for the last
82 s (9 % of the window), where X scatters ±6 % around CV while the thresholds were learned on
only 15 minutes (~670 samples, a handful of filter time constants). A unit without a matrix
can only detect, so no FAILURE is possible; the test checks the plumbing on real data and the
flow test's false detection rate.
"""

from __future__ import annotations

import csv
import json

from helpers import DAMADICS_HOW, damadics_file, requires, run_diag

REAL = damadics_file()
PERIOD = ("--period", "1s")


@requires("real DAMADICS data", REAL is not None, DAMADICS_HOW)
def test_real_hour_unit_from_a_plain_csv(tmp_path):
    from diag_plugin.examples.damadics import load_hour

    load_hour(REAL).rename_axis("timestamp").to_csv(tmp_path / "actuator3.csv")
    half, three_q, end = "2001-11-17T00:30:00Z", "2001-11-17T00:45:00Z", "2001-11-17T01:00:00Z"
    steps = [
        ("import", "actuator3.csv"),
        ("model", "new", "rf", "--output", "F", "--input", "X[k]", "--input", "P1[k]", *PERIOD),
        ("model", "new", "rx", "--output", "X", "--input", "CV[k-1]", *PERIOD),
        ("train", "rf", "--to", half),
        ("train", "rx", "--to", half),
        ("unit", "new", "a3", "--model", "rf=rf", "--model", "rx=rx"),
        ("unit", "learn", "a3", "--from", half, "--to", three_q),
    ]
    for args in steps:
        p = run_diag(tmp_path, *args)
        assert p.returncode == 0, (args, p.stderr)

    p = run_diag(tmp_path, "diagnose", "a3", "--from", three_q, "--to", end, "--json")
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    assert out["samples"] == 900
    assert abs(sum(out["status_share"].values()) - 1) < 1e-5
    assert sum(i["samples"] for i in out["intervals"]) == 900
    print("real hour, fault-free:", out["status_share"], "detected", out["detected_share"])

    p = run_diag(tmp_path, "diagnose", "a3", "--from", three_q, "--to", end, "--csv", "d.csv")
    assert p.returncode == 0, p.stderr
    with open(tmp_path / "d.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 900
    assert {"ts", "status", "r_rf", "r_rx", "s_rf", "s_rx", "detected"} <= set(rows[0])
    assert {r["status"] for r in rows} <= {"0", "2", "3"}  # no matrix: detection only
    known = [r for r in rows if r["s_rf"] != ""]
    assert len(known) > 0.95 * len(rows)
    false_rf = sum(r["s_rf"] not in ("0", "") for r in known) / len(known)
    assert false_rf < 0.05, false_rf
