"""Edges of the alarm lifecycle and severities a mutation check found untested (issue 28):
the severity of an alarm whose shelving runs out while its condition is on, shelving with or
without an end, an alarm shelved before it was ever raised, and exact severities at the ends of
the bands. Only the public interface (``Alarm``, ``severity``), so they hold through rewrites
of the module."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from connectors.alarms import Alarm, AlarmState, severity

S = AlarmState
T0 = datetime(2026, 1, 1, tzinfo=UTC)


def test_a_shelving_that_runs_out_while_on_annunciates_the_current_severity():
    a = Alarm("v1")
    a.update(True, 850, "f_P0", now=T0)
    a.shelve(now=T0, duration=timedelta(minutes=10))
    a.update(True, 870, "f_P0", now=T0 + timedelta(minutes=5))  # on, but shelved
    t = a.update(True, 990, "f_S", now=T0 + timedelta(minutes=10))
    assert t.after is S.ACTIVE_UNACK
    assert (a.severity, a.message) == (990, "f_S")  # what is annunciated now, not before


def test_shelving_without_an_end_lasts_until_unshelved_and_an_end_given_is_kept():
    a = Alarm("v1")
    a.update(True, 900, now=T0)
    assert a.shelve(now=T0).after is S.SHELVED  # no duration, no end: until unshelved
    assert a.shelved_until is None
    assert a.update(True, 900, now=T0 + timedelta(days=30)).after is S.SHELVED
    a.unshelve()
    end = T0 + timedelta(hours=1)
    a.shelve(until=end, now=T0, duration=timedelta(minutes=5))  # an end given wins
    assert a.shelved_until == end


def test_an_alarm_shelved_before_it_was_ever_raised_unshelves_to_normal():
    a = Alarm("v1")
    a.shelve()
    assert a.unshelve().after is S.NORMAL and not a.active and a.acked


@pytest.mark.parametrize(
    ("status", "certainty", "want"),
    [
        (1, 0.0, 801),
        (1, 0.25, 801 + 50),
        (1, 1.0, 1000),
        (3, 0.0, 601),
        (3, 0.25, 601 + 50),
        (4, 0.0, 301),
        (4, 0.25, 301 + 25),
        (4, 1.0, 400),
        (1, -0.5, 801),  # out of [0, 1]: clipped
        (4, float("nan"), 301),
    ],
)
def test_severity_within_a_band_follows_the_certainty_exactly(status, certainty, want):
    assert severity(status, certainty) == want
