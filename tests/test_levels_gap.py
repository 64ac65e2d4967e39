"""No coarse level bridges a gap in one input (issue 34, item 5).

A pasteuriser's feed pump, ``FEED_VFD = f(FEED_FLOW_SP, …)``, learned production rates of
8.5-11 m³/h, idle (0) and the cleaning's 14 m³/h: the coarse levels filled the empty sets
between 11.3 and 14 and answered a new rate of 12.7 m³/h as if they knew it
(docs/explanation/acceptance-pasteuriser.md, item (c)). Here the same shape on a synthetic
plant (a set-point held at a few values for long, a continuous second input): the answer in
the gap is withdrawn (NaN, reason *gap*), the held values still answer, and a continuous
input's sparse tail, empty sets between sets of a few samples, is bridged as before.
"""

from __future__ import annotations

import numpy as np

from diag_plugin.fuzzy.stack import WangMendelStack
from diag_plugin.fuzzy.wang_mendel import (
    REASON_GAP,
    WangMendelRegressor,
    occupancy_gaps,
)

#: the set-point's values (m³/h), held for hours: sets 0, 14-17 and 21 of 31 on 0-20
HELD = (0.0, 28 / 3, 10.0, 32 / 3, 34 / 3, 14.0)


def _setpoint_plant(seed: int, n: int = 20_000):
    """A set-point stepping through :data:`HELD` every 400-1,200 samples, a continuous
    pressure, and the pump speed they set."""
    rng = np.random.default_rng(seed)
    sp = np.empty(n)
    i = 0
    j = 0
    while i < n:  # each value in turn, for 400-1,200 samples
        k = int(rng.integers(400, 1200))
        sp[i : i + k] = HELD[j % len(HELD)]
        i, j = i + k, j + 1
    p = 2.0 + 0.3 * np.sin(np.arange(n) / 500.0) + rng.normal(0, 0.05, n)
    y = 5.0 * sp + 3.0 * p + rng.normal(0, 0.2, n)
    return np.column_stack([sp, p]), y


def _fit(X, y):
    """The model, its set-point (input 0) marked as a unit marks an operator's input."""
    m = WangMendelRegressor(input_spans=[(0.0, 20.0), (1.0, 3.0)], n_sets=31).fit(X, y)
    m.unbridged = (0,)
    return m


def test_an_answer_across_a_set_points_gap_is_withdrawn():
    X, y = _setpoint_plant(3)
    m = _fit(X, y)
    # 11.33 and 14 are sets 17 and 21 (step 0.667): the three sets between them empty
    gaps = m.input_gaps()
    assert gaps[0].tolist() == [[0, 14], [17, 21]]
    assert gaps[1].size == 0  # the continuous pressure: none
    q = np.column_stack([[12.7, 12.3, 13.2, 10.3, 14.0, 5.0], np.full(6, 2.0)])
    # unmarked, the levels bridge it as the paper's levels do (a measured input's gap)
    m.unbridged = ()
    assert np.isfinite(m.predict_detail(q).y).all()
    m.unbridged = (0,)
    det = m.predict_detail(q)
    # in the gap (12.3-13.2 and 5.0): no answer, reason gap
    for r in (0, 1, 2, 5):
        assert np.isnan(det.y[r]), r
        assert det.reason[r] == REASON_GAP or det.support[r] < 0.9, r
    assert (det.reason[[0, 5]] == REASON_GAP).all()  # a coarse level had answered there
    # the held values answer with the fine rules' full weight, as before
    for r in (3, 4):
        assert det.support[r] >= 0.9 and abs(det.y[r] - (5 * q[r, 0] + 6.0)) < 1.5, r
    # the stacked kernel of many models (the live loop) withdraws the same rows
    other = _fit(*_setpoint_plant(4))
    stack = WangMendelStack.from_models([other, m])
    sd = stack.predict_detail(np.ones(6, np.int64), q)
    np.testing.assert_array_equal(np.isnan(sd.y), np.isnan(det.y))
    np.testing.assert_array_equal(sd.reason, det.reason)


def test_a_continuous_inputs_sparse_tail_is_still_bridged():
    """Empty fine sets between a few samples each, in the tails of a continuous input (an
    unseen seed of noise): no gap, and every value between its first and last occupied set
    still answers where it did."""
    rng = np.random.default_rng(11)
    n = 6000
    X = np.column_stack([rng.standard_t(3, n) * 0.9 + 10.0, rng.uniform(1, 3, n)])
    y = 2.0 * X[:, 0] + X[:, 1] + rng.normal(0, 0.1, n)
    m = _fit(X, y)
    counts = m.set_counts()[0]
    occ = np.flatnonzero(counts > 0)
    holes = [s for s in range(occ[0], occ[-1]) if counts[s] == 0]
    assert holes, "the seed must leave empty sets inside the tail for this test to mean anything"
    assert m.input_gaps()[0].size == 0
    step = 20.0 / 30
    q = np.column_stack([np.array(holes) * step, np.full(len(holes), 2.0)])
    det = m.predict_detail(q)
    assert not (det.reason == REASON_GAP).any()
    assert np.isfinite(det.y).all()


def test_occupancy_gaps_weigh_the_run_against_the_typical_set():
    # a set-point: thousands on both sides of 3 empty sets
    assert occupancy_gaps(np.r_[5000, 0, 0, 0, 4000, 4500]).tolist() == [[0, 4]]
    # a sparse tail: 2 and 1 samples either side of an empty set, the core thousands
    assert occupancy_gaps(np.r_[2, 0, 1, 3000, 5000, 4000]).size == 0
    # a thin edge set beside a long run: 3 empty x 40 = 120 <= the median 4000
    assert occupancy_gaps(np.r_[40, 0, 0, 0, 4000, 4000, 4500]).size == 0
    assert occupancy_gaps(np.r_[0, 0, 7, 0]).size == 0
