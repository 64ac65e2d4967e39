"""Our OPC UA server: one object per unit with its diagnosis, alarms, and the plant's tags.

Address space (namespace ``urn:diag-plugin:diagnosis``, string node ids; see
docs/reference/connectors.md, "OPC UA")::

    Objects/
      Units/                               ns;s=Units
        <unit>/                            ns;s=Units.<unit>          (object)
          DeviceHealth      Int32          NE 107 (0 NORMAL, 1 FAILURE, 2 CHECK_FUNCTION, ...)
          StatusName        String         NE 107 name
          Quality           Int32          0 Good, 1 Uncertain, 2 Bad (the diagnosis itself)
          Detected          Boolean        a fault is detected (Bad: unknown)
          Faults            String         isolated faults, comma separated
          Message           String         why CHECK_FUNCTION / FAILURE of the unit itself
          LastUpdate        DateTime       time of the diagnosis (UnitStatus.ts)
          Certainty/<fault> Double         certainty in [0, 1] per fault
          Residual/<test>   Double         residual in % of span per test
          Symptom/<test>    Double         -1, 0, 1 (NaN: unknown)
          Coverage/<model>  Double         share of samples inside the trained region
          Alarm/            ns;s=Units.<unit>.Alarm: the ConditionId of the unit's alarm;
                            Part 9 methods Acknowledge, Confirm, AddComment (i=9111, i=9113,
                            i=9029) as its components
            State String, Active Boolean, Acked Boolean, Confirmed Boolean, Shelved Boolean,
            ShelvedUntil DateTime, Severity UInt16, Comment String,
            AckRequest Boolean (writable by operators: write true to acknowledge)
          Acknowledge()  Shelve(Double seconds)  Unshelve()     methods (operators)
      Plant/                               ns;s=Plant
        <tag>             Double           ns;s=Plant.<tag> (F, CV, X, P0, P1, P2, T1)
      Plugin/                              ns;s=Plugin: the plug-in's own conditions
        <notice>/ Active Boolean, Message String   (e.g. Historian, Source_plc1)
        Historian/Backlog UInt64           samples waiting for the historian

Values carry a StatusCode from :class:`UnitStatus.quality` (see docs/reference/connectors.md).
Alarms are AlarmConditionType events emitted by the Server object (i=2253) with SourceNode
= the unit object; their lifecycle is the ISA-18.2 state machine of :mod:`connectors.alarms`
with Part 9's ConfirmedState and Retain (:mod:`connectors.opcua_conditions`). A unit's
alarm is raised by FAILURE, OFF_SPEC and MAINTENANCE_REQUIRED; CHECK_FUNCTION (the
diagnosis cannot be trusted: inputs stale, Bad, a source out) is no fault: it neither raises
the alarm nor clears one that stands (the condition holds until the diagnosis is back).
*Notices* (:meth:`notice`) are the plug-in's own conditions — a source out, a historian
away — in the maintenance band, needing no acknowledgement and returning to normal by
themselves.

Who may do what is :mod:`connectors.opcua_access`; every operator action (and every
refusal) is logged with its user and handed to ``on_action`` as an :class:`Action`.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import TYPE_CHECKING, Any

from connectors.alarms import ALARM_STATUSES, Alarm, AlarmState, Transition, condition
from connectors.base import TagSample
from connectors.opcua_logins import LoginGuard, LoginLimits

if TYPE_CHECKING:
    from asyncua import Node, Server, ua

    from connectors.opcua_access import OpcUaUser
    from connectors.opcua_conditions import ConditionEvents
    from diag_plugin.status import UnitStatus

log = logging.getLogger(__name__)

NAMESPACE = "urn:diag-plugin:diagnosis"
#: the simulated valve plant's measured tags served in the Plant folder (diag_plugin.simulate)
DEFAULT_PLANT_TAGS: tuple[str, ...] = ("F", "CV", "X", "P0", "P1", "P2", "T1")
NE107_NAMES = ("NORMAL", "FAILURE", "CHECK_FUNCTION", "OFF_SPEC", "MAINTENANCE_REQUIRED")
#: the severity of a notice (a source out, the historian away): the maintenance band
NOTICE_SEVERITY = 350
#: security policy names (plant.toml) → asyncua's Basic256Sha256 policy types
POLICIES = {
    "SignAndEncrypt": "Basic256Sha256_SignAndEncrypt",
    "Sign": "Basic256Sha256_Sign",
    "None": "NoSecurity",
}
LOOPBACK = ("127.0.0.1", "localhost", "::1")


@dataclass(frozen=True)
class ServerSecurity:
    """Basic256Sha256 with a server certificate, a client trust list and users.

    ``certificate``/``private_key``: the server's (created on first start when absent, see
    :attr:`DiagOpcUaServer.certificate_created`). ``trusted_dir`` holds the client
    certificates (PEM/DER, or their CA) allowed to connect; any other client certificate is
    refused (BadCertificateUntrusted). ``users``: :class:`~connectors.opcua_access.OpcUaUser`
    (user name + password hash, or a certificate; a role each). ``allow_anonymous`` admits
    anonymous sessions as read-only. ``policies``: of ``SignAndEncrypt``, ``Sign`` and
    ``None`` (None only on a loopback address).
    """

    certificate: Path
    private_key: Path
    trusted_dir: Path | None = None
    users: tuple[OpcUaUser, ...] = ()
    allow_anonymous: bool = False
    policies: tuple[str, ...] = ("SignAndEncrypt",)
    application_uri: str = "urn:diag-plugin:server"
    #: session and login caps, back-off (None: :meth:`LoginLimits.derive` from the users)
    logins: LoginLimits | None = None

    def login_limits(self) -> LoginLimits:
        """``logins``, or the limits derived from the users and the machine."""
        if self.logins is not None:
            return self.logins
        return LoginLimits.derive(len(self.users), self.allow_anonymous)


@dataclass(frozen=True)
class Action:
    """One operator action on an alarm, or a refused request: who, what, on which unit."""

    ts: datetime
    user: str  # "alice (operator)", "anonymous", "Modbus client", "local"
    action: str  # acknowledge, confirm, comment, shelve, unshelve, refused, login (refused)
    unit: str | None
    ok: bool
    detail: str = ""
    via: str = "OPC UA"

    @property
    def text(self) -> str:
        """``alice (operator) over OPC UA: shelve valve (for 600 s, ...)``, or ``... refused``."""
        if self.action == "refused":
            return f"{self.user} over {self.via}: refused {self.detail} (operators only)"
        if self.action == "login":
            return self.detail
        what = f"{self.action} {self.unit}" if self.unit else self.action
        tail = f" ({self.detail})" if self.detail else ""
        return f"{self.user} over {self.via}: {what}{'' if self.ok else ' refused'}{tail}"


@dataclass
class _UnitNodes:
    obj: Node
    alarm_obj: Node
    folders: dict[str, Node]
    vars: dict[str, Node]
    alarm: Alarm
    events: ConditionEvents | None = None


@dataclass
class _Notice:
    obj: Node
    vars: dict[str, Node]
    events: ConditionEvents
    active: bool = False
    message: str = ""
    extra: dict[str, Node] = field(default_factory=dict)


def _finite(x: float) -> bool:
    return isinstance(x, int | float) and math.isfinite(x)


class ShelveRefused(ValueError):
    """A shelving request outside the rules (untimed, longer than the maximum, ...)."""


class DiagOpcUaServer:
    """The diagnosis as an OPC UA server (asyncua), bound to 127.0.0.1 by default.

    Usage::

        srv = DiagOpcUaServer(port=4840, security=ServerSecurity(...), on_action=print)
        await srv.start()
        await srv.add_unit("valve", faults=["f1"], tests=["r1"], models=["F"])  # optional
        await srv.publish(status)          # each cycle, one UnitStatus per unit
        await srv.update_plant({"F": 12.3, ...})
        await srv.notice("Historian", True, "database locked")   # a notice on / off
        await srv.stop()

    Without ``security`` the server offers only the None policy with anonymous, read-only
    sessions, and only on a loopback address. ``max_shelve``: the longest shelving in
    seconds (shelving is always timed). ``confirmation``: an acknowledged alarm also waits
    for Part 9's Confirm before it leaves the alarm list (Retain).
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 4840,
        *,
        security: ServerSecurity | None = None,
        plant_tags: Sequence[str] = DEFAULT_PLANT_TAGS,
        application_uri: str = "urn:diag-plugin:server",
        name: str = "diag-plugin diagnosis",
        alarm_statuses: Iterable[int] = ALARM_STATUSES,
        max_shelve: float = 3600.0,
        confirmation: bool = False,
        on_action: Callable[[Action], Any] | None = None,
    ) -> None:
        self.host, self.port = host, int(port)
        self.security = security
        if security is not None:
            bad = [p for p in security.policies if p not in POLICIES]
            if bad or not security.policies:
                raise ValueError(f"security policies must be of {list(POLICIES)}, not {bad}")
            if "None" in security.policies and host not in LOOPBACK:
                raise ValueError(f"security policy None only on a loopback address, not {host}")
            application_uri = security.application_uri
        if not max_shelve > 0:
            raise ValueError("max_shelve must be positive (shelving is always timed)")
        self.plant_tags = tuple(plant_tags)
        self.application_uri = application_uri
        self.name = name
        self.alarm_statuses = frozenset(int(s) for s in alarm_statuses)
        self.max_shelve = float(max_shelve)
        self.confirmation = bool(confirmation)
        self.on_action = on_action
        self.server: Server | None = None
        self.ns = 0
        #: SHA-256 fingerprint of the server certificate (secured servers, after start)
        self.fingerprint: str | None = None
        #: the certificate was created by this start (it did not exist)
        self.certificate_created = False
        self.actions: list[Action] = []
        self._units: dict[str, _UnitNodes] = {}
        self._by_condition: dict[Any, str] = {}
        self._plant: dict[str, Node] = {}
        self._units_folder: Node | None = None
        self._plugin_folder: Node | None = None
        self._notices: dict[str, _Notice] = {}
        self._notice_state: dict[str, tuple[bool, str]] = {}
        self._tasks: set[asyncio.Task[None]] = set()
        self._lock = asyncio.Lock()
        self._generates_event = False
        self._alarms: dict[str, Alarm] = {}
        self._condition: dict[str, bool] = {}
        self._shown: dict[Any, tuple[Any, int]] = {}  # node id → (value, code) last written
        self._declared: dict[str, tuple[set[str], set[str], set[str]]] = {}
        self.permissions: Any = None
        #: the login guard of a secured server (after start): refusals, back-off, caps
        self.logins: LoginGuard | None = None

    @property
    def endpoint(self) -> str:
        return f"opc.tcp://{self.host}:{self.port}/diag/"

    @property
    def alarms(self) -> dict[str, Alarm]:
        """Each unit's alarm (ISA-18.2 state, severity, message)."""
        return dict(self._alarms)

    def node_id(self, *path: str) -> str:
        """The string node id of a node, e.g. ``node_id("Units", "valve", "DeviceHealth")``."""
        return f"ns={self.ns};s=" + ".".join(path)

    # -- lifecycle -------------------------------------------------------------------------

    async def start(self, timeout: float = 30.0) -> None:
        """Build the address space and listen (within ``timeout`` seconds). A secured server
        creates its certificate and key on first start (see :attr:`certificate_created`)."""
        if self.security is None and self.host not in LOOPBACK:
            raise ValueError(
                f"an OPC UA server without security only on a loopback address, not {self.host}"
            )
        if self.security is not None:
            from connectors.certs import certificate_der, ensure_certificate, fingerprint

            sec = self.security
            created = await asyncio.to_thread(
                ensure_certificate, sec.certificate, sec.private_key, sec.application_uri
            )
            self.certificate_created = self.certificate_created or created
            self.fingerprint = fingerprint(certificate_der(sec.certificate))
            if created:
                log.warning(
                    "OPC UA server certificate created: %s (SHA-256 %s)",
                    sec.certificate,
                    self.fingerprint,
                )
        async with asyncio.timeout(timeout):
            await self._start()
        log.info("OPC UA server listening on %s", self.endpoint)

    async def _start(self) -> None:
        from asyncua import Server, ua

        from connectors.opcua_access import Permissions, UserManager

        sec = self.security
        users = UserManager(sec.users if sec else (), sec.allow_anonymous if sec else True)
        server = Server(user_manager=users)
        server.iserver.bind_condition_methods = 1  # ConditionRefresh; refresh events severity 1
        await server.init()
        server.set_endpoint(self.endpoint)
        server.set_server_name(self.name)
        await server.set_application_uri(self.application_uri)
        self.permissions = Permissions(on_refused=self._refused)
        if sec is not None:
            await server.load_certificate(str(sec.certificate))
            await server.load_private_key(str(sec.private_key))
            policies = [getattr(ua.SecurityPolicyType, POLICIES[p]) for p in sec.policies]
            server.set_security_policy(policies, permission_ruleset=self.permissions)
            tokens: list[type] = []
            if sec.allow_anonymous or any(u.certificate for u in sec.users):
                tokens.append(ua.AnonymousIdentityToken)
            if any(u.password_hash for u in sec.users):
                tokens.append(ua.UserNameIdentityToken)
            if any(u.certificate for u in sec.users):
                tokens.append(ua.X509IdentityToken)
            server.set_identity_tokens(tokens)
            server.set_certificate_validator(await self._validator(sec))
        else:
            server.set_security_policy(
                [ua.SecurityPolicyType.NoSecurity], permission_ruleset=self.permissions
            )
            server.set_identity_tokens([ua.AnonymousIdentityToken])
        self._generates_event = False
        self.ns = await server.register_namespace(NAMESPACE)
        objects = server.nodes.objects
        self._units_folder = await objects.add_folder(self._nid("Units"), self._bn("Units"))
        plant = await objects.add_folder(self._nid("Plant"), self._bn("Plant"))
        self._plugin_folder = await objects.add_folder(self._nid("Plugin"), self._bn("Plugin"))
        for tag in self.plant_tags:
            v = await plant.add_variable(
                self._nid("Plant", tag), self._bn(tag), math.nan, ua.VariantType.Double
            )
            self._plant[tag] = v
            await server.write_attribute_value(
                v.nodeid,
                ua.DataValue(
                    ua.Variant(math.nan, ua.VariantType.Double),
                    StatusCode=ua.StatusCode(ua.StatusCodes.BadWaitingForInitialData),
                ),
            )
        self.server = server
        self._link_condition_methods()
        for unit, (faults, tests, models) in list(self._declared.items()):  # after a restart
            await self.add_unit(unit, faults, tests, models)
        for name, (on, msg) in list(self._notice_state.items()):
            await self.notice(name, on, msg, emit=False)
        await server.start()
        if sec is not None:
            limits = sec.login_limits()
            self.logins = LoginGuard(users.verify, limits, on_event=self._login_refused)
            self.logins.install(server)
            log.info(
                "OPC UA logins: %d sessions at most, %d logins checked at once in %d threads",
                limits.max_sessions,
                limits.max_activations,
                limits.hash_workers,
            )

    @staticmethod
    async def _validator(sec: ServerSecurity) -> Any:
        """The client-certificate check: the trust list, or refuse all when it is empty."""
        from asyncua.crypto.truststore import TrustStore
        from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions

        store = TrustStore([Path(sec.trusted_dir)] if sec.trusted_dir else [], [])
        try:
            await store.load()
        except ValueError:  # cryptography refuses an empty store
            log.warning("OPC UA trust list %s is empty: every client is refused", sec.trusted_dir)
            return _refuse_all
        opts = (
            CertificateValidatorOptions.TRUSTED_VALIDATION | CertificateValidatorOptions.PEER_CLIENT
        )
        return CertificateValidator(opts, store)

    async def stop(self, timeout: float = 10.0) -> None:
        """Stop listening; the object can be started again (a fresh address space)."""
        if self.server is None:
            return
        for t in list(self._tasks):
            t.cancel()
        server, self.server = self.server, None
        if self.logins is not None:
            self.logins.close()
        try:
            async with asyncio.timeout(timeout):
                await server.stop()
        except (TimeoutError, OSError) as exc:
            log.warning("OPC UA server stop: %s", exc)
        self._plant.clear()
        self._units.clear()  # the alarms stay in self._alarms
        self._by_condition.clear()
        self._shown.clear()
        self._notices.clear()
        log.info("OPC UA server on %s stopped", self.endpoint)

    async def __aenter__(self) -> DiagOpcUaServer:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    # -- address space ---------------------------------------------------------------------

    def _nid(self, *path: str) -> ua.NodeId:
        from asyncua import ua

        return ua.NodeId(".".join(path), self.ns)

    def _bn(self, name: str) -> ua.QualifiedName:
        from asyncua import ua

        return ua.QualifiedName(name, self.ns)

    async def add_unit(
        self,
        unit: str,
        faults: Iterable[str] = (),
        tests: Iterable[str] = (),
        models: Iterable[str] = (),
    ) -> None:
        """Create the unit's object (idempotent); fault/test/model variables may also come
        later with :meth:`publish`."""
        from asyncua import ua

        if self.server is None or self._units_folder is None:
            raise RuntimeError("start the server before adding units")
        faults, tests, models = set(faults), set(tests), set(models)
        d = self._declared.setdefault(unit, (set(), set(), set()))
        d[0].update(faults), d[1].update(tests), d[2].update(models)
        if unit not in self._units:
            await self._create_unit(unit)
        n = self._units[unit]
        for folder, names in (
            ("Certainty", faults),
            ("Residual", tests),
            ("Symptom", tests),
            ("Coverage", models),
        ):
            for name in names:
                await self._var(n, unit, folder, name, math.nan, ua.VariantType.Double)

    async def _create_unit(self, unit: str) -> None:
        from asyncua import ua

        assert self.server is not None and self._units_folder is not None
        obj = await self._units_folder.add_object(self._nid("Units", unit), self._bn(unit))
        alarm_obj = await obj.add_object(self._nid("Units", unit, "Alarm"), self._bn("Alarm"))
        alarm = self._alarms.setdefault(unit, Alarm(unit, confirmation=self.confirmation))
        n = _UnitNodes(obj, alarm_obj, {}, {}, alarm)
        self._units[unit] = n
        self._by_condition[alarm_obj.nodeid] = unit
        V = ua.VariantType
        epoch = datetime(1601, 1, 1, tzinfo=UTC)
        for name, val, vt in (
            ("DeviceHealth", 2, V.Int32),
            ("StatusName", "CHECK_FUNCTION", V.String),
            ("Quality", 1, V.Int32),
            ("Detected", False, V.Boolean),
            ("Faults", "", V.String),
            ("Message", "initialising: no diagnosis yet", V.String),
            ("LastUpdate", epoch, V.DateTime),
        ):
            n.vars[name] = await obj.add_variable(
                self._nid("Units", unit, name), self._bn(name), val, vt
            )
        # no diagnosis yet: CHECK_FUNCTION, and the status itself Uncertain ("initialising")
        await self._write(n.vars["DeviceHealth"], 2, V.Int32, self._code(1), None)
        await self._write(n.vars["Detected"], False, V.Boolean, self._code(2), None)
        for name, val, vt in (*_alarm_values(alarm), ("AckRequest", False, V.Boolean)):
            n.vars["Alarm." + name] = await alarm_obj.add_variable(
                self._nid("Units", unit, "Alarm", name), self._bn(name), val, vt
            )
        ack_req = n.vars["Alarm.AckRequest"]
        await ack_req.set_writable(True)
        self.server.set_attribute_value_setter(ack_req.nodeid, self._ack_setter(unit))
        for method in (
            ua.ObjectIds.AcknowledgeableConditionType_Acknowledge,
            ua.ObjectIds.AcknowledgeableConditionType_Confirm,
            ua.ObjectIds.ConditionType_AddComment,
        ):  # Part 9 methods as components of the condition, so HMIs find them by name
            await alarm_obj.add_reference(
                ua.NodeId(method), ua.ObjectIds.HasComponent, bidirectional=False
            )
        await self._unit_methods(unit, obj)
        n.events = await self._events(obj, unit, alarm_obj, "Diagnosis")

    async def _events(self, obj: Node, name: str, source: Node, kind: str) -> ConditionEvents:
        """The condition events ``obj`` sends for ``name`` (from ``source``); the first one
        made adds the server's GeneratesEvent reference."""
        from connectors.opcua_conditions import ConditionEvents

        assert self.server is not None
        events = await ConditionEvents.create(
            self.server.iserver.isession,
            obj.nodeid,
            name,
            source.nodeid,
            kind,
            add_generates_event=not self._generates_event,
        )
        self._generates_event = True
        return events

    async def _unit_methods(self, unit: str, obj: Node) -> None:
        """Our own Acknowledge(), Shelve(Seconds), Unshelve() on the unit object."""
        from asyncua import ua

        async def _ack(parent: ua.NodeId) -> Any:
            code, t = await self._call("acknowledge", unit)
            return self._result(code, t)

        async def _shelve(parent: ua.NodeId, seconds: ua.Variant) -> Any:
            secs = float(seconds.Value) if seconds.Value is not None else 0.0
            code, t = await self._call("shelve", unit, seconds=secs)
            return self._result(code, t)

        async def _unshelve(parent: ua.NodeId) -> Any:
            code, t = await self._call("unshelve", unit)
            return self._result(code, t)

        changed = ua.Argument(
            Name="Changed", DataType=ua.NodeId(ua.ObjectIds.Boolean), ValueRank=-1
        )
        secs_arg = ua.Argument(
            Name="Seconds",
            DataType=ua.NodeId(ua.ObjectIds.Double),
            ValueRank=-1,
            Description=ua.LocalizedText(f"shelving time, 0 < s <= {self.max_shelve:g}"),
        )
        for name, fn, args in (
            ("Acknowledge", _ack, []),
            ("Shelve", _shelve, [secs_arg]),
            ("Unshelve", _unshelve, []),
        ):
            node = await obj.add_method(
                self._nid("Units", unit, name), self._bn(name), fn, args, [changed]
            )
            self.permissions.operator_methods.add(node.nodeid)

    @staticmethod
    def _result(code: int, t: Any) -> Any:
        from asyncua import ua

        if code != ua.StatusCodes.Good:
            return ua.StatusCode(code)
        return [ua.Variant(bool(t), ua.VariantType.Boolean)]

    def _link_condition_methods(self) -> None:
        """Part 9's Acknowledge, Confirm, AddComment and the shelving methods, called with a
        unit's ConditionId (``Units.<unit>.Alarm``) as the object."""
        from asyncua import ua

        assert self.server is not None
        O = ua.ObjectIds  # noqa: E741 - the asyncua name

        def with_event(action: str) -> Callable[..., Any]:
            async def call(parent: ua.NodeId, event_id: Any, comment: Any = None) -> Any:
                return await self._condition_call(action, parent, event_id, comment)

            return call

        async def timed_shelve(parent: ua.NodeId, ms: Any) -> Any:
            unit = self._by_condition.get(parent)
            if unit is None:
                return ua.StatusCode(ua.StatusCodes.BadNodeIdUnknown)
            secs = float(ms.Value or 0.0) / 1000.0
            code, _ = await self._call("shelve", unit, seconds=secs)
            return ua.StatusCode(code)

        async def unshelve(parent: ua.NodeId) -> Any:
            unit = self._by_condition.get(parent)
            if unit is None:
                return ua.StatusCode(ua.StatusCodes.BadNodeIdUnknown)
            code, _ = await self._call("unshelve", unit)
            return ua.StatusCode(code)

        link = self.server.iserver.isession.add_method_callback
        link(ua.NodeId(O.AcknowledgeableConditionType_Acknowledge), with_event("acknowledge"))
        link(ua.NodeId(O.AcknowledgeableConditionType_Confirm), with_event("confirm"))
        link(ua.NodeId(O.ConditionType_AddComment), with_event("comment"))
        for m in (
            O.AlarmConditionType_ShelvingState_TimedShelve,
            O.ShelvedStateMachineType_TimedShelve,
        ):
            link(ua.NodeId(m), timed_shelve)
        for m in (O.AlarmConditionType_ShelvingState_Unshelve, O.ShelvedStateMachineType_Unshelve):
            link(ua.NodeId(m), unshelve)

    async def _condition_call(self, action: str, parent: Any, event_id: Any, comment: Any) -> Any:
        """A Part 9 method on a condition: the EventId must be one the condition sent."""
        from asyncua import ua

        unit = self._by_condition.get(parent)
        if unit is None:
            return ua.StatusCode(ua.StatusCodes.BadNodeIdUnknown)
        n = self._units[unit]
        text = ""
        if comment is not None and comment.Value is not None:
            text = getattr(comment.Value, "Text", None) or str(comment.Value)
        eid = event_id.Value if event_id is not None else None
        if n.events is None or not n.events.knows(eid):
            self._record(action, unit, False, "unknown EventId")
            return ua.StatusCode(ua.StatusCodes.BadEventIdUnknown)
        code, _ = await self._call(action, unit, comment=text)
        return ua.StatusCode(code)

    async def _var(
        self, n: _UnitNodes, unit: str, folder: str, name: str, val: Any, vt: ua.VariantType
    ) -> Node:
        key = f"{folder}.{name}"
        if key in n.vars:
            return n.vars[key]
        if folder not in n.folders:
            n.folders[folder] = await n.obj.add_folder(
                self._nid("Units", unit, folder), self._bn(folder)
            )
        node = await n.folders[folder].add_variable(
            self._nid("Units", unit, folder, name), self._bn(name), val, vt
        )
        n.vars[key] = node
        return node

    # -- values ----------------------------------------------------------------------------

    async def _write(
        self, node: Node, value: Any, vt: ua.VariantType, code: int, ts: datetime | None
    ) -> None:
        from asyncua import ua

        assert self.server is not None
        now = datetime.now(UTC)
        dv = ua.DataValue(
            ua.Variant(value, vt),
            StatusCode=ua.StatusCode(code),
            SourceTimestamp=ts or now,
            ServerTimestamp=now,
        )
        await self.server.write_attribute_value(node.nodeid, dv)

    def _new(self, writes: list) -> Callable[[Node, Any, Any, int], None]:
        """An ``add(node, value, vt, code)`` that appends to ``writes`` only what differs from
        what the node already holds (value or StatusCode)."""
        shown = self._shown

        def add(node: Node, value: Any, vt: Any, code: int) -> None:
            key = node.nodeid
            last = shown.get(key)
            if last is not None and last[1] == code:
                if last[0] == value or (value != value and last[0] != last[0]):  # NaN == NaN
                    return
            shown[key] = (value, code)
            writes.append((node, value, vt, code))

        return add

    @staticmethod
    def _code(q: int) -> int:
        """The StatusCode of a quality: 0 Good, 1 Uncertain, 2 Bad (OPC 10000-4 §7.34)."""
        return (0x00000000, 0x40000000, 0x80000000)[min(int(q), 2)]

    async def publish(self, status: UnitStatus) -> None:
        """Show one unit's diagnosis and drive its alarm (creates missing nodes).

        ``DeviceHealth`` and ``LastUpdate`` are written every time (the heartbeat an HMI
        watches); every other value only when it or its StatusCode changed, so a hundred
        units cost a few hundred writes a cycle, not thousands."""
        from asyncua import ua

        if self.server is None:
            log.debug("publish while the OPC UA server is stopped: %s dropped", status.unit)
            return
        V = ua.VariantType
        async with self._lock:
            names = (set(status.certainties), set(status.residuals), set(status.coverage))
            known = self._declared.get(status.unit)
            if (
                status.unit not in self._units
                or known is None
                or not all(
                    a <= b for a, b in zip(names, (known[0], known[1], known[2]), strict=True)
                )
            ):
                await self.add_unit(status.unit, *names)
            n = self._units[status.unit]
            ts = status.ts.to_pydatetime() if hasattr(status.ts, "to_pydatetime") else status.ts
            if ts is not None and ts.tzinfo is None:
                ts = ts.replace(tzinfo=UTC)
            q = int(status.quality)
            code, good = self._code(q), self._code(0)
            health_code = good if q == 0 else self._code(1)
            writes: list[tuple[Node, Any, Any, int]] = [
                (n.vars["DeviceHealth"], int(status.status), V.Int32, health_code),
                (n.vars["LastUpdate"], ts, V.DateTime, good),
            ]
            new = self._new(writes)
            new(n.vars["StatusName"], NE107_NAMES[int(status.status)], V.String, good)
            new(n.vars["Quality"], q, V.Int32, good)
            detected_code = code if status.detected is not None else self._code(2)
            new(n.vars["Detected"], bool(status.detected), V.Boolean, detected_code)
            new(n.vars["Faults"], ",".join(status.faults), V.String, code)
            new(n.vars["Message"], status.message, V.String, good)
            uncertain = self._code(1)
            for folder, values in (
                ("Certainty", status.certainties),
                ("Residual", status.residuals),
                ("Symptom", status.symptoms),
                ("Coverage", status.coverage),
            ):
                for k, v in values.items():
                    vcode = code
                    if folder == "Coverage":
                        vcode = good
                    elif q == 0 and not _finite(v):
                        vcode = uncertain  # an unknown value in a Good diagnosis
                    new(n.vars[f"{folder}.{k}"], float(v), V.Double, vcode)
            for node, value, vt, vcode in writes:
                await self._write(node, value, vt, vcode, ts)
            top = max((v for v in status.certainties.values() if _finite(v)), default=0.0)
            was_on = self._condition.get(status.unit, False)
            on, sev = condition(status.status, top, was_on, n.alarm.severity, self.alarm_statuses)
            # through CHECK_FUNCTION the condition holds, and so does its message
            msg = n.alarm.message if int(status.status) == 2 else self._alarm_message(status, top)
            self._condition[status.unit] = on
            shown = self._shown_severity(n)
            t = n.alarm.update(on, sev, msg, now=datetime.now(UTC))  # shelving: wall time
            if t.changed and t.event.value == "unshelve":
                self._record("unshelve", status.unit, True, "shelving time over", who="timer")
            if (
                t.changed
                or (on and n.alarm.retain and sev != shown)
                or (n.alarm.shelved and on != was_on)  # still visible, as shelved
            ):
                await self._emit(status.unit)

    @staticmethod
    def _alarm_message(status: UnitStatus, top: float) -> str:
        name = NE107_NAMES[int(status.status)]
        faults = ", ".join(status.faults)
        s = f"{status.unit}: {name}"
        if faults:
            s += f" ({faults}, certainty {top:.2f})"
        if status.message:
            s += f": {status.message}"
        return s

    @staticmethod
    def _shown_severity(n: _UnitNodes) -> int:
        return int(n.events.event.Severity or 0) if n.events is not None else 0

    async def update_plant(
        self, values: Mapping[str, float | TagSample], ts: datetime | None = None
    ) -> None:
        """Set the Plant folder's tags; a :class:`TagSample` brings its own time and quality."""
        from asyncua import ua

        if self.server is None:
            return
        for tag, v in values.items():
            node = self._plant.get(tag)
            if node is None:
                raise KeyError(f"{tag!r} is not a plant tag of this server ({self.plant_tags})")
            if isinstance(v, TagSample):
                code = self._code(int(v.quality))
                await self._write(node, float(v.value), ua.VariantType.Double, code, v.ts or ts)
            else:
                await self._write(node, float(v), ua.VariantType.Double, self._code(0), ts)

    # -- notices: the plug-in's own conditions -----------------------------------------------

    async def notice(
        self, name: str, active: bool, message: str = "", *, emit: bool = True
    ) -> None:
        """Set the plug-in's own condition ``name`` (``Plugin.<name>``: a source out, the
        historian away) on or off: maintenance band, no acknowledgement needed, Retain while
        it is on; an event on every change of state or message."""
        from asyncua import ua

        self._notice_state[name] = (active, message)
        if self.server is None or self._plugin_folder is None:
            return
        nt = self._notices.get(name)
        if nt is None:
            nt = await self._create_notice(name)
        changed = nt.active != active or (active and nt.message != message)
        nt.active, nt.message = active, message
        V, good = ua.VariantType, self._code(0)
        await self._write(nt.vars["Active"], active, V.Boolean, good, None)
        await self._write(nt.vars["Message"], message, V.String, good, None)
        if changed and emit:
            await nt.events.emit(
                active=active,
                acked=True,
                confirmed=True,
                retain=active,
                severity=NOTICE_SEVERITY,
                message=f"{name}: {message}" if message else name,
            )

    async def _create_notice(self, name: str) -> _Notice:
        from asyncua import ua

        assert self.server is not None and self._plugin_folder is not None
        obj = await self._plugin_folder.add_object(self._nid("Plugin", name), self._bn(name))
        vars_ = {}
        for var, val, vt in (
            ("Active", False, ua.VariantType.Boolean),
            ("Message", "", ua.VariantType.String),
        ):
            vars_[var] = await obj.add_variable(
                self._nid("Plugin", name, var), self._bn(var), val, vt
            )
        events = await self._events(obj, name, obj, "Notice")
        nt = _Notice(obj, vars_, events)
        self._notices[name] = nt
        return nt

    async def set_plugin_value(self, name: str, var: str, value: float) -> None:
        """A number under a notice's object (``Plugin.Historian.Backlog``), created on first
        use as UInt64."""
        from asyncua import ua

        if self.server is None:
            return
        nt = self._notices.get(name) or await self._create_notice(name)
        node = nt.extra.get(var)
        if node is None:
            node = await nt.obj.add_variable(
                self._nid("Plugin", name, var), self._bn(var), 0, ua.VariantType.UInt64
            )
            nt.extra[var] = node
        await self._write(node, int(value), ua.VariantType.UInt64, self._code(0), None)

    # -- alarms: operator actions ----------------------------------------------------------

    def _ack_setter(self, unit: str) -> Any:
        def setter(node_data: Any, attr: Any, dv: ua.DataValue) -> None:
            if dv.Value is not None and bool(dv.Value.Value):
                task = asyncio.get_running_loop().create_task(self._call("acknowledge", unit))
                self._tasks.add(task)
                task.add_done_callback(self._tasks.discard)
            # the request is consumed: AckRequest reads false again (value kept as is)

        return setter

    def _unit(self, unit: str) -> _UnitNodes:
        try:
            return self._units[unit]
        except KeyError:
            raise KeyError(f"no unit {unit!r} on this server") from None

    async def _call(
        self,
        action: str,
        unit: str,
        *,
        seconds: float | None = None,
        comment: str = "",
        who: str | None = None,
        via: str | None = None,
    ) -> tuple[int, bool]:
        """Do ``action`` for the current caller: (StatusCode, whether the state changed)."""
        from asyncua import ua

        S = ua.StatusCodes
        if unit not in self._units:
            self._record(action, unit, False, "no such unit", who=who, via=via)
            return S.BadNodeIdUnknown, False
        n = self._units[unit]
        a = n.alarm
        user = who or self._caller()
        if action == "acknowledge":
            if a.acked:
                self._record(action, unit, False, "nothing to acknowledge", who=who, via=via)
                return S.BadConditionBranchAlreadyAcked, False
            t = a.acknowledge()
        elif action == "confirm":
            if not a.confirm():
                self._record(action, unit, False, "nothing to confirm", who=who, via=via)
                return S.BadConditionBranchAlreadyConfirmed, False
            t = None
        elif action == "comment":
            t = None
        elif action == "shelve":
            secs = float(seconds or 0.0)
            if a.shelved:
                self._record(action, unit, False, "already shelved", who=who, via=via)
                return S.BadConditionAlreadyShelved, False
            if not 0 < secs <= self.max_shelve:
                why = f"{secs:g} s: shelving is timed, 0 < s <= {self.max_shelve:g}"
                self._record(action, unit, False, why, who=who, via=via)
                return S.BadShelvingTimeOutOfRange, False
            t = a.shelve(now=datetime.now(UTC), duration=timedelta(seconds=secs))
        elif action == "unshelve":
            if not a.shelved:
                self._record(action, unit, False, "not shelved", who=who, via=via)
                return S.BadConditionNotShelved, False
            t = a.unshelve()
        else:
            raise ValueError(f"unknown action {action!r}")
        if comment:
            a.comment = comment
        detail = f"{t.before} -> {t.after}" if t is not None else ""
        if action == "shelve":
            detail = f"for {secs:g} s, until {a.shelved_until:%H:%M:%S} UTC"
        if comment:
            detail = f"{detail}; comment {comment!r}" if detail else f"comment {comment!r}"
        self._record(action, unit, True, detail, who=who, via=via)
        await self._emit(unit, comment=comment or None, user=user)
        return S.Good, t is None or t.changed

    def _caller(self) -> str:
        from connectors.opcua_access import current_identity

        ident = current_identity.get()
        return ident.label if ident is not None else "local"

    def _record(
        self,
        action: str,
        unit: str | None,
        ok: bool,
        detail: str = "",
        *,
        who: str | None = None,
        via: str | None = None,
    ) -> None:
        user = who or self._caller()
        via = via or ("local" if user in ("local", "timer") else "OPC UA")
        a = Action(datetime.now(UTC), user, action, unit, ok, detail, via)
        (log.info if ok else log.warning)("OPC UA alarm action: %s", a.text)
        self._keep(a)

    def _keep(self, a: Action) -> None:
        """``a`` into :attr:`actions` (the last 1,000 kept) and to ``on_action``."""
        self.actions.append(a)
        del self.actions[:-1000]
        if self.on_action is not None:
            try:
                self.on_action(a)
            except Exception:  # noqa: BLE001 - a listener must not break the server
                log.exception("on_action listener failed")

    def _login_refused(self, text: str) -> None:
        """A refused login (or a merged run of them): an :class:`Action` ``login``."""
        self._keep(Action(datetime.now(UTC), "", "login", None, False, text, "OPC UA"))

    def _refused(self, ident: Any, what: str) -> None:
        self._keep(Action(datetime.now(UTC), ident.label, "refused", None, False, what, "OPC UA"))

    async def acknowledge(
        self, unit: str, who: str = "local", via: str = "local", comment: str = ""
    ) -> Transition:
        """Acknowledge in-process (the live loop: a Modbus ack coil, a scripted operator)."""
        self._unit(unit)
        before = self._alarms[unit].state
        await self._call("acknowledge", unit, who=who, via=via, comment=comment)
        return _transition(before, self._alarms[unit].state, "acknowledge")

    async def confirm(self, unit: str, who: str = "local", via: str = "local") -> bool:
        """Confirm in-process; True when there was something to confirm."""
        from asyncua import ua

        self._unit(unit)
        code, _ = await self._call("confirm", unit, who=who, via=via)
        return code == ua.StatusCodes.Good

    async def shelve(
        self, unit: str, seconds: float, who: str = "local", via: str = "local"
    ) -> Transition:
        """Shelve in-process for ``seconds`` (0 < seconds <= ``max_shelve``; else
        :class:`ShelveRefused`)."""
        from asyncua import ua

        self._unit(unit)
        before = self._alarms[unit].state
        code, _ = await self._call("shelve", unit, seconds=seconds, who=who, via=via)
        if code not in (ua.StatusCodes.Good, ua.StatusCodes.BadConditionAlreadyShelved):
            raise ShelveRefused(
                f"{unit}: shelving for {seconds!r} s refused (0 < s <= {self.max_shelve:g})"
            )
        return _transition(before, self._alarms[unit].state, "shelve")

    async def unshelve(self, unit: str, who: str = "local", via: str = "local") -> Transition:
        self._unit(unit)
        before = self._alarms[unit].state
        await self._call("unshelve", unit, who=who, via=via)
        return _transition(before, self._alarms[unit].state, "unshelve")

    async def _emit(self, unit: str, comment: str | None = None, user: str | None = None) -> None:
        """Show the alarm's state in its variables and send an AlarmConditionType event."""

        n = self._units[unit]
        a = n.alarm
        good = self._code(0)
        for name, val, vt in _alarm_values(a):
            await self._write(n.vars["Alarm." + name], val, vt, good, None)
        assert n.events is not None
        state = a.state.value
        if a.shelved:
            state += f" until {a.shelved_until:%H:%M:%S} UTC" if a.shelved_until else ""
        await n.events.emit(
            active=a.condition,
            acked=a.acked,
            confirmed=a.confirmed,
            retain=a.retain,
            severity=a.severity,
            message=f"{a.message or unit} [{state}]",
            shelved=a.shelved,
            max_shelved_s=self.max_shelve,
            comment=comment,
            user=user,
        )


def _transition(before: AlarmState, after: AlarmState, event: str) -> Transition:
    from connectors.alarms import AlarmInput

    return Transition(before, after, AlarmInput(event))


async def _refuse_all(cert: Any, app_description: Any) -> None:
    """Certificate validator for an empty trust list."""
    from asyncua import ua
    from asyncua.common.utils import ServiceError

    raise ServiceError(ua.StatusCodes.BadCertificateUntrusted)


def _alarm_values(alarm: Alarm) -> list[tuple[str, Any, Any]]:
    """The alarm's variables under ``Units/UNIT/Alarm``: name, value, variant type (a never
    shelved alarm's ShelvedUntil is OPC UA's zero time, 1601-01-01)."""
    from asyncua import ua

    V = ua.VariantType
    return [
        ("State", alarm.state.value, V.String),
        ("Active", alarm.active, V.Boolean),
        ("Acked", alarm.acked, V.Boolean),
        ("Confirmed", alarm.confirmed, V.Boolean),
        ("Shelved", alarm.shelved, V.Boolean),
        ("ShelvedUntil", alarm.shelved_until or datetime(1601, 1, 1, tzinfo=UTC), V.DateTime),
        ("Severity", alarm.severity, V.UInt16),
        ("Comment", alarm.comment, V.String),
    ]
