"""A short window's blind slow tag and the test that covers it out of the combined T² (issue 34,
SKAB round 14; docs/how-to/unit-short-windows.md).

A pipe at 1 s (physics written here, not a plant the build was tuned on): the temperature at
its inlet ``TI1`` wanders (a time constant of 12 s: about 17 independent values in 400 s, a
slow tag), and the outlet ``TI2`` is the inlet 35 s later, beside a flow that has nothing to
do with them. From 400 samples ``TI2``'s test reads ``TI1`` 35 s back (a parity relation),
and no input predicts ``TI1`` (the outlet only follows it); ``TI1`` is too slow for a level
test. A rise of
the feed's temperature then moves both together: it cancels in ``TI2``'s test and ``TI1`` has
none — the unit on main is blind to it (SKAB's other/5: two accelerometers). The build now
adds the pair's joint test (their score on the first principal component) and keeps it out of
the combined ``T²`` (``combined = false``: a test added for a blind tag sees nothing of what
the other tests see, and as one more dimension of ``T²`` would lower ``T²`` through them).
The setting round-trips through the unit file, ``diag unit learn`` and ``diag unit accept``
keep it, and the live plant's batched path gives the one-by-one path's statuses with it.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tests.test_any_plant_tour import diag, fmt, import_csv
from tests.test_unit_joint import _ou
from tests.test_unit_short import _statuses, build_short_unit

ROWS = 400
#: the pipe's transport delay, samples (inside the build's 40-sample dead-time horizon)
DELAY = 35


def pipe(seed: int, n: int, rise_from: int | None = None, start: str = "2026-05-04 08:00"):
    """The pipe at 1 s: ``TI1`` (the feed's temperature, °C, an Ornstein–Uhlenbeck wander of
    0.3 °C with a time constant of 12 s), ``TI2`` the same temperature :data:`DELAY` s later
    (each sensor with its own 0.01 °C noise), ``FLOW`` its own demand. With ``rise_from`` the
    feed warms from that sample on by 0.5 °C a minute (6 of seeds 1-8 leave ``TI1`` blind on
    main; seeds 1 and 6 give it a test of its own)."""
    rng = np.random.default_rng([seed, 14])
    m = n + DELAY
    feed = 60.0 + 0.3 * _ou(rng, m, 12.0)
    if rise_from is not None:
        k = np.arange(m) - DELAY - rise_from
        feed = feed + np.where(k > 0, 0.5 * k / 60.0, 0.0)
    flow = 32.0 + 0.3 * _ou(rng, n, 2.0) + 0.3 * rng.normal(size=n)
    return pd.DataFrame(
        {
            "TI1": feed[DELAY:] + 0.01 * rng.normal(size=n),
            "TI2": feed[:n] + 0.01 * rng.normal(size=n),
            "FLOW": flow,
        },
        index=pd.date_range(start, periods=n, freq="1s", name="ts"),
    )


def record_t2(cm) -> list[float]:
    """The combined T² of each call of ``cm.evaluate`` (a live plant's model, one sample a
    cycle), appended to the list returned as the plant runs."""
    got: list[float] = []
    evaluate = cm.evaluate

    def recorded(r, point=None):
        out = evaluate(r, point)
        got.append(out[0][0])
        return out

    cm.evaluate = recorded
    return got


def _pair_test(unit) -> str:
    return next(t.name for t in unit.file.tests if t.name.endswith("_pair"))


@pytest.fixture()
def built(tmp_path):
    frame = pipe(3, ROWS + 1800, rise_from=ROWS + 600)
    g, text, unit = build_short_unit(tmp_path, frame.iloc[:ROWS])
    return g, text, unit, frame


def test_a_blind_slow_pair_gets_a_pair_test_that_sees_their_common_rise(built):
    g, text, unit, frame = built
    rows = unit.file.build["tests"]
    ti2 = next(r for r in rows.values() if r["tag"] == "TI2")
    assert len(ti2["inputs"]) == 1 and ti2["inputs"][0].startswith("TI1[k-"), ti2
    assert "TI1" in unit.file.build["skipped"]  # no test of its own: too slow for a level test
    name = _pair_test(unit)  # fails on main: no such test, TI1 is blind
    assert unit.file.test(name).combined is False
    assert "combined = false" in unit.file.path.read_text()
    assert "pair test of TI2 and TI1[k-" in rows[name]["why"], rows[name]
    alarm, _, _ = _statuses(unit, frame)
    k = np.arange(len(frame))
    quiet = (k >= ROWS) & (k < ROWS + 600)
    rise = k >= ROWS + 1200  # ten minutes into the rise: 5 °C, many times the wander
    print(f"rise: unit in alarm {alarm[rise].mean():.2f}; before it {alarm[quiet].mean():.2f}")
    assert alarm[rise].mean() > 0.9 and alarm[quiet].mean() < 0.1
    d = unit.reset().evaluate(frame)
    assert d.symptoms[name].to_numpy()[rise].mean() > 0.9  # its own alarm, not T²'s


def test_a_test_kept_out_leaves_the_combined_t2_as_the_other_tests_make_it(built):
    """``T²`` is taken over the other tests only: whatever the kept-out test's residual, the
    same ``T²`` (its threshold learned on the same statistic), and its dimensions are the
    other tests' (no χ² mapping to one more degree of freedom)."""
    g, text, unit, frame = built
    name = _pair_test(unit)
    j = unit.tests.index(name)
    cm = unit.cmodel
    assert cm.outside is not None and cm.outside.tolist() == [t == name for t in unit.tests]
    assert cm.dims == len(unit.tests) - 1
    assert unit.file.combined.tests == unit.tests  # every test still listed (file checks)
    r = unit.reset().evaluate(frame).residuals.to_numpy()
    t2 = cm.evaluate(r, shares=False)[0]
    wild = r.copy()
    wild[:, j] = 1e6
    np.testing.assert_array_equal(cm.evaluate(wild, shares=False)[0], t2)
    others = [i for i in range(len(unit.tests)) if i != j]
    z = (r[:, others] - cm.center[others]) / cm.scale[others]
    inv = np.linalg.pinv(cm.cov[np.ix_(others, others)])
    ok = np.isfinite(z).all(axis=1)
    np.testing.assert_allclose(t2[ok], np.einsum("ij,jk,ik->i", z[ok], inv, z[ok]), rtol=1e-9)


def test_the_setting_round_trips_and_the_live_path_equals_the_replay_with_it(built, tmp_path):
    from diag_plugin.diagnose.plant import Plant
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.diagnose.unitfile import UnitError, UnitFile

    g, text, unit, frame = built
    name = _pair_test(unit)
    path = unit.file.path
    # learned again: the row keeps its setting
    rc, out = diag(g, "unit", "learn", "u", "--from", fmt(frame.index[0]),
                   "--to", fmt(frame.index[ROWS]))  # fmt: skip
    assert rc == 0, out
    again = Unit.load(path, tmp_path / "rb")
    assert again.file.test(name).combined is False and again.cmodel.outside is not None
    assert [t.combined for t in again.file.tests].count(False) == 1
    # a wrong value is a file:line problem
    bad = path.read_text().replace("combined = false", 'combined = "no"', 1)  # [tests]
    with pytest.raises(UnitError, match="combined must be true or false"):
        UnitFile(bad, path)
    # the live plug-in: batched and one by one, and its T² the replay's
    rb = [path]
    fast = Plant.load(rb, tmp_path / "rb")
    slow = Plant(Plant.load(rb, tmp_path / "rb").units, batched=False)
    assert fast.fast == ["u"] and slow.slow == ["u"]
    part = frame.iloc[ROWS : ROWS + 1000]
    replay = again.reset().evaluate(part)
    got = record_t2(fast._multi[0][1])
    for ts, row in part.iterrows():
        values = row.to_dict()
        (x,), (y,) = fast.cycle(ts, values), slow.cycle(ts, values)
        assert (x.status, x.faults, x.message) == (y.status, y.faults, y.message), ts
    np.testing.assert_allclose(got, replay.combined["T2"].to_numpy(), rtol=1e-9, equal_nan=True)


def test_unit_accept_keeps_a_test_out_of_the_combined_t2(built, tmp_path):
    g, text, unit, frame = built
    from diag_plugin.diagnose.unit import Unit

    name = _pair_test(unit)
    later = pipe(4, 3600, start="2026-05-04 12:00")
    import_csv(g, later, tmp_path / "later.csv")
    rc, out = diag(g, "unit", "accept", "u", "--from", fmt(later.index[0]),
                   "--to", fmt(later.index[-1]))  # fmt: skip
    assert rc == 0, out
    acc = Unit.load(unit.file.path, tmp_path / "rb")
    assert acc.file.test(name).combined is False
    assert acc.cmodel.outside is not None and acc.cmodel.dims == len(acc.tests) - 1
    assert acc.file.combined.point_center and len(acc.file.combined.point_center) == 2
    r = acc.reset().evaluate(later).residuals.to_numpy()
    wild = r.copy()
    wild[:, acc.tests.index(name)] = 1e6
    point = acc.cmodel.point_of(later)
    np.testing.assert_array_equal(
        acc.cmodel.evaluate(wild, point, shares=False)[0],
        acc.cmodel.evaluate(r, point, shares=False)[0],
    )


def test_the_pair_tests_alarm_names_the_blind_tag_in_the_replay_and_live(built, tmp_path):
    """Issue 34 item 4: the kept-out pair test adds nothing to ``T²`` and so to no tag's share
    of it; in alarm it names its own tags (``TI2``, the tag it models, and ``TI1``, the blind
    one it reads) ahead of the ``T²`` contributions (:class:`~diag_plugin.diagnose.unittags.
    TestNames`). On main the rise is named from ``T²`` alone, without ``TI1``. The live
    plug-in, batched and one by one, names the replay's tags."""
    from diag_plugin.diagnose.plant import Plant

    g, text, unit, frame = built
    name = _pair_test(unit)
    d = unit.reset().evaluate(frame)
    k = np.arange(len(frame))
    rise = k >= ROWS + 1200
    pair_on = (d.symptoms[name].to_numpy() != 0) & rise
    assert pair_on[rise].mean() > 0.9
    top = d.top[["top1", "top2", "top3"]].to_numpy(object)
    named = (top == "TI1").any(axis=1)
    print(f"pair test in alarm: TI1 in the top three {named[pair_on].mean():.2f}")
    assert named[pair_on].mean() > 0.9  # fails on main: 0
    assert set(top[pair_on, 0]) <= {"TI1", "TI2"}  # ranked first: its statistic over 1
    rb = [unit.file.path]
    fast = Plant.load(rb, tmp_path / "rb")
    slow = Plant(Plant.load(rb, tmp_path / "rb").units, batched=False)
    part = frame.iloc[ROWS + 1100 : ROWS + 1400]
    replay = unit.reset().evaluate(part).top
    seen = 0
    for i, (ts, row) in enumerate(part.iterrows()):
        values = row.to_dict()
        (x,), (y,) = fast.cycle(ts, values), slow.cycle(ts, values)
        assert x.tags == y.tags, ts
        want = [t for t in replay.iloc[i][["top1", "top2", "top3"]] if t]
        assert [t for t, _ in x.tags] == want, ts
        want_v = [v for v in replay.iloc[i][["share1", "share2", "share3"]] if v == v]
        np.testing.assert_allclose([v for _, v in x.tags], want_v, rtol=1e-9)
        seen += "TI1" in want
    assert seen > 200
