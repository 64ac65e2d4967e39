"""A discrete state (a pump's run feedback) in a plant's history (issue 34, items 3 and 6).

Acceptance pass on a pumping station (docs/explanation/acceptance-pumps.md): `diag unit
build` on all the tags that vary tested each pump's on/off feedback, modelled it from the
pump's motor current (exactly: the current is zero when the pump stands), and then refused
the whole unit, `test PMP2_ON: its residual is exactly zero over the window`, at 1 s and at
1 min alike. A discrete state is a mode of the plant, not a measured quantity: it is left out
of the tests, said why, and kept a candidate input. The plant here is written for this test
(an assist pump started on demand with a hysteresis, its current from the flow it gives).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from diag_plugin.unitbuild.build import build_unit, choose_tests
from historian.errors import UserError


def demand_and_run(days: float, seed: int):
    """The station's 1-min demand (a daily cycle, a slow walk, noise) and pump 2's run
    feedback (on above 260 m3/h, off below 200): ``(rng, t in days, demand, run2)``, the
    generator left where the rest of the plant draws on."""
    rng = np.random.default_rng(seed)
    n = int(days * 1440)
    t = np.arange(n) / 1440.0
    walk = np.cumsum(rng.normal(0, 0.002, n))
    demand = 220 + 80 * np.sin(2 * np.pi * (t - 0.3)) + 20 * walk + rng.normal(0, 5, n)
    run2 = np.zeros(n)
    on = False
    for k in range(n):
        on = demand[k] > 260 or (on and demand[k] > 200)
        run2[k] = float(on)
    return rng, t, demand, run2


def _station(days: float, seed: int, worn: float = 0.0) -> pd.DataFrame:
    """1-min samples: a demand with a daily cycle; pump 2 assists above 260 m3/h and stops
    below 200 (its run feedback RUN2 is 0/1); the header pressure falls with the flow a pump
    gives; each motor's current is the power of its share, zero when it stands. ``worn``:
    pump 2's motor draws that much more current for the same duty from day 1 on (a worn
    impeller's lost efficiency)."""
    rng, t, demand, run2 = demand_and_run(days, seed)
    n = len(t)
    pumps = 1 + run2
    share = demand / pumps
    press = 5.0 - 2.5e-5 * share**2 + rng.normal(0, 0.01, n)
    i1 = 5 + 0.002 * share**2 * press / 4 + rng.normal(0, 0.3, n)
    i2 = run2 * (5 + 0.002 * share**2 * press / 4 + rng.normal(0, 0.3, n))
    i2 *= 1 + worn * (t >= 1.0)
    flow = demand + rng.normal(0, 2, n)
    idx = pd.date_range("2026-06-01", periods=n, freq="60s", tz="UTC")
    return pd.DataFrame({"FLOW": flow, "PRESS": press, "I1": i1, "I2": i2, "RUN2": run2},
                        index=idx)  # fmt: skip


def test_a_pump_run_feedback_is_not_a_test_and_the_unit_builds(tmp_path):
    """Fails on main, where RUN2 is tested (here `RUN2 = f(I2, PRESS)`, a model of a mode;
    on the pumping station `PMP2_ON` from its motor's current exactly, and the build stopped:
    `cannot learn thresholds: test PMP2_ON: its residual is exactly zero`)."""
    train = _station(4, 1)
    assert 0 < train["RUN2"].mean() < 1  # the assist pump starts and stops in the window
    res = build_unit("station", train, folder=tmp_path, period="60s", far=0.01)
    tested = {t.tag for t in res.tests}
    assert "RUN2" not in tested
    assert {"FLOW", "PRESS", "I1", "I2"} <= tested
    assert "discrete state" in res.skipped["RUN2"]
    assert "candidate input" in res.skipped["RUN2"]


def test_a_discrete_state_is_never_the_tag_at_fault(tmp_path):
    """The station's pump 2 worn (its current 25 % higher for the same duty while it runs):
    the isolation names the current, no alarm the run feedback, which the build writes in
    ``[build] states``. On the pumping station of the acceptance pass the unit (with the
    feedback a candidate input, as the current's test reads it) named `PMP1_ON` on 61.5 % of a
    worn pump's alarm samples and `PMP3_ON` at a pump start; fails on main, where the
    feedback is a tag the unit can name."""
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.diagnose.unittags import structure

    res = build_unit("station", _station(4, 1), folder=tmp_path, period="60s", far=0.01)
    unit = Unit.load(res.path, tmp_path)
    assert unit.file.build["states"] == ["RUN2"]
    assert "RUN2" not in structure(unit)[0]
    d = unit.reset().evaluate(_station(2, 7, worn=0.25))
    on = 1440
    alarm = d.detected.to_numpy()[on:] == 1
    assert alarm.mean() > 0.2
    named = {t for c in ("top1", "top2", "top3") for t in d.top_tags[c].iloc[on:][alarm] if t}
    assert "RUN2" not in named and "RUN2" not in {f for f in d.faults if f}
    # the isolation (the derived matrix's exact column, named first) the worn pump's current;
    # the ranking's first tag follows where its column allows the symptoms too (``I2|FLOW``:
    # the ranking names FLOW here, unittags.with_ranked)
    first = d.faults.iloc[on:][alarm].str.split("|").str[0]
    assert first.value_counts().index[0] == "I2"


def test_a_state_the_grid_averaged_at_a_switch_is_still_discrete():
    """At 1 s a jittered export puts two samples in a few grid points, and the grid averages
    them: a run feedback reads 0.5 where a switch fell. Still a discrete state; a measured
    tag (the current) and a tag the user lists are tested."""
    from diag_plugin.unitbuild.build import two_states

    f = _station(2, 2)
    run = f["RUN2"].to_numpy().copy()
    switches = np.flatnonzero(np.diff(run) != 0)
    assert len(switches) >= 2
    run[switches] = 0.5
    f["RUN2"] = run
    assert two_states(run) == (0.0, 1.0)
    assert two_states(f["I2"].to_numpy()) is None
    chosen, skipped = choose_tests(f)
    assert "RUN2" not in chosen and "I2" in chosen
    assert "0 or 1" in skipped["RUN2"]
    chosen, skipped = choose_tests(f, tags=["RUN2", "I2"])
    assert chosen == ["RUN2", "I2"] and not skipped


@pytest.mark.parametrize("values", [[0, 1, 2, 3] * 50, list(np.linspace(0, 1, 200))])
def test_a_tag_of_more_than_two_values_is_not_a_state(values):
    from diag_plugin.unitbuild.build import two_states

    assert two_states(np.asarray(values, float)) is None


def test_after_accept_a_discrete_state_is_still_never_named(tmp_path):
    """``diag unit accept`` of a fault-free day, then pump 2 worn: no alarm sample names the
    run feedback (top1..3, faults): accept keeps the file's ``[build] states``."""

    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.unitbuild.accept import accept, reader

    built = _station(4, 1)
    res = build_unit("station", built, folder=tmp_path, period="60s", far=0.01)
    day = _station(6, 3).iloc[4 * 1440 : 5 * 1440]  # a later fault-free day, unseen
    read = reader(pd.concat([built, day]))
    accept(Unit.load(res.path, tmp_path), lambda a, b: [read(a, b)], day.index[0], day.index[-1])
    unit = Unit.load(res.path, tmp_path)
    assert "states" in unit.file.build  # accept keeps the file's [build] as it was
    d = unit.reset().evaluate(_station(2, 7, worn=0.25))
    on = 1440
    alarm = d.detected.to_numpy()[on:] == 1
    assert alarm.mean() > 0.2
    named = {t for c in ("top1", "top2", "top3") for t in d.top_tags[c].iloc[on:][alarm] if t}
    faults = {x for f in d.faults.iloc[on:][alarm] if f for x in f.split("|")}
    assert "RUN2" not in named | faults


def test_a_state_of_three_modes_is_said_with_its_three_values():
    """A filter's state (0 filtering, 1 backwash, 2 filter-to-waste; the third mode 0.6 % of
    the window, so the two commonest values hold 99 % and it is a discrete state): the build's
    note names all three values it held. Acceptance pass 8 (docs/explanation/acceptance-filters.md):
    on main the note said `(0 or 1: a mode of the plant …)` for the four filters' states."""
    rng = np.random.default_rng(5)
    n = 6000
    state = np.zeros(n)
    for start in range(500, n - 100, 1800):  # a backwash (12 samples) then filter-to-waste (10)
        state[start : start + 12] = 1
        state[start + 12 : start + 22] = 2
    idx = pd.date_range("2026-03-02", periods=n, freq="60s", tz="UTC")
    flow = 400 + 30 * np.sin(np.arange(n) / 300) + rng.normal(0, 3, n)
    f = pd.DataFrame({"FLOW": np.where(state == 1, 0.0, flow), "STATE": state}, index=idx)
    assert 0.003 < (state == 2).mean() < 0.01
    chosen, skipped = choose_tests(f)
    assert "STATE" not in chosen
    assert "(0, 1 or 2:" in skipped["STATE"]


def test_a_three_mode_state_washed_once_in_a_short_window_is_a_state():
    """400 samples of a filter washed once (acceptance-filters.md, the short window): 0 on
    380, backwash 1 on 12, filter-to-waste 2 on 8. Its two commonest values hold 98 %, under
    the 99 % two states need, so it was tested… as an input of a pair test. Its three levels,
    each held, hold all of it: a state. Four levels each held (SKAB's quantized pressure),
    or values never held, are not one."""
    from diag_plugin.unitbuild.build import two_states

    state = np.r_[np.zeros(200), np.ones(12), np.full(8, 2.0), np.zeros(180)]
    assert two_states(state) == (0.0, 1.0, 2.0)
    rng = np.random.default_rng(5)
    frame = pd.DataFrame({"F1_STATE": state, "F1_FLOW": 400 + rng.normal(0, 3, 400)})
    chosen, skipped = choose_tests(frame)
    assert chosen == ["F1_FLOW"]
    assert skipped["F1_STATE"].startswith("a discrete state (0, 1 or 2: ")
    steps = np.repeat(np.arange(4.0), [330, 30, 20, 20])  # four levels, each held
    assert two_states(steps) is None
    blips = state.copy()
    blips[[50, 100, 150]] = 3.0  # a fourth value on single samples: no mode
    assert two_states(blips) == (0.0, 1.0, 2.0)
    assert two_states(np.r_[np.zeros(380), [1.0, 2.0] * 10]) is None  # 1, 2 never held


def _batches(days: float, seed: int) -> pd.DataFrame:
    """1-min samples of a batch reactor's recipe: idle 0, charge 1, heat-up 2, hold 3,
    cool-down 4, discharge 5 (``PHASE``), the reactor's temperature following the recipe's
    set-point through a first-order lag, its weight rising in the charge and falling in the
    discharge, the agitator's power with the weight."""
    rng = np.random.default_rng(seed)
    phase, sp, w = [], [], []
    s, m = 30.0, 150.0
    while len(phase) < days * 1440:
        size = rng.uniform(4000, 6000)
        for ph, n in ((0, int(rng.integers(20, 80))), (1, 25), (2, 55), (3, 120), (4, 40), (5, 25)):
            for _ in range(n):
                ramp = {2: min(85.0, s + 1), 3: 85.0, 4: max(40.0, s - 1.5)}
                s = 30.0 if ph < 2 else ramp.get(ph, s)
                m = {1: m + size / 25, 5: max(150.0, m - size / 25)}.get(ph, m)
                phase.append(ph), sp.append(s), w.append(m)
    n = int(days * 1440)
    phase, sp, w = np.array(phase[:n], float), np.array(sp[:n]), np.array(w[:n])
    temp = np.empty(n)
    temp[0] = 30.0
    for k in range(1, n):
        temp[k] = temp[k - 1] + (sp[k - 1] - temp[k - 1]) / 8
    idx = pd.date_range("2026-03-02", periods=n, freq="60s", tz="UTC")
    return pd.DataFrame({"PHASE": phase, "TR_SP": sp, "TR_TEMP": temp + rng.normal(0, 0.05, n),
                         "TR_WEIGHT": w + rng.normal(0, 4, n),
                         "AGIT_PWR": 10 + w / 400 + rng.normal(0, 0.2, n)}, index=idx)  # fmt: skip


def test_a_recipe_phase_declared_a_state_is_never_tested_nor_named(tmp_path):
    """A batch recipe's phase tag takes six values (acceptance-batch.md): more than the three
    levels the build finds a state by (``MAX_LEVELS``), so on main it is a tag the unit tests
    (`PHASE = f(AGIT_PWR, TR_TEMP, …)`) and may name, and a user had no way to say it is a
    mode. ``--state PHASE`` (``build_unit(states=…)``, a tags CSV's role ``state``) leaves it
    out as a found state is: untested, a candidate input, in ``[build] states``, never a tag
    at fault. Fails on main (no ``states``, no role ``state``)."""
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.diagnose.unittags import structure
    from diag_plugin.unitbuild.loops import states_from_tags_csv

    train = _batches(4, 1)
    assert set(np.unique(train["PHASE"])) == {0.0, 1.0, 2.0, 3.0, 4.0, 5.0}
    chosen, skipped = choose_tests(train)
    assert "PHASE" in chosen  # not found by itself: six levels
    tags = tmp_path / "tags.csv"
    tags.write_text("name,unit,description,loop,role\nPHASE,,recipe phase,,state\n"
                    "TR_TEMP,degC,reactor temperature,,\n")  # fmt: skip
    assert states_from_tags_csv(tags) == ["PHASE"]
    res = build_unit("rx", train, folder=tmp_path, period="60s", far=0.01, states=["PHASE"])
    assert "PHASE" not in {t.tag for t in res.tests}
    assert res.skipped["PHASE"].startswith("a discrete state (declared; 0, 1, 2, 3, 4 or 5: ")
    unit = Unit.load(res.path, tmp_path)
    assert unit.file.build["states"] == ["PHASE"]
    assert "PHASE" not in structure(unit)[0]
    with pytest.raises(UserError, match="--state LEVEL: not in the data"):
        build_unit("rx2", train, folder=tmp_path, period="60s", far=0.01, states=["LEVEL"])


def test_a_standby_s_current_on_a_few_samples_is_no_state():
    """The compressed-air station's short window (acceptance-compressors.md): the standby
    ran 4 of 400 samples, its current 0 on 396 and 32.3-34.8 A on 4, and it became `a
    discrete state (0 or 34.83 …)` — the two commonest values, 0 and one of the four, held
    99 %. A state's other level is read exactly on two samples at least; a few analog
    values each seen once are not one. Fails on main. Its run tag, 1 on the same 4
    samples, stays a state. Nor is the current tested: a level test against the window's
    mean (0) alarmed whenever the standby ran (57 % of the pass's fault-free days); the
    window shows too little of it running (`holds one value …`, a candidate input)."""
    from diag_plugin.unitbuild.build import two_states

    amps = np.zeros(400)
    amps[[101, 102, 103, 104]] = [32.3, 33.9, 34.83, 34.8]
    assert two_states(amps) is None
    run = (amps > 0).astype(float)
    assert two_states(run) == (0.0, 1.0)
    rng = np.random.default_rng(2)
    frame = pd.DataFrame({"C2_AMPS": amps, "C2_RUN": run, "FLOW": 20 + rng.normal(0, 1, 400)})
    chosen, skipped = choose_tests(frame)
    assert chosen == ["FLOW"]
    assert skipped["C2_RUN"].startswith("a discrete state (0 or 1: ")
    assert skipped["C2_AMPS"].startswith("holds one value (0) on 396 of 400 samples, others on 4")
    amps[[300, 301]] = 40.0  # a second level read twice: a state (0 and 40 hold 99 %)
    assert two_states(amps) == (0.0, 40.0)
