"""Logins to our OPC UA server (issue 35, items 2 and 3), tried with real asyncua clients.

A flood of parallel logins is hashed in the login pool, never on the event loop, and no more
are checked at once than the cap; connections beyond ``max_sessions`` are refused. A wrong
password and an unknown user cost one scrypt each, indistinguishable in time; a failure backs
the user name and the address off (refused without a hash until it passes) and every
refusal reaches the event log with user and address, identical ones merged but counted.
"""

from __future__ import annotations

import asyncio
import hashlib
import statistics
import threading
import time

import pytest
from opcua_peers import PASSWORDS, free_port, users

from connectors.opcua_access import UserManager
from connectors.opcua_logins import LoginGuard, LoginLimits, LoginRefused
from connectors.opcua_server import Action, DiagOpcUaServer, ServerSecurity

pytestmark = pytest.mark.anyio


def security(keys, limits: LoginLimits | None) -> ServerSecurity:
    d = keys["dir"]
    return ServerSecurity(
        d / "own" / "srv.pem",
        d / "own" / "srv.key.pem",
        d / "trusted",
        users(keys),
        allow_anonymous=False,
        logins=limits,
    )


async def login(srv: DiagOpcUaServer, keys, user: str, password: str) -> str:
    """Log in as ``user`` with ``password`` over SignAndEncrypt: "Good" or the refusal."""
    from asyncua import Client

    cert = keys["hmi"]
    c = Client(srv.endpoint, timeout=30)
    c.application_uri = cert.application_uri
    c.set_user(user)
    c.set_password(password)
    try:  # the security string reads the server's endpoints: a refusal may come there
        await c.set_security_string(
            f"Basic256Sha256,SignAndEncrypt,{cert.certificate},{cert.private_key}"
        )
        await c.connect()
    except Exception as exc:  # noqa: BLE001 - the refusal is the answer
        return type(exc).__name__
    await c.disconnect()
    return "Good"


def spy_scrypt(monkeypatch) -> list[str]:
    """Every scrypt call from now on: the name of the thread that ran it."""
    calls: list[str] = []
    real = hashlib.scrypt

    def scrypt(*a, **k):
        calls.append(threading.current_thread().name)
        return real(*a, **k)

    monkeypatch.setattr(hashlib, "scrypt", scrypt)
    return calls


def test_unknown_user_and_wrong_password_cost_the_same(keys, monkeypatch):
    """Both refusals run exactly one scrypt, and their times differ by less than the spread
    of repeated measurements of either (before: 137 ms against 4.7 ms)."""
    um = UserManager(users(keys), allow_anonymous=False)
    calls = spy_scrypt(monkeypatch)
    assert not um.verify("alice", "wrong-password")
    assert len(calls) == 1
    assert not um.verify("mallory", "wrong-password")
    assert len(calls) == 2
    assert not um.verify("carol", "x")  # a certificate-only user: no hash of its own either
    assert len(calls) == 3
    assert um.verify("alice", PASSWORDS["alice"]) and len(calls) == 4

    known, unknown = [], []
    for i in range(24):  # interleaved, so the machine's load falls on both alike
        for name, into in (("alice", known), (f"nobody{i}", unknown))[:: 1 if i % 2 else -1]:
            t0 = time.perf_counter()
            um.verify(name, "wrong-password")
            into.append(time.perf_counter() - t0)

    def mad(x: list[float]) -> float:
        m = statistics.median(x)
        return statistics.median(abs(v - m) for v in x)

    gap = abs(statistics.median(known) - statistics.median(unknown))
    # the noise of one condition's median: the scaled MAD over sqrt(n), both conditions
    noise = 1.4826 * (mad(known) ** 2 + mad(unknown) ** 2) ** 0.5 / len(known) ** 0.5
    hash_time = statistics.median(known)
    assert gap < max(6 * noise, 0.1 * hash_time), (gap, noise, hash_time)


async def test_backoff_engages_and_every_refusal_is_logged(anyio_backend, keys, monkeypatch):
    limits = LoginLimits(backoff_base=1.5, backoff_cap=3.0, log_window=60.0)
    srv = DiagOpcUaServer(port=free_port(), security=security(keys, limits))
    seen: list[Action] = []
    srv.on_action = seen.append
    await srv.start()
    try:
        guard = srv.logins
        assert guard is not None
        calls = spy_scrypt(monkeypatch)
        assert await login(srv, keys, "alice", "guess-1") == "BadUserAccessDenied"
        assert len(calls) == 1 and calls[0].startswith("diag-login")  # hashed off the loop
        assert guard.backoff(user="alice") > 0 and guard.backoff(host="127.0.0.1") > 0
        lines = [a.detail for a in seen if a.action == "login"]
        assert lines == [
            "OPC UA login refused: user 'alice' from 127.0.0.1: unknown user or wrong password"
        ]
        # backed off: the right password is refused too, at once and without a hash
        for _ in range(3):
            assert await login(srv, keys, "alice", PASSWORDS["alice"]) == "BadUserAccessDenied"
        assert len(calls) == 1
        lines = [a.detail for a in seen if a.action == "login"]
        assert len(lines) == 2 and "backed off" in lines[1] and "'alice'" in lines[1]
        guard.flush(force=True)  # the merged run is written with its count
        lines = [a.detail for a in seen if a.action == "login"]
        assert "repeated 2 times" in lines[-1] and "backed off" in lines[-1]
        assert guard.refusals == 4
        # an unknown user is keyed the same way (and backs off the address as well)
        await asyncio.sleep(guard.backoff(user="alice", host="127.0.0.1") + 0.1)
        assert await login(srv, keys, "mallory", "guess") == "BadUserAccessDenied"
        assert len(calls) == 2 and guard.backoff(user="mallory") > 0
        # the back-off doubles, capped, and passes: then the right password logs in
        await asyncio.sleep(guard.backoff(user="alice", host="127.0.0.1") + 0.1)
        assert await login(srv, keys, "alice", PASSWORDS["alice"]) == "Good"
        assert guard.backoff(user="alice") == 0
    finally:
        await srv.stop()


async def test_login_flood_is_hashed_off_the_loop_and_capped(anyio_backend, keys, monkeypatch):
    """20 parallel logins (half of them wrong) while a ticker runs on the loop: every hash in
    the pool thread, never more checked at once than the cap, the ones over it refused at
    once (BadTooManyOperations) and the right passwords logged in."""
    limits = LoginLimits(hash_workers=1, max_activations=3, backoff_base=0.0, backoff_cap=0.0)
    srv = DiagOpcUaServer(port=free_port(), security=security(keys, limits))
    await srv.start()
    try:
        calls = spy_scrypt(monkeypatch)
        loop_thread = threading.current_thread().name
        results = await asyncio.gather(
            *(
                login(srv, keys, "bob", PASSWORDS["bob"] if i % 2 else f"wrong-{i}")
                for i in range(20)
            )
        )
        guard = srv.logins
        assert guard is not None
        assert calls and loop_thread not in calls
        assert all(c.startswith("diag-login") for c in calls)
        assert guard.peak_active <= limits.max_activations
        assert guard.checked == len(calls)
        assert set(results) <= {"Good", "BadUserAccessDenied", "BadTooManyOperations"}
        wrong = [r for i, r in enumerate(results) if i % 2 == 0]
        assert "Good" not in wrong
        # which three arrive first is up to the handshakes: a right password checked in the
        # flood logged in, and once it is over the right password logs in
        right = [r for i, r in enumerate(results) if i % 2]
        assert set(right) <= {"Good", "BadTooManyOperations"}
        assert await login(srv, keys, "bob", PASSWORDS["bob"]) == "Good"
    finally:
        await srv.stop()


async def test_sessions_over_the_cap_are_refused(anyio_backend, keys):
    from asyncua import Client

    limits = LoginLimits(max_sessions=2)
    srv = DiagOpcUaServer(port=free_port(), security=security(keys, limits))
    await srv.start()
    cert = keys["hmi"]
    open_: list = []
    try:
        for _ in range(2):
            c = Client(srv.endpoint, timeout=10)
            c.application_uri = cert.application_uri
            c.set_user("bob")
            c.set_password(PASSWORDS["bob"])
            await c.set_security_string(
                f"Basic256Sha256,SignAndEncrypt,{cert.certificate},{cert.private_key}"
            )
            await c.connect()
            open_.append(c)
        assert await login(srv, keys, "bob", PASSWORDS["bob"]) != "Good"
        await open_.pop().disconnect()
        await asyncio.sleep(0.2)
        assert await login(srv, keys, "bob", PASSWORDS["bob"]) == "Good"
    finally:
        for c in open_:
            await c.disconnect()
        await srv.stop()


async def test_guard_refuses_over_the_activation_cap_without_hashing(anyio_backend):
    """The cap itself, on the guard: logins past ``max_activations`` never reach the hash."""
    gate = threading.Event()
    ran: list[str] = []

    def verify(user: str, password: object) -> bool:
        ran.append(user)
        gate.wait(5)
        return False

    guard = LoginGuard(verify, LoginLimits(hash_workers=1, max_activations=2, backoff_base=0))
    tasks = [asyncio.ensure_future(guard.check(f"u{i}", "pw", "10.0.0.1:5")) for i in range(5)]
    await asyncio.sleep(0.1)
    gate.set()
    got = await asyncio.gather(*tasks, return_exceptions=True)
    busy = [g for g in got if isinstance(g, LoginRefused) and g.busy]
    assert len(busy) == 3 and got[:2] == [False, False]
    assert sorted(ran) == ["u0", "u1"]
    guard.close()


def test_limits_derived_from_users_and_cores():
    lim = LoginLimits.derive(n_users=3, anonymous=True, cpus=2)
    assert (lim.hash_workers, lim.max_activations, lim.max_sessions) == (1, 4, 40)
    assert LoginLimits.derive(0, False, cpus=16).hash_workers == 8
    assert LoginLimits.derive(0, False, cpus=1).max_sessions == 20
    assert LoginLimits.derive(500, True, cpus=4).max_sessions == 1000
    with pytest.raises(ValueError, match="max_sessions"):
        LoginLimits(max_sessions=0)


def test_plant_toml_sets_the_caps_and_refuses_nonsense(tmp_path):
    from diag_plugin.live.config import ConfigError, build_server, load_config

    (tmp_path / "u.unit.toml").write_text("", encoding="utf-8")
    (tmp_path / "plc.csv").write_text("tag,table,address,type\nF,hr,0,uint16\n")
    text = """\
[plant]
cycle = 1.0
units = ["u.unit.toml"]

[[source]]
port = 1502
map = "plc.csv"

[outputs]
modbus_port = 0
opcua_port = {port}

[opcua]
anonymous = true
{extra}
"""
    p = tmp_path / "plant.toml"
    p.write_text(text.format(port=free_port(), extra=""), encoding="utf-8")
    derived = build_server(load_config(p)).security.logins
    assert derived == LoginLimits.derive(0, True)  # no users: derived from anonymous alone
    p.write_text(text.format(port=free_port(), extra="max_sessions = 7\nmax_logins = 2"))
    lim = build_server(load_config(p)).security.logins
    assert (lim.max_sessions, lim.max_activations) == (7, 2)
    p.write_text(text.format(port=free_port(), extra="max_logins = 0"), encoding="utf-8")
    with pytest.raises(ConfigError, match=r"plant.toml:15: opcua.max_logins: must be 1-10000"):
        load_config(p)


def test_refusal_log_merges_counts_and_forgets(anyio_backend):
    """Identical refusals within the window are one line with their count; the window's
    entries are dropped when it is over, and a flood of distinct names stays bounded."""
    lines: list[str] = []
    now = [0.0]
    lim = LoginLimits(log_window=10.0, max_tracked=50)
    guard = LoginGuard(lambda u, p: False, lim, on_event=lines.append, clock=lambda: now[0])
    for _ in range(38):
        guard.refused("alice", "10.0.0.7", "unknown user or wrong password")
    assert len(lines) == 1 and "'alice' from 10.0.0.7" in lines[0]
    now[0] = 11.0
    guard.flush()
    assert lines[-1].endswith("(repeated 37 times in 11 s)") and not guard._merged
    for i in range(500):
        guard.refused(f"name{i}", "10.0.0.8", "unknown user or wrong password")
    assert len(guard._merged) <= lim.max_tracked and len(lines) == 502
    for i in range(500):  # strikes too: at most max_tracked names and addresses kept
        guard._strike(("user", f"name{i}"), now[0])
    assert len(guard._strikes) <= lim.max_tracked
    guard.close()
