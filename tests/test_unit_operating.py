"""What CHECK_FUNCTION says when a unit's test has no rule (issue 34 item 5, closed under issue
38's mutation check of ``diagnose/operating.py``): the learned range of each input, the input
named outside it with its value and since when (carried from piece to piece), and the inputs
that are each inside but not together, or without a value.

:mod:`tests.test_unit_accept` checks the same through ``diag diagnose`` on one plant; these
check each sentence and each boundary through the public classes the unit uses."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from diag_plugin.diagnose.operating import OutsideLearned, Range, learned_ranges, model_ranges
from diag_plugin.fuzzy.wang_mendel import WangMendelRegressor
from diag_plugin.models.linear import LinearRegressor


def _frame(period: str, **cols) -> pd.DataFrame:
    n = len(next(iter(cols.values())))
    idx = pd.date_range("2026-05-01 00:00:03", periods=n, freq=period, tz="UTC")
    return pd.DataFrame({k: np.asarray(v, float) for k, v in cols.items()}, index=idx)


@pytest.mark.parametrize("lo,hi,sets", [(2.0, 4.0, 11), (31.0, 47.5, 21)])
def test_a_rule_grids_learned_range_is_its_outer_rule_sets_half_a_step_out(lo, hi, sets):
    rng = np.random.default_rng(5)
    x = np.c_[rng.uniform(lo, hi, 800), rng.uniform(0.0, 100.0, 800)]
    m = WangMendelRegressor(
        input_spans=[(0.0, 100.0), (0.0, 100.0)], output_span=(0.0, 200.0), n_sets=sets
    ).fit(x, x.sum(axis=1))
    step = 100.0 / (sets - 1)
    a, b = np.rint(x[:, 0].min() / step), np.rint(x[:, 0].max() / step)
    got = model_ranges(m, ["FLOW[k]", "dir(LEVEL)[k]"])  # a derived input is left out
    assert [t for t, *_ in got] == ["FLOW"]
    assert got[0][1] == pytest.approx((a - 0.5) * step)
    assert got[0][2] == pytest.approx((b + 0.5) * step)
    both = model_ranges(m, ["FLOW[k]", "LEVEL[k-1]"])
    assert both[1][1:] == pytest.approx((-0.5 * step, 100.0 + 0.5 * step))


def test_a_model_without_a_rule_grid_answers_over_its_nominal_span():
    rng = np.random.default_rng(6)
    x = rng.uniform(0.0, 1.0, (200, 2))
    m = LinearRegressor(input_spans=[(-3.0, 12.0), (0.5, 0.75)]).fit(x, x @ [1.0, 2.0])
    assert model_ranges(m, ["A[k]", "B[k-2]"]) == [("A", -3.0, 12.0), ("B", 0.5, 0.75)]


@pytest.mark.parametrize("period", ["1s", "15s", "3min"])
def test_the_input_outside_is_named_with_its_value_and_when_it_left(period):
    a = [3.0, 3.2, 5.25, 6.0, 4.0, 1.0, 1.25, 3.0]
    f = _frame(period, A=a)
    t = f.index
    ol = OutsideLearned([Range(0, "A", 1.5, 4.5)], names={"A": "PI-101"})
    unknown = np.ones((8, 1), bool)
    report = np.ones(8, bool)
    report[6] = False  # a row the unit answers is not explained
    out = ol.transform(f, unknown, report)
    sent = "PI-101 = {} outside what the unit learned (1.5 … 4.5) since {}"
    assert list(out[[2, 3, 5]]) == [
        sent.format("5.25", t[2].isoformat()),
        sent.format("6", t[2].isoformat()),  # the same excursion: since it began
        sent.format("1", t[5].isoformat()),
    ]
    # inside the range a test of one input has its value in a gap (no rule there)
    assert out[0] == "PI-101 = 3: in a gap of what the unit learned (1.5 … 4.5)"
    assert out[4].startswith("PI-101 = 4: in a gap") and out[6] == ""
    # the edges themselves were learned
    edge = ol.reset().transform(_frame(period, A=[1.5, 4.5]), np.ones((2, 1), bool),
                                np.ones(2, bool))  # fmt: skip
    assert all("in a gap of" in s for s in edge)


def test_only_an_unknown_tests_input_is_named_and_the_first_one_out_wins():
    f = _frame("10s", A=[9.0, 9.0, 9.0], B=[-5.0, -5.0, 0.0])
    ranges = [Range(0, "A", 0.0, 1.0), Range(1, "B", -1.0, 1.0), Range(1, "A", 0.0, 20.0)]
    unknown = np.array([[False, True], [True, True], [True, False]])
    out = OutsideLearned(ranges).transform(f, unknown, np.ones(3, bool))
    assert out[0].startswith("B = -5 outside")  # test 0 answers: its input A is not blamed
    assert out[1].startswith("A = 9 outside")
    assert out[2].startswith("A = 9 outside") and "(0 … 1)" in out[2]


def test_an_excursion_keeps_its_start_across_pieces():
    a = np.r_[np.full(5, 2.0), np.full(10, 7.0), np.full(5, 2.0), np.full(5, 7.0)]
    f = _frame("1min", A=a)
    t = f.index
    # out at 5-14 and from 20: pieces that begin out, are wholly out, and begin out, come
    # back and leave again (the second excursion has its own start)
    cuts = [0, 7, 11, 13, 22, 25]
    ol = OutsideLearned([Range(0, "A", 0.0, 5.0)])
    parts = [
        ol.transform(f.iloc[i:j], np.ones((j - i, 1), bool), np.ones(j - i, bool))
        for i, j in zip(cuts[:-1], cuts[1:], strict=True)
    ]
    whole = OutsideLearned([Range(0, "A", 0.0, 5.0)]).transform(
        f, np.ones((25, 1), bool), np.ones(25, bool)
    )
    assert list(np.concatenate(parts)) == list(whole)
    assert all(s.endswith(f"since {t[5].isoformat()}") for s in whole[5:15])
    assert all(s.endswith(f"since {t[20].isoformat()}") for s in whole[20:])
    # a piece that begins inside after an excursion does not inherit its start
    ol = OutsideLearned([Range(0, "A", 0.0, 5.0)])
    ol.transform(f.iloc[:15], np.ones((15, 1), bool), np.ones(15, bool))
    again = ol.transform(f.iloc[15:], np.ones((10, 1), bool), np.ones(10, bool))
    assert again[5].endswith(f"since {t[20].isoformat()}")


def test_one_input_inside_its_range_is_in_a_gap_not_together():
    """A test of one input with no rule at a value inside its learned range (acceptance pass
    10, docs/explanation/acceptance-pasteuriser.md: a pasteuriser's new production rate,
    12.6 m³/h, between the runs' 8.5-11 and the cleaning's 14 m³/h, `FEED_VFD =
    f(FEED_FLOW_SP)`): main said `FEED_FLOW_SP = 12.6: each within what the unit learned,
    but not together`, of one value; it is a gap in what the unit learned, with its range.
    A test of two inputs keeps its sentence, and each test is named by its own inputs."""
    f = _frame("1s", SP=[12.6, 12.6, 9.0], B=[1.0, 1.0, 2.0])
    ranges = [Range(0, "SP", 0.0, 14.0), Range(1, "SP", 0.0, 14.0, lag=2), Range(1, "B", 0.0, 4.0)]
    unknown = np.array([[True, False], [False, True], [False, True]])
    out = OutsideLearned(ranges, names={"SP": "FEED_FLOW_SP"}).transform(
        f, unknown, np.ones(3, bool)
    )
    assert out[0] == "FEED_FLOW_SP = 12.6: in a gap of what the unit learned (0 … 14)"
    assert "not together" not in out[0]
    assert out[1] == "FEED_FLOW_SP[k-2] without a value"
    assert out[2] == (
        "FEED_FLOW_SP[k-2] = 12.6, B = 2: each within what the unit learned, but not together"
    )


def test_inputs_inside_but_not_together_or_without_a_value_are_said_so():
    f = _frame("5s", A=[1.0, np.nan, 1.0, 2.0], B=[2.0, 3.0, np.nan, np.nan])
    ranges = [Range(0, "A", 0.0, 4.0), Range(0, "B", 0.0, 4.0), Range(0, "C", 0.0, 4.0)]
    unknown = np.ones((4, 1), bool)
    report = np.array([True, True, True, False])
    out = OutsideLearned(ranges, names={"B": "FT 2"}).transform(f, unknown, report)
    # C is not in the data: the sentence names the inputs it has
    assert list(out) == [
        "A = 1, FT 2 = 2: each within what the unit learned, but not together",
        "A without a value",
        "FT 2 without a value",
        "",
    ]
    # an empty piece says nothing and keeps what it carried
    ol = OutsideLearned(ranges)
    assert ol.transform(f.iloc[:0], unknown[:0], report[:0]).size == 0


def test_a_lagged_input_is_judged_by_the_value_the_model_reads():
    """A model reading A[k-3] is judged by A three samples back, named so, its history carried
    across pieces; the current value of A does not count (issue 34: a unit at 1 s reading
    lags up to k-595 blamed, or cleared, the input by its value now)."""
    a = np.r_[np.full(6, 2.0), np.full(4, 9.0), np.full(6, 2.0)]
    f = _frame("1s", A=a)
    t = f.index
    ranges = [Range(0, "A", 0.0, 5.0, lag=3)]
    unknown = np.ones((16, 1), bool)
    whole = (
        OutsideLearned(ranges, names={"A": "FT1"}).reset().transform(f, unknown, np.ones(16, bool))
    )
    # A is out at rows 6-9; the model reads it at rows 9-12; rows 0-2 have no A[k-3] yet
    assert list(whole[:3]) == ["FT1[k-3] without a value"] * 3
    for i in range(3, 16):
        if 9 <= i <= 12:
            assert (
                whole[i]
                == f"FT1[k-3] = 9 outside what the unit learned (0 … 5) since {t[9].isoformat()}"
            ), i
        else:
            assert whole[i] == "FT1[k-3] = 2: in a gap of what the unit learned (0 … 5)", i
    ol = OutsideLearned(ranges, names={"A": "FT1"}).reset()
    cuts = [0, 2, 8, 10, 16]
    parts = [
        ol.transform(f.iloc[i:j], unknown[i:j], np.ones(j - i, bool))
        for i, j in zip(cuts[:-1], cuts[1:], strict=True)
    ]
    assert list(np.concatenate(parts)) == list(whole)
    # the live loop's shortcut asks for the value at the lag: idle while A[k-3] is inside
    ol = OutsideLearned(ranges).reset()
    assert ol.idle(lambda tag, lag: {0: 9.0, 3: 2.0}[lag])
    assert not ol.idle(lambda tag, lag: {0: 2.0, 3: 9.0}[lag])


def test_a_restart_from_the_saved_state_judges_as_without_the_restart():
    """The range check's carried state (each excursion's start, each tag's last values for
    its lags) goes through JSON: pieces judged after a restart from it read as the whole
    run, and a fresh check after the restart does not (a unit run one by one saves it in
    ``Unit.to_state``)."""
    import json

    a = np.r_[np.full(6, 2.0), np.full(4, 9.0), np.full(6, 2.0)]
    f = _frame("1s", A=a)
    ranges = [Range(0, "A", 0.0, 5.0, lag=3)]
    unknown = np.ones((16, 1), bool)
    report = np.ones(16, bool)
    whole = OutsideLearned(ranges).reset().transform(f, unknown, report)
    for cut in (2, 8, 10, 11):
        before = OutsideLearned(ranges).reset()
        head = before.transform(f.iloc[:cut], unknown[:cut], report[:cut])
        state = json.loads(json.dumps(before.to_state()))
        after = OutsideLearned(ranges).reset().load_state(state)
        tail = after.transform(f.iloc[cut:], unknown[cut:], report[cut:])
        assert list(np.r_[head, tail]) == list(whole), cut
        cold = OutsideLearned(ranges).reset().transform(f.iloc[cut:], unknown[cut:], report[cut:])
        assert list(cold) != list(whole[cut:]), cut


def test_the_input_that_left_first_is_named_not_the_first_test_in_order():
    """A column's feed cut below any throughput learned, the steam the operators set two
    minutes after it, the condenser valve later (the column acceptance pass,
    docs/explanation/acceptance-column.md: `cw_valve[k-18] = 13.33 outside …` on 99.6 % of the
    CHECK_FUNCTION samples, the feed never named, its test the fifth of the unit). Test 0
    reads the valve, test 1 the steam, test 2 the feed two samples back: from row 6 all three
    are unknown and outside, and the feed, which left at row 2 (read at row 4), is named.
    Fails on main, which named the valve (the first range in order)."""
    feed = [50.0, 50.0, 35.0, 35.0, 35.0, 35.0, 35.0, 35.0, 35.0]
    steam = [10.0, 10.0, 10.0, 10.0, 7.0, 7.0, 7.0, 7.0, 7.0]
    valve = [20.0, 20.0, 20.0, 20.0, 20.0, 20.0, 13.0, 13.0, 13.0]
    f = _frame("1min", FEED=feed, STEAM=steam, CWV=valve)
    ranges = [Range(0, "CWV", 15.0, 38.0), Range(1, "STEAM", 7.5, 12.5),
              Range(2, "FEED", 40.0, 62.0, lag=2)]  # fmt: skip
    unknown = np.ones((9, 3), bool)
    ol = OutsideLearned(ranges, period_s=60.0).reset()
    out = ol.transform(f, unknown, np.ones(9, bool))
    t = f.index
    assert (
        out[6] == f"FEED[k-2] = 35 outside what the unit learned (40 … 62) since {t[4].isoformat()}"
    )
    assert out[8].startswith("FEED[k-2] = 35")
    assert out[5].startswith("FEED[k-2] = 35")  # the steam (row 4) left after the feed (row 2)
    # read at lag 0 the feed would have left at row 4 with the steam: a tie, the first in order
    tie = OutsideLearned([ranges[1], Range(2, "FEED", 40.0, 62.0)], period_s=60.0).reset()
    g = _frame("1min", FEED=[50, 50, 50, 50, 35, 35], STEAM=[10, 10, 10, 10, 7, 7])
    assert tie.transform(g, np.ones((6, 3), bool), np.ones(6, bool))[5].startswith("STEAM = 7")
    # across pieces: the feed's excursion carried from the first piece still wins
    ol.reset()
    ol.transform(f.iloc[:5], unknown[:5], np.ones(5, bool))
    later = ol.transform(f.iloc[5:], unknown[5:], np.ones(4, bool))
    assert later[1] == out[6]


def test_a_two_input_tests_set_point_in_a_gap_is_named_with_its_neighbours_and_since():
    """Issue 34 item 5 (the pasteuriser's new rate, run 171): a test of two inputs,
    ``FEED_VFD = f(FEED_FLOW_SP, P[k-6])``, learned a set-point at 0, 9.3-11.3 and 14 m³/h
    only; at 12.7 its model does not bridge the empty sets (unknown) and the sentence names
    the set-point, its value, the learned values either side and when it entered the gap,
    carried into the next piece, not "each within …, but not together". Main said
    ``FEED_FLOW_SP = 12.7, P[k-6] = 2: each within what the unit learned, but not together``
    (when its model was unknown at all)."""
    rng = np.random.default_rng(21)
    held = np.repeat(rng.choice([0.0, 28 / 3, 10.0, 32 / 3, 34 / 3, 14.0], 40), 300)
    p = rng.uniform(1.5, 2.5, held.size)
    m = WangMendelRegressor(input_spans=[(0.0, 20.0), (1.0, 3.0)], n_sets=31).fit(
        np.c_[held, p], 5 * held + 3 * p
    )
    m.unbridged = (0,)  # the set-point, as a unit marks it (unittags.unbridge)
    tm = type("TM", (), {"model": m, "inputs": ["SP[k]", "P[k-6]"]})()
    ranges = learned_ranges({"pump": tm}, ["pump"])
    gap = [r for r in ranges if r.gap and r.tag == "SP"]
    assert [(round(r.near[0], 2), round(r.near[1], 2)) for r in gap] == [(0, 9.33), (11.33, 14)]
    sp = np.r_[np.full(3, 34 / 3), np.full(4, 12.7)]
    f = _frame("10s", SP=sp, P=np.full(7, 2.0))
    x = np.c_[sp, np.full(7, 2.0)]
    unknown = ~(m.predict_detail(x).support >= 0.9)[:, None]
    assert not unknown[:3].any() and unknown[3:].all()  # the model itself: no answer at 12.7
    ol = OutsideLearned(ranges, names={"SP": "FEED_FLOW_SP"}).reset()
    first = ol.transform(f.iloc[:5], unknown[:5], unknown[:5, 0])
    t = f.index[3].isoformat()
    said = f"FEED_FLOW_SP = 12.7: in a gap of what the unit learned (11.33 … 14) since {t}"
    assert list(first) == ["", "", "", said, said]
    # the next piece: the entry carried
    assert list(ol.transform(f.iloc[5:], unknown[5:], unknown[5:, 0])) == [said, said]


def test_one_input_at_its_learned_edge_is_at_the_edge_not_in_a_gap():
    """Acceptance pass 11 (docs/explanation/acceptance-aeration2.md): a day at 10 s saw the
    zone 1 air valve at 18–58 %; the next day `AIR1 = f(DO1_VLV[k])` had no answer at 57.7–58.3
    %, inside the last rule set's outer half, where that rule carries under 90 % of the firing
    weight, and main said `DO1_VLV = 58.1: in a gap of what the unit learned (18.33 … 58.33)`
    on 107 samples: no gap, the range printed as if it were one. Within one set width of an end
    it is the edge; deeper inside it stays a gap; a model without a rule grid (no set width)
    keeps the gap sentence."""
    rng = np.random.default_rng(11)
    x = rng.uniform(19.0, 57.5, (3000, 1))
    wm = WangMendelRegressor(input_spans=[(0.0, 100.0)], output_span=(0.0, 8000.0), n_sets=31)
    wm.fit(x, 56.0 * x[:, 0])
    model = type("TestModel", (), {"model": wm, "inputs": ["DO1_VLV[k]"]})()
    ranges = learned_ranges({"AIR1": model}, ["AIR1"])
    step = 100.0 / 30
    plain = [r for r in ranges if not r.gap]
    lo, hi = plain[0].lo, plain[0].hi
    assert (lo, hi) == pytest.approx((step * 5.5, step * 17.5))  # 18.33 … 58.33
    f = _frame("10s", DO1_VLV=[58.1, hi - 1.5 * step, lo + 0.5, 40.0])
    out = OutsideLearned(ranges).transform(f, np.ones((4, 1), bool), np.ones(4, bool))
    said = f"what the unit learned ({lo:.4g} … {hi:.4g})"
    assert out[0] == f"DO1_VLV = 58.1: at the edge of {said}"
    assert out[1] == f"DO1_VLV = {hi - 1.5 * step:.4g}: in a gap of {said}"
    assert out[2] == f"DO1_VLV = {lo + 0.5:.4g}: at the edge of {said}"
    assert out[3] == f"DO1_VLV = 40: in a gap of {said}"
    assert [r.step for r in plain] == pytest.approx([step])
    lin = LinearRegressor(input_spans=[(0.0, 100.0)]).fit(x, 56.0 * x[:, 0])
    flat = learned_ranges({"AIR1": type("M", (), {"model": lin, "inputs": ["DO1_VLV[k]"]})()},
                          ["AIR1"])  # fmt: skip
    assert [r.step for r in flat] == [0.0]
    out = OutsideLearned(flat).transform(_frame("10s", DO1_VLV=[99.5]), np.ones((1, 1), bool),
                                         np.ones(1, bool))  # fmt: skip
    assert out[0] == "DO1_VLV = 99.5: in a gap of what the unit learned (0 … 100)"
