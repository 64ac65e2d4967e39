"""Start-up faults of ``diag run`` (issue 35, item 6), each a real fault: a damaged spill
file, a broken unit or rule-base file, a plant.toml that is not UTF-8, and processes racing
to create a new database's tables."""

from __future__ import annotations

import asyncio
import logging
import multiprocessing as mp
import subprocess
import uuid
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from diag_plugin.live.writer import HistorianWriter
from historian.spool import Block, Spool
from historian.store import Historian
from tests.helpers import require, run_diag

T0 = pd.Timestamp("2026-03-01", tz="UTC")


@pytest.fixture(scope="module")
def plant_dir(tmp_path_factory):
    """The example unit trained on a fault-free day, a PLC register map and a plant.toml."""
    from connectors.modbus_server import default_plant_map
    from diag_plugin.examples.build import build_valve_unit
    from diag_plugin.simulate import simulate_valve

    d = tmp_path_factory.mktemp("startup")
    (d / "rb").mkdir()
    build_valve_unit(d / "rb", simulate_valve(1, seed=5), "test")
    rows = ["tag,table,address,type"] + [
        f"{t.tag},{t.table},{t.address},{t.type}" for t in default_plant_map().tags
    ]
    (d / "plc.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
    (d / "plant.toml").write_text(
        """\
[plant]
cycle = 1.0
historian = "sqlite:///h.db"
units = ["rb/valve_unit.unit.toml"]

[[source]]
name = "plc"
port = 5502
map = "plc.csv"

[outputs]
modbus_port = 0
opcua_port = 0
""",
        encoding="utf-8",
    )
    return d


def diag_run(cwd: Path, *args: str) -> subprocess.CompletedProcess:
    """``diag run ARGS`` in ``cwd``."""
    return run_diag(cwd, "run", *args, timeout=120)


# ------------------------------------------------------------------ a damaged spill file
def test_damaged_spill_file_is_quarantined_named_and_the_rest_stored(tmp_path, caplog):
    url = f"sqlite:///{tmp_path / 'h.db'}"
    spill = Spool(tmp_path / "h.db.spill")
    tags = ["A", "B"]
    for k in range(3):  # three segments of an earlier run
        ts = np.array([(T0 + pd.Timedelta(seconds=10 * k + i)).value // 1000 for i in range(4)])
        spill.write(Block(tags, ts, np.full((4, 2), float(k)), np.zeros((4, 2), np.uint8)))
    segs = spill.segments()
    # the middle one truncated (a crash of the disk, a copy cut short), the last overwritten
    segs[1].write_bytes(segs[1].read_bytes()[:200])
    segs[2].write_bytes(b"this is not a spill segment")

    async def main():
        w = HistorianWriter(url, tags, spill_dir=spill.folder, flush_every=2, cycle=0.02)
        await w.start()
        for i in range(4):  # the plug-in goes on: new cycles are stored too
            w.put(T0 + pd.Timedelta(seconds=100 + i), np.array([9.0, 9.0]), np.zeros(2, np.uint8))
            await asyncio.sleep(0.05)
        await w.close()
        return w

    with caplog.at_level(logging.ERROR, logger="historian.spool"):
        w = asyncio.run(main())
    assert w.stats.quarantined == 2
    for seg in segs[1:]:
        assert not seg.exists()
        assert seg.with_name(seg.name + ".corrupt").is_file()
        assert any(
            str(seg) in r.getMessage() and ".corrupt" in r.getMessage() for r in caplog.records
        )
    assert spill.segments() == []
    with Historian(url) as h:
        a = h.read_samples("A")
        assert sorted(set(a.to_numpy())) == [0.0, 9.0]  # the sound segment and the new cycles
        assert len(a) == 8
        ev = h.events()
    assert sum("is damaged" in m and ".corrupt" in m for m in ev["message"]) == 2
    # a new segment never takes a quarantined one's number
    assert (
        spill.write(Block(tags, np.array([1]), np.ones((1, 2)), np.zeros((1, 2), np.uint8))).name
        == "spill-00000004.npz"
    )


# ------------------------------------------------------------------ broken unit files
@pytest.mark.parametrize(
    "what, breaks",
    [
        (
            "unit file",
            lambda rb: _edit(rb / "valve_unit.unit.toml", "on_delay = 30", "on_delay = "),
        ),
        ("rule-base syntax", lambda rb: _edit(rb / "valve_r2.toml", '"wm-avg"', '"wm-avg')),
        ("rule-base content", lambda rb: _edit(rb / "valve_r2.toml", "[output]", "[outputs]")),
        ("matrix file", lambda rb: (rb / "valve_unit.matrix.toml").unlink()),
    ],
)
def test_broken_unit_refuses_check_and_start_with_file_line(plant_dir, tmp_path, what, breaks):
    d = tmp_path / "p"
    import shutil

    shutil.copytree(plant_dir, d)
    r = diag_run(d, "--config", "plant.toml", "--check")
    assert r.returncode == 0, r.stderr
    assert "plant.toml: sound: 1 units, 1 sources" in r.stdout
    breaks(d / "rb")
    for args in (("--check",), ("--plain", "--duration", "2")):
        r = diag_run(d, "--config", "plant.toml", *args)
        assert r.returncode == 2, (what, args, r.stdout, r.stderr)
        assert "diag run: plant.toml:4: plant.units: " in r.stderr, r.stderr
        assert "valve_unit.unit.toml: unit valve_unit does not load:" in r.stderr, r.stderr
        assert "Traceback" not in r.stderr + r.stdout
        assert "polling" not in r.stdout  # nothing started
        # each problem names its file and line
        probs = [x.split()[2] for x in r.stderr.splitlines() if x.startswith("diag run:   ")]
        assert probs and all(p.split(":")[1].isdigit() for p in probs), r.stderr


def _edit(path: Path, old: str, new: str, count: int = -1) -> None:
    text = path.read_text(encoding="utf-8")
    assert old in text
    path.write_text(text.replace(old, new, count), encoding="utf-8")


def test_check_needs_config(tmp_path):
    r = diag_run(tmp_path, "--check")
    assert r.returncode == 2 and "--check needs --config" in r.stderr


# ------------------------------------------------------------------ cycle and period
def test_a_cycle_that_is_not_the_units_period_is_said_with_file_line(plant_dir, tmp_path):
    """The live loop gives a unit one sample a cycle: the example unit (10 s) polled every
    1 s would read its lags and delays in seconds where it learned them in 10 s steps. Said
    at --check (the plant still sound: a fast cycle replays a unit on a test bench) with the
    file, the line and the cycle that fits; not said when the cycle is the period. On main
    nothing was said."""
    text = (plant_dir / "plant.toml").read_text(encoding="utf-8")
    p = plant_dir / "plant-1s.toml"
    p.write_text(text, encoding="utf-8")
    r = diag_run(plant_dir, "--config", str(p), "--check")
    assert r.returncode == 0, r.stderr
    line = text.splitlines().index("cycle = 1.0") + 1
    assert (
        f"{p}:{line}: warning: plant.cycle 1 s is not the period of unit valve_unit" in r.stdout
    ), r.stdout
    assert "set cycle = 10 to diagnose in real time" in r.stdout and "sound" in r.stdout
    p.write_text(text.replace("cycle = 1.0", "cycle = 10.0"), encoding="utf-8")
    r = diag_run(plant_dir, "--config", str(p), "--check")
    assert r.returncode == 0 and "warning" not in r.stdout + r.stderr, r.stdout + r.stderr


# ------------------------------------------------------------------ plant.toml not UTF-8
def test_plant_toml_not_utf8_names_file_line_and_byte(plant_dir, tmp_path):
    text = (plant_dir / "plant.toml").read_text(encoding="utf-8")
    # a comment in Latin-1, as an editor on a Windows machine saves it
    bad = text.replace("[[source]]", "# Pumpe Nr. 3 (Kühlwasser)\n[[source]]")
    raw = bad.encode("latin-1")
    p = tmp_path / "plant.toml"
    p.write_bytes(raw)
    at = raw.index(b"\xfc")
    line = raw[:at].count(b"\n") + 1
    for args in (("--check",), ("--plain", "--duration", "1")):
        r = diag_run(tmp_path, "--config", str(p), *args)
        assert r.returncode == 2, r.stderr
        assert f"{p}:{line}: not UTF-8 text: byte 0xfc at offset {at}" in r.stderr, r.stderr
        assert "Traceback" not in r.stderr
    p.write_bytes(b"\xef\xbb\xbf" + text.encode())  # a UTF-8 BOM is fine
    r = diag_run(plant_dir, "--config", str(p), "--check")
    assert "not UTF-8" not in r.stderr


# ------------------------------------------------------------------ first start race
def _open(url: str, barrier, q) -> None:
    barrier.wait()
    try:
        Historian(url).close()
        q.put("ok")
    except Exception as exc:  # noqa: BLE001 - reported to the parent
        q.put(f"{type(exc).__name__}: {str(exc).splitlines()[0]}")


def race(url_of, trials: int, n: int = 4) -> list[str]:
    ctx = mp.get_context("fork")
    errors = []
    for k in range(trials):
        url = url_of(k)
        barrier, q = ctx.Barrier(n), ctx.Queue()
        ps = [ctx.Process(target=_open, args=(url, barrier, q)) for _ in range(n)]
        for p in ps:
            p.start()
        for p in ps:
            p.join(60)
        errors += [r for r in (q.get(timeout=5) for _ in ps) if r != "ok"]
    return errors


def test_first_start_on_a_new_sqlite_database_races_no_more(tmp_path):
    """Four processes open a new database at once, ten times over (before the fix every
    trial failed with "table tags already exists")."""
    assert race(lambda k: f"sqlite:///{tmp_path / f'new{k}.db'}", 10) == []
    with Historian(f"sqlite:///{tmp_path / 'new0.db'}") as h:
        assert h.tags().empty and h.integrity_check() == []


def test_first_start_on_a_new_postgresql_database_races_no_more():
    import sqlalchemy as sa

    admin = sa.create_engine(
        "postgresql+psycopg://postgres@127.0.0.1:5432/postgres", isolation_level="AUTOCOMMIT"
    )
    try:
        with admin.connect() as c:
            c.execute(sa.text("SELECT 1"))
    except Exception:  # noqa: BLE001
        require("PostgreSQL at 127.0.0.1:5432", False, "the shared server; CI has one")
    names = [f"h35race_{uuid.uuid4().hex[:8]}_{k}" for k in range(5)]
    try:
        with admin.connect() as c:
            for n in names:
                c.execute(sa.text(f'CREATE DATABASE "{n}"'))
        errors = race(lambda k: f"postgresql://postgres@127.0.0.1:5432/{names[k]}", len(names))
        assert errors == []
    finally:
        with admin.connect() as c:
            for n in names:
                c.execute(sa.text(f'DROP DATABASE IF EXISTS "{n}" WITH (FORCE)'))
        admin.dispose()


# ------------------------------------------------------------------ an output port taken
def test_an_output_port_taken_is_named_with_file_line(plant_dir, tmp_path):
    """Another program listens on the OPC UA port: the start stops with the file, line, key
    and address and the system's reason, not a traceback, and not as a start-up time-out."""
    import shutil
    import socket

    d = tmp_path / "p"
    shutil.copytree(plant_dir, d)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        _edit(d / "plant.toml", "opcua_port = 0", f"opcua_port = {port}")
        r = diag_run(d, "--config", "plant.toml", "--plain", "--duration", "2")
    assert r.returncode == 2, (r.stdout, r.stderr)
    want = f"plant.toml:13: outputs.opcua_port: 127.0.0.1:{port} is busy (Address already in use"
    assert want in r.stderr, r.stderr
    assert "did not start in time" not in r.stderr and "Traceback" not in r.stderr
