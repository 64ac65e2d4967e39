"""A short window's unit is built and learned without a malformed fuzzy-breakpoints error
(issue 34, H8).

A test whose fault-free residual never crosses 0 over the learning window (a transmitter
drifted since the build, a block of a range the model never saw) has its threshold on that
side at the 1e-4 floor and its fuzzy ramp within 0.1 % of it: ``n0`` (or ``p0``) ≈ ∓1e-7,
which the unit file wrote at 4 decimals as 0.0 and then refused to read ("fuzzy must list
the N, 0, P breakpoints ... got [-0.0002, -0.0, 168.29, 171.87]"): ``diag unit learn``
stopped with that error, ``build_unit`` with its traceback. The windows below are the ones
the report named (one tag's last fifth far from the rest) and its kin (two clusters, one
cluster and outliers, a constant with one step, quantised values) at several rates.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tests.test_any_plant_tour import diag, fmt, import_csv

KINDS = ("far_block", "two_clusters", "outliers", "one_step", "quantised")
RATES = ("10s", "60s", "180s")


def window(kind: str, seed: int, rows: int, period: str) -> pd.DataFrame:
    """A short fault-free window of a flow ``FLOW`` (shaped by ``kind``), an output ``OUT``
    linear in it and a pressure ``PRESS`` that falls slightly with it."""
    rng = np.random.default_rng(seed)
    last = rows // 5
    if kind == "far_block":  # in a 0.01-wide band, its last fifth across 10-40
        flow = rng.uniform(20, 20.01, rows)
        flow[-last:] = np.linspace(10, 40, last) + rng.normal(0, 0.3, last)
    elif kind == "two_clusters":
        flow = np.where(rng.random(rows) < 0.5, 10.0, 30.0) + rng.normal(0, 0.01, rows)
    elif kind == "outliers":
        flow = rng.normal(20, 0.005, rows)
        at = rng.choice(rows, 5, replace=False)
        flow[at] += rng.normal(0, 15, 5)
    elif kind == "one_step":
        flow = np.where(np.arange(rows) < rows // 2 + seed % 50, 20.0, 25.0)
    else:  # quantised to steps of 2
        flow = np.round(rng.normal(20, 1, rows) / 2) * 2
    out = 10 + 2 * flow + rng.normal(0, 1, rows)
    press = 7 - 0.02 * flow + rng.normal(0, 0.02, rows)
    idx = pd.date_range("2026-06-02T06:00", periods=rows, freq=period, tz="UTC")
    return pd.DataFrame({"FLOW": flow, "OUT": out, "PRESS": press}, index=idx)


def _valid(fuzzy) -> bool:
    n1, n0, p0, p1 = fuzzy
    return n1 <= n0 < 0 < p0 <= p1


@pytest.mark.parametrize("period", RATES)
@pytest.mark.parametrize("kind", KINDS)
def test_a_short_window_builds_and_relearns_on_a_drifted_one(tmp_path, kind, period):
    """Every window builds, and learning its unit again on the same window with one tag's
    reading shifted up or down (its test's residual wholly on one side of 0) writes a unit
    file that reads back, with a note naming the test."""
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.diagnose.unitfile import UnitFile
    from diag_plugin.learn.thresholds import learn_thresholds
    from diag_plugin.regressors import InputSpec
    from diag_plugin.unitbuild.build import build_unit

    frame = window(kind, 0, 400, period)
    res = build_unit("u", frame, folder=tmp_path, period=period, far=0.01, tags=["OUT", "PRESS"])
    assert all(_valid(t.fuzzy) for t in UnitFile.load(res.path).tests if t.fuzzy)
    for shift in (+1.0, -1.0):
        unit = Unit.load(res.path, tmp_path)
        tag = InputSpec.parse(unit.models[unit.tests[0]].output).tags[0]
        drifted = frame.assign(**{tag: frame[tag] + shift * 50 * frame[tag].std()})
        learned = learn_thresholds(unit, [drifted], far=0.01, cross_fit=False)
        unit.file.set_learned(learned)  # read back: raised UnitError on main
        unit.file.save()
        tests = UnitFile.load(res.path).tests
        assert all(_valid(t.fuzzy) for t in tests if t.fuzzy)
        said = [w for w in learned.warnings if "stays" in w]
        side = "above" if shift > 0 else "below"
        assert any(w.startswith(f"{unit.tests[0]}: its residual stays {side} 0") for w in said)


def test_diag_unit_learn_on_a_drifted_window_says_which_test(tmp_path):
    """The report's window through the CLI: ``diag unit build`` over it, ``diag unit learn``
    over the next day where PRESS reads 1 bar high (main: exit 2, "fuzzy must list the N, 0,
    P breakpoints ... got [-0.0002, -0.0, ...]"): thresholds learned and the note naming PRESS
    and why."""
    a = window("far_block", 0, 400, "180s")
    b = window("far_block", 1, 400, "180s")
    b.index = a.index + 400 * pd.Timedelta("180s")
    b["PRESS"] += 1.0
    g = ["--db", f"sqlite:///{tmp_path / 'h.db'}", "--rulebases", str(tmp_path / "rb")]
    import_csv(g, pd.concat([a, b]), tmp_path / "w.csv")
    end = b.index[-1] + pd.Timedelta("180s")
    rc, text = diag(g, "unit", "build", "u", "--from", fmt(a.index[0]), "--to", fmt(b.index[0]),
                    "--tags", "OUT", "PRESS", "--far", "0.01")  # fmt: skip
    assert rc == 0, text
    rc, text = diag(g, "unit", "learn", "u", "--from", fmt(b.index[0]), "--to", fmt(end),
                    "--far", "0.01")  # fmt: skip
    assert rc == 0, text
    assert "note: PRESS: its residual stays above 0 over the window" in text, text
    assert "its low threshold is the floor -0.0001" in text, text
