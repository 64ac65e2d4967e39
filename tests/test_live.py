"""`diag run` (embedded default) as a user runs it, with mbpoll as the SCADA reading our status."""

import json
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

from diag_plugin.live.embedded import FAULT_OFF, HISTORY_START

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
    # the isolation narrows to the P0 group once r3 follows r2, and the operator is told
    assert any("valve_unit: isolated f_P0, f_S (was" in x for x in lines), out
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


PLANT_TOML = """\
[plant]
cycle = 0.05
historian = "sqlite:///cfg.db"
units = ["rb/valve_unit.unit.toml"]

[source]
host = "127.0.0.1"
port = {port}
map = "plc.csv"

[outputs]
modbus_port = {modbus}
opcua_port = 0
"""


def _config_dir(tmp_path):
    from connectors.modbus_server import default_plant_map

    (tmp_path / "rb").mkdir()
    (tmp_path / "rb" / "valve_unit.unit.toml").write_text("", encoding="utf-8")
    rows = ["tag,table,address,type"] + [
        f"{t.tag},{t.table},{t.address},{t.type}" for t in default_plant_map().tags
    ]
    (tmp_path / "plc.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
    return tmp_path


def test_config_errors_name_key_and_line(tmp_path):
    from diag_plugin.live.config import ConfigError, load_config

    d = _config_dir(tmp_path)
    good = PLANT_TOML.format(port=5021, modbus=5020)
    p = d / "plant.toml"
    p.write_text(good, encoding="utf-8")
    cfg = load_config(p)
    assert cfg.sources[0].port == 5021 and cfg.cycle == 0.05 and cfg.opcua_port == 0
    assert cfg.historian == f"sqlite:///{d / 'cfg.db'}"
    for bad, want in (
        (
            good.replace("port = 5021", 'port = "x"'),
            "plant.toml:8: source.port: must be an integer",
        ),
        (good.replace("port = 5021", "port = 70000"), "plant.toml:8: source.port: must be a TCP"),
        (good.replace('"plc.csv"', '"nope.csv"'), "plant.toml:9: source.map: 'nope.csv': no such"),
        (good.replace("cycle = 0.05", "cycle = -1"), "plant.toml:2: plant.cycle: must be positive"),
        (good.replace("opcua_port", "opc_port"), "plant.toml:13: outputs.opc_port: unknown key"),
        (good.replace("units = ", "unit = "), "plant.toml:4: plant.unit: unknown key"),
        (good.replace("[source]", "[source"), "plant.toml:6: TOML syntax error: "),
    ):
        p.write_text(bad, encoding="utf-8")
        try:
            load_config(p)
        except ConfigError as exc:
            assert want in str(exc), str(exc)
        else:
            raise AssertionError(f"no error for {want}")
    p.write_text(good.replace("port = 5021", "port = 0"), encoding="utf-8")
    env = {k: v for k, v in os.environ.items() if not k.startswith("DIAG_")}
    res = subprocess.run(
        [sys.executable, "-m", "diag_plugin", "run", "--config", str(p)],
        capture_output=True,
        text=True,
        env=env,
        timeout=60,
    )
    assert res.returncode == 2 and "plant.toml:8: source.port" in res.stderr, res.stderr


def test_config_run_polls_a_plc_stores_and_publishes(tmp_path):
    """`run_config` against our PlantServer: samples stored, status served, exit 0."""
    import asyncio

    from connectors.modbus_server import PlantServer
    from diag_plugin.examples.build import build_valve_unit
    from diag_plugin.live.config import load_config, run_config
    from diag_plugin.simulate import simulate_valve
    from historian.store import Historian

    d = _config_dir(tmp_path)
    frame = simulate_valve(1, seed=5)
    build_valve_unit(d / "rb", frame, "test")
    plc_port, modbus = free_port(), free_port()
    (d / "plant.toml").write_text(PLANT_TOML.format(port=plc_port, modbus=modbus), "utf-8")
    cfg = load_config(d / "plant.toml")
    assert cfg.state == (d / "plant.state.json").resolve() and cfg.state_every == 60
    cfg.state_every = 5
    during: list[int] = []  # the saved state's cycles, read while the run goes on

    async def peek(loop, i, statuses):
        if i % 5 == 4 and cfg.state.exists():
            during.append(json.loads(cfg.state.read_text(encoding="utf-8"))["cycles"])

    class Out:
        lines: list[str] = []

        def write(self, s):
            self.lines.append(s)

        def flush(self):
            pass

        def isatty(self):
            return False

    async def main():
        async with PlantServer(port=plc_port) as plc:
            await plc.set_row(frame.iloc[100].to_dict())
            task = asyncio.create_task(run_config(cfg, duration=3.0, out=Out(), after=peek))
            await asyncio.sleep(1.0)
            word = await asyncio.to_thread(_status_word, modbus) if shutil.which("mbpoll") else 0
            return await task, word

    rc, word = asyncio.run(main())
    out = "".join(Out.lines)
    assert rc == 0, out
    assert word in (0, 1, 2, 3, 4), out
    assert "stopped after" in out
    h = Historian.open(cfg.historian)
    # several cycles stored (40 at a 0.05 s cycle on a free core; a loaded test machine once
    # gave the loop 3 in 2 s, so the count asked for is small and the run a little longer)
    assert len(h.read_samples("F")) >= 3
    h.close()
    # the units' state saved on the stop (none before it), restored by the next start, and
    # refused (start fresh, said) once a unit file changed
    assert f"state {cfg.state}: none yet, units start fresh" in out
    saved = json.loads(cfg.state.read_text(encoding="utf-8"))
    assert saved["cycles"] >= 3 and list(saved["versions"]) == ["valve_unit"]
    # saved every 5 cycles while running (written by a thread: seen a cycle or more later;
    # a loaded machine may give the run fewer than the 10 cycles this needs)
    assert all(c % 5 == 0 for c in during), during
    assert during or saved["cycles"] < 10, saved["cycles"]

    async def again(duration: float) -> str:
        Out.lines = []
        async with PlantServer(port=plc_port) as plc:
            await plc.set_row(frame.iloc[100].to_dict())
            assert await run_config(cfg, duration=duration, out=Out()) == 0
        return "".join(Out.lines)

    out = asyncio.run(again(1.0))
    assert f"state {cfg.state} restored: 1 units go on where they stopped" in out, out
    assert json.loads(cfg.state.read_text(encoding="utf-8"))["cycles"] > saved["cycles"]
    unit = d / "rb" / "valve_unit.unit.toml"
    unit.write_text(unit.read_text(encoding="utf-8") + "# edited\n", encoding="utf-8")
    out = asyncio.run(again(0.5))
    assert "not restored (units changed since the state was saved: valve_unit)" in out, out
