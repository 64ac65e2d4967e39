"""The frozen-value clock of the live loop (:class:`diag_plugin.live.stale.StaleDetector`):
a Bad stretch restarts it (issue 38, bug 15).

A tag whose value stays the same is stale once it has been unchanged for longer than its
limit. While its samples are Bad it is not judged (age NaN, never stale); when Good samples
come back, with the value it had before, the clock starts again at that first Good sample:
the time it spent Bad is no time it was seen frozen. Checked at cycles of 1 s and 1 min,
timestamps off the grid, Bad samples carrying the old value (a source's last value with a
Bad status) or NaN, and with OPC UA source timestamps.
"""

from __future__ import annotations

import numpy as np
import pytest

from connectors.base import TagQuality
from diag_plugin.live.stale import StaleDetector

GOOD, BAD = int(TagQuality.GOOD), int(TagQuality.BAD)


@pytest.mark.parametrize("period", [1.0, 60.0])
@pytest.mark.parametrize("bad_value", ["kept", "nan"])
@pytest.mark.parametrize("source_ts", [False, True])
def test_a_bad_stretch_restarts_the_stale_clock(period, bad_value, source_ts):
    limit = 5.5 * period  # stale after more than 5.5 periods unchanged
    det = StaleDetector(["T", "moving"], stale_after=limit)
    t0 = 1_700_000_000.37  # off the grid
    v = 20.0
    history = []  # (cycle, quality of T, stale T, age T)
    # cycles 0-3 Good (frozen), 4-11 Bad, 12-30 Good with the same value again
    for k in range(31):
        t = t0 + k * period
        bad = 4 <= k <= 11
        value = np.nan if (bad and bad_value == "nan") else v
        q = np.array([BAD if bad else GOOD, GOOD], np.uint8)
        src = np.array([t0, t], float) if source_ts else None  # T's source time frozen too
        stale, age = det.update(t, np.array([value, float(k)]), q, src)
        history.append((k, bad, bool(stale[0]), float(age[0])))
        assert not stale[1] and age[1] == 0.0  # a moving tag is never stale
    for k, bad, stale, age in history:
        if bad:
            assert np.isnan(age) and not stale, (k, age)
        elif k < 4:
            assert age == pytest.approx(k * period) and not stale, (k, age)
        else:  # the clock restarted at the first Good sample after the Bad stretch, cycle 12
            assert age == pytest.approx((k - 12) * period), (k, age)
            assert stale == ((k - 12) * period > limit), (k, age)
    assert [k for k, _, s, _ in history if s][0] == 18  # 6 periods after the Bad stretch


def test_a_value_change_still_restarts_the_clock_and_bad_alone_is_never_stale():
    det = StaleDetector(["T"], stale_after=3.0)
    q_good, q_bad = np.array([GOOD], np.uint8), np.array([BAD], np.uint8)
    ages = []
    for t, value, q in [
        (0, 1.0, q_good),
        (2, 1.0, q_good),
        (4, 1.0, q_good),  # 4 s unchanged > 3 s: stale
        (5, 2.0, q_good),  # changed: age 0
        (6, 2.0, q_bad),
        (100, 2.0, q_bad),  # a long Bad stretch is never stale
        (101, 2.0, q_good),
        (104, 2.0, q_good),
        (104.5, 2.0, q_good),
    ]:
        stale, age = det.update(float(t), np.array([value]), q)
        ages.append((t, bool(stale[0]), None if np.isnan(age[0]) else float(age[0])))
    assert ages == [
        (0, False, 0.0),
        (2, False, 2.0),
        (4, True, 4.0),
        (5, False, 0.0),
        (6, False, None),
        (100, False, None),
        (101, False, 0.0),
        (104, False, 3.0),
        (104.5, True, 3.5),
    ]


def test_a_cycle_that_did_not_read_the_tag_keeps_its_clock():
    """Issue 34: a poll late for the cycle's deadline (a loaded machine) gives the tag Bad
    for that cycle without reading it; taken as a Bad stretch it restarted the clock, and
    with a late poll every few cycles a frozen PLC was never judged stale
    (tests/test_live_hardened.py's frozen PLC at a load of 16-18). Such a cycle neither
    restarts nor judges the tag; a Bad sample the source reported still restarts it."""
    q_good, q_bad = np.array([GOOD], np.uint8), np.array([BAD], np.uint8)
    runs = {}
    for unread in (True, False):
        det = StaleDetector(["T"], stale_after=3.0)
        seen = []
        for t in np.arange(0.0, 10.0, 0.5):  # frozen at 7.0; every 4th cycle not read
            late = int(t * 2) % 4 == 3
            q = q_bad if late else q_good
            mask = np.array([late]) if unread else None
            stale, age = det.update(float(t), np.array([np.nan if late else 7.0]), q, None, mask)
            seen.append((float(t), bool(stale[0]), None if np.isnan(age[0]) else float(age[0])))
        runs[unread] = seen
    # not read: no judgement that cycle; the clock runs on from the first sample
    for t, stale, age in runs[True]:
        if int(t * 2) % 4 == 3:
            assert age is None and not stale, t
        else:
            assert age == t and stale == (t > 3.0), (t, age)
    # a Bad sample (the source said so) restarts it: never 3 s unchanged, never stale
    assert not any(s for _, s, _ in runs[False])
