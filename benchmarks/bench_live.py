"""One whole cycle of the embedded plant (issue 10): poll the simulated PLC over Modbus TCP,
store in the SQLite historian, diagnose, publish over OPC UA and Modbus. Target < 100 ms.

Runs ``diag run`` (the embedded default) for 40 s at one cycle per 0.05 s on free ports and
prints the cycle work times it reports (median, p95, max) and the overruns. The Modbus polling
speed for 10,000 tags is ``bench_modbus.py``.
"""

from __future__ import annotations

import re
import socket
import subprocess
import sys
import tempfile


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main() -> int:
    with tempfile.TemporaryDirectory() as d:
        cmd = [sys.executable, "-m", "diag_plugin", "run", "--duration", "40", "--cycle", "0.05"]
        cmd += ["--data", d, "--plain", "--plc-port", str(free_port())]
        cmd += ["--modbus-port", str(free_port()), "--opcua-port", str(free_port())]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    m = re.search(
        r"stopped after (\d+) cycles, (\d+) overruns.*median ([\d.]+) ms, p95 ([\d.]+) "
        r"ms, max ([\d.]+) ms",
        r.stdout,
    )
    if r.returncode != 0 or m is None:
        print(r.stdout[-2000:], r.stderr[-2000:])
        return 1
    cycles, overruns, med, p95, mx = m.groups()
    print(
        f"embedded plant, {cycles} cycles of poll + store + diagnose + publish: median {med} ms, "
        f"p95 {p95} ms, max {mx} ms; {overruns} cycles over the 50 ms period"
    )
    ok = float(med) < 100
    print(f"target: one cycle < 100 ms: {'met' if ok else 'MISSED'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
