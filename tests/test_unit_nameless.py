"""An alarm names the tag whose test is on when the combined test names none (issue 34, item 4;
docs/explanation/acceptance-ahu.md, "Alarms that name nothing").

Three pairs of transmitters at 1 s (physics written here, not a plant the build was tuned on):
a flow, a temperature and a pressure, each measured twice along a line, the second reading
the first a few seconds later, each with its own noise. The build gives each tag a test of its
partner (six tests). Then the remote I/O card of the temperature and pressure transmitters
drops out (their four readings gone: four tests unknown, two known, fewer than the half
``T²`` needs) and the downstream flow meter ``F2`` reads high. ``F2``'s test fires; ``T²`` is
unknown, so no tag had a share of it: on main every alarm sample said ``faults = unit`` with
``top1`` empty. Now the test on names its own tag first (then the one it reads), held through
the episode, in the replay and in the live plant alike.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from diag_plugin.status import NE107
from tests.test_unit_joint import _ou
from tests.test_unit_short import build_short_unit

BUILD = 1200
#: the I/O card drops out, then the meter's bias starts (samples)
CARD_OUT = 1800
BIAS_FROM = 2000


def line(seed: int, n: int, bias: float = 0.0, start: str = "2026-05-04 08:00") -> pd.DataFrame:
    """The three pairs (``F`` t/h, ``T`` °C, ``P`` bar): a wander (an Ornstein–Uhlenbeck series
    of its own time constant) read at ``X1`` and, ``delay`` s later, at ``X2``, each reading
    with 2 % of the wander's spread as noise. With ``bias``: the card of ``T*`` and ``P*``
    out from :data:`CARD_OUT` and ``F2`` reading ``bias`` t/h high from :data:`BIAS_FROM`."""
    rng = np.random.default_rng([seed, 34, 4])
    cols = {}
    for p, (mean, sd, tau, delay) in {
        "F": (40.0, 2.0, 15.0, 3),
        "T": (60.0, 0.8, 25.0, 6),
        "P": (5.0, 0.3, 10.0, 2),
    }.items():
        x = mean + sd * _ou(rng, n + delay, tau)
        cols[f"{p}1"] = x[delay:] + 0.02 * sd * rng.normal(size=n)
        cols[f"{p}2"] = x[:n] + 0.02 * sd * rng.normal(size=n)
    out = pd.DataFrame(cols, index=pd.date_range(start, periods=n, freq="1s", name="ts"))
    if bias:
        k = np.arange(n)
        out.loc[k >= CARD_OUT, ["T1", "T2", "P1", "P2"]] = np.nan
        out.loc[k >= BIAS_FROM, "F2"] += bias
    return out


@pytest.fixture(scope="module", params=[3, 8])
def built(request, tmp_path_factory):
    tmp = tmp_path_factory.mktemp(f"line{request.param}")
    frame = line(request.param, 3000, bias=1.2)
    _, _, unit = build_short_unit(tmp, frame.iloc[:BUILD])
    return tmp, unit, frame


def _alarm(d) -> np.ndarray:
    return np.isin(d.status.to_numpy(), [NE107.FAILURE, NE107.OFF_SPEC])


def test_an_alarm_with_the_combined_test_unknown_names_the_test_on(built):
    tmp, unit, frame = built
    assert sorted(unit.tests) == ["F1", "F2", "P1", "P2", "T1", "T2"]
    assert unit.file.build["tests"]["F2"]["inputs"] == ["F1[k-3]"]  # the pairs' tests
    d = unit.reset().evaluate(frame.iloc[BUILD:])
    alarm = _alarm(d)
    s = d.symptoms.to_numpy()
    on = np.nan_to_num(s) != 0
    t2 = d.combined["T2"].to_numpy()
    blind = alarm & np.isnan(t2)  # T² unknown: no tag has a share of it
    print(f"alarm samples {alarm.sum()}, T² unknown on {blind.sum()}")
    assert blind.sum() > 300
    top1 = d.top["top1"].to_numpy(object)
    faults = d.faults.to_numpy(object)
    assert (top1[alarm] != "").all()  # fails on main: empty on every blind sample
    assert (faults[alarm] != "unit").all()  # main: "unit"
    # the tag of a test on (its own), on each sample where one is on
    tags = np.array(unit.tests, object)
    own = [top1[i] in set(tags[on[i]]) for i in np.flatnonzero(blind & on.any(axis=1))]
    assert all(own)
    assert set(top1[blind]) == {"F2"}
    assert set(d.top["top2"].to_numpy(object)[blind]) == {"F1"}  # the tag F2's test reads


def test_the_names_are_the_same_in_pieces_and_live(built):
    """The episode's names carried from piece to piece, and the live plant (batched and one
    by one) names the replay's tags."""
    from diag_plugin.diagnose.plant import Plant
    from diag_plugin.diagnose.unit import concat

    tmp, unit, frame = built
    part = frame.iloc[BUILD:]
    whole = unit.reset().evaluate(part).top
    unit.reset()
    a, b = BIAS_FROM - BUILD + 40, BIAS_FROM - BUILD + 300  # cut inside the episode
    pieces = concat([unit.evaluate(p) for p in (part.iloc[:a], part.iloc[a:b], part.iloc[b:])])
    pieces = pieces.top
    pd.testing.assert_frame_equal(pieces, whole)
    rb = [unit.file.path]
    fast = Plant.load(rb, tmp / "rb")
    slow = Plant(Plant.load(rb, tmp / "rb").units, batched=False)
    seen = 0
    for i, (ts, row) in enumerate(part.iterrows()):
        values = row.to_dict()
        (x,), (y,) = fast.cycle(ts, values), slow.cycle(ts, values)
        assert x.tags == y.tags, ts
        want = [t for t in whole.iloc[i][["top1", "top2", "top3"]] if t]
        assert [t for t, _ in x.tags] == want, ts
        if want:
            assert x.faults and x.faults != ["unit"], (ts, x.faults)
        seen += want[:1] == ["F2"]
    assert seen > 300


def test_the_bench_names_what_the_unit_names_where_t2_is_unknown(built):
    """The matched benchmark's naming of the unit (:func:`~diag_plugin.bench.publicbench.
    unit_score`'s contributions, ranked by :func:`~diag_plugin.bench.matched.ranked_tags`)
    names, where ``T²`` is unknown, the tags the unit's tests on name: ``F2`` (its test on),
    then ``F1`` (the tag it reads), as the unit's own ``top`` does. On main every share was
    unknown there and the bench named the first columns by the sort's tie order."""
    from diag_plugin.bench.matched import episode_names, ranked_tags
    from diag_plugin.bench.plant import top_from_contributions
    from diag_plugin.bench.publicbench import unit_score

    _, unit, frame = built
    part = frame.iloc[BUILD:]
    d = unit.reset().evaluate(part)
    blind = np.flatnonzero(_alarm(d) & np.isnan(d.combined["T2"].to_numpy()))
    assert blind.size > 300
    _, contrib = unit_score(unit.reset(), part, 1, 1)
    top = top_from_contributions(contrib.iloc[blind])
    on = (np.nan_to_num(d.symptoms.to_numpy()[blind]) != 0).any(axis=1)
    assert set(top["top1"][on]) == {"F2"} and set(top["top2"][on]) == {"F1"}
    assert set(top["top1"][~on]) <= {""}  # no test on: no tag named
    assert ranked_tags(contrib, blind)[:2] == ["F2", "F1"]
    assert set(episode_names(contrib, blind)) == {"F2"}
