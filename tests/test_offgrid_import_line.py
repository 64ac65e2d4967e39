"""The 7-tag line's flow-meter bias through the CLI a user runs, off the grid (issue 34,
"Lessons"; benchmarks/offgrid_import_line.py; docs/how-to/unit-loops.md, "The line imported
off the grid").

The line's 15 s runs (tests/line7.py) are written as a plant export: each row stamped at its
grid time ±20 % of the period, local times with ``+02:00``, one row repeated
(:func:`tests.offgrid.stamps_off_grid`). ``diag import --duplicates first``, ``diag unit
build`` (the loop declared, the period left to the data) and ``diag diagnose --csv --json``
must give the diagnosis the Python API gives on the on-grid frames, and name the meter.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from tests import line7
from tests.offgrid import stamps_off_grid, write_csv
from tests.test_any_plant_tour import diag

DAY = pd.Timedelta(days=1)


def _utc(t: pd.Timestamp) -> str:
    return t.strftime("%Y-%m-%dT%H:%M:%SZ")


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    """The training run (6 days, seed 1) and seed 101's flow bias (2 days, from day 1) off
    the grid through import, build and diagnose; the diagnose CSV, its JSON, the build's
    output and the runs."""
    tmp = tmp_path_factory.mktemp("offgrid_line")
    g = ["--db", f"sqlite:///{tmp / 'h.db'}", "--rulebases", str(tmp / "rb")]
    runs = {"train": line7.simulate(6.0, 1), "fault": line7.simulate(2.0, 101, "flow_bias")}
    spans = {}
    for k, (name, run) in enumerate(runs.items()):
        run.index = run.index + 10 * k * DAY
        write_csv(stamps_off_grid(run, 5 + k), tmp / f"{name}.csv")
        rc, text = diag(g, "import", str(tmp / f"{name}.csv"), "--duplicates", "first")
        assert rc == 0, text
        spans[name] = (_utc(run.index[0]), _utc(run.index[-1] + pd.Timedelta(seconds=15)))
    rc, built = diag(g, "unit", "build", "line", "--from", spans["train"][0], "--to",
                     spans["train"][1], "--loop", line7.LOOP, "--far", "0.01")  # fmt: skip
    assert rc == 0, built
    out = tmp / "fault.out.csv"
    rc, text = diag(g, "diagnose", "line", "--from", spans["fault"][0], "--to",
                    spans["fault"][1], "--csv", str(out), "--json")  # fmt: skip
    assert rc == 0, text
    return pd.read_csv(out, low_memory=False), json.loads(text), built, runs


def test_the_export_is_read_back_on_the_line_s_own_grid(imported):
    """The period found from the jittered stamps is the line's 15 s, and the diagnosis has
    one row per grid point of the two days (the repeated row dropped, none lost or split)."""
    d, summary, built, runs = imported
    assert "(period 15s)" in built.splitlines()[0]
    ts = pd.to_datetime(d["ts"], utc=True)
    assert len(d) == len(runs["fault"])
    assert (ts.to_numpy() == runs["fault"].index.to_numpy()).all()
    known = d["detected"].dropna()  # empty where every test is unknown
    assert summary["detected_share"] == pytest.approx((known == 1).mean(), abs=1e-6)


def test_the_meter_bias_is_raised_and_held_on_the_meter(imported):
    """From day 1 on the bias is raised on most samples and ``top1`` (the CSV's held top
    tag) is ``FEED_FLOW`` on more than 70 % of the alarm samples. Measured: 4,991 of 5,760
    raised, the meter 88 % and the valve 7 % (the on-grid API's figures, identical); before
    i34-gain3 this seed had the meter 25 % and the valve 74 %, and with the meter's and the
    valve's columns swapped in the export the valve has 100 %. 70 %: 18 points under the
    measured share, far above 25 %. (A column one sample late passes here: the last test
    catches it.)"""
    d, *_ = imported
    after = (pd.to_datetime(d["ts"], utc=True) >= pd.to_datetime(d["ts"].iloc[0]) + DAY).to_numpy()
    alarm = (d["detected"] == 1).to_numpy() & after
    assert alarm.sum() > 0.6 * after.sum()
    top = d["top1"].fillna("").astype(str).to_numpy()[alarm]
    share = pd.Series(top).value_counts(normalize=True)
    assert share.get("FEED_FLOW", 0.0) > 0.7, share.head()
    assert share.index[0] == "FEED_FLOW"


def test_the_cli_off_the_grid_gives_the_api_s_diagnosis_on_it(imported, tmp_path):
    """The same runs on the grid through ``build_unit`` and ``Unit.evaluate``
    (as benchmarks/line7_meter_bias.py): the status the same on every sample; every test's
    residual the same on every sample (to the CSV's six significant digits, unknown on the
    same samples); detected and ``top1`` on at least 99.9 % of the samples (measured: all).

    ``diag diagnose --from`` replays a lead-in before ``--from``
    (:mod:`diag_plugin.diagnose.leadin`); here it falls in the historian's gap after the
    training run, and its empty rows are not replayed (the unit starts cold at the first
    sample, as ``evaluate`` does). Until 2026-12-03 they were, and the spread test's filtered
    residual differed on samples 21-83 (5-21 min; both CHECK_FUNCTION). Tried: the meter's
    column one sample late in the export moves every ``FEED_FLOW`` residual (detected and
    ``top1`` barely: they alone would pass it); two columns swapped or stamps ±60 % of the
    period (into the neighbours' bins) fail too."""
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.unitbuild.build import build_unit
    from diag_plugin.unitbuild.loops import parse_loop

    d, _, _, runs = imported
    res = build_unit("line", runs["train"], folder=tmp_path, period="15s",
                     loops=[parse_loop(line7.LOOP)], far=0.01, force=True)  # fmt: skip
    api = Unit.load(res.path, tmp_path).evaluate(runs["fault"])
    assert (d["status"].to_numpy(int) == api.status.to_numpy(int)).all()
    for test, r in api.residuals.items():
        cli, ref = d[f"r_{test}"].to_numpy(float), r.to_numpy()
        assert (np.isnan(cli) == np.isnan(ref)).all(), test
        np.testing.assert_allclose(cli, ref, rtol=1e-5, atol=1e-9, err_msg=test)
    det = np.nan_to_num(api.detected.to_numpy(float), nan=-1.0)
    assert (det == np.nan_to_num(d["detected"].to_numpy(float), nan=-1.0)).mean() >= 0.999
    top = api.top_tags["top1"].to_numpy().astype(str)
    assert (top == d["top1"].fillna("").astype(str).to_numpy()).mean() >= 0.999
