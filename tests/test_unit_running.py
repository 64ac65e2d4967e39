"""A unit that stops is judged only while it runs (issue 34, items 5 and 6; ISA-18.2's
state-based alarming; docs/how-to/unit-loops.md, "A plant that stops").

The supply fan of :mod:`tests.fanplant` (a duct-pressure loop, off at night and at weekends,
its run feedback ``FAN_RUN``) built on 12 days (seed 1) with and without its run condition,
judged on 14 days of seeds never used to build (7, 8): with the run condition nothing is
learned from the nights (the loop test's band is the running loop's), the nights are
CHECK_FUNCTION ``not running`` and never an alarm, a fault by day is detected and named, an
alarm is not carried across a stop, and the replay, a restart and the live plant agree. The
same through the CLI with a tags CSV's role ``running``.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from diag_plugin.diagnose.plant import Plant
from diag_plugin.diagnose.unit import Unit, concat
from diag_plugin.status import NE107
from diag_plugin.unitbuild.build import build_unit
from diag_plugin.unitbuild.loops import Loop, Running
from historian.errors import UserError
from tests import fanplant
from tests.test_any_plant_tour import diag, fmt, import_csv

DAYS = 14
ONSET = 7.0  # the faults from the third Monday (2026-03-23) on
WEEK = int(ONSET * 86400 / fanplant.PERIOD_S)
START = "2026-03-16"
WHY = "not running (FAN_RUN = 0): judged only while it runs"


def _judged(seed: int, fault: str | None = None) -> pd.DataFrame:
    return fanplant.simulate(DAYS, seed, fault, onset_days=ONSET, start=START)


def _build(tmp, name: str, running) -> Unit:
    frame = fanplant.simulate(12, 1)
    res = build_unit(name, frame, folder=tmp, period="5min", far=0.01, running=running,
                     loops=[Loop("DP", "DP_SP", "FAN_SPD")], disturbances=["T_OUT"])  # fmt: skip
    return res, Unit.load(res.path, tmp)


@pytest.fixture(scope="module")
def fan(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("running")
    return _build(tmp, "fan", Running("FAN_RUN"))


@pytest.fixture(scope="module")
def fan_all(tmp_path_factory):
    """The same window built without the run condition (as main builds it)."""
    tmp = tmp_path_factory.mktemp("running_all")
    return _build(tmp, "fan", None)


# ---------------------------------------------------------------- the build
def test_nothing_is_learned_from_the_nights(fan, fan_all):
    res, unit = fan
    _, every = fan_all
    lo, hi = unit.file.tests[unit.tests.index("DP")].limits
    lo0, hi0 = every.file.tests[every.tests.index("DP")].limits
    # the loop's band: the running loop's (a few % of 0 … 500 Pa), not the nights' 0 Pa
    # against a 250 Pa set-point
    assert hi - lo < (hi0 - lo0) / 5, ((lo, hi), (lo0, hi0))
    assert hi - lo < 10.0, (lo, hi)
    rc = unit.file.running
    assert (rc.tag, rc.run, rc.stop) == ("FAN_RUN", 1.0, 0.0)
    # 10 weekdays of 13 h in 12 days
    assert rc.share == pytest.approx(10 * 13 / (12 * 24), abs=0.01)
    said = [n for n in res.notes if n.startswith("FAN_RUN: the run condition")]
    assert said and "ran on 45.1% of the window's samples (1560 of 3456)" in said[0], res.notes
    # the run feedback is no test, no model input, no state of [states]
    assert not any("FAN_RUN" in t for m in unit.models.values() for t in m.tags)
    assert "FAN_RUN" not in (unit.file.states or {}).get("tags", [])
    assert "FAN_RUN" in unit.tags  # but the unit reads it


def test_the_start_is_a_state_change_its_settle_bounded_by_the_running_window(fan):
    res, unit = fan
    said = [n for n in res.notes if n.startswith("state_settle_max_s")]
    assert said, res.notes
    bound = unit.file.evaluation["state_settle_max_s"]
    assert 0 < bound < 13 * 3600  # shorter than a working day


# ---------------------------------------------------------------- judging
@pytest.mark.parametrize("seed", [7, 8])
def test_fault_free_nights_are_not_running_never_an_alarm(fan, seed):
    _, unit = fan
    f = _judged(seed)
    d = unit.reset().evaluate(f)
    stopped = f["FAN_RUN"].to_numpy() == 0
    assert stopped.mean() > 0.5
    assert (d.status.to_numpy()[stopped] == NE107.CHECK_FUNCTION).all()
    assert (d.why.to_numpy()[stopped] == WHY).all()
    assert (d.faults.to_numpy()[stopped] == "").all()
    assert np.isnan(d.detected.to_numpy()[stopped]).all()
    assert (d.top["top1"].to_numpy()[stopped] == "").all()
    # by day, fault-free: at most 2 % FAILURE
    fail = d.status.to_numpy()[~stopped] == NE107.FAILURE
    assert fail.mean() < 0.02, fail.mean()


def test_a_stopped_sample_is_said_at_the_value_its_run_tag_holds(fan):
    """The why named the stop value (``FAN_RUN = 0``) whatever the run tag held: a fan locked
    out for maintenance (its feedback 2, nearer the stop than the run) is said at 2; an analog
    run tag's many values keep the stop value (one text, not one per value)."""
    _, unit = fan
    f = _judged(7)
    run = f["FAN_RUN"].to_numpy().copy()
    stopped = run == 0
    night = np.flatnonzero(stopped)[: stopped.sum() // 3]
    run[night] = -1.0  # locked out: stopped, nearer 0 than 1
    d = unit.reset().evaluate(f.assign(FAN_RUN=run))
    why = d.why.to_numpy()
    assert (d.status.to_numpy()[stopped] == NE107.CHECK_FUNCTION).all()
    assert (why[night] == "not running (FAN_RUN = -1): judged only while it runs").all()
    rest = np.setdiff1d(np.flatnonzero(stopped), night)
    assert (why[rest] == WHY).all()
    rng = np.random.default_rng(0)
    analog = np.where(stopped, rng.uniform(-0.3, 0.3, len(run)), 1.0)  # a current near 0
    d = unit.reset().evaluate(f.assign(FAN_RUN=analog))
    assert (d.why.to_numpy()[stopped] == WHY).all()


@pytest.mark.parametrize("seed", [7, 8])
@pytest.mark.parametrize(
    ("fault", "named"), [("belt_slip", {"FAN_SPD", "DP"}), ("flow_bias", {"FLOW"})]
)
def test_a_fault_by_day_is_detected_and_named(fan, seed, fault, named):
    _, unit = fan
    f = _judged(seed, fault)
    d = unit.reset().evaluate(f)
    runs = f["FAN_RUN"].to_numpy() == 1
    after = np.arange(len(f)) >= WEEK
    fail = d.status.to_numpy() == NE107.FAILURE
    assert fail[after & runs].mean() > 0.5, fail[after & runs].mean()
    assert not fail[~runs].any()
    top = pd.Series(d.top["top1"].to_numpy()[after & fail])
    # the right tag named first on most alarm samples (the flow meter's bias: FLOW 73 %,
    # the fan speed's test, which reads FLOW, the rest)
    assert top.value_counts().index[0] in named, top.value_counts()
    assert top.isin(named).mean() > 0.6, top.value_counts()


def test_an_alarm_is_not_carried_across_a_stop(fan):
    """The flow meter's bias from 14:00 until a 10 min stop at 17:00, none after it (the
    morning's start settled): the unit's off-delay holds the alarm without the stop; across
    it, nothing is carried."""
    _, unit = fan
    f = _judged(7).copy()
    day = f.index.normalize() == pd.Timestamp("2026-03-17", tz="UTC")
    hour = f.index.hour + f.index.minute / 60
    f.loc[day & (hour >= 14) & (hour < 17), "FLOW"] += 0.6
    stop = day & (hour >= 17) & (hour < 17 + 10 / 60)
    f.loc[stop, ["FAN_RUN", "DP", "FAN_SPD", "VAV", "FLOW", "FAN_KW"]] = 0.0
    d = unit.reset().evaluate(f)
    at = np.flatnonzero(stop)
    assert d.status.iloc[at[0] - 1] == NE107.FAILURE  # in alarm up to the stop
    assert (d.status.iloc[at] == NE107.CHECK_FUNCTION).all()
    after = d.status.iloc[at[-1] + 1 : at[-1] + 1 + unit.ev["off_delay"] + 3]
    assert (after != NE107.FAILURE).all(), after
    # the same stretch without the stop: the alarm held by the off-delay after the bias
    g = _judged(7).copy()
    g.loc[day & (hour >= 14) & (hour < 17), "FLOW"] += 0.6
    held = unit.reset().evaluate(g).status.iloc[at[0]]
    assert held == NE107.FAILURE


def same_in_pieces(unit: Unit, f: pd.DataFrame, step: int):
    """``unit``'s replay of ``f`` whole, checked equal to its replay in pieces of ``step``
    samples, each from the state the last one saved (JSON); the whole one returned."""
    whole = unit.reset().evaluate(f)
    unit.reset()
    parts = []
    for a in range(0, len(f), step):
        state = json.loads(json.dumps(unit.to_state()))
        parts.append(unit.load_state(state).evaluate(f.iloc[a : a + step]))
    pd.testing.assert_frame_equal(whole.to_frame(), concat(parts).to_frame())
    return whole


def test_pieces_a_restart_and_the_live_plant_say_the_same(fan):
    """Through stops and starts: the replay whole, in pieces from a saved state (cut in the
    night and by day), and the plant cycle by cycle with a restart at night."""
    _, unit = fan
    f = _judged(8, "flow_bias").iloc[WEEK - 400 : WEEK + 500]
    whole = same_in_pieces(unit, f, 137)
    plant = Plant({"fan": unit.reset()}, {})
    got = []
    night = int(np.flatnonzero(f["FAN_RUN"].to_numpy() == 0)[50])
    for k, (ts, row) in enumerate(f.iterrows()):
        if k == night:
            state = json.loads(json.dumps(plant.to_state()))
            plant = Plant({"fan": Unit.load(unit.file.path, unit.file.path.parent)}, {})
            plant.load_state(state)
        got.append(plant.cycle(ts, row.to_dict())[0])
    assert [int(s.status) for s in got] == whole.status.astype(int).tolist()
    stopped = f["FAN_RUN"].to_numpy() == 0
    assert all(s.message.startswith(WHY) for s, x in zip(got, stopped, strict=True) if x)


# ---------------------------------------------------------------- declaration errors
@pytest.mark.parametrize(
    ("running", "says"),
    [
        (Running("NOPE", None, "--running NOPE"), "--running NOPE: run condition NOPE (running) "
         "is not in the data"),
        (Running("DP", None, "tags.csv:3"), "tags.csv:3: run condition DP (running) is a tag "
         "of loop DP=DP_SP:FAN_SPD"),
        (Running("VAV", None, "--running VAV"), "--running VAV: run condition VAV (running) is "
         "not a state over the window"),
        (Running("FAN_RUN", 5.0, "--running FAN_RUN=5"), "--running FAN_RUN=5: run condition "
         "FAN_RUN (running) is 0 or 1 over the window, never 5"),
    ],
)  # fmt: skip
def test_a_bad_run_condition_names_the_tag_and_where(tmp_path, running, says):
    build_refused(tmp_path, fanplant.simulate(3, 1), "5min", says, running=running,
                  loops=[Loop("DP", "DP_SP", "FAN_SPD")])  # fmt: skip


def build_refused(tmp_path, frame: pd.DataFrame, period: str, says: str, **kw) -> None:
    """``build_unit`` of ``frame`` refused with a message starting ``says``, nothing written."""
    with pytest.raises(UserError) as exc:
        build_unit("x", frame, folder=tmp_path, period=period, **kw)
    assert str(exc.value).startswith(says), str(exc.value)
    assert not any(tmp_path.iterdir())


# ---------------------------------------------------------------- the CLI
@pytest.fixture(scope="module")
def cli(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("running_cli")
    g = ["--db", f"sqlite:///{tmp / 'h.db'}", "--rulebases", str(tmp / "rb")]
    tags = tmp / "tags.csv"
    fanplant.tags_csv().to_csv(tags, index=False)
    frame = fanplant.simulate(12, 2)
    import_csv(g, frame, tmp / "train.csv", tags=tags)
    judged = _judged(9, "flow_bias")
    import_csv(g, judged, tmp / "judged.csv")
    t0, t1 = frame.index[0], frame.index[-1] + pd.Timedelta("5min")
    rc, text = diag(g, "unit", "build", "fan", "--from", fmt(t0), "--to", fmt(t1),
                    "--loops-from", str(tags), "--far", "0.01")  # fmt: skip
    assert rc == 0, text
    return g, tmp, text, judged


def test_the_cli_reads_the_role_running_and_diagnose_says_not_running(cli):
    g, tmp, text, judged = cli
    assert "FAN_RUN: the run condition (declared: judged only while FAN_RUN = 1)" in text, text
    a, b = judged.index[0], judged.index[-1] + pd.Timedelta("5min")
    csv = tmp / "d.csv"
    rc, out = diag(g, "diagnose", "fan", "--from", fmt(a), "--to", fmt(b), "--csv", str(csv))
    assert rc == 0, out
    d = pd.read_csv(csv, index_col="ts", parse_dates=True, low_memory=False)
    stopped = judged["FAN_RUN"].to_numpy() == 0
    assert len(d) == len(judged)
    assert (d["status"].to_numpy()[stopped] == NE107.CHECK_FUNCTION).all()
    assert (d["why"].to_numpy()[stopped] == WHY).all()
    after = (np.arange(len(d)) >= WEEK) & ~stopped
    fail = d["status"].to_numpy() == NE107.FAILURE
    assert fail[after].mean() > 0.5 and not fail[stopped].any()
    assert (d["top1"].to_numpy()[after & fail] == "FLOW").mean() > 0.6


def test_the_cli_refuses_a_run_condition_in_a_loop_as_file_line(cli, tmp_path):
    g, tmp, _, _ = cli
    bad = fanplant.tags_csv()
    bad.loc[bad["name"] == "FAN_SPD", "role"] = "running"  # in loop dsp
    bad.to_csv(tmp_path / "bad.csv", index=False)
    rc, text = diag(g, "unit", "build", "fan2", "--from", "2026-03-02T00:00:00", "--to",
                    "2026-03-10T00:00:00", "--loops-from", str(tmp_path / "bad.csv"))  # fmt: skip
    assert rc == 2, text
    says = "FAN_SPD is a run condition (role running) and in loop dsp"
    assert f"{tmp_path / 'bad.csv'}:5: {says}" in text, text


def test_accept_learns_only_the_running_rows(cli):
    g, tmp, _, judged = cli
    a = judged.index[0]
    b = a + pd.Timedelta(days=5)  # Monday … Friday of the first (fault-free) week
    rc, text = diag(g, "unit", "accept", "fan", "--from", fmt(a), "--to", fmt(b), "--json")
    assert rc == 0, text
    doc = json.loads(text)
    w = judged.loc[(judged.index >= a) & (judged.index < b)]
    ran = int((w["FAN_RUN"] == 1).sum())
    assert 0 < max(doc["samples"].values()) <= ran, (doc["samples"], ran, len(w))
