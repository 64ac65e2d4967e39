"""A piece running on a replay's first sample, with no history, is a start of unknown age
(issue 34, item 5; docs/explanation/acceptance-compressors.md, "After i34-comp").

The compressed-air station (benchmarks/acceptance/compressors_sim.py, the three compressors
declared) starts every simulated run with the lead and the lag running from cold: the
discharge temperature of the lead 31 °C on the first sample, 64 °C nine minutes later. No
settle opened for it (a start is a change of the run tag, and the first sample has none
before it), so its tests judged the transient: on main the fault-free runs 102, 103, 202,
203 and 206 raised 5-8 samples of FAILURE on `C3_TD` in their first 40 minutes, every
FAILURE of the ten fault-free runs. A piece found running where the unit has no history (a
replay's first sample, a fresh live start's lead-in) now starts there: its tests held off
until quiet, as after any start. Built here on other days and seeds (14 days from 1 June,
seed 2) than the page's unit, judged on seeds never used.
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from diag_plugin.diagnose.equipment import SETTLING
from diag_plugin.diagnose.plant import Plant
from diag_plugin.diagnose.unit import Unit
from diag_plugin.status import NE107
from diag_plugin.unitbuild.build import build_unit
from diag_plugin.unitbuild.loops import parse_running
from tests.test_unit_running import same_in_pieces

SIM = Path(__file__).resolve().parents[1] / "benchmarks" / "acceptance" / "compressors_sim.py"
PIECES = [f"C{n}:C{n}_RUN:C{n}_AMPS,C{n}_KW,C{n}_TD,C{n}_TAC" for n in (1, 2, 3)]


def _sim():
    spec = importlib.util.spec_from_file_location("compressors_sim", SIM)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _run(sim, start: str, days: float, seed: int) -> pd.DataFrame:
    """``days`` at 3 min on the grid (no jitter)."""
    f = sim.simulate(start, days, seed, period=180.0, jitter=0.0, dt=2.0)
    f.index = f.index.round("3min")
    return f[~f.index.duplicated()]


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    sim = _sim()
    folder = tmp_path_factory.mktemp("compressors_first")
    info = {n: {"unit": u, "lo": lo, "hi": hi} for n, u, lo, hi, _, _ in sim.TAG_ROWS}
    res = build_unit("air", _run(sim, "2026-06-01", 14, 2), folder=folder, period="3min",
                     far=0.01, tag_info=info, disturbances=["FT_PLANT", "T_AMB"],
                     equipment=[parse_running(p) for p in PIECES])  # fmt: skip
    return sim, Unit.load(res.path, folder)


@pytest.mark.parametrize("seed", [31, 32, 33])
def test_a_piece_running_cold_on_the_first_sample_settles(station, seed):
    """29 June: C3 leads and C1 lags, both running from cold on the first sample: both
    settling there (main: running, judged), C2 stopped; no FAILURE in the run's first two
    hours, and the settle ends (C3 judged again within its bound)."""
    sim, unit = station
    f = _run(sim, "2026-06-29", 1, seed)
    d = unit.reset().evaluate(f)
    eq = d.equipment
    first = f.iloc[0][["C1_RUN", "C2_RUN", "C3_RUN"]].to_numpy()
    assert first.tolist() == [1.0, 0.0, 1.0]
    assert eq.iloc[0].tolist() == [SETTLING, 1, SETTLING], eq.iloc[:3]
    assert not (d.status.to_numpy()[:40] == NE107.FAILURE).any(), d.faults.iloc[:40].tolist()
    hold = unit.equipment_holds[2]
    assert (eq["C3"].to_numpy()[: hold + 1] == 0).any()


def test_the_first_sample_s_start_in_pieces_and_live_as_the_replay(station):
    """The start of unknown age is the replay's first sample only: the replay in pieces from
    saved states (cut inside the settle and after it) and the live plant cycle by cycle say
    the same as the replay whole; a restart from a state saved while C3 runs goes on, no
    settle opened by it."""
    sim, unit = station
    f = _run(sim, "2026-06-29", 0.5, 34)
    whole = same_in_pieces(unit, f, 7)
    plant = Plant({"air": unit.reset()}, {})
    got = []
    for k, (ts, row) in enumerate(f.iterrows()):
        if k == 100:  # C3 (the lead) running for 5 h: a restart from the saved state
            state = json.loads(json.dumps(plant.to_state()))
            plant = Plant({"air": Unit.load(unit.file.path, unit.file.path.parent)}, {})
            plant.load_state(state)
        got.append(plant.cycle(ts, row.to_dict())[0])
    assert [int(s.status) for s in got] == whole.status.astype(int).tolist()
    assert (whole.equipment["C3"].to_numpy()[100:] != SETTLING).all()
    assert whole.equipment["C3"].iloc[0] == SETTLING


def test_a_saved_state_from_before_it_is_running_long(station):
    """A state saved before the start of unknown age (no ``equipment`` in it): the pieces
    running long, no settle at the first sample, as before."""
    sim, unit = station
    f = _run(sim, "2026-06-29", 0.25, 35)
    state = json.loads(json.dumps(unit.reset().to_state()))
    state.pop("equipment")
    d = unit.reset().load_state(state).evaluate(f)
    assert d.equipment.iloc[0].tolist() == [0, 1, 0]


def test_a_piece_s_envelope_is_learned_at_the_ages_its_settle_judges(station):
    """Each piece's start envelope (``[envelope.C1]`` …) is learned at the ages its own settle
    judges (the guard replayed over the window), not from each start to its stop: every bin
    it writes was reached by at least ``MIN_STARTS`` of the window's settles of that piece
    (those starting at a known start), and it counts those starts. On main C3's envelope
    held bins from 5760 and 8640 s, learned from rows after its settles had ended (its
    settles of the window end within 48 min)."""
    from diag_plugin.diagnose.envelope import MIN_STARTS

    sim, unit = station
    window = _run(sim, "2026-06-01", 14, 2)
    eq = unit.reset().evaluate(window).equipment
    unit.reset()
    for name, env in unit.file.envelope.items():
        settling = eq[name].to_numpy() == SETTLING
        runs = window[f"{name}_RUN"].to_numpy() > 0.5
        known = runs & np.r_[False, ~runs[:-1]]  # started, stopped the sample before
        begins = np.flatnonzero(settling & ~np.r_[False, settling[:-1]])
        ends = np.flatnonzero(settling & ~np.r_[settling[1:], False])
        lengths = [(b - a + 1) * 180 for a, b in zip(begins, ends, strict=True) if known[a]]
        assert env.starts == len(lengths), (name, env.starts, len(lengths))
        for age in env.age_s:
            assert sum(n > age for n in lengths) >= MIN_STARTS, (name, age, sorted(lengths))
