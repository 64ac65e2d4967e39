"""One OPC UA condition's events as Part 9 (OPC 10000-9) describes them, on asyncua.

asyncua sends events but keeps no condition state, so :class:`ConditionEvents` fills an
``AlarmConditionType`` event from our state each time it is sent: ActiveState, AckedState,
ConfirmedState (with their ``Id`` and ``TransitionTime``), Retain, Severity, Comment and
ClientUserId, SuppressedOrShelved and MaxTimeShelved. Every event gets a fresh EventId
(asyncua's ``trigger``); the last :data:`KEPT_EVENT_IDS` of them are remembered so that an
Acknowledge, Confirm or AddComment naming one of them is accepted (Part 9 §5.7.3: the
EventId identifies the state being acknowledged) and any other is ``BadEventIdUnknown``.
With ``bind_condition_methods`` set on the server, asyncua keeps the last event of every
condition with Retain true and answers ConditionRefresh with them (§5.5.7).
"""

from __future__ import annotations

from collections import deque
from datetime import UTC, datetime
from typing import Any

#: EventIds of a condition that an acknowledgement may still name
KEPT_EVENT_IDS = 64

_TIMES = (
    "ActiveState/TransitionTime",
    "AckedState/TransitionTime",
    "ConfirmedState/TransitionTime",
    "EnabledState/TransitionTime",
    "Comment/SourceTimestamp",
)


class ConditionEvents:
    """The events of one condition (see module doc). Create with :meth:`create`."""

    def __init__(self, generator: Any) -> None:
        self.generator = generator
        self.event = generator.event
        self.event_ids: deque[bytes] = deque(maxlen=KEPT_EVENT_IDS)
        self._last: dict[str, Any] = {}

    @classmethod
    async def create(
        cls,
        isession: Any,
        source_node: Any,
        source_name: str,
        condition_id: Any,
        condition_name: str,
        *,
        add_generates_event: bool,
    ) -> ConditionEvents:
        """An AlarmConditionType generator emitted by the Server object (i=2253)."""
        from asyncua import ua
        from asyncua.server.event_generator import EventGenerator

        gen = EventGenerator(isession)
        await gen.init(
            ua.NodeId(ua.ObjectIds.AlarmConditionType),
            ua.ObjectIds.Server,
            add_generates_event=add_generates_event,
        )
        ev = gen.event
        ev.SourceNode = source_node
        ev.SourceName = source_name
        ev.NodeId = condition_id  # the ConditionId
        ev.ConditionName = condition_name
        ev.BranchId = ua.NodeId()
        for prop in _TIMES:
            ev.data_types[prop] = ua.VariantType.DateTime  # declared as NodeId(UtcTime)
        ev.data_types["MaxTimeShelved"] = ua.VariantType.Double  # Duration, ms
        ev.EnabledState = ua.LocalizedText("Enabled")
        setattr(ev, "EnabledState/Id", True)
        ev.Quality = ua.StatusCode(ua.StatusCodes.Good)
        return cls(gen)

    def knows(self, event_id: Any) -> bool:
        """``event_id`` (bytes) is one of the recent events of this condition."""
        return bytes(event_id or b"") in self.event_ids

    async def emit(
        self,
        *,
        active: bool,
        acked: bool,
        confirmed: bool,
        retain: bool,
        severity: int,
        message: str,
        shelved: bool = False,
        max_shelved_s: float | None = None,
        comment: str | None = None,
        user: str | None = None,
    ) -> bytes:
        """Send the condition's current state as one event; returns its EventId."""
        from asyncua import ua

        ev = self.event
        now = datetime.now(UTC)
        for name, value, on, off in (
            ("ActiveState", active, "Active", "Inactive"),
            ("AckedState", acked, "Acknowledged", "Unacknowledged"),
            ("ConfirmedState", confirmed, "Confirmed", "Unconfirmed"),
        ):
            if self._last.get(name) is not value:
                setattr(ev, f"{name}/TransitionTime", now)
            self._last[name] = value
            setattr(ev, name, ua.LocalizedText(on if value else off))
            setattr(ev, f"{name}/Id", value)
        ev.Retain = retain
        ev.Severity = max(1, min(1000, int(severity)))
        ev.SuppressedOrShelved = shelved
        if max_shelved_s is not None:
            ev.MaxTimeShelved = float(max_shelved_s) * 1000.0
        if comment is not None:
            ev.Comment = ua.LocalizedText(comment)
            setattr(ev, "Comment/SourceTimestamp", now)
        if user is not None:
            ev.ClientUserId = user
        await self.generator.trigger(message=message)
        eid = bytes(ev.EventId.Value if hasattr(ev.EventId, "Value") else ev.EventId)
        ev.EventId = eid  # kept as bytes: ConditionRefresh re-sends this very event
        self.event_ids.append(eid)
        return eid
