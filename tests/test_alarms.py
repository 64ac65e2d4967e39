"""ISA-18.2 alarm state machine (connectors/alarms.py): each state × input; severity bands."""

from __future__ import annotations

import itertools
from datetime import UTC, datetime, timedelta

import pytest

from connectors.alarms import (
    Alarm,
    AlarmInput,
    AlarmState,
    condition,
    next_state,
    severity,
)

S, Ev = AlarmState, AlarmInput

#: the expected table, written out by hand from ISA-18.2's diagram: (state, input, condition)
EXPECTED = {
    # condition on
    (S.NORMAL, Ev.ON): S.ACTIVE_UNACK,
    (S.ACTIVE_UNACK, Ev.ON): S.ACTIVE_UNACK,
    (S.ACTIVE_ACK, Ev.ON): S.ACTIVE_ACK,
    (S.RTN_UNACK, Ev.ON): S.ACTIVE_UNACK,
    (S.SHELVED, Ev.ON): S.SHELVED,
    # condition off
    (S.NORMAL, Ev.OFF): S.NORMAL,
    (S.ACTIVE_UNACK, Ev.OFF): S.RTN_UNACK,
    (S.ACTIVE_ACK, Ev.OFF): S.NORMAL,
    (S.RTN_UNACK, Ev.OFF): S.RTN_UNACK,
    (S.SHELVED, Ev.OFF): S.SHELVED,
    # acknowledge
    (S.NORMAL, Ev.ACK): S.NORMAL,
    (S.ACTIVE_UNACK, Ev.ACK): S.ACTIVE_ACK,
    (S.ACTIVE_ACK, Ev.ACK): S.ACTIVE_ACK,
    (S.RTN_UNACK, Ev.ACK): S.NORMAL,
    (S.SHELVED, Ev.ACK): S.SHELVED,
    # shelve: from anywhere
    **{(s, Ev.SHELVE): S.SHELVED for s in S},
    # unshelve outside the shelf: nothing happens
    (S.NORMAL, Ev.UNSHELVE): S.NORMAL,
    (S.ACTIVE_UNACK, Ev.UNSHELVE): S.ACTIVE_UNACK,
    (S.ACTIVE_ACK, Ev.UNSHELVE): S.ACTIVE_ACK,
    (S.RTN_UNACK, Ev.UNSHELVE): S.RTN_UNACK,
}


@pytest.mark.parametrize(("state", "event"), list(itertools.product(S, Ev)))
def test_every_state_and_input(state, event):
    """All 25 (state, input) pairs; unshelving from the shelf depends on the condition."""
    if (state, event) == (S.SHELVED, Ev.UNSHELVE):
        assert next_state(state, event, condition=True) is S.ACTIVE_UNACK
        assert next_state(state, event, condition=False) is S.NORMAL
    else:
        for cond in (True, False):
            assert next_state(state, event, cond) is EXPECTED[(state, event)]


def test_table_is_complete():
    assert len(EXPECTED) == len(S) * len(Ev) - 1


def test_lifecycle_raise_ack_clear():
    a = Alarm("v1")
    t = a.update(True, severity=900, message="f17")
    assert t.changed and a.state is S.ACTIVE_UNACK and a.active and not a.acked and a.retain
    assert (a.severity, a.message) == (900, "f17")
    assert a.acknowledge().after is S.ACTIVE_ACK and a.acked and a.active
    assert not a.update(True, 900).changed
    t = a.update(False)
    assert t.after is S.NORMAL and not a.retain and not a.active
    assert a.severity == 900  # the last active severity stays for the clear event
    assert [x.after for x in a.history] == [S.ACTIVE_UNACK, S.ACTIVE_ACK, S.NORMAL]


def test_lifecycle_clear_before_ack():
    a = Alarm("v1")
    a.update(True, 700)
    assert a.update(False).after is S.RTN_UNACK and not a.active and not a.acked and a.retain
    assert a.update(True, 700).after is S.ACTIVE_UNACK  # comes back before anyone looked
    a.update(False)
    assert a.acknowledge().after is S.NORMAL
    assert not a.acknowledge().changed  # nothing left to acknowledge


def test_shelve_remembers_condition():
    a = Alarm("v1")
    a.update(True, 900)
    # shelved, the condition still on: Part 9 keeps it retained (an HMI hides it by
    # SuppressedOrShelved), ISA-18.2 no longer annunciates it
    assert a.shelve().after is S.SHELVED and a.shelved and not a.active and a.retain
    a.update(False)
    assert not a.retain  # shelved and off: nothing for an alarm list
    a.update(True, 950)
    assert a.state is S.SHELVED
    assert a.unshelve().after is S.ACTIVE_UNACK  # still on: annunciated afresh
    assert a.severity == 950
    a.shelve()
    a.update(False)
    assert a.unshelve().after is S.NORMAL


def test_shelving_expires():
    t0 = datetime(2026, 1, 1, tzinfo=UTC)
    a = Alarm("v1")
    a.update(True, 900, now=t0)
    a.shelve(now=t0, duration=timedelta(minutes=10))
    assert a.shelved_until == t0 + timedelta(minutes=10)
    assert a.update(True, 900, now=t0 + timedelta(minutes=5)).after is S.SHELVED
    t = a.update(True, 900, now=t0 + timedelta(minutes=10))
    assert t.event is Ev.UNSHELVE and t.after is S.ACTIVE_UNACK and a.shelved_until is None
    a.acknowledge()
    a.shelve(until=t0 + timedelta(minutes=20))
    t = a.update(False, now=t0 + timedelta(minutes=30))
    assert t.after is S.NORMAL


@pytest.mark.parametrize(
    ("status", "certainty", "band"),
    [
        (1, 0.0, (801, 801)),
        (1, 1.0, (1000, 1000)),
        (1, 0.5, (801, 1000)),
        (3, 0.0, (601, 601)),
        (3, 1.0, (800, 800)),
        (4, 0.3, (301, 400)),
        (4, 1.0, (400, 400)),
        (2, 0.9, (500, 500)),
        (0, 1.0, (0, 0)),
        (1, float("nan"), (801, 801)),
        (1, 7.0, (1000, 1000)),
    ],
)
def test_severity_bands(status, certainty, band):
    assert band[0] <= severity(status, certainty) <= band[1]


def test_confirmation_after_acknowledge_part9():
    """Part 9 §5.7.4: with confirmations asked for, an acknowledged alarm waits for Confirm
    (ConfirmedState False, still retained after it clears); without, it never waits."""
    a = Alarm("v1", confirmation=True)
    a.update(True, 900)
    assert a.confirmed and not a.confirm()  # nothing acknowledged: nothing to confirm
    a.acknowledge()
    assert not a.confirmed and a.retain
    a.update(False)
    assert a.state is S.NORMAL and a.retain  # cleared, but not yet confirmed
    assert a.confirm() and a.confirmed and not a.retain
    assert not a.confirm()
    plain = Alarm("v2")
    plain.update(True, 900)
    plain.acknowledge()
    plain.update(False)
    assert plain.confirmed and not plain.retain and not plain.confirm()


def test_condition_holds_condition_and_severity_through_check_function():
    """The one rule of the OPC UA server's alarm and the live loop's own: a fault status raises
    it at its band's severity, NORMAL clears it, CHECK_FUNCTION keeps both as they were (the
    loop's copy set the minor CHECK_FUNCTION severity, 500, where the server held the fault's)."""
    on, sev = condition(1, 1.0, False, 0)
    assert on and sev == 1000
    assert condition(2, 0.0, on, sev) == (True, 1000)
    assert condition(2, 0.0, False, 0) == (False, 0)
    assert condition(0, 0.0, True, 1000) == (False, 0)
    assert condition(3, float("nan"), False, 0) == (True, 601)
    assert condition(3, 1.0, False, 0, statuses=frozenset({1})) == (False, 0)
