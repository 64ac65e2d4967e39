"""A run condition per piece of equipment (issue 34, item 5: a stop is not a blackout;
docs/how-to/unit-loops.md, "A piece of equipment that stops").

The two chillers of :mod:`tests.twinplant` (B staged on by day only) built on 10 days
(seed 1) with and without B declared (``--running 'B:B_RUN:B_T,B_CAP,B_KW'``), judged on
seeds never used to build (7, 8, 9), B stopped for two days of maintenance: B's tests learn
from the rows where it runs (its loop's band narrower), are off while it is stopped (no
symptom, not unknown, the why says so), and the unit goes on judging chiller A: A's sensor
bias during B's maintenance is an alarm named on A. The replay in pieces from a saved state
and the live plant say the same; the CLI writes and reads ``[equipment]``.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pandas as pd
import pytest
import tomlkit

from diag_plugin.diagnose.plant import Plant
from diag_plugin.diagnose.unit import Unit
from diag_plugin.status import NE107
from diag_plugin.unitbuild.build import build_unit
from diag_plugin.unitbuild.loops import Loop, parse_running
from historian.errors import UserError
from tests import twinplant
from tests.test_any_plant_tour import diag, fmt, import_csv
from tests.test_unit_running import build_refused, same_in_pieces

LOOPS = [Loop("A_T", "A_SP", "A_CAP"), Loop("B_T", "B_SP", "B_CAP")]
B = "B:B_RUN:B_T,B_CAP,B_KW"
DAY = 1440


def _build(tmp, equipment):
    frame = twinplant.simulate(10, 1)
    res = build_unit("chw", frame, folder=tmp, period="1min", far=0.01, loops=LOOPS,
                     disturbances=["LOAD"], equipment=equipment)  # fmt: skip
    return res, Unit.load(res.path, tmp)


@pytest.fixture(scope="module")
def declared(tmp_path_factory):
    return _build(tmp_path_factory.mktemp("equipment"), [parse_running(B)])


@pytest.fixture(scope="module")
def undeclared(tmp_path_factory):
    return _build(tmp_path_factory.mktemp("equipment_none"), [])


def _maintenance(seed: int, fault: str | None = None) -> pd.DataFrame:
    """4 days, B stopped on days 1 and 2; a fault from day 2 (B still stopped)."""
    return twinplant.simulate(4, seed, fault, onset_days=2.0, stop_days=(1.0, 3.0))


def _band(unit: Unit, test: str) -> float:
    t = next(t for t in unit.file.tests if t.name == test)
    return t.high - t.low


# ---------------------------------------------------------------- the build
def test_the_equipment_s_tests_learn_where_it_runs(declared, undeclared):
    res, unit = declared
    (eq,) = unit.file.equipment
    assert (eq.name, eq.rc.tag, eq.rc.run, eq.rc.stop) == ("B", "B_RUN", 1.0, 0.0)
    assert eq.tags == ("B_T", "B_CAP", "B_KW")
    assert 0.4 < eq.rc.share < 0.6
    assert any(n.startswith("B: runs while B_RUN = 1") for n in res.notes), res.notes
    # B's loop band without the nights' plant-room water: far narrower than built on all rows
    assert _band(unit, "B_T") < 0.5 * _band(undeclared[1], "B_T"), (
        _band(unit, "B_T"), _band(undeclared[1], "B_T"))  # fmt: skip
    # A's tests learned from every row: the same inputs as without the declaration
    for t in ("A_T", "A_CAP", "A_KW"):
        assert unit.models[t].inputs == undeclared[1].models[t].inputs


# ---------------------------------------------------------------- judging
@pytest.mark.parametrize("seed", [7, 8])
def test_a_stopped_equipment_s_tests_are_off_and_the_unit_judges_the_rest(declared, seed):
    unit = declared[1]
    f = _maintenance(seed)
    stopped = f["B_RUN"].to_numpy() == 0
    d = unit.reset().evaluate(f)
    b_tests = [t for t in unit.tests if t.startswith("B_")]
    assert np.isnan(d.symptoms[b_tests].to_numpy()[stopped]).all()
    why = d.why.to_numpy()
    assert all(w.startswith("B stopped (B_RUN = 0): tests B_T, B_CAP") for w in why[stopped])
    assert not any("B stopped" in w for w in why[~stopped])
    # the unit judges the rest where B is stopped: rarely CHECK_FUNCTION (a unit-wide run
    # condition: all of it), never an alarm named on B's tags
    status = d.status.to_numpy()
    # (A alone by day at the full load is new to A's tests: their guards may say so)
    cf = (status[stopped] == NE107.CHECK_FUNCTION).mean()
    assert cf < 0.5, pd.Series(status[stopped]).value_counts()
    assert not d.top["top1"].to_numpy()[stopped].astype(str).tolist().count("B_T")
    # its nights (A alone as it was built on): NORMAL
    night = stopped & ~((np.arange(len(f)) >= DAY) & (np.arange(len(f)) < 3 * DAY))
    assert (status[night] == NE107.NORMAL).mean() > 0.95, pd.Series(status[night]).value_counts()
    # per sample B's state: stopped, settling after its starts (its tests off), running
    state = d.equipment["B"].to_numpy()
    assert ((state == 1) == stopped).all()
    assert ((state == 2) & stopped).sum() == 0 and (state == 2).sum() > 0


@pytest.mark.parametrize("seed", [8, 9])
def test_a_fault_of_the_running_chiller_is_found_while_the_other_is_stopped(declared, seed):
    _, unit = declared
    f = _maintenance(seed, "a_bias")
    d = unit.reset().evaluate(f)
    at = (np.arange(len(f)) >= 2 * DAY) & (f["B_RUN"].to_numpy() == 0)
    fail = d.status.to_numpy()[at] == NE107.FAILURE
    assert fail.mean() > 0.5, fail.mean()
    top = pd.Series(d.top["top1"].to_numpy()[at][fail])
    assert top.str.startswith("A_").mean() > 0.8, top.value_counts()


def test_pieces_a_restart_and_the_live_plant_say_the_same(declared):
    _, unit = declared
    f = _maintenance(9, "a_bias").iloc[DAY - 300 : DAY + 400]
    whole = same_in_pieces(unit, f, 157)
    plant = Plant({"chw": unit.reset()}, {})
    got = [plant.cycle(ts, row.to_dict())[0] for ts, row in f.iterrows()]
    assert [int(s.status) for s in got] == whole.status.astype(int).tolist()


# ---------------------------------------------------------------- declaration errors
@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("B:NOPE:B_T", "--running B:NOPE:B_T: NOPE not in the data"),
        ("B:B_RUN:B_T,NOPE", "--running B:B_RUN:B_T,NOPE: NOPE not in the data"),
        ("B:A_SP:B_T", "--running B:A_SP:B_T: run condition A_SP of B is not two-valued"),
        ("B:B_RUN=5:B_T", "--running B:B_RUN=5:B_T: run condition B_RUN of B is 0 or 1 over "
         "the window, never 5"),
    ],
)  # fmt: skip
def test_a_bad_equipment_names_the_tag_and_where(tmp_path, text, says):
    build_refused(tmp_path, twinplant.simulate(1, 1), "1min", says, loops=LOOPS,
                  equipment=[parse_running(text)])  # fmt: skip


def test_the_syntax_names_the_equipment_its_tags_and_the_value():
    r = parse_running("CH2:Chlr2 Status=1:CH2_LWT, Chlr2 Cap%,CH2 Power")
    assert (r.name, r.tag, r.value) == ("CH2", "Chlr2 Status", 1.0)
    assert r.tags == ("CH2_LWT", "Chlr2 Cap%", "CH2 Power")
    assert parse_running("B_RUN:B_T").name == "B_RUN"  # no name: the run tag's
    with pytest.raises(UserError, match="cannot be one of the equipment's tags"):
        parse_running("B:B_RUN:B_T,B_RUN")


# ---------------------------------------------------------------- the CLI
def test_the_cli_writes_the_equipment_and_diagnose_says_it_stopped(tmp_path):
    g = ["--db", f"sqlite:///{tmp_path / 'h.db'}", "--rulebases", str(tmp_path / "rb")]
    frame = twinplant.simulate(6, 3)
    import_csv(g, frame, tmp_path / "train.csv")
    t0, t1 = frame.index[0], frame.index[-1] + pd.Timedelta("1min")
    rc, text = diag(g, "unit", "build", "chw", "--from", fmt(t0), "--to", fmt(t1), "--loop",
                    "B_T=B_SP:B_CAP", "--running", B, "--far", "0.01")  # fmt: skip
    assert rc == 0, text
    assert "B: runs while B_RUN = 1" in text, text
    unit = Unit.load(tmp_path / "rb" / "chw.unit.toml", tmp_path / "rb")
    assert [e.name for e in unit.file.equipment] == ["B"]
    judged = twinplant.simulate(4, 8, stop_days=(1.0, 3.0), start="2026-06-08")
    import_csv(g, judged, tmp_path / "judged.csv")
    a, b = judged.index[0], judged.index[-1] + pd.Timedelta("1min")
    csv = tmp_path / "d.csv"
    rc, out = diag(g, "diagnose", "chw", "--from", fmt(a), "--to", fmt(b), "--csv", str(csv))
    assert rc == 0, out
    d = pd.read_csv(csv, low_memory=False)
    stopped = judged["B_RUN"].to_numpy() == 0
    why = d["why"].fillna("").astype(str).to_numpy()
    assert all(w.startswith("B stopped (B_RUN = 0)") for w in why[stopped])
    assert (d["status"].to_numpy()[stopped] == NE107.CHECK_FUNCTION).mean() < 0.5
    # the summaries count B's stopped samples on their own (H4), not as unknown
    rc, out = diag(g, "diagnose", "chw", "--from", fmt(a), "--to", fmt(b), "--json")
    assert rc == 0, out
    off = json.loads(out)["equipment_off"]["B"]
    assert off["stopped"] == stopped.sum() and off["stopped_share"] == round(stopped.mean(), 6)
    assert 0 < off["settling"] < (~stopped).sum(), off
    rc, out = diag(g, "diagnose", "chw", "--from", fmt(a), "--to", fmt(b))
    assert f"off: B stopped on {stopped.sum():,} samples" in out, out
    rc, out = diag(g, "unit", "show", "chw", "--json")
    learned = {t["test"]: t["learned"] for t in json.loads(out)["tests"]}
    share = unit.file.equipment[0].rc.share
    for t in ("B_T", "B_CAP", "B_KW"):  # learned over 6 days B was stopped half of
        assert learned[t]["unknown"] < 0.02 and learned[t]["off"] == round(1 - share, 5), (
            learned[t])  # fmt: skip
        assert learned[t]["off_equipment"] == "B"
    assert "off" not in learned["A_T"] and learned["A_T"]["unknown"] < 0.02
    (piece,) = json.loads(out)["equipment"]
    assert (piece["name"], piece["tag"], piece["tags"]) == ("B", "B_RUN", ["B_T", "B_CAP", "B_KW"])
    assert set(piece["tests"]) == {"B_T", "B_CAP", "B_KW", "B_T_spread"}
    rc, out = diag(g, "unit", "show", "chw")
    out = " ".join(out.split())  # rich wraps at the console's width (a worker's path is longer)
    assert rc == 0 and "B_T: " in out and "off: B stopped 50.0% (its tests off, not unknown)" in out
    assert "equipment B: runs while B_RUN = 1 (50.0% of the build window); tests " in out, out
    # accepting two days B was stopped on (one a maintenance day): B's tests learn B's
    # running rows only, the others every row
    c = a + pd.Timedelta(days=2)
    rc, text = diag(g, "unit", "accept", "chw", "--from", fmt(a), "--to", fmt(c), "--json")
    assert rc == 0, text
    samples = json.loads(text)["samples"]
    w = judged.loc[judged.index < c, "B_RUN"].to_numpy()
    assert 0 < samples["B_T"] <= (w == 1).sum() < samples["A_T"], (samples, (w == 1).sum())
    # a day B never ran (its maintenance): B's models keep what they learned, said so
    rc, text = diag(g, "unit", "accept", "chw", "--from", fmt(c), "--to",
                    fmt(c + pd.Timedelta(days=1)), "--json")  # fmt: skip
    assert rc == 0, text
    doc = json.loads(text)
    assert "B_T" not in doc["samples"] and doc["samples"]["A_T"] > 0, doc["samples"]
    assert any(n.startswith("B_T: its equipment did not run") for n in doc["warnings"]), doc


# ---------------------------------------------------------------- the stages (H4)
def _sample_arrays(obj, n: int, depth: int = 0) -> list:
    """The arrays of ``n`` rows ``obj``'s attributes hold (in tuples, lists, dicts too)."""
    if isinstance(obj, np.ndarray):
        return [obj.shape] if obj.ndim and obj.shape[0] == n else []
    if depth > 2:
        return []
    if isinstance(obj, (tuple, list)):
        items = obj
    elif isinstance(obj, dict):
        items = list(obj.values())
    else:
        return []
    return [s for x in items for s in _sample_arrays(x, n, depth + 1)]


def test_the_stopped_mask_goes_with_the_residuals_not_through_the_unit(declared):
    """The stopped pieces' mask is returned with the residuals it blanks, not left on the
    unit for the next stage: after an evaluate no attribute of the unit holds an array of
    the frame's samples, and the residuals of a frame say where B's tests were off."""
    unit = declared[1]
    f = _maintenance(7).iloc[600:1300]  # 10:00 to 21:40: B stops at 19:00
    n = len(f)
    unit.reset().evaluate(f)
    left = {k: _sample_arrays(v, n) for k, v in vars(unit).items()}
    assert not {k: v for k, v in left.items() if v}, left
    r = unit.reset().raw_residuals(f)
    stopped = f["B_RUN"].to_numpy() == 0
    b = [t for t in unit.tests if t.startswith("B_")]
    assert np.isnan(r[b].to_numpy()[stopped]).all()
    assert 0 < stopped.sum() < n and np.isfinite(r[b].to_numpy()[~stopped]).all(axis=0).any()


def _lags(specs: list[str], tag: str) -> set[int]:
    """The lags at which a model's input specs read ``tag`` (``TAG[k-3]``: 3)."""
    got = (re.fullmatch(r'"?([^"\[]+)"?\[k(?:-(\d+))?\]', s.strip()) for s in specs)
    return {int(m[2] or 0) for m in got if m and m[1] == tag}


def test_a_stopped_piece_s_rows_are_left_out_of_its_unknown_counts(declared):
    """The learning's unknown counts of a piece's test are taken on its running rows (issue
    34 review, H4 item 1): a NaN of a unit-wide input (LOAD) on B's stopped rows counts
    nowhere, one on its running rows is missing exactly on the rows whose design reads it;
    the counts do not rest on every stopped row having been counted missing once. (A
    refactor: main's subtraction gave the same counts here.)"""
    from diag_plugin.learn.thresholds import test_residuals

    unit = declared[1]
    f = _maintenance(7)
    stopped = f["B_RUN"].to_numpy() == 0
    base = test_residuals(unit, f, 5, True)
    g = f.copy()
    load = g.columns.get_loc("LOAD")
    off_rows = np.flatnonzero(stopped)[100::37]
    g.iloc[off_rows, load] = np.nan
    got = test_residuals(unit, g, 5, True)
    # running rows by day, well inside B's runs, 50 samples apart
    on_rows = np.flatnonzero(~stopped)[600:700:50]
    h = g.copy()
    h.iloc[on_rows, load] = np.nan
    more = test_residuals(unit, h, 5, True)
    for t in unit.tests:
        if got[t].piece != "B":
            continue
        assert got[t].unknown["missing"] == base[t].unknown["missing"], t
        lags = _lags(unit.models[t].inputs, "LOAD")
        hit = {int(i) + k for i in on_rows for k in lags}
        assert more[t].unknown["missing"] == base[t].unknown["missing"] + len(hit), (t, lags)


# ---------------------------------------------------------------- a tags CSV declares it (H4)
#: the twin plant's tags CSV: chiller B's loop, and B by its 'equipment' column
TAGS = """name,loop,role,equipment
LOAD,,disturbance,
B_RUN,,running,B
A_T,LA,pv,
A_SP,LA,sp,
A_CAP,LA,out,
B_T,LB,pv,B
B_SP,LB,sp,
B_CAP,LB,out,B
A_KW,,,
B_KW,,,B
"""


def test_a_tags_csv_declares_the_equipment_as_the_flag_does(tmp_path):
    g = ["--db", f"sqlite:///{tmp_path / 'h.db'}", "--rulebases", str(tmp_path / "rb")]
    frame = twinplant.simulate(3, 3)
    tags = tmp_path / "tags.csv"
    tags.write_text(TAGS)
    import_csv(g, frame, tmp_path / "train.csv", tags=tags)
    t0, t1 = frame.index[0], frame.index[-1] + pd.Timedelta("1min")
    rc, text = diag(g, "unit", "build", "chw", "--from", fmt(t0), "--to", fmt(t1),
                    "--loops-from", str(tags), "--far", "0.01")  # fmt: skip
    assert rc == 0, text
    assert "B: runs while B_RUN = 1" in text, text
    unit = Unit.load(tmp_path / "rb" / "chw.unit.toml", tmp_path / "rb")
    (eq,) = unit.file.equipment
    assert (eq.name, eq.rc.tag, eq.rc.run, eq.tags) == ("B", "B_RUN", 1.0, ("B_T", "B_CAP", "B_KW"))
    assert unit.file.running is None  # B's run tag is B's, not the unit's
    # a tag the data lacks: named at its own line
    (tmp_path / "bad.csv").write_text(TAGS.replace("B_KW,,,B", "B_KWH,,,B"))
    rc, text = diag(g, "unit", "build", "x", "--from", fmt(t0), "--to", fmt(t1),
                    "--loops-from", str(tmp_path / "bad.csv"))  # fmt: skip
    assert rc == 2 and f"{tmp_path / 'bad.csv'}:11: B_KWH not in the data" in text, text


@pytest.mark.parametrize(
    ("edits", "says"),
    [
        ([("B_RUN,,running,B", "B_RUN,,,")], ":7: equipment B has no run tag (a row of role"),
        ([("A_KW,,,", "A_KW,,running,B")], ":10: equipment B has two run tags (B_RUN on line 3, "
         "A_KW)"),
        ([("A_KW,,,", "B_KW,,,A")], ":11: B_KW in equipment B and in A (line 10)"),
        ([("B_T,LB,pv,B", "B_T,LB,pv,"), ("B_CAP,LB,out,B", "B_CAP,LB,out,"),
          ("B_KW,,,B", "B_KW,,,")], ":3: equipment B has no tag but its run tag B_RUN"),
    ],
)  # fmt: skip
def test_a_tags_csv_s_bad_equipment_is_refused_at_its_line(tmp_path, edits, says):
    from diag_plugin.unitbuild.loops import equipment_from_tags_csv

    text = TAGS
    for a, b in edits:
        text = text.replace(a, b)
    p = tmp_path / "tags.csv"
    p.write_text(text)
    with pytest.raises(UserError) as exc:
        equipment_from_tags_csv(p)
    assert str(exc.value).startswith(f"{p}{says}"), str(exc.value)


# ---------------------------------------------------------------- a run tag the models read (H4)
@pytest.fixture(scope="module")
def read_run_tag(tmp_path_factory):
    """The plant without B's valve and power: chiller A's power model reads B_RUN (its share
    of the load), a ``[build] states`` tag the settle guard would watch."""
    tmp = tmp_path_factory.mktemp("equipment_states")
    frame = twinplant.simulate(10, 1).drop(columns=["B_KW", "B_CAP"])
    res = build_unit("chw", frame, folder=tmp, period="1min", far=0.01, loops=LOOPS[:1],
                     disturbances=["LOAD"], equipment=[parse_running("B:B_RUN:B_T")])  # fmt: skip
    return Unit.load(res.path, tmp)


@pytest.mark.parametrize("seed", [8, 9])
def test_a_piece_s_start_holds_its_own_tests_not_the_unit(read_run_tag, seed):
    """A's sensor bias from 10 min after B's start: B's start settles B's tests only (off
    for state_settle_max_s), A's alarm is raised at once, not CHECK_FUNCTION 'settling
    after a state change' for the unit."""
    unit = read_run_tag
    assert "B_RUN" in unit.file.build["states"] and any(
        "B_RUN" in i for t in unit.tests for i in unit.models[t].inputs)  # fmt: skip
    hold = unit.equipment_hold
    assert hold == round(unit.ev["state_settle_max_s"] / 60) > 30
    onset = 1 + (7 * 60 + 10) / 1440  # day 1, 07:10 (B started at 07:00)
    f = twinplant.simulate(2, seed, "a_bias", onset_days=onset)
    d = unit.reset().evaluate(f)
    start = DAY + 7 * 60
    after = slice(start, start + hold)
    status = d.status.to_numpy()[after]
    why = d.why.to_numpy()[after].astype(str)
    assert not any("settling after a state change" in w for w in why), set(why)
    # (the bias shows in A's valve against its power, intermittently on this unit: on main
    # about half of the hold was CHECK_FUNCTION for the unit and not one sample FAILURE)
    fail = status == NE107.FAILURE
    assert fail.sum() >= 10, pd.Series(status).value_counts()
    # while B settles (at most its own bound) only A is named; B's test is off, its state
    # says so (after B's settle, B_T, whose model reads A_T, may see A's bias too)
    settle = d.equipment["B"].to_numpy()[after] == 2
    assert settle[:10].all() and settle.sum() <= unit.equipment_holds[0] < hold
    faults = d.faults.to_numpy()[after]
    assert all(x.startswith("A_") for x in faults[fail & settle]), faults[fail & settle]
    assert np.isnan(d.symptoms["B_T"].to_numpy()[after][settle]).all()


# ---------------------------------------------------------------- a piece's settle (H8)
def _settles(eq: np.ndarray) -> list[tuple[int, int]]:
    """(first sample, length) of each settle (state 2) in a piece's states."""
    on = np.r_[False, eq == 2, False].astype(np.int8)
    a, b = np.flatnonzero(np.diff(on) == 1), np.flatnonzero(np.diff(on) == -1)
    return list(zip(a.tolist(), (b - a).tolist(), strict=True))


def test_the_build_measures_the_piece_s_own_bound(declared):
    """``[equipment.B] settle_max_s`` from B's own starts on B's own tests (the 90 %
    quantile of their settling times plus the quiet time), said in a build note; shorter on
    the twin plant than the unit-wide bound B's start was held for (120 min)."""
    res, unit = declared
    (e,) = unit.equipment
    note = next(n for n in res.notes if n.startswith("[equipment.B] settle_max_s"))
    assert f"= {e.settle_max_s:.0f} s" in note and "B start(s)" in note, note
    assert unit.equipment_holds == [round(e.settle_max_s / 60)]
    assert 0 < unit.equipment_holds[0] < unit.equipment_hold
    assert "settle_max_s" in unit.file.doc["equipment"]["B"]


def test_a_piece_s_settle_ends_when_its_tests_are_quiet(declared, tmp_path):
    """An old file (no ``settle_max_s`` in ``[equipment.B]``) keeps the unit-wide bound, and
    B's start holds B's tests only until none of them has been on for the quiet time: each
    fault-free start's settle ends before that bound, on the sample the quiet time
    completes; the same whole, in pieces cut inside the settle from a saved state, and
    after a restart of the live plant."""
    _, built = declared
    doc = tomlkit.parse(built.file.path.read_text(encoding="utf-8"))
    del doc["equipment"]["B"]["settle_max_s"]
    old = tmp_path / built.file.path.name
    old.write_text(tomlkit.dumps(doc), encoding="utf-8")
    for p in built.file.path.parent.glob("chw_*.toml"):  # the models beside it
        (tmp_path / p.name).write_text(p.read_text(encoding="utf-8"), encoding="utf-8")
    unit = Unit.load(old, tmp_path)
    assert unit.equipment[0].settle_max_s is None
    hold = unit.equipment_hold
    assert unit.equipment_holds == [hold]
    f = twinplant.simulate(2, 8).iloc[DAY + 7 * 60 - 200 : DAY + 7 * 60 + hold + 200]
    whole = same_in_pieces(unit, f, 37)  # cut inside the settle, from a saved state
    (start, n), = _settles(whole.equipment["B"].to_numpy())  # fmt: skip
    assert start == 200 and 2 * unit._quiet_n() <= n < hold
    # B's tests off while it settles, judged (known, quiet) from the next sample
    sym = whole.symptoms.to_numpy()[:, unit.equipment_tests[0]]
    assert np.isnan(sym[start : start + n]).all() and (sym[start + n] == 0).all()
    plant = Plant({"chw": unit.reset()}, {})
    got = []
    for k, (ts, row) in enumerate(f.iterrows()):
        if k == start + n // 2:  # a restart inside the settle
            state = json.loads(json.dumps(plant.to_state()))
            plant = Plant({"chw": Unit.load(old, tmp_path)}, {})
            plant.load_state(state)
        got.append(plant.cycle(ts, row.to_dict())[0])
    assert [int(s.status) for s in got] == whole.status.astype(int).tolist()


@pytest.mark.parametrize("seed", [8, 9])
def test_a_fault_of_the_piece_after_its_start_is_raised_when_it_has_settled(declared, seed):
    """B's leaving-water sensor reads +1 K from 90 min after B's start: its own settle has
    ended (quiet, or its own bound), so the bias is FAILURE named on B within minutes (on
    main B's tests were held for the unit-wide 120 min: 35 min after the onset)."""
    _, unit = declared
    onset = DAY + 8 * 60 + 30
    f = twinplant.simulate(2, seed, "b_bias", onset_days=onset / DAY)
    d = unit.reset().evaluate(f)
    fail = np.flatnonzero(d.status.to_numpy()[onset:] == NE107.FAILURE)
    assert fail.size and fail[0] <= 15, fail[:5]
    assert d.faults.to_numpy()[onset + fail[0]].startswith("B_")
