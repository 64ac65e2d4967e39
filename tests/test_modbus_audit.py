"""The Modbus acknowledge coil's audit names the client that wrote it (issue 35, item 8):
real clients (pyModbusTCP, pymodbus) against our status server on 127.0.0.1."""

from __future__ import annotations

import asyncio
import logging

from modbus_peers import needs_pymodbustcp

from connectors.modbus_server import StatusServer, UnitLayout


@needs_pymodbustcp
def test_ack_coil_names_the_client_address_in_the_audit(caplog):
    from pymodbus.client import AsyncModbusTcpClient
    from pyModbusTCP.client import ModbusClient

    async def main():
        srv = StatusServer([UnitLayout("V1", ["f1"], ["r1"]), UnitLayout("V2", ["f1"], ["r1"])])
        await srv.start()
        loop = asyncio.get_running_loop()
        try:
            ack_v2 = srv.regmap["V2.ack"].address

            def write_with_pymodbustcp():
                c = ModbusClient(host="127.0.0.1", port=srv.port, unit_id=1, auto_open=False)
                assert c.open()
                try:
                    me = c._sock.getsockname()
                    ok = c.write_single_coil(ack_v2, True)
                    refused = c.write_single_register(3, 7)  # a status register: refused
                    return f"{me[0]}:{me[1]}", ok, refused
                finally:
                    c.close()

            who1, ok, refused = await loop.run_in_executor(None, write_with_pymodbustcp)
            first = await asyncio.wait_for(srv.acks.get(), 5)
            mb = AsyncModbusTcpClient("127.0.0.1", port=srv.port)
            await mb.connect()
            sock = mb.ctx.transport.get_extra_info("sockname")
            who2 = f"{sock[0]}:{sock[1]}"
            await mb.write_coil(srv.regmap["V1.ack"].address, True)
            second = await asyncio.wait_for(srv.acks.get(), 5)
            mb.close()
            return who1, ok, refused, first, who2, second
        finally:
            await srv.stop()

    with caplog.at_level(logging.INFO, logger="connectors.modbus_server"):
        who1, ok, refused, first, who2, second = asyncio.run(main())
    assert ok and not refused  # the refused write got an exception reply
    assert who1 != who2  # two connections, two addresses
    assert first == "V2" and first.client == who1
    assert second == "V1" and second.client == who2
    logged = [r.getMessage() for r in caplog.records]
    assert f"modbus server: unit V2 acknowledged by client {who1}" in logged, logged
    assert f"modbus server: unit V1 acknowledged by client {who2}" in logged, logged
    assert any(f"refused a write by client {who1} (fc 6)" in m for m in logged), logged
