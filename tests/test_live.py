"""`diag run` (embedded default) as a user runs it, with mbpoll as the SCADA reading our status."""

import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time

import pandas as pd
from helpers import REPO, requires
from modbus_peers import free_port

from diag_plugin.live import FAULT_OFF, HISTORY_START

needs_mbpoll = requires(
    "mbpoll (Debian package)", bool(shutil.which("mbpoll")), "apt-get install mbpoll"
)


def _diag_run(data, *args: str) -> tuple[subprocess.Popen, dict[str, int]]:
    ports = {"plc": free_port(), "modbus": free_port(), "opcua": free_port()}
    env = {k: v for k, v in os.environ.items() if not k.startswith("DIAG_")}
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "diag_plugin",
            "run",
            "--data",
            str(data),
            "--cycle",
            "0.04",
            "--plc-port",
            str(ports["plc"]),
            "--modbus-port",
            str(ports["modbus"]),
            "--opcua-port",
            str(ports["opcua"]),
            *args,
        ],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    return proc, ports


def _status_word(port: int) -> int | None:
    """The unit's NE 107 status (holding register 0 = mbpoll reference 1) or None."""
    res = subprocess.run(
        ["mbpoll", "-m", "tcp", "-a", "1", "-r", "1", "-c", "1", "-t", "4", "-1", "-o", "1"]
        + ["-p", str(port), "127.0.0.1"],
        capture_output=True,
        text=True,
        timeout=10,
    )
    m = re.search(r"^\[1\]:\s+(-?\d+)", res.stdout, re.M)
    return int(m.group(1)) if res.returncode == 0 and m else None


def _collect(stream, lines: list[str]) -> None:
    for line in stream:
        lines.append(line)


@needs_mbpoll
def test_diag_run_embedded_alarm_cycle_mbpoll_and_historian(tmp_path):
    """Raised → operator acknowledges → cleared; mbpoll reads NORMAL and FAILURE; samples stored;
    a second start reuses the cached plant and SIGTERM exits 0 after flushing."""
    data = tmp_path / "diag-data"
    proc, ports = _diag_run(data, "--duration", "30")
    lines: list[str] = []
    reader = threading.Thread(target=_collect, args=(proc.stdout, lines), daemon=True)
    reader.start()
    seen: set[int] = set()
    deadline = time.monotonic() + 90
    while proc.poll() is None and time.monotonic() < deadline:
        if any("embedded plant:" in x for x in lines):
            word = _status_word(ports["modbus"])
            if word is not None:
                seen.add(word)
        time.sleep(0.5)
    rc = proc.wait(timeout=max(1, deadline - time.monotonic()))
    reader.join(5)
    out, err = "".join(lines), proc.stderr.read()
    assert rc == 0, out + err
    assert "first start" in out
    raised = [x for x in lines if "alarm raised: FAILURE" in x and "f_P0" in x]
    assert raised, out
    assert any("operator acknowledges" in x for x in lines), out
    assert any("alarm acknowledged by operator" in x for x in lines), out
    assert any("alarm cleared: NORMAL" in x for x in lines), out
    order = [
        next(i for i, x in enumerate(lines) if key in x)
        for key in ("alarm raised", "operator acknowledges", "alarm cleared")
    ]
    assert order == sorted(order), out
    assert {0, 1} <= seen, f"mbpoll read {seen}"

    from historian.store import Historian

    h = Historian.open(f"sqlite:///{data / 'plant.db'}")
    p0 = h.read_samples("P0", start=HISTORY_START + pd.Timedelta(days=7))
    assert len(p0) > FAULT_OFF, len(p0)  # live samples after the 7 days of history
    assert len(h.read_samples("P0", end=HISTORY_START + pd.Timedelta(days=1))) == 8640
    h.close()

    # a later start reuses the cache; SIGTERM flushes and exits 0
    proc, ports = _diag_run(data)
    lines = []
    reader = threading.Thread(target=_collect, args=(proc.stdout, lines), daemon=True)
    reader.start()
    deadline = time.monotonic() + 30
    while not any("embedded plant:" in x for x in lines) and time.monotonic() < deadline:
        time.sleep(0.2)
    time.sleep(2)
    proc.send_signal(signal.SIGTERM)
    rc = proc.wait(timeout=20)
    reader.join(5)
    out = "".join(lines)
    assert rc == 0, out + proc.stderr.read()
    assert "using the embedded plant" in out and "first start" not in out
    assert re.search(r"stopped after \d+ cycles", out), out
