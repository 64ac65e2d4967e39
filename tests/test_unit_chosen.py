"""A loop's set-point the window saw at few values: the tests reading it are unknown at a
set-point it never saw (issue 34, items 3 and 5; ``[chosen]``, diagnose/manual.py).

The heater of :mod:`tests.spstep_plant` (a cascade: the outlet temperature's PI sets the
heating flow's set-point) built as a user would on two days with three operator's steps of
its target ``HEAT_TGT`` (60, 70, 65 °C: about five independent values), at two rates, and
judged on unseen seeds at 75 °C, a target the window never held: the tests that read the
target, or the outlet temperature its loop holds at it, are unknown there and the unit names
the target; the loop's own tests judge on; ``diag unit accept`` of a period at 75 °C widens
the row and the tests answer there; the replay and the live loop agree. The cascade's inner
set-point (the outer controller's output) is never a ``[chosen]`` row.
"""

from __future__ import annotations

import re
import shutil

import numpy as np
import pandas as pd
import pytest

from diag_plugin.diagnose.unit import Unit, UnitError
from diag_plugin.models.linear import LinearRegressor
from diag_plugin.regressors import parse_specs
from diag_plugin.status import NE107
from diag_plugin.unitbuild.build import build_unit
from diag_plugin.unitbuild.loops import parse_loop
from tests import spstep_plant as sp

CF = int(NE107.CHECK_FUNCTION)
#: judged: the target stepped to 75 °C at 3 h of a 0.6-day run
NEW = [(3 * 3600.0, 75.0)]


@pytest.fixture(scope="module", params=[30, 120], ids=["30s", "2min"])
def heater(request, tmp_path_factory):
    period = request.param
    window = sp.at_period(sp.simulate(2.0, 1, steps=sp.TRAIN_STEPS), period)
    folder = tmp_path_factory.mktemp(f"chosen{period}")
    res = build_unit("heater", window, folder=folder, period=f"{period}s", far=0.01,
                     loops=[parse_loop(lp) for lp in sp.LOOPS], force=True)  # fmt: skip
    return period, window, res, folder


def _load(res, folder, guarded: bool = True) -> Unit:
    u = Unit.load(res.path, folder)
    if not guarded:  # the same unit without the [chosen] guard: what main did
        u.manual = None
    return u


def _guarded(unit: Unit) -> list[int]:
    """The positions of the lines that read HEAT_TGT or TEMP (neither a loop's own test nor a
    rule grid)."""
    out = []
    for j, t in enumerate(unit.file.tests):
        if getattr(unit.models[t.name].model, "partitions_", None) is not None:
            continue
        read = {s.tags[0] for s in parse_specs(unit.models[t.name].inputs) if s.fn == ""}
        if t.set_point is None and read & {"HEAT_TGT", "TEMP"}:
            out.append(j)
    return out


def test_the_build_writes_the_target_not_the_cascade_set_point(heater):
    period, window, res, folder = heater
    unit = _load(res, folder)
    assert set(unit.file.chosen) == {"HEAT_TGT"}  # FLOW_SP: the outer controller's output
    row = unit.file.chosen["HEAT_TGT"]
    assert (row.min, row.max) == (60.0, 70.0) and 0 < row.margin < 0.01
    note = [n for n in res.notes if "set-point(s) seen at" in n]
    assert note and "HEAT_TGT 60 … 70" in note[0], res.notes
    assert _guarded(unit), "no test reads the target: the row would do nothing"


def test_a_target_never_seen_makes_its_readers_unknown_and_is_named(heater):
    period, _, res, folder = heater
    unit, plain = _load(res, folder), _load(res, folder, guarded=False)
    x = sp.at_period(sp.simulate(0.6, 5, steps=NEW), period)
    new = (x["HEAT_TGT"] == 75.0).to_numpy()
    raw, raw0 = unit.reset().raw_residuals(x), plain.reset().raw_residuals(x)
    late = new & (np.arange(len(x)) > np.argmax(new) + 40)  # past the lags' history
    tests = [t.name for t in unit.file.tests]
    cols = [tests[j] for j in _guarded(unit)]
    assert raw[cols].to_numpy()[late].size and np.isnan(raw[cols].to_numpy()[late]).all()
    # before the step every one of them judged as without the guard
    pd.testing.assert_frame_equal(raw.loc[~new], raw0.loc[~new])
    # the loop's own tests judge on at the new target
    own = [t.name for t in unit.file.tests if t.set_point == "HEAT_TGT"]
    assert own and np.isfinite(raw[own].to_numpy()[late]).mean() > 0.99
    # a line extrapolates there without the guard (at 30 s the valve is a linear test)
    lines = [tests[j] for j in _guarded(unit)
             if isinstance(unit.models[tests[j]].model, LinearRegressor)]  # fmt: skip
    if period == 30:
        assert lines, "the 30 s heater's valve test is linear"
    for t in lines:
        assert np.isfinite(raw0[t].to_numpy()[late]).mean() > 0.99, t
    # the unit says which input and since when
    d = unit.reset().evaluate(x)
    why = d.why.to_numpy(dtype=object)[late & (d.status.to_numpy() == CF)]
    assert why.size
    t0 = x.index[np.argmax(new)].isoformat()
    said = f"HEAT_TGT = 75 outside what the unit learned (59.99 … 70.01) since {t0}"
    assert all(said in w for w in why), pd.Series(why).value_counts().head()


def test_accept_at_the_new_target_widens_the_row_and_the_tests_answer(heater, tmp_path):
    from diag_plugin.unitbuild.accept import accept

    period, window, res, folder = heater
    work = tmp_path / "u"
    shutil.copytree(folder, work)
    u = Unit.load(work / "heater.unit.toml", work)
    at75 = sp.at_period(sp.simulate(2.0, 7, steps=[(0.0, 75.0)]), period)
    at75.index = at75.index + pd.Timedelta(days=10)
    both = pd.concat([window, at75])

    def read(a, b):
        yield both.iloc[both.index.searchsorted(a) : both.index.searchsorted(b)]

    got = accept(u, read, at75.index[0], at75.index[-1] + pd.Timedelta(seconds=period))
    assert any(w.startswith("set-point HEAT_TGT: span 60 … 70") and "→ 60 … 75" in w
               for w in got.warnings), got.warnings  # fmt: skip
    after = Unit.load(work / "heater.unit.toml", work)
    assert after.file.chosen["HEAT_TGT"].max == 75.0
    x = sp.at_period(sp.simulate(0.6, 8, steps=NEW), period)
    new = (x["HEAT_TGT"] == 75.0).to_numpy()
    late = new & (np.arange(len(x)) > np.argmax(new) + 40)
    d = after.reset().evaluate(x)
    assert not any("HEAT_TGT = 75" in w for w in d.why.to_numpy(dtype=object)[late])
    raw = after.reset().raw_residuals(x)
    lines = [t.name for t in after.file.tests
             if isinstance(after.models[t.name].model, LinearRegressor)
             and t.name in [after.file.tests[j].name for j in _guarded(after)]]  # fmt: skip
    assert lines, "no line reads the target: nothing to answer"
    for t in lines:  # the line answers at 75 °C now
        assert np.isfinite(raw[t].to_numpy()[late]).mean() > 0.99, t


def test_a_piece_without_the_set_point_names_the_missing_tag(heater):
    """The guard reads the set-point before the models do: a piece without it is the models'
    error naming the tag, not a bare lookup failure."""
    period, _, res, folder = heater
    x = sp.at_period(sp.simulate(0.2, 5, steps=NEW), period).drop(columns=["HEAT_TGT"])
    with pytest.raises(KeyError, match="tag.s. HEAT_TGT needed by the model are not in the data"):
        _load(res, folder).reset().evaluate(x)


def test_the_live_loop_and_a_restart_agree_with_the_replay(heater):
    import json

    from diag_plugin.diagnose.plant import Plant

    period, _, res, folder = heater
    unit = _load(res, folder)
    x = sp.at_period(sp.simulate(0.4, 9, steps=[(2 * 3600.0, 75.0), (6 * 3600.0, 65.0)]), period)
    one = unit.reset().evaluate(x)
    assert one.why.str.contains("HEAT_TGT = 75 outside").any()
    fast = Plant.load([res.path], folder)
    slow = Plant(Plant.load([res.path], folder).units, batched=False)
    assert fast.fast == ["heater"] and slow.slow == ["heater"]
    mid = int(3 * 3600 / period)  # the target outside: the excursion carried over a restart
    for i, (ts, row) in enumerate(x.iterrows()):
        if i == mid:
            state = json.loads(json.dumps(fast.to_state()))
            fast = Plant.load([res.path], folder).load_state(state)
        a, b = fast.cycle(ts, row.to_dict())[0], slow.cycle(ts, row.to_dict())[0]
        ref = one.at(i)
        assert (a.status, a.faults, a.message) == (ref.status, ref.faults, ref.message), i
        assert (b.status, b.faults, b.message) == (ref.status, ref.faults, ref.message), i


def test_a_row_that_guards_nothing_or_is_broken_is_said_where(heater, tmp_path):
    period, _, res, folder = heater
    if period != 120:
        pytest.skip("a file check: one rate")
    work = tmp_path / "bad"
    shutil.copytree(folder, work)
    p = work / "heater.unit.toml"
    text = p.read_text()
    # a typo'd row: no test reads HEAT_TGTX
    idle = re.sub(r"(?m)^HEAT_TGT = \{", "HEAT_TGTX = {", text)
    assert idle != text
    p.write_text(idle)
    with pytest.raises(UnitError) as e:
        Unit.load(p, work)
    line = next(i for i, s in enumerate(idle.splitlines(), 1) if s.startswith("HEAT_TGTX = {"))
    assert f"heater.unit.toml:{line}: [chosen] HEAT_TGTX: not the set-point of a loop test" in str(
        e.value
    )
    broken = re.sub(r"(?m)^HEAT_TGT = \{.*\}$", "HEAT_TGT = { min = 70.0 }", text)
    assert broken != text
    p.write_text(broken)
    with pytest.raises(UnitError) as e:
        Unit.load(p, work)
    assert "[chosen] HEAT_TGT: must be { min = …, max = …, margin = … } (max missing" in str(
        e.value
    )
