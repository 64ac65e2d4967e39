"""Our OPC UA server: one object per unit with its diagnosis, alarms, and the plant's tags.

Address space (namespace ``urn:diag-plugin:diagnosis``, string node ids; see
docs/connectors.md, "OPC UA")::

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
          Alarm/            ns;s=Units.<unit>.Alarm (ConditionId of its events)
            State String, Active Boolean, Acked Boolean, Shelved Boolean, Severity UInt16,
            AckRequest Boolean (writable: write true to acknowledge)
          Acknowledge()  Shelve(Double seconds)  Unshelve()     methods
      Plant/                               ns;s=Plant
        <tag>             Double           ns;s=Plant.<tag> (F, CV, X, P0, P1, P2, T1)

Values carry a StatusCode from :class:`UnitStatus.quality`: Certainty, Residual, Symptom,
Detected and Faults get Good/Uncertain/Bad as the quality says (a Bad value is null, as
OPC 10000-4 §7.7.1 asks); DeviceHealth gets Uncertain whenever the quality is not Good (its
value, usually CHECK_FUNCTION, stays readable); Quality, StatusName, Message, LastUpdate and
the alarm variables are always Good. Alarms are AlarmConditionType events emitted by the
Server object (i=2253) with SourceNode = the unit object; their lifecycle is the ISA-18.2
state machine of :mod:`connectors.alarms`.
"""

from __future__ import annotations

import asyncio
import hmac
import logging
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import TYPE_CHECKING, Any

from connectors.alarms import Alarm, Transition, severity
from connectors.base import TagSample

if TYPE_CHECKING:
    from asyncua import Node, Server, ua

    from diag_plugin.diagnose.status import UnitStatus

log = logging.getLogger(__name__)

NAMESPACE = "urn:diag-plugin:diagnosis"
#: the simulated valve plant's measured tags served in the Plant folder (diag_plugin.simulate)
DEFAULT_PLANT_TAGS: tuple[str, ...] = ("F", "CV", "X", "P0", "P1", "P2", "T1")
NE107_NAMES = ("NORMAL", "FAILURE", "CHECK_FUNCTION", "OFF_SPEC", "MAINTENANCE_REQUIRED")
#: NE 107 statuses that raise the unit's alarm (NORMAL is the condition off)
ALARM_STATUSES = frozenset({1, 2, 3, 4})


@dataclass(frozen=True)
class ServerSecurity:
    """Basic256Sha256 SignAndEncrypt with a server certificate, users and a trust list.

    ``trusted_dir`` holds the client certificates (PEM/DER) allowed to connect; any other
    client certificate is refused (BadCertificateUntrusted). ``users`` maps user name →
    password. ``allow_anonymous`` adds the anonymous identity (still SignAndEncrypt).
    """

    certificate: Path
    private_key: Path
    trusted_dir: Path
    users: Mapping[str, str] = field(default_factory=dict)
    allow_anonymous: bool = False


class _Users:
    """asyncua user manager: user name and password checked in constant time."""

    def __init__(self, users: Mapping[str, str], allow_anonymous: bool) -> None:
        self.users = dict(users)
        self.allow_anonymous = allow_anonymous

    def get_user(
        self,
        iserver: Any,
        username: str | None = None,
        password: str | None = None,
        certificate: Any = None,
    ) -> Any:
        from asyncua.crypto.permission_rules import User, UserRole

        if username is None:
            return User(role=UserRole.User) if self.allow_anonymous else None
        expected = self.users.get(username)
        if (
            expected is not None
            and password is not None
            and hmac.compare_digest(expected.encode(), str(password).encode())
        ):
            return User(role=UserRole.User, name=username)
        log.warning("OPC UA login refused for user %r", username)
        return None


async def _refuse_all(cert: Any, app_description: Any) -> None:
    """Certificate validator for an empty trust list."""
    from asyncua import ua
    from asyncua.common.utils import ServiceError

    raise ServiceError(ua.StatusCodes.BadCertificateUntrusted)


@dataclass
class _UnitNodes:
    obj: Node
    alarm_obj: Node
    folders: dict[str, Node]
    vars: dict[str, Node]
    alarm: Alarm
    event: Any = None  # asyncua EventGenerator


def _finite(x: float) -> bool:
    return isinstance(x, int | float) and math.isfinite(x)


class DiagOpcUaServer:
    """The diagnosis as an OPC UA server (asyncua), bound to 127.0.0.1 by default.

    Usage::

        srv = DiagOpcUaServer(port=4840, security=ServerSecurity(...))
        await srv.start()
        await srv.add_unit("valve", faults=["f1"], tests=["r1"], models=["F"])  # optional
        await srv.publish(status)          # each cycle, one UnitStatus per unit
        await srv.update_plant({"F": 12.3, ...})
        await srv.stop()
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
    ) -> None:
        self.host, self.port = host, int(port)
        self.security = security
        self.plant_tags = tuple(plant_tags)
        self.application_uri = application_uri
        self.name = name
        self.alarm_statuses = frozenset(int(s) for s in alarm_statuses)
        self.server: Server | None = None
        self.ns = 0
        self._units: dict[str, _UnitNodes] = {}
        self._plant: dict[str, Node] = {}
        self._units_folder: Node | None = None
        self._tasks: set[asyncio.Task[None]] = set()
        self._lock = asyncio.Lock()
        self._generates_event = False
        self._alarms: dict[str, Alarm] = {}
        self._declared: dict[str, tuple[set[str], set[str], set[str]]] = {}

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
        """Build the address space and listen (within ``timeout`` seconds)."""
        if self.host not in ("127.0.0.1", "localhost", "::1"):
            log.warning(
                "OPC UA server on %s, not loopback%s",
                self.host,
                "" if self.security else ", and without security",
            )
        async with asyncio.timeout(timeout):
            await self._start()
        log.info("OPC UA server listening on %s", self.endpoint)

    async def _start(self) -> None:
        from asyncua import Server, ua

        sec = self.security
        server = Server(user_manager=_Users(sec.users, sec.allow_anonymous) if sec else None)
        await server.init()
        server.set_endpoint(self.endpoint)
        server.set_server_name(self.name)
        await server.set_application_uri(self.application_uri)
        if sec is not None:
            from asyncua.crypto.truststore import TrustStore
            from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions

            await server.load_certificate(str(sec.certificate))
            await server.load_private_key(str(sec.private_key))
            server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt])
            tokens: list[type] = [ua.UserNameIdentityToken]
            if sec.allow_anonymous:
                tokens.append(ua.AnonymousIdentityToken)
            server.set_identity_tokens(tokens)
            store = TrustStore([Path(sec.trusted_dir)], [])
            try:
                await store.load()
            except ValueError:  # cryptography refuses an empty store
                log.warning(
                    "OPC UA trust list %s is empty: every client is refused", sec.trusted_dir
                )
                server.set_certificate_validator(_refuse_all)
            else:
                opts = (
                    CertificateValidatorOptions.TRUSTED_VALIDATION
                    | CertificateValidatorOptions.PEER_CLIENT
                )
                server.set_certificate_validator(CertificateValidator(opts, store))
        else:
            server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
            server.set_identity_tokens([ua.AnonymousIdentityToken])
        self._generates_event = False
        self.ns = await server.register_namespace(NAMESPACE)
        objects = server.nodes.objects
        self._units_folder = await objects.add_folder(self._nid("Units"), self._bn("Units"))
        plant = await objects.add_folder(self._nid("Plant"), self._bn("Plant"))
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
        for unit, (faults, tests, models) in list(self._declared.items()):  # after a restart
            await self.add_unit(unit, faults, tests, models)
        await server.start()

    async def stop(self, timeout: float = 10.0) -> None:
        """Stop listening; the object can be started again (a fresh address space)."""
        if self.server is None:
            return
        for t in list(self._tasks):
            t.cancel()
        server, self.server = self.server, None
        try:
            async with asyncio.timeout(timeout):
                await server.stop()
        except (TimeoutError, OSError) as exc:
            log.warning("OPC UA server stop: %s", exc)
        self._plant.clear()
        self._units.clear()  # the alarms stay in self._alarms
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
        from asyncua.server.event_generator import EventGenerator

        assert self.server is not None and self._units_folder is not None
        obj = await self._units_folder.add_object(self._nid("Units", unit), self._bn(unit))
        alarm_obj = await obj.add_object(self._nid("Units", unit, "Alarm"), self._bn("Alarm"))
        alarm = self._alarms.setdefault(unit, Alarm(unit))
        n = _UnitNodes(obj, alarm_obj, {}, {}, alarm)
        self._units[unit] = n
        V = ua.VariantType
        epoch = datetime(1601, 1, 1, tzinfo=UTC)
        for name, val, vt in (
            ("DeviceHealth", 2, V.Int32),
            ("StatusName", "CHECK_FUNCTION", V.String),
            ("Quality", 2, V.Int32),
            ("Detected", False, V.Boolean),
            ("Faults", "", V.String),
            ("Message", "no diagnosis yet", V.String),
            ("LastUpdate", epoch, V.DateTime),
        ):
            n.vars[name] = await obj.add_variable(
                self._nid("Units", unit, name), self._bn(name), val, vt
            )
        # no diagnosis yet: CHECK_FUNCTION, and the status itself Uncertain
        await self._write(n.vars["DeviceHealth"], 2, V.Int32, self._code(1), None)
        for name, val, vt in (
            ("State", alarm.state.value, V.String),
            ("Active", alarm.active, V.Boolean),
            ("Acked", alarm.acked, V.Boolean),
            ("Shelved", alarm.shelved, V.Boolean),
            ("Severity", alarm.severity, V.UInt16),
            ("AckRequest", False, V.Boolean),
        ):
            n.vars["Alarm." + name] = await alarm_obj.add_variable(
                self._nid("Units", unit, "Alarm", name), self._bn(name), val, vt
            )
        ack_req = n.vars["Alarm.AckRequest"]
        await ack_req.set_writable(True)
        self.server.set_attribute_value_setter(ack_req.nodeid, self._ack_setter(unit))

        async def _ack(parent: ua.NodeId) -> list[ua.Variant]:
            t = await self.acknowledge(unit)
            return [ua.Variant(t.changed, V.Boolean)]

        async def _shelve(parent: ua.NodeId, seconds: ua.Variant) -> list[ua.Variant]:
            secs = float(seconds.Value) if seconds.Value is not None else 0.0
            t = await self.shelve(unit, secs if secs > 0 else None)
            return [ua.Variant(t.changed, V.Boolean)]

        async def _unshelve(parent: ua.NodeId) -> list[ua.Variant]:
            t = await self.unshelve(unit)
            return [ua.Variant(t.changed, V.Boolean)]

        changed = ua.Argument(
            Name="Changed", DataType=ua.NodeId(ua.ObjectIds.Boolean), ValueRank=-1
        )
        secs_arg = ua.Argument(
            Name="Seconds",
            DataType=ua.NodeId(ua.ObjectIds.Double),
            ValueRank=-1,
            Description=ua.LocalizedText("shelving time, 0: until unshelved"),
        )
        await obj.add_method(
            self._nid("Units", unit, "Acknowledge"), self._bn("Acknowledge"), _ack, [], [changed]
        )
        await obj.add_method(
            self._nid("Units", unit, "Shelve"), self._bn("Shelve"), _shelve, [secs_arg], [changed]
        )
        await obj.add_method(
            self._nid("Units", unit, "Unshelve"), self._bn("Unshelve"), _unshelve, [], [changed]
        )

        gen = EventGenerator(self.server.iserver.isession)
        await gen.init(
            ua.NodeId(ua.ObjectIds.AlarmConditionType),
            ua.ObjectIds.Server,
            add_generates_event=not self._generates_event,
        )
        self._generates_event = True
        ev = gen.event
        ev.SourceNode = obj.nodeid
        ev.SourceName = unit
        ev.NodeId = alarm_obj.nodeid  # the ConditionId
        ev.ConditionName = "Diagnosis"
        ev.BranchId = ua.NodeId()
        for prop in ("ActiveState/TransitionTime", "AckedState/TransitionTime"):
            ev.data_types[prop] = ua.VariantType.DateTime  # declared as NodeId(UtcTime)
        ev.EnabledState = ua.LocalizedText("Enabled")
        setattr(ev, "EnabledState/Id", True)
        n.event = gen

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

    @staticmethod
    def _code(q: int) -> int:
        from asyncua import ua

        return (ua.StatusCodes.Good, ua.StatusCodes.Uncertain, ua.StatusCodes.Bad)[min(int(q), 2)]

    async def publish(self, status: UnitStatus) -> None:
        """Show one unit's diagnosis and drive its alarm (creates missing nodes)."""
        from asyncua import ua

        if self.server is None:
            log.debug("publish while the OPC UA server is stopped: %s dropped", status.unit)
            return
        V = ua.VariantType
        async with self._lock:
            await self.add_unit(status.unit, status.certainties, status.residuals, status.coverage)
            n = self._units[status.unit]
            ts = status.ts.to_pydatetime() if hasattr(status.ts, "to_pydatetime") else status.ts
            if ts is not None and ts.tzinfo is None:
                ts = ts.replace(tzinfo=UTC)
            q = int(status.quality)
            code, good = self._code(q), self._code(0)
            health_code = good if q == 0 else self._code(1)
            w = self._write
            await w(n.vars["DeviceHealth"], int(status.status), V.Int32, health_code, ts)
            await w(n.vars["StatusName"], NE107_NAMES[int(status.status)], V.String, good, ts)
            await w(n.vars["Quality"], q, V.Int32, good, ts)
            await w(
                n.vars["Detected"],
                bool(status.detected),
                V.Boolean,
                code if status.detected is not None else self._code(2),
                ts,
            )
            await w(n.vars["Faults"], ",".join(status.faults), V.String, code, ts)
            await w(n.vars["Message"], status.message, V.String, good, ts)
            await w(n.vars["LastUpdate"], ts, V.DateTime, good, ts)
            for folder, values in (
                ("Certainty", status.certainties),
                ("Residual", status.residuals),
                ("Symptom", status.symptoms),
                ("Coverage", status.coverage),
            ):
                for k, v in values.items():
                    node = await self._var(n, status.unit, folder, k, math.nan, V.Double)
                    vcode = code
                    if folder == "Coverage":
                        vcode = good
                    elif not _finite(v) and q == 0:
                        vcode = self._code(1)  # an unknown value in a Good diagnosis
                    await w(node, float(v), V.Double, vcode, ts)
            top = max((v for v in status.certainties.values() if _finite(v)), default=0.0)
            on = int(status.status) in self.alarm_statuses
            sev = severity(int(status.status), top) if on else 0
            msg = self._alarm_message(status, top)
            t = n.alarm.update(on, sev, msg, now=datetime.now(UTC))  # shelving runs on wall time
            if t.changed or (on and n.alarm.retain and sev != self._shown_severity(n)):
                await self._emit(status.unit, t)

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
        return int(n.event.event.Severity or 0) if n.event is not None else 0

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

    # -- alarms ----------------------------------------------------------------------------

    def _ack_setter(self, unit: str) -> Any:
        def setter(node_data: Any, attr: Any, dv: ua.DataValue) -> None:
            if dv.Value is not None and bool(dv.Value.Value):
                task = asyncio.get_running_loop().create_task(self.acknowledge(unit))
                self._tasks.add(task)
                task.add_done_callback(self._tasks.discard)
            # the request is consumed: AckRequest reads false again (value kept as is)

        return setter

    def _unit(self, unit: str) -> _UnitNodes:
        try:
            return self._units[unit]
        except KeyError:
            raise KeyError(f"no unit {unit!r} on this server") from None

    async def acknowledge(self, unit: str) -> Transition:
        """The operator acknowledges the unit's alarm (method, AckRequest tag or HMI)."""
        t = self._unit(unit).alarm.acknowledge()
        log.info("alarm %s acknowledged: %s → %s", unit, t.before, t.after)
        if t.changed:
            await self._emit(unit, t)
        return t

    async def shelve(self, unit: str, seconds: float | None = None) -> Transition:
        """Shelve the unit's alarm for ``seconds`` (None: until :meth:`unshelve`)."""
        now = datetime.now(UTC)
        dur = timedelta(seconds=seconds) if seconds else None
        t = self._unit(unit).alarm.shelve(now=now, duration=dur)
        log.info("alarm %s shelved (%s)", unit, f"{seconds:g} s" if seconds else "no limit")
        if t.changed:
            await self._emit(unit, t)
        return t

    async def unshelve(self, unit: str) -> Transition:
        t = self._unit(unit).alarm.unshelve()
        log.info("alarm %s unshelved: %s", unit, t.after)
        if t.changed:
            await self._emit(unit, t)
        return t

    async def _emit(self, unit: str, t: Transition) -> None:
        """Show the alarm's state in its variables and send an AlarmConditionType event."""
        from asyncua import ua

        n = self._units[unit]
        a = n.alarm
        V, good = ua.VariantType, self._code(0)
        for name, val, vt in (
            ("State", a.state.value, V.String),
            ("Active", a.active, V.Boolean),
            ("Acked", a.acked, V.Boolean),
            ("Shelved", a.shelved, V.Boolean),
            ("Severity", a.severity, V.UInt16),
        ):
            await self._write(n.vars["Alarm." + name], val, vt, good, None)
        ev = n.event.event
        now = datetime.now(UTC)
        ev.Severity = max(1, min(1000, a.severity))
        ev.Retain = a.retain
        ev.Quality = ua.StatusCode(good)
        ev.ActiveState = ua.LocalizedText("Active" if a.active else "Inactive")
        setattr(ev, "ActiveState/Id", a.active)
        ev.AckedState = ua.LocalizedText("Acknowledged" if a.acked else "Unacknowledged")
        setattr(ev, "AckedState/Id", a.acked)
        ev.SuppressedOrShelved = a.shelved
        if t.changed and t.event.value in ("condition-on", "condition-off", "unshelve"):
            setattr(ev, "ActiveState/TransitionTime", now)
        if t.changed and t.event.value == "acknowledge":
            setattr(ev, "AckedState/TransitionTime", now)
        text = f"{a.message or unit} [{a.state.value}]"
        await n.event.trigger(message=text)
