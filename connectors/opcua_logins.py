"""Logins to our OPC UA server that cannot stall the live loop: hashing off the event loop,
caps on sessions and logins in progress, back-off after failures, every refusal logged.

asyncua checks a user name and password synchronously inside ActivateSession, on the event
loop that also runs the live loop; a scrypt check costs ~50 ms of CPU, so 20 parallel logins
used to hold the loop for seconds (issue 35). :class:`LoginGuard` hooks every connection's
request processing (:meth:`LoginGuard.install`, after the server started): before asyncua
handles an ActivateSession with a user name, the guard

1. refuses at once (no hash) a user name, or an address, that is *backed off*: after ``k``
   failures in a row it is locked for ``min(cap, base · 2**(k-1))`` seconds — user names are
   keyed whether they exist or not, so the back-off tells nothing about which ones do;
2. refuses at once (BadTooManyOperations) when ``max_activations`` logins are already being
   checked;
3. runs the check (:func:`connectors.passwords.check_password`: one scrypt for a known and an
   unknown user alike, compared in constant time) in a pool of ``hash_workers`` threads
   (hashlib.scrypt releases the GIL), and hands the verdict to
   :class:`~connectors.opcua_access.UserManager` through :data:`login_verdict`.

The server also accepts at most ``max_sessions`` connections (asyncua's ``max_connections``).
Each refusal is logged with user, address and reason, and handed to ``on_event``; identical
refusals (same user, address, reason) within ``log_window`` seconds are merged into one line
that says how many there were ("repeated 37 times in 60 s"), so a flood stays countable
without flooding the event log.

:meth:`LoginLimits.derive` chooses the limits from the machine and the configured users
(docs/reference/live.md, "Logins, slow sources and memory").
"""

from __future__ import annotations

import asyncio
import logging
import os
import time
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from contextvars import ContextVar
from dataclasses import dataclass
from typing import Any

log = logging.getLogger(__name__)

#: (user name, password, verdict) of the ActivateSession being processed, set by the guard
login_verdict: ContextVar[tuple[str, Any, bool] | None] = ContextVar(
    "diag_opcua_login_verdict", default=None
)


@dataclass(frozen=True)
class LoginLimits:
    """How logins are bounded (see the module doc; :meth:`derive` for the defaults)."""

    hash_workers: int = 1
    max_activations: int = 4
    max_sessions: int = 50
    backoff_base: float = 1.0
    backoff_cap: float = 60.0
    log_window: float = 60.0
    #: a user name or address with no failure for this long is forgotten (and the table
    #: holds at most ``max_tracked`` of them: a flood of new names cannot grow memory)
    forget_after: float = 900.0
    max_tracked: int = 10_000

    def __post_init__(self) -> None:
        for key in ("hash_workers", "max_activations", "max_sessions", "max_tracked"):
            if getattr(self, key) < 1:
                raise ValueError(f"login limits: {key} must be at least 1")
        if self.backoff_base < 0 or self.backoff_cap < self.backoff_base:
            raise ValueError("login limits: need 0 <= backoff_base <= backoff_cap")

    @classmethod
    def derive(cls, n_users: int, anonymous: bool, cpus: int | None = None) -> LoginLimits:
        """The defaults: ``hash_workers`` half the cores (at least 1), so a flood of logins
        leaves the other half to the live loop; ``max_activations`` four per worker (a
        legitimate login queues behind at most three others, ~200 ms at 50 ms a hash);
        ``max_sessions`` ten per configured user (and ten for anonymous access: an HMI, a
        historian, an engineering station or two each), at least 20 and at most 1,000
        (asyncua's own default)."""
        cpus = cpus or os.cpu_count() or 1
        workers = max(1, cpus // 2)
        sessions = min(1000, max(20, 10 * (n_users + int(anonymous))))
        return cls(hash_workers=workers, max_activations=4 * workers, max_sessions=sessions)


@dataclass
class _Strikes:
    failures: int = 0
    until: float = 0.0  # locked until (monotonic)
    last: float = 0.0  # last failure (monotonic)


class LoginRefused(Exception):
    """A login refused by the guard before any hash (backed off, or too many at once)."""

    def __init__(self, why: str, busy: bool = False) -> None:
        super().__init__(why)
        self.busy = busy


class LoginGuard:
    """Checks logins off the event loop with back-off and a merged refusal log.

    ``verify(user, password) -> bool`` is the (blocking) password check, run in the pool;
    ``on_event(text)`` hears each refusal line (the live loop's event log).
    """

    def __init__(
        self,
        verify: Callable[[str, Any], bool],
        limits: LoginLimits | None = None,
        on_event: Callable[[str], Any] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.verify = verify
        self.limits = limits or LoginLimits()
        self.on_event = on_event
        self.clock = clock
        self._pool: ThreadPoolExecutor | None = None
        self._active = 0
        self._strikes: OrderedDict[tuple[str, str], _Strikes] = OrderedDict()
        # merged refusal lines: key -> (first time, repeats since the line was written)
        self._merged: dict[tuple[str, str, str], list[float]] = {}
        self._flush_handle: asyncio.TimerHandle | None = None
        self.refusals = 0  #: refusals so far (each one, merged or not)
        self.checked = 0  #: password checks run in the pool
        self.peak_active = 0  #: most logins checked at once

    # -- hooking asyncua ---------------------------------------------------------------
    def install(self, server: Any) -> None:
        """Hook every new connection of a started asyncua ``Server`` and cap its sessions."""
        iserver, bserver = server.iserver, server.bserver
        iserver.max_connections = self.limits.max_sessions
        guard = self

        class _Clients(list):
            """asyncua's list of connections: each new one has its processor hooked."""

            def append(self, proto: Any) -> None:
                super().append(proto)
                processor = getattr(proto, "processor", None)
                if processor is not None:
                    guard._hook(processor)

        bserver.clients = _Clients(bserver.clients)

    def _hook(self, processor: Any) -> None:
        from asyncua import ua
        from asyncua.server.internal_session import ServiceError
        from asyncua.ua.ua_binary import struct_from_binary

        activate = ua.NodeId(ua.ObjectIds.ActivateSessionRequest_Encoding_DefaultBinary)
        original = processor._process_message
        iserver = processor.iserver

        async def guarded(typeid: Any, requesthdr: Any, seqhdr: Any, body: Any) -> Any:
            session = processor.session
            if typeid != activate or session is None:
                return await original(typeid, requesthdr, seqhdr, body)
            params = struct_from_binary(ua.ActivateSessionParameters, body.copy())
            token = params.UserIdentityToken
            if not isinstance(token, ua.UserNameIdentityToken):
                return await original(typeid, requesthdr, seqhdr, body)
            try:
                user, password = iserver.decrypt_user_token(session, token)
            except Exception:  # noqa: BLE001 - asyncua refuses it the same way
                return await original(typeid, requesthdr, seqhdr, body)
            address = _address(getattr(processor, "name", None))
            try:
                ok = await self.check(str(user), password, address)
            except LoginRefused as exc:
                code = ua.StatusCodes.BadTooManyOperations if exc.busy else None
                raise ServiceError(code or ua.StatusCodes.BadUserAccessDenied) from None
            mark = login_verdict.set((str(user), password, ok))
            try:
                return await original(typeid, requesthdr, seqhdr, body)
            finally:
                login_verdict.reset(mark)

        processor._process_message = guarded

    # -- the check ---------------------------------------------------------------------
    async def check(self, user: str, password: Any, address: str) -> bool:
        """One login: refused at once when backed off or too many are being checked
        (:class:`LoginRefused`), else the password checked in the pool; a failure counts a
        strike against the user name and the address."""
        host = address.rsplit(":", 1)[0]
        now = self.clock()
        wait = max(self._locked(("user", user), now), self._locked(("host", host), now))
        if wait > 0:
            why = f"backed off after repeated failures ({wait:.1f} s left)"
            self.refused(user, host, "backed off after repeated failures")
            raise LoginRefused(why)
        if self._active >= self.limits.max_activations:
            self.refused(user, host, f"{self._active} logins already being checked")
            raise LoginRefused("too many logins at once", busy=True)
        if self._pool is None:
            self._pool = ThreadPoolExecutor(self.limits.hash_workers, "diag-login")
        self._active += 1
        self.peak_active = max(self.peak_active, self._active)
        try:
            loop = asyncio.get_running_loop()
            ok = await loop.run_in_executor(self._pool, self.verify, user, password)
        finally:
            self._active -= 1
        self.checked += 1
        if ok:
            self._strikes.pop(("user", user), None)
            self._strikes.pop(("host", host), None)
            return True
        now = self.clock()
        for key in (("user", user), ("host", host)):
            self._strike(key, now)
        self.refused(user, host, "unknown user or wrong password")
        return False

    def _locked(self, key: tuple[str, str], now: float) -> float:
        s = self._strikes.get(key)
        return max(0.0, s.until - now) if s is not None else 0.0

    def _strike(self, key: tuple[str, str], now: float) -> None:
        lim = self.limits
        s = self._strikes.pop(key, None) or _Strikes()
        s.failures += 1
        s.last = now
        s.until = now + min(lim.backoff_cap, lim.backoff_base * 2 ** (s.failures - 1))
        self._strikes[key] = s  # most recent last
        while self._strikes:  # forget the old ones, and never more than max_tracked
            k, first = next(iter(self._strikes.items()))
            if len(self._strikes) <= lim.max_tracked and now - first.last < lim.forget_after:
                break
            del self._strikes[k]

    def backoff(self, user: str | None = None, host: str | None = None) -> float:
        """Seconds the user name or host is still locked (0 when it is not)."""
        now = self.clock()
        keys = [("user", user)] * (user is not None) + [("host", host)] * (host is not None)
        return max((self._locked(k, now) for k in keys), default=0.0)  # type: ignore[arg-type]

    # -- the refusal log ---------------------------------------------------------------
    def refused(self, user: str, host: str, why: str) -> None:
        """Log one refusal: the first of a kind at once, identical ones within
        ``log_window`` counted and written as one "repeated N times" line."""
        self.refusals += 1
        key = (user, host, why)
        now = self.clock()
        merged = self._merged.get(key)
        if merged is not None and now - merged[0] < self.limits.log_window:
            merged[1] += 1
            self._schedule_flush()
            return
        if merged is not None and merged[1]:
            self._emit(key, merged[1], now - merged[0])
        if len(self._merged) >= self.limits.max_tracked:  # a flood of distinct names
            self.flush(force=True)
        self._merged[key] = [now, 0]
        self._emit(key, 0, 0.0)
        self._schedule_flush()  # the window's entry is dropped (with its count) when over

    def flush(self, force: bool = False) -> None:
        """Write the repeat counts of the windows that are over (all of them: ``force``)."""
        now = self.clock()
        for key, (first, n) in list(self._merged.items()):
            if force or now - first >= self.limits.log_window:
                if n:
                    self._emit(key, n, now - first)
                del self._merged[key]

    def _schedule_flush(self) -> None:
        if self._flush_handle is not None:
            return
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:
            return

        def run() -> None:
            self._flush_handle = None
            self.flush()
            if self._merged:
                self._schedule_flush()

        self._flush_handle = loop.call_later(self.limits.log_window, run)

    def _emit(self, key: tuple[str, str, str], repeats: int, span: float) -> None:
        user, host, why = key
        text = f"OPC UA login refused: user {user!r} from {host}: {why}"
        if repeats:
            text += f" (repeated {repeats} times in {span:.0f} s)"
        log.warning("%s", text)
        if self.on_event is not None:
            try:
                self.on_event(text)
            except Exception:  # noqa: BLE001 - a listener must not break the server
                log.exception("login on_event listener failed")

    def close(self) -> None:
        """Write the counts still open and stop the pool."""
        if self._flush_handle is not None:
            self._flush_handle.cancel()
            self._flush_handle = None
        self.flush(force=True)
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None


def _address(peer: Any) -> str:
    """``host:port`` of an asyncio peer name (``unknown`` when there is none)."""
    if isinstance(peer, tuple) and len(peer) >= 2:
        return f"{peer[0]}:{peer[1]}"
    return str(peer) if peer else "unknown"
