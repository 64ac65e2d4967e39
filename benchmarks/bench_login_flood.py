"""A login flood against our OPC UA server while the live loop runs (issue 35, item 2).

Our secured server (Basic256Sha256 SignAndEncrypt, a trust list, users with scrypt password
hashes) runs in this process beside a cycle that keeps the live loop's timing (a fixed grid
of ``--period`` seconds, catching up as :meth:`LiveLoop.run` does) and publishes a unit's
status to the server each cycle. For ``--flood`` seconds a child process runs ``--clients``
asyncua clients holding a trusted certificate and the right password, each logging in and
out again as fast as it can (the attacker of the issue: any trusted client, a valid user).
Printed: the cycle time (start to start) median, p99 and maximum before, during and after
the flood, the cycles skipped (a grid slot with no cycle), and the logins done/refused.

Before/after: run it on this branch, then on the code of main (no other change)::

    python benchmarks/bench_login_flood.py
    git archive main | tar -x -C /tmp/main && \\
        PYTHONPATH=/tmp/main python benchmarks/bench_login_flood.py
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CLIENTS = r"""
import asyncio, json, sys, time
from asyncua import Client
endpoint, cert, key, uri, user, pw, n, secs = sys.argv[1:9]
import logging; logging.disable(logging.CRITICAL)
done, refused = [0], {}

async def worker():
    end = time.monotonic() + float(secs)
    while time.monotonic() < end:
        c = Client(endpoint, timeout=15)
        c.application_uri = uri
        c.set_user(user)
        c.set_password(pw)
        try:
            await c.set_security_string(f"Basic256Sha256,SignAndEncrypt,{cert},{key}")
            await c.connect()
            done[0] += 1
            await c.disconnect()
        except Exception as exc:
            refused[type(exc).__name__] = refused.get(type(exc).__name__, 0) + 1
            await asyncio.sleep(0.05)

async def main():
    print("go", flush=True)
    await asyncio.gather(*(worker() for _ in range(int(n))))
    print(json.dumps({"done": done[0], "refused": refused}), flush=True)

asyncio.run(main())
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


async def run(period: float, flood: float, clients: int, quiet: float) -> dict:
    import pandas as pd

    from connectors.certs import make_certificate, trust
    from connectors.opcua_access import OpcUaUser
    from connectors.opcua_server import DiagOpcUaServer, ServerSecurity
    from connectors.passwords import hash_password
    from diag_plugin.status import NE107, Quality, UnitStatus

    d = Path(tempfile.mkdtemp(prefix="bench_login_"))
    hmi = make_certificate(d / "clients", "hmi", "urn:diag-plugin:bench:hmi")
    trust(hmi, d / "trusted")
    pw = "operator-pw-1"
    users = (OpcUaUser("op", "operator", hash_password(pw)),)
    sec = ServerSecurity(d / "own" / "srv.pem", d / "own" / "srv.key.pem", d / "trusted", users)
    srv = DiagOpcUaServer(port=free_port(), security=sec)
    await srv.start()
    await srv.add_unit("valve", ["f1"], ["r1"], ["F"])
    starts: list[float] = []
    phase_of: list[str] = []
    phase = ["before"]
    stop = asyncio.Event()

    async def cycles() -> None:
        next_t = time.monotonic()
        i = 0
        while not stop.is_set():
            starts.append(time.monotonic())
            phase_of.append(phase[0])
            st = UnitStatus(
                "valve",
                pd.Timestamp.now(tz="UTC"),
                NE107.NORMAL,
                Quality.GOOD,
                residuals={"r1": float(i % 7)},
                symptoms={"r1": 0.0},
                certainties={"f1": 0.1},
            )
            await srv.publish(st)
            i += 1
            next_t += period
            delay = next_t - time.monotonic()
            if delay < 0:
                next_t, delay = time.monotonic(), 0
            await asyncio.sleep(delay)

    task = asyncio.ensure_future(cycles())
    await asyncio.sleep(quiet)
    env = dict(os.environ)
    proc = await asyncio.create_subprocess_exec(
        sys.executable,
        "-c",
        CLIENTS,
        srv.endpoint,
        str(hmi.certificate),
        str(hmi.private_key),
        hmi.application_uri,
        "op",
        pw,
        str(clients),
        str(flood),
        stdout=subprocess.PIPE,
        env=env,
    )
    assert proc.stdout is not None
    await proc.stdout.readline()  # "go"
    phase[0] = "flood"
    out = await proc.stdout.readline()
    await proc.wait()
    phase[0] = "after"
    await asyncio.sleep(quiet)
    stop.set()
    await task
    guard = getattr(srv, "logins", None)
    await srv.stop()
    shutil.rmtree(d, ignore_errors=True)
    res = json.loads(out or b"{}")
    res["guard"] = (
        {
            "checked": guard.checked,
            "refusals": guard.refusals,
            "peak_active": guard.peak_active,
            "limits": str(guard.limits),
        }
        if guard is not None
        else None
    )
    s = np.array(starts)
    gaps = np.diff(s)
    ph = np.array(phase_of[1:])
    res["phases"] = {}
    for p in ("before", "flood", "after"):
        g = gaps[ph == p]
        if len(g) == 0:
            continue
        skipped = int(np.maximum(0, np.round(g / period) - 1).sum())
        res["phases"][p] = {
            "cycles": len(g),
            "slots": len(g) + skipped,
            "skipped": skipped,
            "p50_ms": float(np.percentile(g, 50) * 1000),
            "p99_ms": float(np.percentile(g, 99) * 1000),
            "max_ms": float(g.max() * 1000),
        }
    return res


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--period", type=float, default=0.25, help="cycle, s (diag run's default)")
    ap.add_argument("--flood", type=float, default=30.0, help="seconds of login flood")
    ap.add_argument("--clients", type=int, default=20, help="parallel logging-in clients")
    ap.add_argument("--quiet", type=float, default=5.0, help="seconds before and after")
    args = ap.parse_args()
    import connectors

    code = Path(connectors.__file__).resolve().parents[1]
    import connectors.opcua_server as server_module

    guarded = "LoginGuard" in vars(server_module)
    which = "login guard (this branch)" if guarded else "no login guard (before)"
    res = asyncio.run(run(args.period, args.flood, args.clients, args.quiet))
    print(f"code: {code} — {which}; {os.cpu_count()} cores")
    print(
        f"{args.clients} clients logging in for {args.flood:.0f} s: {res.get('done', 0)} logins, "
        f"refused {res.get('refused', {})}"
    )
    if res["guard"]:
        print(f"guard: {res['guard']}")
    for p, r in res["phases"].items():
        print(
            f"{p:>6}: {r['cycles']:4d} cycles of {args.period * 1000:.0f} ms, cycle time p50 "
            f"{r['p50_ms']:.0f} ms, p99 {r['p99_ms']:.0f} ms, max {r['max_ms']:.0f} ms; "
            f"{r['skipped']} of {r['slots']} cycles skipped"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
