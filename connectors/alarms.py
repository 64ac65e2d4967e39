"""The ISA-18.2 alarm state machine and the severity bands, pure Python (no I/O, no asyncua).

asyncua has no server-side acknowledge or shelve, so the OPC UA server (and any other
publisher) keeps one :class:`Alarm` per unit and reports its state.

States (ISA-18.2 §11, "alarm state transition diagram", without latching):

======================================  =========  ===========  ====================
state                                   condition  acknowledged  annunciated
======================================  =========  ===========  ====================
``normal``                              off        yes           no
``active-unacknowledged``               on         no            yes
``active-acknowledged``                 on         yes           yes
``return-to-normal-unacknowledged``     off        no            yes
``shelved``                             any        —             no (suppressed)
======================================  =========  ===========  ====================

Transitions (:func:`next_state`; the process condition is remembered separately, so a
shelved alarm knows where to return):

- condition on: normal → active-unacknowledged; return-to-normal-unacknowledged →
  active-unacknowledged; active-* stay; shelved stays shelved.
- condition off: active-unacknowledged → return-to-normal-unacknowledged;
  active-acknowledged → normal; others stay.
- acknowledge: active-unacknowledged → active-acknowledged;
  return-to-normal-unacknowledged → normal; others stay (nothing to acknowledge).
- shelve: any state → shelved (the operator takes the alarm off the list for a while).
- unshelve (by the operator or when the shelving time runs out): shelved →
  active-unacknowledged if the condition is on (it is annunciated afresh), else normal;
  other states stay.

Beside the ISA-18.2 state, :class:`Alarm` keeps what OPC UA Part 9 adds: ``confirmed``
(ConfirmedState) and the last operator ``comment``. With ``confirmation`` on, an
acknowledgement makes ``confirmed`` False until the operator confirms (OPC 10000-9 §5.7.4);
off (the default, as in ISA-18.2), an alarm is never waiting for a confirmation. ``retain``
(Part 9 §5.5.2) is True while the condition is on, or the alarm waits for an
acknowledgement or a confirmation.

Severity (OPC UA ``Severity`` 1–1000) from the unit's NE 107 status and the certainty of
its most certain fault, in the DESIGN.md bands (:func:`severity`):

================================  ==========  ======================================
NE 107 status                     band        severity
================================  ==========  ======================================
FAILURE (1)                       critical    801 + round(199 · certainty)
OFF_SPEC (3)                      major       601 + round(199 · certainty)
CHECK_FUNCTION (2)                minor       500 (the diagnosis cannot be trusted)
MAINTENANCE_REQUIRED (4)          maintenance 301 + round(99 · certainty)
NORMAL (0)                        —           no alarm (condition off)
================================  ==========  ======================================
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime, timedelta
from enum import StrEnum


class AlarmState(StrEnum):
    """The five ISA-18.2 states this product uses."""

    NORMAL = "normal"
    ACTIVE_UNACK = "active-unacknowledged"
    ACTIVE_ACK = "active-acknowledged"
    RTN_UNACK = "return-to-normal-unacknowledged"
    SHELVED = "shelved"


class AlarmInput(StrEnum):
    """What can happen to an alarm."""

    ON = "condition-on"
    OFF = "condition-off"
    ACK = "acknowledge"
    SHELVE = "shelve"
    UNSHELVE = "unshelve"


S, Ev = AlarmState, AlarmInput

#: the transition table, (state, input) → state; SHELVED/UNSHELVE depends on the condition
_TABLE: dict[tuple[AlarmState, AlarmInput], AlarmState] = {
    (S.NORMAL, Ev.ON): S.ACTIVE_UNACK,
    (S.NORMAL, Ev.OFF): S.NORMAL,
    (S.NORMAL, Ev.ACK): S.NORMAL,
    (S.NORMAL, Ev.UNSHELVE): S.NORMAL,
    (S.ACTIVE_UNACK, Ev.ON): S.ACTIVE_UNACK,
    (S.ACTIVE_UNACK, Ev.OFF): S.RTN_UNACK,
    (S.ACTIVE_UNACK, Ev.ACK): S.ACTIVE_ACK,
    (S.ACTIVE_UNACK, Ev.UNSHELVE): S.ACTIVE_UNACK,
    (S.ACTIVE_ACK, Ev.ON): S.ACTIVE_ACK,
    (S.ACTIVE_ACK, Ev.OFF): S.NORMAL,
    (S.ACTIVE_ACK, Ev.ACK): S.ACTIVE_ACK,
    (S.ACTIVE_ACK, Ev.UNSHELVE): S.ACTIVE_ACK,
    (S.RTN_UNACK, Ev.ON): S.ACTIVE_UNACK,
    (S.RTN_UNACK, Ev.OFF): S.RTN_UNACK,
    (S.RTN_UNACK, Ev.ACK): S.NORMAL,
    (S.RTN_UNACK, Ev.UNSHELVE): S.RTN_UNACK,
    (S.SHELVED, Ev.ON): S.SHELVED,
    (S.SHELVED, Ev.OFF): S.SHELVED,
    (S.SHELVED, Ev.ACK): S.SHELVED,
}


def next_state(state: AlarmState, event: AlarmInput, condition: bool) -> AlarmState:
    """The ISA-18.2 transition for ``event`` in ``state``; ``condition`` is the process
    condition after the event (only unshelving needs it)."""
    if event is Ev.SHELVE:
        return S.SHELVED
    if state is S.SHELVED and event is Ev.UNSHELVE:
        return S.ACTIVE_UNACK if condition else S.NORMAL
    return _TABLE[(state, event)]


@dataclass(frozen=True)
class Transition:
    """One applied input: the state before and after (``changed`` when they differ)."""

    before: AlarmState
    after: AlarmState
    event: AlarmInput

    @property
    def changed(self) -> bool:
        return self.before is not self.after


@dataclass
class Alarm:
    """One alarm: ISA-18.2 state, the remembered process condition, severity, shelving end.

    Feed the condition each cycle with :meth:`update`; the operator acts through
    :meth:`acknowledge`, :meth:`shelve` and :meth:`unshelve`. Each returns a
    :class:`Transition`; publish an event when ``changed``.
    """

    name: str
    state: AlarmState = AlarmState.NORMAL
    condition: bool = False
    severity: int = 0
    message: str = ""
    shelved_until: datetime | None = None
    confirmed: bool = True
    confirmation: bool = False
    comment: str = ""
    history: list[Transition] = field(default_factory=list, repr=False)

    def _apply(self, event: AlarmInput) -> Transition:
        t = Transition(self.state, next_state(self.state, event, self.condition), event)
        self.state = t.after
        if t.changed:
            self.history.append(t)
        return t

    def update(
        self, condition: bool, severity: int = 0, message: str = "", now: datetime | None = None
    ) -> Transition:
        """Set the process condition (on/off) for this cycle; ends an expired shelving first.

        ``severity`` and ``message`` are kept while the condition is on (the last active
        ones stay for return-to-normal)."""
        if now is not None and self.shelved_until is not None and now >= self.shelved_until:
            self.condition = condition
            self.shelved_until = None
            t = self._apply(Ev.UNSHELVE)
            if t.changed:
                if condition:
                    self.severity, self.message = severity, message
                return t
        self.condition = condition
        if condition:
            self.severity, self.message = severity, message
        return self._apply(Ev.ON if condition else Ev.OFF)

    def acknowledge(self) -> Transition:
        """The operator acknowledges (a no-op unless unacknowledged); with ``confirmation``
        the alarm then waits for a confirmation (Part 9 ConfirmedState False)."""
        t = self._apply(Ev.ACK)
        if t.changed and self.confirmation:
            self.confirmed = False
        return t

    def confirm(self) -> bool:
        """The operator confirms an acknowledged alarm (Part 9 §5.7.4); False when there was
        nothing to confirm."""
        if self.confirmed or not self.acked:
            return False
        self.confirmed = True
        return True

    def shelve(
        self,
        until: datetime | None = None,
        now: datetime | None = None,
        duration: timedelta | None = None,
    ) -> Transition:
        """Shelve until ``until`` (or ``now + duration``; None: until :meth:`unshelve`)."""
        if until is None and duration is not None and now is not None:
            until = now + duration
        self.shelved_until = until
        return self._apply(Ev.SHELVE)

    def unshelve(self) -> Transition:
        """Back from the shelf: re-annunciated if the condition is still on."""
        self.shelved_until = None
        return self._apply(Ev.UNSHELVE)

    @property
    def active(self) -> bool:
        """The ActiveState of OPC UA: the condition is on (and shown) — not while shelved."""
        return self.state in (S.ACTIVE_UNACK, S.ACTIVE_ACK)

    @property
    def acked(self) -> bool:
        """The AckedState of OPC UA: nothing waits for an acknowledge."""
        return self.state not in (S.ACTIVE_UNACK, S.RTN_UNACK)

    @property
    def shelved(self) -> bool:
        return self.state is S.SHELVED

    @property
    def retain(self) -> bool:
        """OPC UA Retain (Part 9 §5.5.2): the alarm still matters to an operator — its
        condition is on (shelved or not), or it waits for an acknowledgement or a
        confirmation."""
        return (
            self.state in (S.ACTIVE_UNACK, S.ACTIVE_ACK, S.RTN_UNACK)
            or (self.shelved and self.condition)
            or not self.confirmed
        )


#: (low, high) severity band per NE 107 status number; CHECK_FUNCTION is a fixed 500
BANDS: dict[int, tuple[int, int]] = {1: (801, 1000), 3: (601, 800), 4: (301, 400)}
CHECK_FUNCTION_SEVERITY = 500
#: NE 107 statuses that raise a unit's alarm: faults (CHECK_FUNCTION is none)
ALARM_STATUSES = frozenset({1, 3, 4})


def condition(
    status: int,
    certainty: float,
    was_on: bool,
    was_severity: int,
    statuses: frozenset[int] = ALARM_STATUSES,
) -> tuple[bool, int]:
    """A unit's alarm condition and severity for this cycle's NE 107 ``status`` (``certainty``
    its top fault's): on in ``statuses`` at :func:`severity`, off otherwise; through
    CHECK_FUNCTION (the diagnosis cannot be trusted) the last condition and severity hold
    (``was_on``, ``was_severity``). The one rule of the OPC UA server's alarm and of the live
    loop's own where no server keeps it."""
    status = int(status)
    if status == 2:
        return was_on, was_severity
    on = status in statuses
    return on, severity(status, certainty) if on else 0


def severity(status: int, certainty: float) -> int:
    """OPC UA Severity for an NE 107 ``status`` and the top fault ``certainty`` (0 if NORMAL).

    See the module table: FAILURE critical, OFF_SPEC major, CHECK_FUNCTION minor (500),
    MAINTENANCE_REQUIRED maintenance; within a band the certainty in [0, 1] (NaN → 0) moves
    the severity from the band's low to its high end.
    """
    status = int(status)
    if status == 0:
        return 0
    if status == 2:
        return CHECK_FUNCTION_SEVERITY
    lo, hi = BANDS[status]
    c = certainty if certainty == certainty else 0.0  # NaN → 0
    c = min(1.0, max(0.0, float(c)))
    return lo + round((hi - lo) * c)
