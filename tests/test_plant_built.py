"""Units as ``diag unit build`` writes them on the live loop's batched fast path (issue 34, item
6 and speed): a deadband, the unit's own off-delay in seconds and a spread test. The same plant
cycled row by row through the fast path and one by one (:meth:`Unit.evaluate`, ``batched=False``)
gives the same statuses, faults, named tags, messages (CHECK_FUNCTION's reasons included),
residuals and symptoms — through faults that come and go, gaps and an input outside what the
units learned. The state these settings carry across cycles matters on this data: the held
alarms, the deadband's and the spread's (checked below), so a fast path that dropped it would
differ."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from helpers import plant_statuses, same_status

from diag_plugin.diagnose.plant import Plant
from diag_plugin.diagnose.unit import Unit
from diag_plugin.diagnose.unitfile import UnitFile
from diag_plugin.examples.coupled import DAY, build, process
from diag_plugin.learn.thresholds import learn_thresholds
from diag_plugin.status import NE107

TAGS = ("A", "B", "C", "D", "E", "F")
BUILT = {  # what alarm_settings writes, at the process's 60 s
    "combined": True,
    "isolation": "tags",
    "on_delay_s": 180.0,
    "off_delay_s": 600.0,
    "deadband": 0.1,
    "spread_window_s": 1200.0,
}
#: a second unit with other settings: stacked per setting, each its own state
OTHER = {"deadband = 0.1": "deadband = 0.25", "off_delay_s = 600.0": "off_delay_s = 300.0",
         "spread_window_s = 1200.0": "spread_window_s = 600.0"}  # fmt: skip


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """Units u1, u2 (other settings) and u3 (no deadband nor off-delay of its
    own, the spread test's window by default) of the coupled
    process, thresholds learned on 3 fault-free days (seed 1), each reading its own tags."""
    return make_units(tmp_path_factory.mktemp("built"))


def make_units(folder: Path) -> Path:
    """The units of :func:`folder` written in ``folder``."""
    window = process(3 * DAY, 1)
    path = build(folder, window, BUILT)
    text = path.read_text().replace("[tests]\n", '[tests]\nrD_spread = {model = "p_rD.toml", '
                                    'statistic = "spread"}\n', 1)  # fmt: skip
    path.write_text(text)
    uf = UnitFile.load(path)
    uf.set_learned(learn_thresholds(Unit.load(path), [window], far=0.01))
    uf.save()
    learned = path.read_text()
    other = learned
    for a, b in OTHER.items():
        assert a in other
        other = other.replace(a, b)
    plain = learned
    for key in ("deadband", "off_delay_s", "spread_window_s"):
        plain = "\n".join(ln for ln in plain.splitlines() if not ln.startswith(key))
    for k, body in (("u1", learned), ("u2", other), ("u3", plain)):
        tags = "\n".join(f'{t} = "{k.upper()}.{t}"' for t in TAGS)
        body = body.replace('name = "p"', f'name = "{k}"')
        (folder / f"{k}.unit.toml").write_text(body + "\n[tags]\n" + tags + "\n")
    return folder


def _rows() -> pd.DataFrame:
    """Half a day per unit: biases that come and go (one toggling, to be held by the unit's
    off-delay), gaps short and long, an input far outside what the units learned."""
    n = DAY // 2
    parts = {}
    for k, seed in (("U1", 301), ("U2", 302), ("U3", 303)):
        clean = process(n, seed)
        f = clean.copy()
        at = np.arange(n)
        f.iloc[60:200, f.columns.get_loc("D")] += 16.0  # a bias that comes and goes
        toggling = (at >= 240) & (at < 420) & ((at - 240) % 55 < 40)
        f.loc[toggling, "C"] += 12.0  # on 40 samples, off 15: for the off-delay
        wobble = (at >= 440) & (at < 520)
        f.loc[wobble, "D"] += 10.0 * np.where(at[wobble] % 2 == 0, 1.0, -1.0)  # for the spread
        f.iloc[560:563, f.columns.get_loc("B")] = np.nan  # a gap shorter than the on-delay
        f.iloc[580:610, f.columns.get_loc("A")] = np.nan  # a long one: CHECK_FUNCTION
        f.iloc[640:680, f.columns.get_loc("B")] = 180.0  # outside what the unit learned
        for t in TAGS:
            parts[f"{k}.{t}"] = f[t]
    return pd.DataFrame(parts)


def test_built_units_take_the_fast_path_with_the_one_by_one_results(folder):
    names = [folder / f"u{i}.unit.toml" for i in (1, 2, 3)]
    fast, slow = Plant.load(names, folder), Plant.load(names, folder)
    slow = Plant(slow.units, batched=False)
    assert fast.fast == ["u1", "u2", "u3"] and fast.slow == []
    assert slow.slow == ["u1", "u2", "u3"]
    u1 = fast.units["u1"]
    assert u1.deadband is not None and u1.alarm_hold is not None and u1.spread_cols.size == 1
    rows = _rows()
    a, b = plant_statuses(fast, rows), plant_statuses(slow, rows)
    for name in ("u1", "u2", "u3"):
        for i, (x, y) in enumerate(zip(a[name], b[name], strict=True)):
            same_status(x, y, (name, i), exact=False)
    # the run exercises what the state carries: alarms held with no symptom on (the unit's
    # off-delay), a symptom kept on inside the deadband, the spread test on, CHECK_FUNCTION
    # with its reason, and a failure naming tags
    u = a["u1"]
    sym = np.array([list(s.symptoms.values()) for s in u])
    res = np.array([list(s.residuals.values()) for s in u])
    tests = list(u[0].symptoms)
    on = np.nan_to_num(sym) != 0
    held = [i for i, s in enumerate(u) if s.detected and not on[i].any()]
    assert len(held) >= 5, held
    hi = np.array([fast.units["u1"].file.tests[j].high for j in range(len(tests))], float)
    assert (on & (np.abs(res) < np.abs(hi))).any()  # on, back under its threshold
    assert on[:, tests.index("rD_spread")].any()
    checking = [s for s in u if s.status == NE107.CHECK_FUNCTION]
    assert checking and any("B" in s.message for s in checking)
    assert any(s.tags for s in u) and any(s.status == NE107.FAILURE for s in u)


@pytest.mark.parametrize("batched", [True, False])
def test_a_restarted_plant_goes_on_where_it_stopped(folder, batched):
    """Stopped mid-fault (u1 alarming on the toggling bias of C, held by its off-delay)
    and restarted from its JSON state, the plant gives what an uninterrupted run gives,
    cycle by cycle; a fresh one does not."""
    names = [folder / f"u{i}.unit.toml" for i in (1, 2, 3)]

    def plant() -> Plant:
        p = Plant.load(names, folder)
        return p if batched else Plant(p.units, batched=False)

    rows = _rows().iloc[:460]
    whole = plant_statuses(plant(), rows)
    first = plant()
    stop = 300  # inside the toggling bias of rows 240–420, the alarm on
    plant_statuses(first, rows.iloc[:stop])
    assert all(s.detected for s in whole["u1"][stop - 5 : stop])
    state = json.loads(json.dumps(first.to_state()))  # what the live loop writes and reads
    again = plant().load_state(state)
    rest = plant_statuses(again, rows.iloc[stop:])
    fresh = plant_statuses(plant(), rows.iloc[stop:])
    for name in ("u1", "u2", "u3"):
        for i, (x, y) in enumerate(zip(rest[name], whole[name][stop:], strict=True)):
            same_status(x, y, (name, stop + i))
    # the state matters: started fresh, the units warm up again and miss the alarm held on
    assert fresh["u1"][0].status == NE107.CHECK_FUNCTION
    assert "warming up" in fresh["u1"][0].message
    assert rest["u1"][0].status != NE107.CHECK_FUNCTION


def test_a_state_of_other_unit_versions_is_refused(folder, tmp_path):
    """A unit edited since the state was saved: the state is refused, saying which unit."""
    import shutil

    for f in folder.iterdir():
        shutil.copy(f, tmp_path / f.name)
    names = [tmp_path / f"u{i}.unit.toml" for i in (1, 2, 3)]
    p = Plant.load(names, tmp_path)
    plant_statuses(p, _rows().iloc[:40])
    state = json.loads(json.dumps(p.to_state()))
    u2 = tmp_path / "u2.unit.toml"
    u2.write_text(u2.read_text().replace("deadband = 0.25", "deadband = 0.2"))
    with pytest.raises(ValueError, match="units changed since the state was saved: u2"):
        Plant.load(names, tmp_path).load_state(state)
    Plant.load(names[:1], tmp_path).reset()  # the plant of other units is refused too
    with pytest.raises(ValueError, match="u2, u3"):
        Plant.load(names[:1], tmp_path).load_state(state)
