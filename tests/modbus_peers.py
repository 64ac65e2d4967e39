"""Peers for the Modbus tests (not tests themselves): pyModbusTCP PLC, raw misbehaving servers.

Run as a script, this starts pyModbusTCP's server as a stand-in plant PLC in its own
process (so a test can kill it with SIGKILL and start it again)::

    python tests/modbus_peers.py PORT
"""

from __future__ import annotations

import asyncio
import importlib.util
import shutil
import struct
import sys
from collections.abc import Awaitable, Callable
from typing import Any

from helpers import free_port, requires  # noqa: F401 - free_port: the peers' callers import it here

HAVE_PYMODBUSTCP = importlib.util.find_spec("pyModbusTCP") is not None
HAVE_MBPOLL = shutil.which("mbpoll") is not None
needs_pymodbustcp = requires(
    "pyModbusTCP (pip)", HAVE_PYMODBUSTCP, "pip install pyModbusTCP; the dev extra has it"
)
needs_mbpoll = requires("mbpoll (Debian package)", HAVE_MBPOLL, "apt-get install mbpoll")

#: the PLC register map our client uses against the pyModbusTCP peer
PLC_MAP = """\
tag,table,address,type,word_order,scale,offset,unit
F,hr,0,float32,ABCD,1,0,t/h
X,hr,2,float32,CDAB,1,0,%
P1,hr,4,int16,,0.1,0,kPa
T1,hr,5,uint16,,0.01,-50,degC
RUN,hr,6.0,bool,,,,
TRIP,hr,6.15,bool,,,,
CNT,ir,10,int32,ABCD,1,0,
PUMP,co,3,bool,,,,
LEVEL_HI,di,7,bool,,,,
SP,hr,20,float32,ABCD,1,0,t/h
"""


def regs_f32(x: float, cdab: bool = False) -> list[int]:
    """Two registers of a float32 (struct, independent of our numpy code)."""
    hi, lo = struct.unpack(">HH", struct.pack(">f", x))
    return [lo, hi] if cdab else [hi, lo]


def fill_plc(bank: Any) -> None:
    """Known values in a pyModbusTCP DataBank, matching :data:`PLC_MAP`."""
    bank.set_holding_registers(0, regs_f32(12.5) + regs_f32(-41.75, cdab=True))
    bank.set_holding_registers(4, [struct.unpack(">H", struct.pack(">h", -1234))[0], 7500])
    bank.set_holding_registers(6, [0x8001])  # bit 0 and bit 15
    bank.set_holding_registers(20, regs_f32(0.0))
    bank.set_input_registers(10, list(struct.unpack(">HH", struct.pack(">i", -70000))))
    bank.set_coils(3, [True])
    bank.set_discrete_inputs(7, [True])


#: engineering values of :func:`fill_plc` through :data:`PLC_MAP`
PLC_VALUES = {
    "F": 12.5,
    "X": -41.75,
    "P1": -123.4,
    "T1": 25.0,
    "RUN": 1.0,
    "TRIP": 1.0,
    "CNT": -70000.0,
    "PUMP": 1.0,
    "LEVEL_HI": 1.0,
    "SP": 0.0,
}


def start_plc(port: int, size: int = 64) -> Any:
    """pyModbusTCP's ModbusServer on 127.0.0.1 (thread), tables of ``size`` entries."""
    from pyModbusTCP.server import DataBank, ModbusServer

    bank = DataBank(coils_size=size, d_inputs_size=size, h_regs_size=size, i_regs_size=size)
    fill_plc(bank)
    srv = ModbusServer(host="127.0.0.1", port=port, no_block=True, data_bank=bank)
    srv.start()
    return srv


async def raw_server(
    handler: Callable[[asyncio.StreamReader, asyncio.StreamWriter], Awaitable[None]],
) -> tuple[asyncio.Server, int]:
    """An asyncio TCP server on 127.0.0.1 with a free port."""
    srv = await asyncio.start_server(handler, "127.0.0.1", 0)
    return srv, int(srv.sockets[0].getsockname()[1])


async def answering_server(
    answer: Callable[[int, int, bytes], Awaitable[bytes | None]],
    on_connect: Callable[[], None] | None = None,
) -> tuple[asyncio.Server, int]:
    """:func:`raw_server` reading each connection's requests until it closes and writing
    what ``answer(transaction id, unit id, PDU)`` gives (None: nothing); ``on_connect`` is
    called as each connection is accepted."""

    async def handler(r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
        if on_connect is not None:
            on_connect()
        try:
            while True:
                out = await answer(*await read_request(r))
                if out is not None:
                    w.write(out)
                    await w.drain()
        except (asyncio.IncompleteReadError, ConnectionError):
            pass

    return await raw_server(handler)


async def read_request(r: asyncio.StreamReader) -> tuple[int, int, bytes]:
    """(transaction id, unit id, PDU) of one Modbus TCP request."""
    head = await r.readexactly(7)
    tid, _proto, length, unit = struct.unpack(">HHHB", head)
    return tid, unit, await r.readexactly(length - 1)


def reply(tid: int, unit: int, pdu: bytes) -> bytes:
    """A Modbus TCP frame (MBAP header + PDU)."""
    return struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu


def registers_reply(pdu: bytes, value: int = 0) -> bytes:
    """A well-formed read-registers response PDU to request ``pdu`` (all words ``value``)."""
    fc, _addr, count = struct.unpack(">BHH", pdu[:5])
    return struct.pack(">BB", fc, 2 * count) + struct.pack(">H", value) * count


if __name__ == "__main__":
    import time

    start_plc(int(sys.argv[1]))
    print("ready", flush=True)
    while True:
        time.sleep(3600)
