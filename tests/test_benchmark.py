"""``diag benchmark`` (issue 9): the DAMADICS indexes, hand-checked on made-up decisions, and the
quick run of the example unit on a simulator seed used nowhere else (23)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from diag_plugin.bench.damadics import score
from diag_plugin.cli import main


def test_indexes_on_hand_made_decisions():
    # 10 samples before the onset, 20 after, period 10 s
    det = np.zeros(30)
    det[3] = 1  # one false alarm sample before the onset: r_fd = 1/10
    det[12:15] = 1  # chatter after the onset …
    det[18:] = 1  # … then permanent detection from sample 18 (8 samples after t_from)
    det[16] = np.nan  # unknown is not a detection
    faults = np.array([""] * 30, dtype=object)
    faults[20:] = "f_V|f_S"
    faults[13] = "f_X"
    s = score(det, faults, "f_V", 10, 10.0, 1.0)
    assert s["false_detection_rate"] == pytest.approx(0.1)
    assert s["true_detection_rate"] == pytest.approx(15 / 20)
    assert s["detected"] and s["detection_time_s"] == 80.0  # last leading edge, not the first
    assert s["unknown_rate"] == pytest.approx(1 / 20)
    assert s["unknown_rate_before"] == 0.0
    assert s["isolated"] and s["isolation_time_s"] == 100.0
    assert s["true_isolation_rate"] == pytest.approx(10 / 20)
    assert s["mismatch_isolation_rate"] == pytest.approx(1 / 30)
    assert s["diagnosis_accuracy"] == 0.5  # two faults indicated at the horizon
    late = det.copy()
    late[-1] = 0  # not on at the end: no permanent detection
    s = score(late, faults, None, 10, 10.0, None)
    assert not s["detected"] and s["detection_time_s"] is None and s["isolated"] is None


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bench")
    import contextlib
    import io

    buf = io.StringIO()
    page = folder / "results" / "damadics.md"
    with contextlib.redirect_stdout(buf):
        assert main(["benchmark", "--quick", "--seed", "23", "--json", "--page", str(page)]) == 0
    (folder / "b.json").write_text(buf.getvalue())
    return json.loads(buf.getvalue())


def test_the_result_page_says_how_it_was_made_and_holds_every_scenario(quick):
    """``--page``: the generated page names the command, date, commit and seeds, and has one
    row per fault, mode and strength with the run's own detections."""
    text = Path(quick["page"]).read_text(encoding="utf-8")
    assert "*Generated — do not edit by hand" in text
    for line in ("- command: `diag ", "- date: ", "- commit: ", "seeds 23;"):
        assert line in text, line
    rows = [ln for ln in text.splitlines() if ln.startswith("| f") and "| mode |" not in ln]
    assert len(rows) == len(quick["scenarios"]) == 38
    for r, ln in zip(quick["scenarios"], rows, strict=True):
        cells = [c.strip() for c in ln.strip("|").split("|")]
        assert cells[:2] == [r["fault"], r["mode"]]
        assert cells[3] == f"{int(r['detected'])}/1"
    s = quick["summary"]
    assert f"detected {s['scenarios_detected']} of {s['scenarios']} scenarios" in text


def test_quick_benchmark_shape(quick):
    rows = quick["scenarios"]
    assert len(rows) == 38
    assert {r["fault"] for r in rows} == {f"f{i}" for i in range(1, 20)}
    assert {r["mode"] for r in rows} == {"abrupt", "incipient"}
    for r in rows:
        for key in ("detected", "false_detection_rate", "true_detection_rate", "isolated"):
            assert key in r
        assert isinstance(r["detected"], bool)
        assert r["detection_time_s"] is None or r["detection_time_s"] >= 0
        assert (r["detection_time_s"] is not None) == r["detected"]
        if r["unit_fault"] is None:
            assert r["isolated"] is None and r["isolation_time_s"] is None
    s = quick["summary"]
    assert s["scenarios"] == 38 and 0 <= s["literature_detectable_share"] <= 1


def test_quick_benchmark_meets_the_issue_goal(quick):
    """No false alarms on the fault-free periods; the faults the unit is built for are found."""
    rows = {(r["fault"], r["mode"]): r for r in quick["scenarios"]}
    s = quick["summary"]
    assert s["max_false_detection_rate"] < 0.05
    assert s["mean_unknown_rate_before"] < 0.05  # not quiet because it says nothing
    assert rows[("f14", "abrupt")]["isolated"]  # P0 sensor: Table 4's f_P0 column
    for f in ("f1", "f2", "f12", "f13", "f14", "f16"):
        assert rows[(f, "abrupt")]["detected"], f
    # what the literature cannot see with flow/position models, we do not claim either
    assert not rows[("f5", "abrupt")]["detected"]
    # the issue's goal is 0.8 of the 15 faults the literature detects; the full run (every
    # strength) reaches 12/15 pooled over seeds 11, 23, 37 (11, 12, 12 per seed;
    # docs/results/damadics.md). The quick run tries one strength per fault and finds 10/15 here:
    # faults that drive the valve where no model has rules make the unit CHECK_FUNCTION, not
    # detected, and f3 at fs = 0.5 stays under the thresholds learned over 14 days (it was
    # 11/15 with 2-day thresholds, which alarmed on fault-free days: the test below)
    assert s["literature_detectable_share"] >= 0.65


def fault_free_alarms(unit_path, seeds, days: float = 3.0) -> tuple[int, float]:
    """Runs (of ``seeds``, ``days`` fault-free each, after 2 h of warm-up) with any detection,
    and the pooled share of detected samples."""
    import pandas as pd

    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.simulate import simulate_valve

    unit = Unit.load(unit_path)
    runs, on, total = 0, 0, 0
    for seed in seeds:
        frame = simulate_valve(days, seed=seed, period_s=pd.Timedelta(unit.period).total_seconds())
        unit.reset()
        d = unit.evaluate(frame)
        after = d.detected.index >= d.detected.index[0] + pd.Timedelta("2h")
        det = d.detected.to_numpy()[after] == 1
        runs += bool(det.any())
        on += int(det.sum())
        total += det.size
    return runs, on / total


def test_the_shipped_unit_is_quiet_on_fault_free_days_of_unseen_seeds():
    """Twenty fault-free 3-day runs on seeds used nowhere else (5000–5019, criterion fixed
    before they were first run): an alarm on at most 3 runs and < 0.1 % of the samples.
    Thresholds from 2 fault-free days (16–20 independent residual values for r1 and r4) gave
    alarms on 12 of 40 other runs (seeds 3000–3019, 4000–4019; 0.21–0.28 % of samples) and
    on 6 of these 20; from 14 days, 3 of 40 (0.008–0.03 %) and none of these."""
    from pathlib import Path

    shipped = Path(__file__).resolve().parents[1] / "rulebases" / "valve_unit.unit.toml"
    runs, share = fault_free_alarms(shipped, range(5000, 5020))
    assert runs <= 3 and share < 0.001, (runs, share)


def test_the_page_carries_pca_and_dpca_at_the_units_matched_rate(quick):
    """Issue 34: every detection figure beside PCA and DPCA at the same false-alarm rate. The
    page has their detection per row (the run's own, from --json) and says which runs each
    method learned from and which matched the limits; the calibration runs are none of the
    scoring seeds nor the training seed, and each baseline's count on them is the unit's
    within what the calibration resolves (at most the unit's, and the next lower limit it
    offers would alarm on more)."""
    b = quick["baselines"]
    cal = b["calibration"]
    assert set(b["summary"]) == {"PCA", "DPCA"}
    assert not set(cal["seeds"]) & ({b["train"]["seed"]} | set(quick["setup"]["seeds"]))
    k, n = cal["unit"]["alarms"], cal["samples"]
    assert cal["unit"]["share"] == pytest.approx(k / n)
    for m in ("PCA", "DPCA"):
        assert cal[m]["alarms"] <= k < (cal[m]["next_alarms"] or n + 1), m
        assert cal[m]["share"] == pytest.approx(cal[m]["alarms"] / n)
        # the held-out check: the fault-free hours before the onsets, at the matched limit
        assert b["summary"][m]["max_false_detection_rate"] < 0.05, m
    text = Path(quick["page"]).read_text(encoding="utf-8")
    assert f"calibration** — fault-free seeds {', '.join(map(str, cal['seeds']))}" in text
    assert f"alarms on {k} of their {n} samples" in text
    head = next(ln for ln in text.splitlines() if ln.startswith("| fault | mode |"))
    assert head.rstrip(" |").endswith("DPCA detected | DPCA t_dt s | DPCA r_td")
    rows = [ln for ln in text.splitlines() if ln.startswith("| f") and "| mode |" not in ln]
    for r, ln in zip(quick["scenarios"], rows, strict=True):
        cells = [c.strip() for c in ln.strip("|").split("|")]
        for i, m in ((9, "PCA"), (12, "DPCA")):
            x = r["baselines"][m]
            assert cells[i] == f"{int(x['detected'])}/1", (r["fault"], m)
            assert cells[i + 2] == f"{x['true_detection_rate']:.2f}", (r["fault"], m)
    for m in ("PCA", "DPCA"):
        s = b["summary"][m]
        assert f"- {m} at the unit's rate: detected {s['scenarios_detected']} of 38" in text


def test_baselines_match_a_unit_that_alarms_on_the_calibration_runs(tmp_path):
    """The match where the unit does alarm on the calibration runs (its thresholds scaled to
    a third, so the count is not the trivial 0): each baseline alarms on at most the unit's
    count and its next lower limit on more, and the limits' counts are what the alarms give
    on the same runs again. Seeds and lengths used nowhere else (7201, half a day; PCA from
    5 days of the training run)."""
    import re
    import shutil

    from diag_plugin.bench.damadics import calibrate_baselines, fit_baselines
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.simulate import simulate_valve

    src = Path(__file__).resolve().parents[1] / "rulebases"
    for f in src.glob("valve_*"):
        shutil.copy(f, tmp_path / f.name)
    p = tmp_path / "valve_unit.unit.toml"
    text = re.sub(r"(high|low) = (-?[0-9.]+)",
                  lambda m: f"{m[1]} = {float(m[2]) / 3:.4f}", p.read_text())  # fmt: skip
    p.write_text(re.sub(r", (levels|fuzzy) = \[[^]]*\]", "", text))
    unit = Unit.load("valve_unit", tmp_path)
    base = calibrate_baselines(unit, fit_baselines(unit, days=5.0), seeds=(7201,), days=0.5)
    cal = base.calibration
    k, n = cal["unit"]["alarms"], cal["samples"]
    assert 0 < k < n
    frame = simulate_valve(2 / 24 + 0.5, seed=7201)
    keep = frame.index >= frame.index[0] + pd.Timedelta("2h")
    for m, alarm in base.alarms(frame).items():
        assert cal[m]["alarms"] <= k < cal[m]["next_alarms"], (m, cal[m], k)
        assert int(np.nansum(alarm[keep])) == cal[m]["alarms"], m


def test_a_scoring_seed_the_baselines_learn_or_match_on_is_refused():
    """A scenario on the training seed or a calibration seed would score the baselines on
    runs that set them: refused before anything is simulated, naming the seeds."""
    from diag_plugin.bench.damadics import run_benchmark
    from diag_plugin.diagnose.unit import Unit

    unit = Unit.load("valve_unit", Path(__file__).resolve().parents[1] / "rulebases")
    for seed in (1, 7102):
        with pytest.raises(ValueError, match=f"seed\\(s\\) {seed}: the baselines learn"):
            run_benchmark(unit, quick=True, seeds=(23, seed))
