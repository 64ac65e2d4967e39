"""Modbus TCP tag reader/writer (pymodbus client), errors returned as Bad quality.

:class:`ModbusTagClient` polls the tags of one :class:`~connectors.registermap.RegisterMap`
from one device: the map's read plan (blocks of at most 125 registers / 2000 bits) is read
block by block, each with an explicit timeout, and decoded with numpy in one go. What can
go wrong on the wire comes back as samples of Bad quality with a reason, never as an
exception from :meth:`ModbusTagClient.read`:

- an exception reply (e.g. illegal data address) → the tags of that block are Bad;
- no answer within the timeout → the block and the rest of the poll are Bad and *late*
  (:attr:`Poll.late`), the connection is kept: a late answer is no outage. pymodbus matches
  each reply to its request by transaction id and skips any other, so the late request's
  answer, when it comes, is never taken for a later request's (another block's tags). A
  device that answers no request in time for ``silent_after`` seconds is dropped as below;
- a reply from another unit id, a malformed or short reply, a lost connection → the block is
  Bad, the connection is dropped (the byte stream can no longer be trusted) and the
  remaining blocks of this poll are Bad "not connected".

Reconnection runs in the background with :class:`~connectors.base.Backoff` (exponential,
full jitter); the backoff is reset only by a poll that succeeds, so a server that accepts
connections but never answers is retried ever more slowly. Like Home Assistant's update
coordinator, availability follows the last poll: the start of a failure is logged once
(warning) and the recovery once (info), never a line per cycle.

Writes go only to tags on the :class:`~connectors.base.AllowList`; any other tag makes
:meth:`ModbusTagClient.write` raise :class:`~connectors.base.WriteRefused` (and log it)
before anything is written.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import struct
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from datetime import datetime
from typing import Any

import numpy as np

from connectors.base import AllowList, Backoff, TagQuality, TagSample, now
from connectors.registermap import BIT_TABLES, ReadBlock, RegisterMap, encode

__all__ = ["ModbusTagClient", "Poll", "quiet_pymodbus"]

log = logging.getLogger(__name__)

_EXC_NAMES = {
    1: "illegal function",
    2: "illegal data address",
    3: "illegal data value",
    4: "server device failure",
    5: "acknowledge",
    6: "server device busy",
    8: "memory parity error",
    10: "gateway path unavailable",
    11: "gateway target device failed to respond",
}


def quiet_pymodbus(level: int = logging.CRITICAL) -> None:
    """Keep pymodbus's own log lines (one per failed request) out of the plant log.

    Our connectors report each failure once with context; pymodbus would log every
    timeout and refused connect. Only applied when the application has not set a level
    for the ``pymodbus`` logger itself.
    """
    for name in ("pymodbus", "pymodbus.logging"):
        lg = logging.getLogger(name)
        if lg.level == logging.NOTSET:
            lg.setLevel(level)


@dataclass
class Poll:
    """One poll of all tags, as arrays in map order (cheap for thousands of tags)."""

    ts: datetime
    values: np.ndarray  #: float64, NaN where the quality is Bad
    quality: np.ndarray  #: uint8 TagQuality per tag
    reasons: list[str]  #: per tag, "" when Good
    seconds: float  #: wall time of the poll
    #: per tag, the source's own time stamp (Unix seconds; NaN where it gives none: Modbus)
    source_ts: np.ndarray | None = None
    #: per tag, True where its source gave no answer within the cycle's poll deadline or its
    #: own timeout (a Modbus block and the rest of that poll, an OPC UA Read): the tag was not
    #: read this cycle (Bad), which says nothing of whether its value moved; late is not down
    late: np.ndarray | None = None

    @property
    def good(self) -> bool:
        return bool(np.all(self.quality == TagQuality.GOOD))


class _Dropped(Exception):
    """A block failure after which the connection cannot be trusted."""


class _Late(Exception):
    """A block whose request got no answer within the timeout (the connection is kept)."""


class ModbusTagClient:
    """Poll (and write) the tags of ``regmap`` on one Modbus TCP device.

    Args:
        regmap: the device's register map.
        host, port: the device (our servers and tests use 127.0.0.1).
        device_id: Modbus unit id sent with every request; a reply from another id is Bad.
        timeout: seconds allowed for each request (and for connecting).
        allow: output tags that :meth:`write` may write (the configured allow-list).
        backoff: reconnect delays (default: 0.5 s doubling to 30 s, full jitter).
        max_gap: unused addresses a read block may span (see ``RegisterMap.plan``).
        name: name used in log lines (default ``host:port/device_id``).
        silent_after: seconds without any request answered in time after which a request
            that times out drops the connection (a device that accepts but never answers);
            a shorter silence is late, not down. At least twice ``timeout`` (one request late
            by its whole timeout is never an outage).
    """

    def __init__(
        self,
        regmap: RegisterMap,
        host: str = "127.0.0.1",
        port: int = 502,
        *,
        device_id: int = 1,
        timeout: float = 1.0,
        allow: AllowList | Iterable[str] = (),
        backoff: Backoff | None = None,
        max_gap: int = 0,
        name: str | None = None,
        silent_after: float = 5.0,
    ) -> None:
        self.regmap = regmap
        self.host, self.port, self.device_id = host, int(port), int(device_id)
        self.timeout = float(timeout)
        self.silent_after = max(float(silent_after), 2.0 * self.timeout)
        self.allow = allow if isinstance(allow, AllowList) else AllowList(allow)
        self.backoff = backoff or Backoff()
        self.plan = regmap.plan(max_gap=max_gap)
        self.name = name or f"modbus://{host}:{port}/{device_id}"
        self._client: Any = None
        self._reconnect_task: asyncio.Task | None = None
        self._closed = False
        self._ever_tried = False
        self._rx = bytearray()
        self._tx_tid = b""
        self.last_error = ""
        #: availability as the last poll left it, and since when it is failing
        self.available = False
        self.failing_since: datetime | None = None
        self.polls = 0
        self.failed_polls = 0
        self.connects = 0
        #: requests that got no answer within the timeout (the connection kept)
        self.read_timeouts = 0
        self._answered = 0.0  # time.monotonic() of the last request answered in time
        quiet_pymodbus()

    @property
    def names(self) -> list[str]:
        """The tags a :meth:`poll` returns, in its order (the register map's)."""
        return list(self.regmap.names)

    # ------------------------------------------------------------ connection
    @property
    def connected(self) -> bool:
        return self._client is not None and bool(self._client.connected)

    async def connect(self) -> bool:
        """One connection attempt (with ``timeout``); True when connected."""
        from pymodbus.client import AsyncModbusTcpClient

        self._drop_client()
        client = AsyncModbusTcpClient(
            self.host,
            port=self.port,
            timeout=self.timeout,
            retries=0,
            reconnect_delay=0,  # reconnection is ours (Backoff), not pymodbus's
            name=self.name,
            trace_packet=self._trace,
        )
        # pymodbus closes the connection itself after 3 requests in a row without an
        # answer; a late answer is no outage here: silent_after decides (see _read_block)
        client.set_max_no_responses(1 << 30)
        why = "refused or unreachable"
        try:
            async with asyncio.timeout(self.timeout + 0.5):
                ok = await client.connect()
        except (TimeoutError, OSError) as exc:
            ok, why = False, f"{type(exc).__name__} {exc}".strip()
        if not ok:
            client.close()
            self.last_error = f"connect to {self.host}:{self.port} failed: {why}"
            log.debug("%s: %s", self.name, self.last_error)
            return False
        self._client = client
        self._answered = time.monotonic()
        self.connects += 1
        log.debug("%s: connected", self.name)
        return True

    def _trace(self, sending: bool, data: bytes) -> bytes:
        """pymodbus packet hook: keep what came back since the last request (diagnosis)."""
        if sending:
            self._rx.clear()
            self._tx_tid = bytes(data[:2])
        elif len(self._rx) < 512:
            self._rx += data
        return data

    def _no_answer(self, where: str) -> tuple[str, bool]:
        """Why a request got no usable answer, from the bytes that did come back, and
        whether it is only late (nothing came, or only whole frames of this unit with another
        transaction id: answers to earlier requests, which pymodbus skipped).

        pymodbus drops frames it cannot use (garbage, another unit id, a short PDU, another
        transaction id) and waits for the timeout; the raw bytes tell which it was.
        """
        rx = bytes(self._rx)
        if not rx:
            return f"timeout after {self.timeout:g} s reading {where}", True
        stale, at = 0, 0
        while at + 7 <= len(rx):  # MBAP: tid, protocol 0, length, unit
            tid, proto, n, unit = struct.unpack_from(">2s2sHB", rx, at)
            size = 6 + n
            ours = proto == b"\x00\x00" and unit == self.device_id and tid != self._tx_tid
            if not ours or at + size > len(rx):
                break
            stale, at = stale + 1, at + size
        if stale and at == len(rx):
            return (
                f"timeout after {self.timeout:g} s reading {where} ({stale} late answer"
                f"{'s' if stale > 1 else ''} to earlier requests came meanwhile, discarded)",
                True,
            )
        if len(rx) >= 8 and rx[2:4] == b"\x00\x00" and rx[6] != self.device_id:
            return f"reply from unit id {rx[6]}, not {self.device_id}, reading {where}", False
        return f"malformed reply reading {where}: {len(rx)} bytes {rx[:16].hex(' ')}…", False

    def _drop_client(self) -> None:
        if self._client is not None:
            with contextlib.suppress(Exception):
                self._client.close()
            self._client = None

    def _ensure_reconnect(self) -> None:
        if self._closed or (self._reconnect_task and not self._reconnect_task.done()):
            return
        self._reconnect_task = asyncio.get_running_loop().create_task(
            self._reconnect_loop(), name=f"reconnect {self.name}"
        )

    async def _reconnect_loop(self) -> None:
        while not self._closed and not self.connected:
            delay = self.backoff.next_delay()
            log.debug("%s: reconnecting in %.2f s", self.name, delay)
            await asyncio.sleep(delay)
            if self._closed:
                return
            if await self.connect():
                return

    async def close(self) -> None:
        """Stop reconnecting and close the connection."""
        self._closed = True
        if self._reconnect_task and not self._reconnect_task.done():
            self._reconnect_task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await self._reconnect_task
        self._drop_client()

    # ------------------------------------------------------------------ read
    async def read(self) -> list[TagSample]:
        """One poll of every tag as :class:`TagSample` (never raises for wire errors)."""
        p = await self.poll()
        q = [TagQuality(int(x)) for x in p.quality]
        return [
            TagSample(tag, float(v), p.ts, qq, r)
            for tag, v, qq, r in zip(self.regmap.names, p.values, q, p.reasons, strict=True)
        ]

    async def poll(self) -> Poll:
        """One poll of every tag as arrays (see :class:`Poll`)."""
        t0 = time.perf_counter()
        ts = now()
        if not self.connected and not self._ever_tried and not self._closed:
            self._ever_tried = True
            await self.connect()
        buf = self.plan.new_buffer()
        errors: list[str] = [""] * len(self.plan.blocks)
        late_from = len(errors)  # blocks from here on got no answer in time (or were not read)
        if not self.connected:
            self._ensure_reconnect()
            errors = [f"not connected ({self.last_error or 'connecting'})"] * len(errors)
        else:
            for i, block in enumerate(self.plan.blocks):
                try:
                    errors[i] = await self._read_block(block, buf)
                except _Late as exc:
                    # late, not down: the connection is kept; the rest of this poll is not
                    # read (a slow device would make each block wait its timeout)
                    self.read_timeouts += 1
                    late_from = i
                    errors[i] = str(exc)
                    for j in range(i + 1, len(errors)):
                        errors[j] = f"not read: an earlier block got no answer in time ({exc})"
                    break
                except _Dropped as exc:
                    errors[i] = str(exc)
                    self.last_error = str(exc)
                    self._drop_client()
                    self._ensure_reconnect()
                    for j in range(i + 1, len(errors)):
                        errors[j] = f"not connected (dropped after: {exc})"
                    break
        values = self.plan.decode(buf)
        tb = self.plan.tag_block
        block_bad = np.array([bool(e) for e in errors] + [True], dtype=bool)  # [-1]: no block
        bad = block_bad[np.where(tb >= 0, tb, len(errors))]
        if bad.any():
            tag_err = [errors[b] if b >= 0 else "not in any read block" for b in tb]
        else:
            tag_err = [""] * len(tb)
        quality = np.where(bad, TagQuality.BAD, TagQuality.GOOD).astype(np.uint8)
        values[bad] = np.nan
        late = tb >= late_from
        if late_from == len(errors):
            self._account(ts, errors)
        else:  # late: availability stays as it was (a late answer is no outage, no recovery)
            self.polls += 1
        return Poll(ts, values, quality, tag_err, time.perf_counter() - t0, None, late)

    async def _read_block(self, b: ReadBlock, buf: np.ndarray) -> str:
        """Read one block into ``buf``; "" or the reason it failed (raise _Late, _Dropped)."""
        from pymodbus.exceptions import ConnectionException, ModbusIOException

        c = self._client
        fn = {
            "co": c.read_coils,
            "di": c.read_discrete_inputs,
            "ir": c.read_input_registers,
            "hr": c.read_holding_registers,
        }[b.table]
        where = f"{b.table} {b.start}+{b.count}"
        try:
            async with asyncio.timeout(self.timeout + 0.25):
                rr = await fn(b.start, count=b.count, device_id=self.device_id)
        except TimeoutError:
            raise self._no_answer_error(where) from None
        except ModbusIOException as exc:
            msg = str(exc)
            if "device id" in msg:
                raise _Dropped(f"reply from a wrong unit id reading {where}: {msg}") from None
            if "No response" in msg:
                raise self._no_answer_error(where) from None
            raise _Dropped(f"malformed reply reading {where}: {msg}") from None
        except ConnectionException as exc:
            raise _Dropped(f"connection lost reading {where}: {exc}") from None
        except Exception as exc:  # noqa: BLE001 - a broken reply must not end the poll
            raise _Dropped(f"malformed reply reading {where}: {exc!r}") from None
        self._answered = time.monotonic()
        if rr.isError():
            code = int(getattr(rr, "exception_code", 0) or 0)
            if code:
                return f"exception reply {code} ({_EXC_NAMES.get(code, 'unknown')}) for {where}"
            raise _Dropped(f"malformed reply reading {where}: {rr}")
        if rr.dev_id and rr.dev_id != self.device_id:
            raise _Dropped(f"reply from unit id {rr.dev_id}, not {self.device_id}, for {where}")
        data = rr.bits if b.table in BIT_TABLES else rr.registers
        if data is None or len(data) < b.count:
            n = 0 if data is None else len(data)
            raise _Dropped(f"malformed reply reading {where}: {n} values, expected {b.count}")
        buf[b.buf_offset : b.buf_offset + b.count] = np.asarray(data[: b.count], dtype=np.uint16)
        return ""

    def _no_answer_error(self, where: str) -> Exception:
        """:class:`_Late` for a request with no answer in time, :class:`_Dropped` when the
        reply was unusable or no request has been answered in time for ``silent_after``."""
        why, late = self._no_answer(where)
        if not late:
            return _Dropped(why)
        if not self.connected:  # the device went away while the request waited
            return _Dropped(f"connection lost reading {where}: closed without an answer")
        silent = time.monotonic() - self._answered
        if silent >= self.silent_after:
            return _Dropped(f"no request answered in time for {silent:.1f} s (last: {why})")
        return _Late(why)

    def _account(self, ts: datetime, errors: list[str]) -> None:
        """Availability from this poll; log the start of a failure once, the recovery once."""
        self.polls += 1
        bad = [e for e in errors if e]
        if not bad:
            if self.failing_since is not None:
                down = (ts - self.failing_since).total_seconds()
                log.info(
                    "%s: recovered, all %d tags good again after %.1f s",
                    self.name,
                    len(self.regmap),
                    down,
                )
            self.failing_since = None
            self.available = True
            self.backoff.reset()
            return
        self.failed_polls += 1
        self.available = False
        if self.failing_since is None:
            self.failing_since = ts
            log.warning(
                "%s: %d of %d read blocks bad (tags Bad until it recovers): %s",
                self.name,
                len(bad),
                len(errors),
                bad[0],
            )

    # ----------------------------------------------------------------- write
    async def write(self, values: Mapping[str, float]) -> dict[str, str]:
        """Write output tags; ``{tag: "ok" or the reason it failed}``.

        Raises :class:`~connectors.base.WriteRefused` (nothing written) when any tag is
        not on the allow-list.
        """
        from pymodbus.exceptions import ModbusException

        self.allow.check(values)
        out: dict[str, str] = {}
        for tag, value in values.items():
            if tag not in self.regmap:
                out[tag] = "not in the register map"
                continue
            spec = self.regmap[tag]
            if not spec.writable:
                out[tag] = f"table {spec.table} is read-only"
                continue
            if not self.connected:
                out[tag] = f"not connected ({self.last_error or 'connecting'})"
                self._ensure_reconnect()
                continue
            c = self._client
            try:
                current = 0
                if spec.type == "bool" and spec.table == "hr":
                    async with asyncio.timeout(self.timeout + 0.25):
                        rr = await c.read_holding_registers(
                            spec.address, count=1, device_id=self.device_id
                        )
                    if rr.isError():
                        out[tag] = f"read before write failed: {rr}"
                        continue
                    current = int(rr.registers[0])
                words = encode(spec, value, current)
                if spec.table == "co":
                    req = c.write_coils(spec.address, list(words), device_id=self.device_id)
                else:
                    req = c.write_registers(spec.address, list(words), device_id=self.device_id)
                async with asyncio.timeout(self.timeout + 0.25):
                    rr = await req
                code = int(getattr(rr, "exception_code", 0) or 0) if rr.isError() else 0
                out[tag] = (
                    f"exception reply {code} ({_EXC_NAMES.get(code, 'unknown')})"
                    if rr.isError()
                    else "ok"
                )
            except ValueError as exc:
                out[tag] = str(exc)
            except (TimeoutError, ModbusException) as exc:
                out[tag] = f"write failed: {exc or 'timeout'}"
            if out[tag] != "ok":
                log.warning("%s: write %s=%r failed: %s", self.name, tag, value, out[tag])
        return out
