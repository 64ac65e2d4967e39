"""Public-plant loaders and the matched benchmark command (issue 34).

The data are not in the repository: each test skips with the loader's reason when they are
absent (``make public-data`` fetches the Tennessee Eastman set; SKAB from a clone named by
``DIAG_SKAB_DIR`` or the team's mirror)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from diag_plugin.bench import publicplants as pp
from diag_plugin.bench.matched import method_score
from diag_plugin.bench.publicbench import pca_fit, pca_statistics, write_page


def _or_skip(load, *a, **kw):
    try:
        return load(*a, **kw)
    except pp.DataMissing as exc:
        pytest.skip(str(exc))


def test_braatz_shapes_onsets_and_split():
    p = _or_skip(pp.load_braatz, faults=["IDV1", "IDV6", "IDV14"])
    assert p.tags == [f"XMEAS{i}" for i in range(1, 42)] + [f"XMV{i}" for i in range(1, 12)]
    assert p.train[0].frame.shape == (500, 52)  # d00.dat is stored transposed
    assert p.calibration[0].frame.shape == (960, 52)
    assert [r.onset for r in p.faults] == [160, 160, 160]
    assert all(len(r.frame) == 160 and r.onset is None for r in p.free)
    assert p.faults[2].tags[0] == "XMV10"
    # d05_te's fault-free first 8 h repeat d04_te's value for value: one scoring piece, not two
    both = _or_skip(pp.load_braatz, faults=["IDV4", "IDV5"])
    assert [r.name for r in both.free] == ["d04_te[:160]"] and len(both.faults) == 2
    idx = p.faults[0].frame.index
    assert (idx[1] - idx[0]) == pd.Timedelta("3min")
    # IDV6 (A feed loss): the A feed reads normal before the onset and near zero after it
    a = p.faults[1].frame["XMEAS1"].to_numpy()
    assert a[:160].mean() > 0.2 and a[200:].mean() < 0.05
    # the training fault files are faulty from their first samples (tuning only)
    assert p.tuning[1].frame["XMEAS1"].to_numpy()[:20].mean() < 0.05
    # no run serves two roles
    frames = [r.frame.index[0] for r in (*p.train, *p.calibration, *p.faults)]
    assert len(set(frames)) == len(frames)


def test_skab_runs_labels_and_split():
    p = _or_skip(pp.load_skab)
    assert p.per_run and p.period_s == 1.0
    assert len(p.faults) == 21 and len(p.tuning) == 13
    assert {r.name for r in p.faults}.isdisjoint({r.name for r in p.tuning})
    run = next(r for r in p.faults if r.name == "valve1/1")
    assert list(run.frame.columns) == list(pp.SKAB_TAGS)
    assert run.labels is not None and run.labels[:400].sum() == 0
    assert run.onset >= 400 and run.labels[run.onset] == 1 and run.labels[run.onset - 1] == 0
    free = [r for r in p.calibration if r.labels is None]
    assert len(free) == 8 and all(len(r.frame) == pp.SKAB_CHUNK for r in free)


def test_skab_missing_says_where_to_get_it(tmp_path, monkeypatch):
    monkeypatch.setenv("DIAG_SKAB_DIR", str(tmp_path))
    with pytest.raises(pp.DataMissing, match="DIAG_SKAB_DIR"):
        pp.load_skab()
    monkeypatch.setenv("DIAG_TEP_BRAATZ_DIR", str(tmp_path))
    with pytest.raises(pp.DataMissing, match="make public-data"):
        pp.load_braatz()


def test_pca_detects_a_big_tep_fault_at_a_matched_rate():
    """On TEP the A-feed loss (IDV6) is seen by PCA within the hour at a limit set on d00_te
    (a run PCA did not learn from)."""
    from diag_plugin.bench.matched import calibrate, rates

    p = _or_skip(pp.load_braatz, faults=["IDV6"])
    det = pca_fit([p.train[0].frame], p.tags, 0, 0.9)
    cal = method_score(pca_statistics(det, p.calibration[0].frame)[0], 3, 3)
    lim = calibrate([cal], 0.01, 180.0)
    s = method_score(pca_statistics(det, p.faults[0].frame)[0], 3, 3)
    assert np.mean(s[160:] > lim.limit) > 0.9
    assert rates([s[:160]], lim.limit, 180.0)[0] < 0.1


def test_cli_matched_benchmark_writes_a_page_only_when_asked(tmp_path):
    """Without ``--page`` the run leaves ``docs/results/`` alone (it used to overwrite
    ``docs/results/PLANT.md`` whenever the folder was there, ``--json`` or not); the JSON it
    prints is what ``--page`` renders."""
    p = _or_skip(pp.load_braatz, faults=["IDV1"])
    assert p.faults
    results = tmp_path / "docs" / "results"
    results.mkdir(parents=True)
    stale = results / "tep.md"
    stale.write_text("kept\n")
    out = subprocess.run(
        [sys.executable, "-m", "diag_plugin", "benchmark", "--plant", "tep",
         "--match-far", "0.01,0.05", "--fault", "IDV1", "--fault", "IDV4",
         "--out", str(tmp_path / "w"), "--json"],
        capture_output=True, text=True, timeout=600, cwd=tmp_path,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    res = json.loads(out.stdout)
    assert "page" not in res
    assert sorted(x.name for x in results.iterdir()) == ["tep.md"]
    assert stale.read_text() == "kept\n"
    assert res["methods"] == ["unit", "PCA", "DPCA"]  # 500 training rows: a short window
    assert res["unit"]["note"] == "" and res["unit"]["tests"] > 0
    assert [p["target"] for p in res["curve"]["points"]] == [0.01, 0.05]
    page = write_page(res, tmp_path / "tep.md", "diag benchmark --plant tep --page tep.md")
    text = page.read_text()
    assert "diag benchmark --plant tep" in text and "built by the plain commands" in text
    assert "d00_te.dat" in text and "| IDV4 |" in text and "| IDV6 |" not in text
    # the held-out false alarms carry their episodes and the interval chance leaves them
    for m in res["methods"]:
        x = res["curve"]["points"][0]["methods"][m]
        lo, hi = x["free_per_hour_95"]
        assert 0 <= lo <= x["free_per_hour"] < hi and x["free_episodes"] >= 0
    assert "false alarms (share, /h: episodes, 95 %)" in text


def test_tep_studio_loops_have_fixed_set_points_that_the_tags_csv_carries(tmp_path):
    """Ricker's loops are declared with fixed set-points (numbers, not tags): each parses as
    ``PV=number[:OUT]``, and the tags CSV the benchmark writes for the build gives them back
    (``set_point`` on the ``pv`` row, the valve as ``out``)."""
    from diag_plugin.bench.publicbench import tags_frame
    from diag_plugin.unitbuild.loops import loops_from_tags_csv, parse_loop

    loops = [parse_loop(s) for s in pp.TEP_STUDIO_LOOPS]
    assert loops and all(lp.fixed is not None for lp in loops)
    assert {lp.pv for lp in loops} <= set(pp.TEP_TAGS)
    assert {lp.out for lp in loops if lp.out} <= set(pp.TEP_TAGS)
    assert parse_loop("XMEAS9=120.4:XMV10") in loops  # the reactor temperature → its coolant
    plant = pp.PublicPlant(
        name="t", title="t", period_s=180.0, tags=list(pp.TEP_TAGS), tag_info=pp.TEP_TAGS,
        train=[], calibration=[], free=[], faults=[], loops=list(pp.TEP_STUDIO_LOOPS),
    )  # fmt: skip
    path = tmp_path / "tags.csv"
    tags_frame(plant).to_csv(path, index=False)
    back = loops_from_tags_csv(path)
    key = {lp.pv: (lp.fixed, lp.out) for lp in loops}
    assert {lp.pv: (lp.fixed, lp.out) for lp in back} == key


def test_tep_studio_declares_rickers_loops_and_the_data_hold_them():
    """The tep-studio loader declares Ricker's fixed-set-point loops to the unit build, and
    each measurement's mean on the fault-free training runs is at its declared set-point
    (within half its standard deviation, or 0.1 % of the value), so the numbers are the
    plant's."""
    from diag_plugin.unitbuild.loops import parse_loop

    p = _or_skip(pp.load_tep_studio, faults=["IDV1"])
    assert p.loops == list(pp.TEP_STUDIO_LOOPS)
    assert any("XMEAS9=120.4:XMV10" in s for s in p.split)
    train = pd.concat([r.frame for r in p.train])
    for lp in map(parse_loop, p.loops):
        x = train[lp.pv]
        assert abs(x.mean() - lp.fixed) < max(0.5 * x.std(), 0.001 * abs(lp.fixed)), lp


def test_tep_studio_tuning_check_needs_no_scoring_runs(tmp_path):
    """A folder with training, calibration and tuning runs only (the scoring runs not yet
    simulated) loads for a tuning check (``need``), and the default still refuses it,
    naming the roles it lacks."""
    idx = pd.date_range("2026-01-01", periods=4, freq="180s", tz="UTC")
    frame = pd.DataFrame(1.0, index=idx.rename("ts"), columns=list(pp.TEP_TAGS))
    runs = {"train_s1": {"role": "train"}, "calibration_s11": {"role": "calibration"},
            "tuning_s101_idv01": {"role": "tuning", "idv": 1, "onset_h": 0.1}}  # fmt: skip
    for name in runs:
        frame.to_csv(tmp_path / f"{name}.csv")
    (tmp_path / "manifest.json").write_text(json.dumps({"runs": runs}))
    with pytest.raises(pp.DataMissing, match="none for free, fault"):
        pp.load_tep_studio(tmp_path)
    p = pp.load_tep_studio(tmp_path, need=("train", "calibration", "tuning"))
    assert [r.name for r in p.tuning] == ["tuning_s101_idv01"] and not p.faults and not p.free
    assert p.tuning[0].fault == "IDV1" and p.tuning[0].onset == 2
