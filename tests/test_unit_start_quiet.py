"""A production start's settle ends once its tests have been quiet for as long as the window's
own starts ever paused before a symptom came back (issue 34, items 5-6; unitbuild/loops.py
``start_quiet``; docs/how-to/unit-loops.md, "A start's settle ends on its own lulls").

The pasteuriser (benchmarks/acceptance/pasteuriser_sim.py, a tuning plant) at 10 s with
``--running MODE=1``: at each production start its tests come on 30 s after the start and stay
on, without a pause, until the start's transient is over (35 min); the settle then waited the
unit's quiet time (the longest history a test reads, its spread tests' 600 s window, plus the
filter's delay and the on-delay: 760 s) with no test on before it ended, 13 of every start's 44
min of CHECK_FUNCTION. Built here through the CLI on 4 days (seed 1), judged on a day of seed
104 (neither used elsewhere).
"""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import tomlkit

from diag_plugin.status import NE107
from tests.test_any_plant_tour import diag

SIM = Path(__file__).parents[1] / "benchmarks" / "acceptance" / "pasteuriser_sim.py"
LOOPS = ["BT_LEVEL=50:BT_INLET_VLV", "FEED_FLOW=FEED_FLOW_SP:FEED_VFD",
         "HEAT_OUT_TEMP=HEAT_OUT_SP:HW_TEMP_SP", "HW_TEMP=HW_TEMP_SP:STEAM_VLV",
         "COOL_OUT_TEMP=4:CHW_VLV"]  # fmt: skip


@pytest.fixture(scope="module")
def judged(tmp_path_factory):
    """The unit file and the diagnosis (``--csv``) of the judged day."""
    tmp = tmp_path_factory.mktemp("start_quiet")
    for name, seed, start, days in (("b.csv", 1, "2026-03-02T00:00:00", 4),
                                    ("r.csv", 104, "2026-03-07T00:00:00", 1)):  # fmt: skip
        subprocess.run([sys.executable, str(SIM), str(tmp / name), "--seed", str(seed),
                        "--start", start, "--days", str(days), "--period", "10"],
                       check=True, capture_output=True)  # fmt: skip
    subprocess.run([sys.executable, str(SIM), "x", "--tags-csv", str(tmp / "tags.csv")],
                   check=True)  # fmt: skip
    g = ["--db", f"sqlite:///{tmp / 'h.db'}", "--rulebases", str(tmp / "rb")]
    for name in ("b.csv", "r.csv"):
        rc, text = diag(g, "import", str(tmp / name), "--tags", str(tmp / "tags.csv"))
        assert rc == 0, text
    rc, text = diag(g, "unit", "build", "p", "--from", "2026-03-02T00:00:00Z", "--to",
                    "2026-03-06T00:00:00Z", "--far", "0.01", "--loops-from",
                    str(tmp / "tags.csv"), *(x for lp in LOOPS for x in ("--loop", lp)),
                    "--running", "MODE=1")  # fmt: skip
    assert rc == 0, text
    # the judged day with the envelope as built (test_the_envelope_as_built_...)
    rc, text = diag(g, "diagnose", "p", "--from", "2026-03-07T00:00:00Z", "--to",
                    "2026-03-08T00:00:00Z", "--csv", str(tmp / "built.csv"))  # fmt: skip
    assert rc == 0, text
    # the envelope's bounds raised a thousandfold (the file's own, as edited by hand): only
    # the quiet time ends a settle
    path = tmp / "rb" / "p.unit.toml"
    doc = tomlkit.parse(path.read_text(encoding="utf-8"))
    tests = doc["envelope"]["state"]["tests"]
    for name in list(tests):
        tests[name] = [1000.0 * float(v) for v in tests[name]]
    path.write_text(tomlkit.dumps(doc), encoding="utf-8")
    rc, text = diag(g, "diagnose", "p", "--from", "2026-03-07T00:00:00Z", "--to",
                    "2026-03-08T00:00:00Z", "--csv", str(tmp / "d.csv"))  # fmt: skip
    assert rc == 0, text
    d = pd.read_csv(tmp / "d.csv", low_memory=False)
    return tomllib.loads((tmp / "rb" / "p.unit.toml").read_text()), d, tmp


def test_the_build_learns_the_quiet_time_of_its_starts(judged):
    """``[envelope.state] quiet_s``, shorter than the unit's quiet time, and said."""
    doc, *_ = judged
    quiet_s = doc["envelope"]["state"]["quiet_s"]
    note = doc["build"]["envelope"][0]
    assert f"a settle ends {quiet_s:.0f} s without a symptom" in note, note
    unit_s = float(note.split("the unit's quiet time ")[1].split(" s")[0])
    assert 0 < quiet_s < unit_s / 4, (quiet_s, unit_s)


def test_a_start_s_settle_ends_soon_after_its_last_symptom(judged):
    """Each start's CHECK_FUNCTION ends within the unit's off-delay hold (240 s) and the learned
    quiet time of its last symptom (main: the unit's quiet time, 760 s, after it), and no
    FAILURE follows an end within that quiet time (a start's transient is not cut short)."""
    doc, d, _ = judged
    why = d["why"].fillna("").astype(str)
    held = why.str.contains("settling after a state change").to_numpy()
    held = held & (d["status"].to_numpy() == 2)
    cols = [c for c in d.columns if c.startswith("s_")]
    on = (d[cols].fillna(0).to_numpy() != 0).any(axis=1)
    ends = np.flatnonzero(held & ~np.r_[held[1:], False])
    assert len(ends) >= 2
    after_s = [10 * int(i - np.flatnonzero(on[: i + 1])[-1]) for i in ends]
    bound = doc["evaluation"]["off_delay_s"] + doc["envelope"]["state"]["quiet_s"] + 10
    assert max(after_s) <= bound < 760, (after_s, bound)
    # no start's transient raised after its settle ended sooner: no FAILURE within the unit's
    # quiet time of an end
    st = d["status"].to_numpy()
    assert not why.str.contains("beyond what").any()
    for i in ends:
        assert not (st[i + 1 : i + 77] == 1).any(), (i, st[i + 1 : i + 77])


def test_the_live_plant_ends_a_start_s_settle_as_the_replay(judged):
    """Through the judged day's first start, from a minute before it to 400 s after its
    settle ended: the live plant cycle by cycle gives the replay's statuses."""
    from diag_plugin.diagnose.plant import Plant
    from diag_plugin.diagnose.unit import Unit

    _, d, tmp = judged
    held = d["why"].fillna("").astype(str).str.contains("settling after a state change")
    rows = np.flatnonzero(held.to_numpy() & (d["status"].to_numpy() == 2))
    a, b = rows[0], rows[np.flatnonzero(np.diff(rows) > 1)[0]] if (np.diff(rows) > 1).any() \
        else rows[-1]  # fmt: skip
    x = pd.read_csv(tmp / "r.csv", index_col=0)
    x.index = pd.to_datetime(x.index, utc=True)
    x = x.iloc[max(0, a - 60) : b + 40]
    path = tmp / "rb" / "p.unit.toml"
    ref = Unit.load(path, path.parent).evaluate(x).status.astype(int).tolist()
    plant = Plant({"p": Unit.load(path, path.parent)}, {})
    got = [int(plant.cycle(ts, row.to_dict())[0].status) for ts, row in x.iterrows()]
    assert got == ref
    assert 2 in ref and ref[-1] == 0


def test_the_envelope_as_built_raises_no_fault_free_start(judged):
    """The envelope as the build wrote it, on the judged day (fault-free, a seed the build
    never saw): no start raised, no sample FAILURE. On main every start was raised 5 min in,
    `HW_TEMP_spread beyond what 18 state changes showed 5 min after a change`: the envelope
    was learned from residuals filtered from rest at each start, while at run time a spread
    test's filter, after the stop, starts at its first value (its peak 14 samples sooner,
    in the bin before, whose bound it passed)."""
    *_, tmp = judged
    d = pd.read_csv(tmp / "built.csv", low_memory=False)
    why = d["why"].fillna("").astype(str)
    starts = why.str.contains("settling after a state change").to_numpy()
    assert (starts & ~np.r_[False, starts[:-1]]).sum() >= 2  # the day's starts were judged
    assert not why.str.contains("beyond what").any(), why[why.str.contains("beyond")].iloc[0]
    alarm = np.isin(d["status"].to_numpy(), [int(NE107.FAILURE), int(NE107.OFF_SPEC)])
    assert not alarm.any(), d.loc[alarm].iloc[0].to_dict()


def _two_state_steps(gap: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two states (a run tag ``MODE`` and a diversion valve ``FDV``, settles of 50 samples
    each) stepping 0 → 1 at sample 10 and ``gap`` samples later, a test on from sample 12 to
    40: per row the age the guard judges it at (-1: no settle), its suppressed rows, its whys."""
    from diag_plugin.diagnose.settle import SettleGuard, SettleLoop

    loops = [SettleLoop(t, t, -1, 0.0, 0.0, 0.25, span=(0.0, 1.0), state=True)
             for t in ("MODE", "FDV")]  # fmt: skip
    n = 120
    x = np.zeros((n, 2))
    x[10:, 0], x[10 + gap :, 1] = 1.0, 1.0
    active = np.zeros(n, bool)
    active[12:41] = True
    g = SettleGuard(loops, [50, 50], 5, 10.0, 1)
    g.ages_seen = []
    index = pd.date_range("2026-03-07", periods=n, freq="10s", tz="UTC")
    sup, why = g.transform(index, x, np.zeros((n, 2)), active, active)
    return g.ages_seen[0][1][:, 0], sup, why


def test_a_state_change_inside_a_start_s_settle_is_the_same_start():
    """The pasteuriser's every production start is two state changes, the run's (``MODE``
    0 → 1) and its diversion valve's step 2 min later that carries the start's product on: one
    start, one settle, one change to learn its envelope from, its age from the start. On main
    the valve's step aged the settle from 0 again: the build counted 18 changes for 9 starts
    (34 for 17 at 8 days) and an envelope bin from 0 held both the start's first 2 min and the
    valve's."""
    from diag_plugin.unitbuild.loops import age_events

    age, sup, why = _two_state_steps(12)
    ev = age_events(age)
    assert set(ev[ev >= 0]) == {0}  # one event (main: two, the second from the valve)
    rows = np.flatnonzero(age >= 0)
    # aged from the sample the run tag left its hold (10; the change confirmed held at 11)
    assert rows[0] == 11 and age[11] == 2 and (np.diff(age[rows]) == 1).all()
    assert age[23] == 14  # the valve's step confirmed: 13 samples on (main: 2, afresh)
    # one settle: suppressed from the first alarm on without a break, its why naming both
    on = np.flatnonzero(sup)
    assert on[0] == 12 and (np.diff(on) == 1).all()
    assert why[30] == ("FDV 0 → 1 at 2026-03-07T00:03:40Z: settling after a state change "
                       "(the settle open since 2026-03-07T00:01:40Z)")  # fmt: skip


def test_the_build_counts_each_production_start_once(judged):
    """The 4-day build's envelope is learned from as many changes as the window has production
    starts (``MODE`` to 1 from another value), each once (main: 18 for 9, each start's valve
    step a change of its own)."""
    doc, _, tmp = judged
    x = pd.read_csv(tmp / "b.csv", index_col=0)
    mode = x["MODE"].to_numpy(float)
    starts = int(((mode[1:] == 1) & (mode[:-1] != 1)).sum())
    note = doc["build"]["envelope"][0]
    got = int(note.split("an envelope from ")[1].split(" ")[0])
    assert got == starts, (got, starts, note[:300])
