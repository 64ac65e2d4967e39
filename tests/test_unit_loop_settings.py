"""The alarm settings of :mod:`diag_plugin.diagnose.unitloops` sample by sample (issue 34
items 4, 6, 7; closed under issue 38's mutation check): the unit's own off-delay, the spread
window in samples, the deadband on the low side, the episode hold's start. The unit-level
behaviour on a plant is in :mod:`tests.test_unit_loops`."""

from __future__ import annotations

import numpy as np
import pytest

from diag_plugin.diagnose.unitloops import AlarmHold, Deadband, EpisodeHold, spread_samples


def _reference_sources(active: list[bool], off: int, since: int) -> list[int]:
    """The hold written out sample by sample: a sample out of alarm repeats the last alarm
    row while fewer than ``off`` samples have passed since it (−1: the previous piece's)."""
    out, last, gap = [], None, since
    for i, a in enumerate(active):
        if a:
            last, gap = i, 0
            out.append(-2)
            continue
        gap += 1
        out.append((last if last is not None else -1) if gap < off else -2)
    return out


@pytest.mark.parametrize("off", [1, 2, 4, 16])
def test_the_units_off_delay_repeats_the_last_alarm_for_off_samples(off):
    rng = np.random.default_rng(off)
    act = rng.random(120) < 0.15
    act[:3] = [True, False, False]
    hold = AlarmHold(off)
    got = hold.sources(act)
    assert got.tolist() == _reference_sources(act.tolist(), off, off)
    # a piece that starts within the hold repeats the previous piece's last alarm row (−1)
    tail = act.size - 1 - np.flatnonzero(act)[-1]
    nxt = np.zeros(off + 2, bool)
    want = _reference_sources(nxt.tolist(), off, tail)
    assert hold.sources(nxt).tolist() == want
    assert (np.asarray(want) == -1).sum() == max(0, off - 1 - tail)


def test_the_off_delay_carries_across_pieces_and_through_its_state():
    act = np.zeros(30, bool)
    act[[4, 5, 20, 29]] = True
    whole = AlarmHold(6).sources(act)
    h = AlarmHold(6)
    first = h.sources(act[:8])
    h2 = AlarmHold(6)
    h2.load_state(h.to_state())
    rest = h2.sources(act[8:])
    # −1: the previous piece's last alarm row (5); rows of this piece counted from 8
    joined = first.tolist() + [5 if s == -1 else s + 8 if s >= 0 else s for s in rest]
    assert joined == whole.tolist()
    assert rest[:3].tolist() == [-1] * 3 and rest[3] == -2  # rows 8-10 hold row 5; 11 does not
    assert h2.sources(np.zeros(0, bool)).size == 0 and h2.to_state() == {"since": 0}
    # cut anywhere (right after an alarm row, one sample at a time), the pieces agree
    for cut in range(1, act.size):
        h = AlarmHold(6)
        a, b = h.sources(act[:cut]), h.sources(act[cut:])
        prev = np.flatnonzero(act[:cut])
        b = [int(prev[-1]) if s == -1 else s + cut if s >= 0 else s for s in b.tolist()]
        assert a.tolist() + b == whole.tolist(), cut
    h = AlarmHold(6)
    assert np.concatenate([h.sources(act[i : i + 1]) for i in range(act.size)]).tolist() == [
        -2 if s < 0 else -1 if s < i else s for i, s in enumerate(whole.tolist())
    ]


@pytest.mark.parametrize(
    "window_s,period,want",
    [(600.0, "1s", 600), (600.0, "15s", 40), (600.0, "7s", 86), (60.0, "1min", 5),
     (100.0, "3min", 5), (75.0, "15s", 5), (90.0, "15s", 6)],
)  # fmt: skip
def test_a_spread_window_is_its_seconds_in_samples_and_at_least_5(window_s, period, want):
    assert spread_samples(window_s, period) == want


def test_a_deadband_holds_a_symptom_until_back_inside_the_band_on_either_side():
    r = np.array([[-1.0], [-1.2], [-0.95], [-0.91], [-0.85], [-0.95], [np.nan], [-1.1], [2.0]])
    lo, hi = np.array([-1.0]), np.array([1.0])
    got = Deadband(0.1, 1).transform(r, lo, hi)[:, 0]
    # at the threshold itself it is not yet past it
    np.testing.assert_array_equal(got, [0, -1, -1, -1, 0, 0, np.nan, -1, 1])
    # the high side mirrors it: inside the band a symptom that is off stays off
    mirrored = Deadband(0.1, 1).transform(-r, lo, hi)[:, 0]
    np.testing.assert_array_equal(mirrored, -got)
    # without a threshold the symptom is unknown
    assert np.isnan(Deadband(0.1, 1).transform(r[:2], lo, np.array([np.nan]))).all()


def test_an_episode_hold_averages_from_the_start_of_each_episode():
    share = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 1.0], [5.0, 5.0], [1.0, 0.0], [0.0, 1.0]])
    act = np.array([True, True, True, False, True, True])
    got = EpisodeHold(2).transform(share, act)
    np.testing.assert_allclose(got[:3], [[1, 0], [0.5, 0.5], [1 / 3, 2 / 3]])
    assert np.isnan(got[3]).all()
    np.testing.assert_allclose(got[4:], [[1, 0], [0.5, 0.5]])
    # the episode left open goes on in the next piece; a closed one does not
    h = EpisodeHold(2)
    h.transform(share[:2], act[:2])
    np.testing.assert_allclose(h.transform(share[2:3], act[2:3]), [[1 / 3, 2 / 3]])
    h = EpisodeHold(2)
    h.transform(share[:4], act[:4])
    np.testing.assert_allclose(h.transform(share[4:5], act[4:5]), [[1, 0]])
