"""Our Modbus TCP servers (pymodbus ``SimDevice``): diagnoses for the SCADA, and the plant as a PLC.

:class:`RegisterServer` serves the tags of a :class:`~connectors.registermap.RegisterMap`
on 127.0.0.1 (by default): the caller sets engineering values with :meth:`update`; only the
map's addresses answer (others give an *illegal data address* exception reply); a client
may write only the tags named ``writable`` — any other write is refused with an exception
reply and logged.

:class:`StatusServer` publishes :class:`~diag_plugin.status.UnitStatus` objects
per an output map (default: :func:`default_output_map`; until a unit's first diagnosis its
status reads 2 CHECK_FUNCTION with quality 1 Uncertain) and reports acknowledgements a
SCADA writes to a unit's ``.ack`` coil through a callback and an :class:`asyncio.Queue`.
:class:`PlantServer` serves the simulated valve plant's tags (:func:`default_plant_map`)
as a PLC would; the caller updates them every cycle.

Default output layout, per unit ``U`` number ``i`` (0-based, in the order given), with
``base = i · stride`` (stride 100), all 0-based PDU addresses, float32 word order ABCD
(high word first; ``mbpoll -B``)::

    holding registers
      base+0   U.status            uint16   NE 107: 0 NORMAL, 1 FAILURE, 2 CHECK_FUNCTION,
                                            3 OFF_SPEC, 4 MAINTENANCE_REQUIRED
      base+1   U.quality           uint16   diagnosis quality: 0 Good, 1 Uncertain, 2 Bad
      base+2   U.faults            uint16   bit j (LSB = 0) set: fault j isolated (j < 16)
      base+3   U.alarm             uint16   alarm state set by the live loop (0 = normal)
      base+4   U.updates           uint16   publish counter (wraps at 65536): a heartbeat
      base+6   U.time              int32    time of the diagnosis, Unix seconds
      base+10  U.certainty.<f>     float32  certainty of fault j in [0, 1] at base+10+2j (j < 20)
      base+50  U.residual.<t>      float32  residual of test k in % of span at base+50+2k (k < 20)
      base+90  U.coverage.<m>      float32  coverage of model m in [0, 1] at base+90+2m (m < 5)
    coils
      base+0   U.ack               write 1 to acknowledge the unit's alarm (reads back 0)
      base+1+j U.fault.<f>         the j-th fault is isolated (mirror of the U.faults bits)

Default plant map (:func:`default_plant_map`): input registers, float32 ABCD, one tag every
two registers in the order F, CV, X, P0, P1, P2, T1 (F at 0, CV at 2, … T1 at 12).
"""

from __future__ import annotations

import asyncio
import contextlib
import contextvars
import logging
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from connectors.modbus import quiet_pymodbus
from connectors.registermap import BIT_TABLES, TABLES, RegisterMap, TagSpec, pack_bits

if TYPE_CHECKING:
    from diag_plugin.status import UnitStatus

__all__ = [
    "PLANT_TAGS",
    "PlantServer",
    "RegisterServer",
    "StatusServer",
    "UnitLayout",
    "default_output_map",
    "default_plant_map",
]

log = logging.getLogger(__name__)

#: the simulated valve plant's tags a PLC serves (diag_plugin.simulate.valve.TAGS)
PLANT_TAGS = ("F", "CV", "X", "P0", "P1", "P2", "T1")
STRIDE = 100
MAX_FAULTS, MAX_TESTS, MAX_MODELS = 20, 20, 5
_WRITE_FC = {5: "co", 15: "co", 6: "hr", 16: "hr", 22: "hr", 23: "hr"}
#: the address (``ip:port``) of the client whose request is being served; set by the
#: connection handler around each request, read by the write hook (same task)
_PEER: contextvars.ContextVar[str] = contextvars.ContextVar("modbus_peer", default="")


class Ack(str):
    """A unit name taken from its ``U.ack`` coil, with the client that wrote it
    (``client``: ``ip:port``, "" when unknown). Compares and hashes as the unit name."""

    client: str

    def __new__(cls, unit: str, client: str = "") -> Ack:
        self = super().__new__(cls, unit)
        self.client = client
        return self


def _tcp_server(device: Any, address: tuple[str, int]) -> Any:
    """pymodbus's TCP server whose connections tell each request's client address (the
    write hook pymodbus calls does not): an audit line must name who wrote."""
    from pymodbus.server import ModbusTcpServer
    from pymodbus.server.requesthandler import ServerRequestHandler

    class _Handler(ServerRequestHandler):
        async def handle_request(self) -> None:
            peer = ""
            with contextlib.suppress(Exception):
                info = self.transport.get_extra_info("peername")
                peer = f"{info[0]}:{info[1]}" if info else ""
            token = _PEER.set(peer)
            try:
                await super().handle_request()
            finally:
                _PEER.reset(token)

    class _Server(ModbusTcpServer):
        def callback_new_connection(self) -> Any:
            return _Handler(self, self.trace_packet, self.trace_pdu, self.trace_connect)

    return _Server(device, address=address)


class RegisterServer:
    """A Modbus TCP server whose tables carry the tags of ``regmap``.

    Args:
        regmap: the tags served (only their addresses answer).
        host, port: where to listen; port 0 picks a free port (see :attr:`port`).
        device_id: the unit id served (requests to another id get an exception reply).
        writable: tags a client may write (co/hr); every other write is refused.
        on_write: called as ``on_write(tag, value)`` after a client wrote a writable tag.
    """

    def __init__(
        self,
        regmap: RegisterMap,
        host: str = "127.0.0.1",
        port: int = 0,
        *,
        device_id: int = 1,
        writable: Iterable[str] = (),
        on_write: Callable[[str, float], Any] | None = None,
    ) -> None:
        self.regmap = regmap
        self.host, self.port, self.device_id = host, int(port), int(device_id)
        self.writable = frozenset(writable)
        bad = sorted(t for t in self.writable if t not in regmap or not regmap[t].writable)
        if bad:
            raise ValueError(f"not writable (unknown tag or read-only table): {', '.join(bad)}")
        self.on_write = on_write
        self.plan = regmap.plan()
        self.values = np.zeros(len(regmap), dtype=np.float64)
        self._buf = self.plan.encode(self.values)
        self._index = {t: i for i, t in enumerate(regmap.names)}
        # (table, address) → tag, for the writes a client may make
        self._write_addr: dict[tuple[str, int], str] = {}
        for t in self.writable:
            s = regmap[t]
            for a in range(s.address, s.end):
                self._write_addr[(s.table, a)] = t
        self._server: Any = None
        self._internal = False
        self.refused_writes = 0
        quiet_pymodbus()

    # ------------------------------------------------------------- lifecycle
    def _device(self) -> Any:
        from pymodbus.simulator import DataType, SimData, SimDevice

        lists: dict[str, list] = {t: [] for t in TABLES}
        for b in self.plan.blocks:
            if b.table in BIT_TABLES:
                lists[b.table].append(
                    SimData(b.start, count=b.count, values=False, datatype=DataType.BITS)
                )
            else:
                lists[b.table].append(
                    SimData(b.start, count=b.count, values=0, datatype=DataType.REGISTERS)
                )
        for t in TABLES:  # pymodbus needs every table; an unused one gets one far address
            if not lists[t]:
                v: Any = False if t in BIT_TABLES else 0
                dt = DataType.BITS if t in BIT_TABLES else DataType.REGISTERS
                lists[t].append(SimData(65520, count=1, values=v, datatype=dt))
        return SimDevice(
            self.device_id,
            simdata=(lists["co"], lists["di"], lists["hr"], lists["ir"]),
            action=self._action,
        )

    async def start(self) -> None:
        """Listen (background task); afterwards :attr:`port` is the bound port."""
        self._server = _tcp_server(self._device(), (self.host, self.port))
        await self._server.serve_forever(background=True)
        self.port = int(self._server.transport.sockets[0].getsockname()[1])
        await self._push(range(len(self.plan.blocks)))
        log.info("modbus server on %s:%d (unit id %d)", self.host, self.port, self.device_id)

    async def stop(self) -> None:
        """Stop listening and drop the clients."""
        if self._server is not None:
            with contextlib.suppress(Exception):
                await self._server.shutdown()
            self._server = None

    async def __aenter__(self) -> RegisterServer:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    # ---------------------------------------------------------------- update
    async def update(self, values: Mapping[str, float]) -> None:
        """Set tags to engineering values (unknown tags raise KeyError)."""
        idx = np.fromiter((self._index[t] for t in values), dtype=np.int64, count=len(values))
        self.values[idx] = np.fromiter(values.values(), dtype=np.float64, count=len(values))
        blocks = sorted({int(self.plan.tag_block[i]) for i in idx})
        await self.update_array(self.values, blocks)

    async def update_array(self, values: np.ndarray, blocks: Iterable[int] | None = None) -> None:
        """Set all tags from an array in map order (fast path for many tags)."""
        self.values = np.asarray(values, dtype=np.float64)
        self._buf = self.plan.encode(self.values, self._buf)
        await self._push(range(len(self.plan.blocks)) if blocks is None else blocks)

    async def _push(self, blocks: Iterable[int]) -> None:
        if self._server is None:
            return
        self._internal = True
        try:
            for bi in blocks:
                b = self.plan.blocks[bi]
                words = self._buf[b.buf_offset : b.buf_offset + b.count]
                if b.table in BIT_TABLES:
                    vals: list = [bool(w) for w in words]
                    fc = 15 if b.table == "co" else 2
                else:
                    vals = words.tolist()
                    fc = 16 if b.table == "hr" else 4
                await self._server.async_setValues(self.device_id, fc, b.start, vals)
        finally:
            self._internal = False

    # -------------------------------------------------------- client writes
    async def _action(
        self,
        func_code: int,
        _start: int,
        address: int,
        _count: int,
        _registers: list[int],
        set_values: list[int] | list[bool] | None,
    ) -> Any:
        """pymodbus hook on every request: refuse writes outside ``writable``."""
        from pymodbus.constants import ExcCodes

        if set_values is None or self._internal:
            return None
        client = _PEER.get() or "unknown client"
        table = _WRITE_FC.get(func_code)
        addrs = range(address, address + len(set_values))
        tags = {self._write_addr.get((table or "", a)) for a in addrs}
        if table is None or None in tags:
            self.refused_writes += 1
            log.warning(
                "modbus server %s:%d: refused a write by client %s (fc %d) to %s %d+%d: not "
                "a writable output tag",
                self.host,
                self.port,
                client,
                func_code,
                table or "?",
                address,
                len(set_values),
            )
            return ExcCodes.ILLEGAL_ADDRESS
        asyncio.get_running_loop().call_soon(
            self._written, table, address, list(set_values), sorted(t for t in tags if t), client
        )
        return None

    def _written(
        self, table: str, address: int, vals: list, tags: list[str], client: str = ""
    ) -> None:
        for tag in tags:
            s = self.regmap[tag]
            i = self._index[tag]
            if table == "co":
                self._buf[self.plan.pos[i]] = int(bool(vals[s.address - address]))
            else:
                for a in range(s.address, s.end):
                    if address <= a < address + len(vals):
                        self._buf[self.plan.pos[i] + a - s.address] = int(vals[a - address])
            value = float(self.plan.decode(self._buf)[i])
            self.values[i] = value
            log.info("modbus server: client %s wrote %s = %g", client or "?", tag, value)
            self._on_write(tag, value, client)

    def _on_write(self, tag: str, value: float, client: str = "") -> None:
        if self.on_write is not None:
            try:
                self.on_write(tag, value)
            except Exception:  # noqa: BLE001 - a callback must not break the server
                log.exception("on_write callback failed for %s", tag)


# ------------------------------------------------------------ diagnoses out
@dataclass(frozen=True)
class UnitLayout:
    """The names a unit publishes: faults (in matrix order), tests, models with coverage."""

    unit: str
    faults: Sequence[str] = ()
    tests: Sequence[str] = ()
    models: Sequence[str] = field(default_factory=tuple)

    @classmethod
    def from_status(cls, status: UnitStatus) -> UnitLayout:
        return cls(
            status.unit, list(status.certainties), list(status.residuals), list(status.coverage)
        )


def default_output_map(layouts: Iterable[UnitLayout], stride: int = STRIDE) -> RegisterMap:
    """The default output register map (layout in the module docstring)."""
    if stride < 100:
        raise ValueError("stride must be at least 100 registers")
    rows: list[TagSpec] = []

    def add(tag: str, table: str, addr: int, typ: str) -> None:
        rows.append(TagSpec(tag, table, addr, typ, line=len(rows) + 2))

    for i, lay in enumerate(layouts):
        u, b = lay.unit, i * stride
        for what, cap in (("faults", MAX_FAULTS), ("tests", MAX_TESTS), ("models", MAX_MODELS)):
            if len(getattr(lay, what)) > cap:
                raise ValueError(f"unit {u}: more than {cap} {what} in the default layout")
        add(f"{u}.status", "hr", b, "uint16")
        add(f"{u}.quality", "hr", b + 1, "uint16")
        add(f"{u}.faults", "hr", b + 2, "uint16")
        add(f"{u}.alarm", "hr", b + 3, "uint16")
        add(f"{u}.updates", "hr", b + 4, "uint16")
        add(f"{u}.time", "hr", b + 6, "int32")
        for j, f in enumerate(lay.faults):
            add(f"{u}.certainty.{f}", "hr", b + 10 + 2 * j, "float32")
        for k, t in enumerate(lay.tests):
            add(f"{u}.residual.{t}", "hr", b + 50 + 2 * k, "float32")
        for m, name in enumerate(lay.models):
            add(f"{u}.coverage.{name}", "hr", b + 90 + 2 * m, "float32")
        add(f"{u}.ack", "co", b, "bool")
        for j, f in enumerate(lay.faults):
            add(f"{u}.fault.{f}", "co", b + 1 + j, "bool")
    return RegisterMap(rows, source="<default output map>")


class StatusServer(RegisterServer):
    """Publishes unit diagnoses to Modbus-only SCADA systems; reports acknowledgements.

    ``outputs`` is either the units' layouts (the default map is built from them) or an
    output :class:`RegisterMap` whose tags follow the same names (``U.status``,
    ``U.certainty.<fault>``, …; any subset). Every ``U.ack`` coil is writable by clients;
    an acknowledgement calls ``on_ack(unit)`` and is put on :attr:`acks`. The coil clears
    itself (reads back 0), so the next acknowledgement is again a 0 → 1 write.
    """

    def __init__(
        self,
        outputs: Iterable[UnitLayout] | RegisterMap,
        host: str = "127.0.0.1",
        port: int = 0,
        *,
        device_id: int = 1,
        on_ack: Callable[[str], Any] | None = None,
    ) -> None:
        regmap = outputs if isinstance(outputs, RegisterMap) else default_output_map(outputs)
        acks = [t for t in regmap.names if t.endswith(".ack") and regmap[t].table == "co"]
        super().__init__(regmap, host, port, device_id=device_id, writable=acks)
        self.on_ack = on_ack
        #: acknowledgements in order, each an :class:`Ack` (the unit, with its client)
        self.acks: asyncio.Queue[Ack] = asyncio.Queue()
        self._counter: dict[str, int] = {}
        self._tasks: set[asyncio.Task] = set()
        # before the first diagnosis: CHECK_FUNCTION with Uncertain quality ("initialising"),
        # never the NORMAL/Good that zeroed registers would say
        for i, tag in enumerate(regmap.names):
            if tag.endswith(".status"):
                self.values[i] = 2
            elif tag.endswith(".quality"):
                self.values[i] = 1
        self._buf = self.plan.encode(self.values, self._buf)

    def _on_write(self, tag: str, value: float, client: str = "") -> None:
        super()._on_write(tag, value, client)
        if tag.endswith(".ack") and value:
            unit = Ack(tag.removesuffix(".ack"), client)
            log.info("modbus server: unit %s acknowledged by client %s", unit, client or "?")
            self.acks.put_nowait(unit)
            if self.on_ack is not None:
                try:
                    self.on_ack(unit)
                except Exception:  # noqa: BLE001 - a callback must not break the server
                    log.exception("on_ack callback failed for %s", unit)
            # self-clearing: the coil reads back 0 once the acknowledgement is taken
            task = asyncio.get_running_loop().create_task(self.update({tag: 0.0}))
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)

    def status_values(self, status: UnitStatus, **extra: float) -> dict[str, float]:
        """The map's tag values for one :class:`UnitStatus` (tags not in the map omitted)."""
        u = status.unit
        n = self._counter[u] = (self._counter.get(u, -1) + 1) % 65536
        faults = [name for name in status.certainties]
        active = set(status.faults)
        v: dict[str, float] = {
            f"{u}.status": int(status.status),
            f"{u}.quality": int(status.quality),
            f"{u}.faults": pack_bits(f in active for f in faults[:16]),
            f"{u}.updates": n,
            f"{u}.time": int(status.ts.timestamp()),
        }
        for f in faults:
            v[f"{u}.certainty.{f}"] = float(status.certainties[f])
            v[f"{u}.fault.{f}"] = float(f in active)
        for f in active - set(faults):
            v[f"{u}.fault.{f}"] = 1.0
        for t, r in status.residuals.items():
            v[f"{u}.residual.{t}"] = float(r)
        for m, c in status.coverage.items():
            v[f"{u}.coverage.{m}"] = float(c)
        for k, x in extra.items():
            v[f"{u}.{k}"] = float(x)
        return {k: x for k, x in v.items() if k in self.regmap}

    async def publish(self, status: UnitStatus, **extra: float) -> None:
        """Publish one unit's diagnosis; ``extra`` sets other tags of the unit (``alarm=2``)."""
        await self.update(self.status_values(status, **extra))

    async def publish_many(self, items: Iterable[tuple[UnitStatus, Mapping[str, float]]]) -> None:
        """Publish many units in one update (one encode, each changed block pushed once):
        ``(status, extra)`` pairs as :meth:`publish` takes them."""
        values: dict[str, float] = {}
        for status, extra in items:
            values.update(self.status_values(status, **extra))
        if values:
            await self.update(values)


# --------------------------------------------------------------- the plant
def default_plant_map(tags: Sequence[str] = PLANT_TAGS, table: str = "ir") -> RegisterMap:
    """Plant tags as float32 ABCD, two registers apart from address 0, in ``table``."""
    from diag_plugin.simulate.valve import TAGS

    rows = [
        TagSpec(t, table, 2 * i, "float32", unit=TAGS[t].unit if t in TAGS else "", line=i + 2)
        for i, t in enumerate(tags)
    ]
    return RegisterMap(rows, source="<default plant map>")


class PlantServer(RegisterServer):
    """The simulated plant served as a Modbus TCP PLC; :meth:`set_row` each cycle.

    Serves :func:`default_plant_map` unless ``regmap`` is given; nothing is writable.
    """

    def __init__(
        self,
        regmap: RegisterMap | None = None,
        host: str = "127.0.0.1",
        port: int = 0,
        *,
        device_id: int = 1,
    ) -> None:
        super().__init__(regmap or default_plant_map(), host, port, device_id=device_id)

    async def set_row(self, row: Mapping[str, float]) -> None:
        """Publish one sample (e.g. a row of ``simulate_valve``); other keys are ignored."""
        await self.update({t: float(row[t]) for t in self.regmap.names if t in row})
