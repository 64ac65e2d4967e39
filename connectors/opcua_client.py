"""OPC UA tag reader/writer (asyncua): subscription or polling, quality from the StatusCode.

:class:`OpcUaReader` keeps one connection per endpoint in a background task. While connected
it either holds a data-change subscription (``mode="subscription"``) or reads all nodes in
one Read request per :meth:`OpcUaReader.read` (``mode="poll"``). Values come from
``DataValue`` s (never ``read_value()``, which raises on Uncertain): the StatusCode's
severity gives :class:`TagQuality`. When the connection fails every tag turns Bad, the
failure is logged once, the task reconnects with :class:`Backoff` (exponential, jitter) and
logs the recovery once (Home Assistant's coordinator pattern, DESIGN.md).
Writes go only to tags on the :class:`AllowList`.

**Trust.** With security the server's certificate is fetched first (GetEndpoints, nothing of
ours is sent) and must be the pinned one (``server_certificate``) or in the trust-list folder
(``trusted_dir``, read again at every attempt, so a certificate copied there is trusted at the
next retry); any other is refused with :class:`UntrustedServer`, which names its SHA-256
fingerprint (and saves it in ``rejected/`` beside the trust folder) — before any session is
created or a password sent. The channel is then pinned to that certificate.

**Node ids** are checked at every connection: ``nsu=<uri>;...`` is resolved through the
server's namespace array, and every node must exist and be a variable. A bad one is logged
once (tag, node id, reason), its tag stays Bad with that reason, and :attr:`OpcUaReader.bad_nodes`
lists them.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from connectors.base import AllowList, Backoff, TagQuality, TagSample, name_tags, now

if TYPE_CHECKING:
    from asyncua import Client, Node, ua

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ClientSecurity:
    """Basic256Sha256 (``mode`` SignAndEncrypt or Sign): our certificate and key, an optional
    user, and which server certificates to trust: the pinned ``server_certificate`` and/or
    those in ``trusted_dir`` (module doc)."""

    certificate: Path
    private_key: Path
    application_uri: str
    username: str | None = None
    password: str | None = None
    server_certificate: Path | None = None
    trusted_dir: Path | None = None
    mode: str = "SignAndEncrypt"


class UntrustedServer(ConnectionError):
    """The server's certificate is neither pinned nor in the trust list (nothing was sent)."""


class ReadTimeout(TimeoutError):
    """A Read request that got no answer within the reader's timeout: says from which server,
    which tags, the timeout and how long the read waited (a loaded event loop waits longer)."""

    def __init__(self, url: str, tags: list[str], timeout: float, waited: float) -> None:
        named = name_tags(tags)
        n = f"{len(tags)} tag{'s' if len(tags) != 1 else ''}"
        super().__init__(
            f"no answer from {url} to the Read of {n} ({named}) within the {timeout:g} s "
            f"timeout (waited {waited:.2f} s)"
        )


def _retrieved(task: asyncio.Future[Any]) -> None:
    """Done callback of a request given up on: its late outcome is nobody's error."""
    if not task.cancelled():
        task.exception()


@dataclass
class OpcUaConfig:
    """One endpoint: tag name → node id (``ns=2;s=Plant.F`` or ``nsu=<uri>;s=...``)."""

    url: str
    nodes: Mapping[str, str]
    mode: Literal["subscription", "poll"] = "poll"
    period: float = 1.0  # publishing interval (subscription) in s
    timeout: float = 4.0  # per request, s
    connect_timeout: float = 10.0
    security: ClientSecurity | None = None
    outputs: tuple[str, ...] = ()  # the write allow-list (tag names of ``nodes``)
    backoff_base: float = 0.5
    backoff_cap: float = 30.0
    #: s: asyncua's watchdog reads the server's state this often and waits this long for the
    #: answer; no answer in time is a lost connection. A server silent this long is down; a
    #: shorter silence (a late answer: a busy server, a loaded machine) is late, not down.
    #: At least twice ``timeout`` (one Read late by its whole timeout is never an outage)
    silent_after: float = 5.0


def quality_of(code: Any) -> TagQuality:
    """:class:`TagQuality` from an OPC UA StatusCode (its two severity bits)."""
    if code is None:
        return TagQuality.GOOD
    value = int(getattr(code, "value", code))
    sev = value >> 30
    return (TagQuality.GOOD, TagQuality.UNCERTAIN, TagQuality.BAD, TagQuality.BAD)[sev]


def sample_of(tag: str, dv: ua.DataValue) -> TagSample:
    """A :class:`TagSample` from a DataValue: NaN for null/non-numeric values."""
    q = quality_of(dv.StatusCode)
    raw = dv.Value.Value if dv.Value is not None else None
    try:
        value = float(raw) if raw is not None else math.nan
    except (TypeError, ValueError):
        value = math.nan
    ts = dv.SourceTimestamp or dv.ServerTimestamp or now()
    if ts.tzinfo is None:
        ts = ts.replace(tzinfo=UTC)
    reason = "" if q == TagQuality.GOOD else getattr(dv.StatusCode, "name", str(dv.StatusCode))
    return TagSample(tag, value, ts, q, reason)


class _Handler:
    def __init__(self, reader: OpcUaReader) -> None:
        self.reader = reader

    def datachange_notification(self, node: Node, val: Any, data: Any) -> None:
        tag = self.reader._tag_of.get(node.nodeid.to_string())
        if tag is not None:
            self.reader._latest[tag] = sample_of(tag, data.monitored_item.Value)

    def status_change_notification(self, status: Any) -> None:
        self.reader._lost.set()


class OpcUaReader:
    """Reads (and writes allowed) tags of one OPC UA server; never raises from :meth:`read`.

    ``await reader.start()`` launches the connection task and returns at once; ``read()``
    gives the latest sample of every tag (Bad while disconnected); ``write()`` writes
    allow-listed tags; ``close()`` stops everything.
    """

    def __init__(self, config: OpcUaConfig) -> None:
        self.config = config
        self.allow = AllowList(config.outputs)
        self._latest: dict[str, TagSample] = {}
        self._tag_of: dict[str, str] = {}
        self._nodes: dict[str, Node] = {}
        self._vtypes: dict[str, Any] = {}
        self._client: Client | None = None
        self._task: asyncio.Task[None] | None = None
        self._connected = asyncio.Event()
        self._lost = asyncio.Event()
        self._stop = asyncio.Event()
        self._failing = False
        #: tag → why its node id is unusable on the server (checked at every connection)
        self.bad_nodes: dict[str, str] = {}
        self._reported_bad: dict[str, str] = {}
        self.outages = 0  # how many times the connection was lost or refused
        #: Read requests that got no answer within the timeout (the connection kept)
        self.read_timeouts = 0
        self.timed_out = False  #: the last read's request got no answer within the timeout
        #: (start, end) of each outage; end is None while it lasts
        self.gaps: list[tuple[datetime, datetime | None]] = []
        self._set_all_bad("not connected yet")

    @property
    def connected(self) -> bool:
        return self._connected.is_set()

    def _set_all_bad(self, reason: str) -> None:
        t = now()
        for tag in self.config.nodes:
            old = self._latest.get(tag)
            value = old.value if old is not None else math.nan
            self._latest[tag] = TagSample(tag, value, t, TagQuality.BAD, reason)

    async def start(self) -> None:
        """Start the background connection task (returns immediately)."""
        if self._task is None:
            self._stop.clear()
            self._task = asyncio.create_task(self._run(), name=f"opcua {self.config.url}")

    async def wait_connected(self, timeout: float) -> bool:
        """Wait up to ``timeout`` s for the connection; True when connected."""
        try:
            await asyncio.wait_for(self._connected.wait(), timeout)
            return True
        except TimeoutError:
            return False

    async def close(self) -> None:
        self._stop.set()
        # wakes _run once connected even if asyncua swallowed the cancel below mid-connect
        self._lost.set()
        if self._task is not None:
            self._task.cancel()
            await asyncio.wait([self._task])  # a cancel of close() itself still propagates
            if not self._task.cancelled() and self._task.exception() is not None:
                log.debug("OPC UA %s: %r on close", self.config.url, self._task.exception())
            self._task = None
        await self._disconnect()

    # -- connection ------------------------------------------------------------------------

    async def _run(self) -> None:
        backoff = Backoff(self.config.backoff_base, self.config.backoff_cap)
        while not self._stop.is_set():
            self._lost.clear()  # here, not in _connect: close() may set it while connecting
            try:
                async with asyncio.timeout(self.config.connect_timeout):
                    await self._connect()
            except Exception as exc:  # noqa: BLE001 - any failure means "retry later"
                await self._disconnect()
                self._on_failure(exc)
                await self._sleep(backoff.next_delay())
                continue
            backoff.reset()
            if self._failing:
                self.gaps[-1] = (self.gaps[-1][0], now())
                log.warning("OPC UA %s: connection restored", self.config.url)
            else:
                log.info("OPC UA %s: connected", self.config.url)
            self._failing = False
            self._connected.set()
            await self._lost.wait()
            self._connected.clear()
            await self._disconnect()
            if self._stop.is_set():
                break
            self._on_failure(ConnectionError("connection lost"))
            await self._sleep(backoff.next_delay())

    def _on_failure(self, exc: BaseException) -> None:
        self._set_all_bad(f"no connection: {exc!r}")
        if not self._failing:
            self.outages += 1
            self.gaps.append((now(), None))
            log.warning(
                "OPC UA %s: unavailable (%r); retrying in the background", self.config.url, exc
            )
        else:
            log.debug("OPC UA %s: still unavailable (%r)", self.config.url, exc)
        self._failing = True

    async def _sleep(self, delay: float) -> None:
        try:
            await asyncio.wait_for(self._stop.wait(), delay)
        except TimeoutError:
            pass

    async def _connect(self) -> None:
        from asyncua import Client, ua
        from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

        cfg = self.config
        # the session's own requests (CreateSession, ActivateSession, a secured handshake)
        # get at least 4 s even when the reads' timeout is a short cycle's. asyncua's
        # watchdog probe waits as long as its interval: from the reads' timeout (0.5 s at a
        # 0.1 s cycle) one answer late by that much dropped the session (issue 34)
        client = Client(
            cfg.url,
            timeout=max(cfg.timeout, 4.0),
            watchdog_intervall=max(cfg.silent_after, 2.0 * cfg.timeout),
        )
        client.session_timeout = 60_000
        sec = cfg.security
        self._client = client
        if sec is not None:
            client.application_uri = sec.application_uri
            mode = getattr(ua.MessageSecurityMode, sec.mode)
            server_der = await self._trusted_server_certificate(client, mode)
            if sec.username is not None:
                client.set_user(sec.username)
            if sec.password is not None:
                client.set_password(sec.password)
            await client.set_security(
                SecurityPolicyBasic256Sha256,
                str(sec.certificate),
                str(sec.private_key),
                server_certificate=server_der,
                mode=mode,
            )

        async def lost(exc: Exception) -> None:
            self._lost.set()

        client.connection_lost_callback = lost
        await client.connect(auto_reconnect=False)
        await self._resolve_nodes(client)
        for tag in cfg.outputs:
            if tag in self._nodes:
                self._vtypes[tag] = await self._nodes[tag].read_data_type_as_variant_type()
        if cfg.mode == "subscription":
            sub = await client.create_subscription(cfg.period * 1000, _Handler(self))
            if self._nodes:
                await sub.subscribe_data_change(list(self._nodes.values()))
        else:
            await self._poll()

    async def _trusted_server_certificate(self, client: Client, mode: Any) -> bytes:
        """The server certificate from its endpoints if trusted, else :class:`UntrustedServer`."""
        from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

        from connectors.certs import certificate_der, fingerprint, trusted_ders

        sec = self.config.security
        assert sec is not None
        endpoints = await client.connect_and_get_server_endpoints()
        uri = SecurityPolicyBasic256Sha256.URI
        ep = next(
            (e for e in endpoints if e.SecurityPolicyUri == uri and e.SecurityMode == mode), None
        )
        if ep is None or not ep.ServerCertificate:
            offered = sorted(
                {f"{e.SecurityPolicyUri.split('#')[-1]} {e.SecurityMode.name}" for e in endpoints}
            )
            raise ConnectionError(
                f"{self.config.url} offers no Basic256Sha256 {mode.name} endpoint "
                f"(it offers {', '.join(offered) or 'nothing'})"
            )
        chain = bytes(ep.ServerCertificate)
        der = chain[: int.from_bytes(chain[2:4], "big") + 4]  # the first of a chain
        trusted = await asyncio.to_thread(trusted_ders, sec.trusted_dir)
        pinned = certificate_der(sec.server_certificate) if sec.server_certificate else None
        if der == pinned or der in trusted:
            return der
        fp = fingerprint(der)
        saved = ""
        if sec.trusted_dir is not None:
            rejected = Path(sec.trusted_dir).parent / "rejected"
            rejected.mkdir(parents=True, exist_ok=True)
            path = rejected / f"{fp.replace(':', '')[:16].lower()}.der"
            path.write_bytes(der)
            saved = f"; saved as {path}: move it into {sec.trusted_dir} to trust it"
        elif pinned is not None:
            saved = f"; it is not the pinned {sec.server_certificate} ({fingerprint(pinned)})"
        else:
            saved = "; set trusted (a folder) or server_certificate for this source"
        raise UntrustedServer(
            f"server certificate of {self.config.url} not trusted (SHA-256 {fp}), nothing sent"
            + saved
        )

    async def _resolve_nodes(self, client: Client) -> None:
        """Node ids to nodes: ``nsu=`` through the namespace array; each must exist and be a
        variable. Unusable ones go to :attr:`bad_nodes` (logged once) and stay Bad."""
        from asyncua import ua

        namespaces = await client.get_namespace_array()
        ids: dict[str, Any] = {}
        bad: dict[str, str] = {}
        for tag, text in self.config.nodes.items():
            try:
                nid = ua.NodeId.from_string(text)
            except Exception as exc:  # noqa: BLE001 - the parser's own errors vary
                bad[tag] = f"not a node id ({exc})"
                continue
            uri = getattr(nid, "NamespaceUri", None)
            if uri:
                if uri not in namespaces:
                    bad[tag] = f"namespace {uri} is not on the server"
                    continue
                nid = ua.NodeId(nid.Identifier, namespaces.index(uri), nid.NodeIdType)
            ids[tag] = nid
        tags = list(ids)
        async with asyncio.timeout(self.config.timeout):
            classes = await client.uaclient.read_attributes(
                [ids[t] for t in tags], ua.AttributeIds.NodeClass
            )
        for tag, dv in zip(tags, classes, strict=True):
            if not dv.StatusCode.is_good():
                bad[tag] = dv.StatusCode.name
            elif dv.Value.Value != ua.NodeClass.Variable:
                bad[tag] = f"a {ua.NodeClass(dv.Value.Value).name}, not a variable"
        self.bad_nodes = bad
        for tag, why in bad.items():
            if self._reported_bad.get(tag) != why:
                log.warning(
                    "OPC UA %s: tag %s: node %s: %s",
                    self.config.url,
                    tag,
                    self.config.nodes[tag],
                    why,
                )
        self._reported_bad = dict(bad)
        self._nodes = {t: client.get_node(n) for t, n in ids.items() if t not in bad}
        self._tag_of = {n.nodeid.to_string(): t for t, n in self._nodes.items()}
        t = now()
        for tag, why in bad.items():
            self._latest[tag] = TagSample(
                tag, math.nan, t, TagQuality.BAD, f"node {self.config.nodes[tag]}: {why}"
            )

    async def _disconnect(self) -> None:
        client, self._client = self._client, None
        if client is None:
            return
        try:
            async with asyncio.timeout(self.config.timeout):
                await client.disconnect()
        except Exception:  # noqa: BLE001 - the peer may be gone already
            client.disconnect_socket()

    async def _poll(self) -> None:
        """One Read request of every node, waited for up to the config's ``timeout``; raises
        :class:`ReadTimeout` (what timed out, after how long, which tags) when it runs out.

        The request runs as a task of its own, awaited with :func:`asyncio.wait`, not
        inside ``asyncio.timeout``: asyncua waits for each answer in its own ``wait_for``
        (``wait_for2`` before Python 3.12), and an answer that came in the same event-loop
        iteration as our timeout (a loaded machine) came out of it as ``CancelledWithResultError``,
        a CancelledError that ``asyncio.timeout`` does not turn into TimeoutError: it escaped
        :meth:`read` and the poll task ended cancelled ("scada: poll failed: CancelledError()",
        issue 34)."""
        assert self._client is not None
        tags = list(self._nodes)
        if not tags:
            return
        t0 = time.monotonic()
        req = asyncio.ensure_future(self._client.read_attributes([self._nodes[t] for t in tags]))
        try:
            done, _ = await asyncio.wait({req}, timeout=self.config.timeout)
        except BaseException:  # this read cancelled (the loop closing): stop the request
            req.cancel()
            req.add_done_callback(_retrieved)
            raise
        if not done:
            req.cancel()
            req.add_done_callback(_retrieved)
            raise ReadTimeout(self.config.url, tags, self.config.timeout, time.monotonic() - t0)
        if req.cancelled():  # by asyncua itself (a channel closing): not ours to propagate
            raise ConnectionError(f"the Read request to {self.config.url} was cancelled")
        for tag, dv in zip(tags, req.result(), strict=True):
            self._latest[tag] = sample_of(tag, dv)

    # -- the reader interface ---------------------------------------------------------------

    async def read(self) -> list[TagSample]:
        """The latest sample of every configured tag (one Read request when polling).
        :attr:`timed_out` says whether this read's request got no answer in time."""
        self.timed_out = False
        if self.config.mode == "poll" and self._connected.is_set():
            try:
                await self._poll()
            except ReadTimeout as exc:
                # a late answer (a loaded machine, a busy server) is no lost connection: the
                # session is kept, the tags are Bad for this read only. A server that stops
                # answering for good is found by asyncua's watchdog (its connection_lost
                # callback), as before
                self._set_all_bad(str(exc))
                self.read_timeouts += 1
                self.timed_out = True
            except Exception as exc:  # noqa: BLE001 - a failed poll means a lost connection
                self._set_all_bad(f"read failed: {exc!r}")
                self._lost.set()
        return [self._latest[t] for t in self.config.nodes]

    async def write(self, values: Mapping[str, float]) -> dict[str, str]:
        """Write allow-listed tags; raises :class:`WriteRefused` for any other tag.

        Returns tag → StatusCode name (``"Good"`` or why the server refused)."""
        from asyncua import ua

        self.allow.check(values)
        unknown = sorted(set(values) - set(self.config.nodes))
        if unknown:
            raise KeyError(f"not configured: {', '.join(unknown)}")
        if self._client is None or not self._connected.is_set():
            return {t: "BadNotConnected" for t in values}
        tags = list(values)
        dvs = []
        for t in tags:
            vt = self._vtypes.get(t, ua.VariantType.Double)
            v: Any = values[t]
            if vt == ua.VariantType.Boolean:
                v = bool(v)
            elif vt in (ua.VariantType.Float, ua.VariantType.Double):
                v = float(v)
            else:
                v = int(v)
            dvs.append(ua.DataValue(ua.Variant(v, vt)))
        try:
            async with asyncio.timeout(self.config.timeout):
                codes = await self._client.uaclient.write_attributes(
                    [self._nodes[t].nodeid for t in tags], dvs, ua.AttributeIds.Value
                )
        except Exception as exc:  # noqa: BLE001 - returned as a value
            log.warning("OPC UA write to %s failed: %r", self.config.url, exc)
            return {t: f"Bad: {exc!r}" for t in tags}
        return {t: c.name for t, c in zip(tags, codes, strict=True)}
