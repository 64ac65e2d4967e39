"""A short window's slow tag that no other tag predicts gets a slow level test, kept out of the
combined T² (issue 34, H1; docs/how-to/unit-short-windows.md, "What the low limits sit on").

A circulation loop at 1 s (physics written here, not a plant the build was tuned on): the
supply temperature ``TS`` wanders slowly (an Ornstein–Uhlenbeck wander of 0.05 °C with a time
constant of 40 s: a handful of independent values in 400 s), and two fast tags that share a
cause, a pump's current ``I`` and its vibration ``VIB``, have nothing to do with it. From 400
samples no input predicts ``TS`` and it is far too slow for a level test in ``T²``: on main it
is left untested, and a hotter supply (SKAB's "hotter water supply"; the tuning run other/10's
fluid temperature, 26 window spreads up) moves a tag no test reads. Now it gets a level test
of its own, kept out of ``T²`` and judged on its own threshold: the unit alarms on the hotter
supply and names ``TS``, stays quiet before it, and ``T²`` is the other tests' as before.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tests.test_unit_joint import _ou
from tests.test_unit_short import _statuses, build_short_unit

ROWS = 400
#: when the supply turns hotter, samples after the window
HOT_FROM = 600


def loop(seed: int, n: int, hot: float = 3.0) -> pd.DataFrame:
    """The loop at 1 s: ``TS`` (°C) 60 + a slow 0.05 °C wander + 0.005 °C noise, ``hot`` °C
    hotter from ``ROWS + HOT_FROM`` on (3 °C: the threshold of a level test from a handful of
    values sits at up to 50 of the window's residual spreads, seed 2's over 1.5 °C); ``I``
    and ``VIB`` one fast wander (2 s) seen twice, each with its own noise."""
    rng = np.random.default_rng([seed, 34])
    ts = 60.0 + 0.05 * _ou(rng, n, 40.0) + 0.005 * rng.normal(size=n)
    ts[ROWS + HOT_FROM :] += hot
    x = _ou(rng, n, 2.0)
    return pd.DataFrame(
        {
            "TS": ts,
            "I": 12.0 + 0.4 * x + 0.1 * rng.normal(size=n),
            "VIB": 3.0 + 0.2 * x + 0.05 * rng.normal(size=n),
        },
        index=pd.date_range("2026-05-04 08:00", periods=n, freq="1s", name="ts"),
    )


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_slow_tag_no_other_predicts_gets_a_level_test_out_of_t2(tmp_path, seed):
    frame = loop(seed, ROWS + HOT_FROM + 600)
    g, text, unit = build_short_unit(tmp_path, frame.iloc[:ROWS])
    rows = unit.file.build["tests"]
    # fails on main: TS is left untested ("too slow for a level test")
    assert "TS" in rows and "TS" not in unit.file.build["skipped"], text
    assert not rows["TS"]["inputs"] and "slow level test" in rows["TS"]["why"], rows["TS"]
    assert unit.file.test("TS").combined is False
    assert unit.cmodel.outside is not None
    assert unit.cmodel.outside.tolist() == [t == "TS" for t in unit.tests]
    alarm, _, _ = _statuses(unit, frame)
    k = np.arange(len(frame))
    quiet = (k >= ROWS) & (k < ROWS + HOT_FROM)
    hot = k >= ROWS + HOT_FROM + 60  # a minute after the supply turned hotter
    print(f"seed {seed}: hotter supply in alarm {alarm[hot].mean():.2f}, "
          f"before it {alarm[quiet].mean():.2f}")  # fmt: skip
    assert alarm[hot].mean() > 0.9 and alarm[quiet].mean() < 0.1
    d = unit.reset().evaluate(frame)
    assert d.symptoms["TS"].to_numpy()[hot].mean() > 0.9  # its own alarm: T² does not see TS
    top = d.top[["top1", "top2", "top3"]].to_numpy(object)[hot & alarm]
    assert (top == "TS").any(axis=1).mean() > 0.9  # the alarm names the slow tag
    # T² is the other tests' alone: whatever TS's residual, the same T²
    r = d.residuals.to_numpy()
    wild = r.copy()
    wild[:, unit.tests.index("TS")] = 1e6
    t2 = unit.cmodel.evaluate(r, shares=False)[0]
    np.testing.assert_array_equal(unit.cmodel.evaluate(wild, shares=False)[0], t2)


def test_the_slow_level_test_runs_live_and_stays_out_after_unit_accept(tmp_path):
    """The live plug-in, batched and one by one, gives the replay's statuses with the slow
    level test in the unit; ``diag unit accept`` of a later fault-free hour keeps it out of
    ``T²`` (``T²`` unmoved by its residual at every operating point)."""
    from diag_plugin.diagnose.plant import Plant
    from diag_plugin.diagnose.unit import Unit
    from tests.test_any_plant_tour import diag, fmt, import_csv

    frame = loop(1, ROWS + HOT_FROM + 600)
    g, text, unit = build_short_unit(tmp_path, frame.iloc[:ROWS])
    assert unit.file.test("TS").combined is False  # fails on main: no test of TS
    rb = [unit.file.path]
    fast = Plant.load(rb, tmp_path / "rb")
    slow = Plant(Plant.load(rb, tmp_path / "rb").units, batched=False)
    assert fast.fast == ["u"] and slow.slow == ["u"]
    part = frame.iloc[ROWS + HOT_FROM - 100 : ROWS + HOT_FROM + 200]
    replay = unit.reset().evaluate(part)
    for ts, row in part.iterrows():
        values = row.to_dict()
        (x,), (y,) = fast.cycle(ts, values), slow.cycle(ts, values)
        assert (x.status, x.faults, x.message) == (y.status, y.faults, y.message), ts
    assert x.status == replay.status.iloc[-1]  # in alarm on the hotter supply, as replayed
    later = loop(5, 3600, hot=0.0)
    later.index = pd.date_range("2026-05-04 12:00", periods=len(later), freq="1s", name="ts")
    import_csv(g, later, tmp_path / "later.csv")
    rc, out = diag(g, "unit", "accept", "u", "--from", fmt(later.index[0]),
                   "--to", fmt(later.index[-1]))  # fmt: skip
    assert rc == 0, out
    acc = Unit.load(unit.file.path, tmp_path / "rb")
    assert acc.file.test("TS").combined is False
    r = acc.reset().evaluate(later).residuals.to_numpy()
    wild = r.copy()
    wild[:, acc.tests.index("TS")] = 1e6
    point = acc.cmodel.point_of(later)
    np.testing.assert_array_equal(
        acc.cmodel.evaluate(wild, point, shares=False)[0],
        acc.cmodel.evaluate(r, point, shares=False)[0],
    )
