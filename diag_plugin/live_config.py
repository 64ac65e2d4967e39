"""A minimal ``plant.toml`` for ``diag run --config`` (one Modbus source).

Example (paths are relative to the file)::

    [plant]
    cycle = 1.0                                   # seconds per cycle
    historian = "sqlite:///plant.db"              # optional; no historian when absent
    flush_every = 20                              # historian write every N cycles
    units = ["rulebases/valve_unit.unit.toml"]    # unit files
    rulebases = "rulebases"                       # optional; default: the first unit's folder

    [source]
    type = "modbus"
    host = "127.0.0.1"
    port = 502
    device_id = 1
    map = "plc.csv"                               # register map CSV (docs/connectors.md)
    timeout = 1.0

    [outputs]
    modbus_port = 5020                            # Modbus status server; 0: none
    opcua_port = 4840                             # OPC UA server; 0: none

Every error names the file, line and key (``plant.toml:12: source.port: ...``).
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


class ConfigError(ValueError):
    """A plant.toml problem; the message is ``file:line: key: what``."""


@dataclass
class LiveConfig:
    path: Path
    cycle: float = 1.0
    historian: str | None = None
    flush_every: int = 20
    units: list[Path] = field(default_factory=list)
    rulebases: Path | None = None
    host: str = "127.0.0.1"
    port: int = 502
    device_id: int = 1
    map: Path | None = None
    timeout: float = 1.0
    modbus_port: int = 5020
    opcua_port: int = 4840


_NAMES = {int: "an integer", float: "a number", str: "a string", list: "a list"}

_KEYS = {
    "plant": {"cycle", "historian", "flush_every", "units", "rulebases"},
    "source": {"type", "host", "port", "device_id", "map", "timeout"},
    "outputs": {"modbus_port", "opcua_port"},
}


def _line_of(lines: list[str], section: str, key: str | None) -> int:
    start = None
    for i, line in enumerate(lines):
        if start is None:
            if re.match(r"^\s*\[\s*" + re.escape(section) + r"\s*\]", line):
                start = i
                if key is None:
                    return i + 1
            continue
        if re.match(r"^\s*\[", line):
            break
        if key is not None and re.match(r"^\s*" + re.escape(key) + r"\s*=", line):
            return i + 1
    return 1 if start is None else start + 1


def load_config(path: str | Path) -> LiveConfig:
    """Read and check ``plant.toml`` (files it names must exist)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}:0: cannot read: {exc.strerror or exc}") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"line (\d+)", str(exc))
        raise ConfigError(f"{path}:{m.group(1) if m else 1}: not valid TOML: {exc}") from None
    lines = text.splitlines()
    base = path.parent

    def fail(section: str, key: str | None, msg: str) -> ConfigError:
        name = f"{section}.{key}" if key else f"[{section}]"
        return ConfigError(f"{path}:{_line_of(lines, section, key)}: {name}: {msg}")

    for section in doc:
        if section not in _KEYS:
            raise ConfigError(
                f"{path}:{_line_of(lines, section, None)}: [{section}]: unknown table "
                f"(expected {', '.join(f'[{s}]' for s in _KEYS)})"
            )
        if not isinstance(doc[section], dict):
            raise fail(section, None, "must be a table")
        for key in doc[section]:
            if key not in _KEYS[section]:
                raise fail(
                    section, key, f"unknown key (expected {', '.join(sorted(_KEYS[section]))})"
                )
    for section in ("plant", "source"):
        if section not in doc:
            raise ConfigError(f"{path}:1: [{section}]: missing table")
    cfg = LiveConfig(path)

    def get(section: str, key: str, typ: type | tuple, default: Any, required: bool = False):
        t = doc.get(section, {})
        if key not in t:
            if required:
                raise fail(section, key, "missing")
            return default
        v = t[key]
        ok = isinstance(v, typ) and not (isinstance(v, bool) and typ is not bool)
        if not ok:
            want = "a number" if isinstance(typ, tuple) else _NAMES[typ]
            raise fail(section, key, f"must be {want}, not {v!r}")
        return v

    def positive(section: str, key: str, v: float) -> float:
        if not v > 0:
            raise fail(section, key, f"must be positive, not {v!r}")
        return v

    def port(section: str, key: str, v: int, zero_ok: bool) -> int:
        if not (0 if zero_ok else 1) <= v <= 65535:
            raise fail(
                section, key, f"must be a TCP port (1-65535{', 0: none' if zero_ok else ''})"
            )
        return v

    def existing(section: str, key: str, v: str) -> Path:
        p = (base / v).resolve()
        if not p.exists():
            raise fail(section, key, f"{v!r}: no such file ({p})")
        return p

    cfg.cycle = float(positive("plant", "cycle", get("plant", "cycle", (int, float), 1.0)))
    cfg.historian = get("plant", "historian", str, None)
    if cfg.historian is not None and not cfg.historian.startswith(("sqlite:", "postgresql")):
        raise fail(
            "plant",
            "historian",
            f"expected a sqlite:/// or postgresql:// URL, not {cfg.historian!r}",
        )
    if (
        cfg.historian
        and cfg.historian.startswith("sqlite:///")
        and not cfg.historian.startswith("sqlite:////")
    ):
        cfg.historian = f"sqlite:///{(base / cfg.historian.removeprefix('sqlite:///')).resolve()}"
    cfg.flush_every = int(positive("plant", "flush_every", get("plant", "flush_every", int, 20)))
    units = get("plant", "units", list, None, required=True)
    if not units or not all(isinstance(u, str) for u in units):
        raise fail("plant", "units", "must be a non-empty list of unit file paths")
    cfg.units = [existing("plant", "units", u) for u in units]
    rb = get("plant", "rulebases", str, None)
    cfg.rulebases = existing("plant", "rulebases", rb) if rb else cfg.units[0].parent

    typ = get("source", "type", str, "modbus")
    if typ != "modbus":
        raise fail("source", "type", f"only 'modbus' is supported, not {typ!r}")
    cfg.host = get("source", "host", str, "127.0.0.1")
    cfg.port = port("source", "port", get("source", "port", int, 502), False)
    cfg.device_id = get("source", "device_id", int, 1)
    if not 0 <= cfg.device_id <= 255:
        raise fail("source", "device_id", "must be 0-255")
    cfg.map = existing("source", "map", get("source", "map", str, None, required=True))
    cfg.timeout = float(positive("source", "timeout", get("source", "timeout", (int, float), 1.0)))
    cfg.modbus_port = port("outputs", "modbus_port", get("outputs", "modbus_port", int, 5020), True)
    cfg.opcua_port = port("outputs", "opcua_port", get("outputs", "opcua_port", int, 4840), True)
    return cfg


async def run_config(
    cfg: LiveConfig, *, duration: float = 0.0, tty: bool | None = None, out=None
) -> int:
    """``diag run --config``: poll one Modbus source, store, diagnose, publish."""
    import contextlib
    import sys

    import pandas as pd

    from connectors.modbus import ModbusTagClient
    from connectors.modbus_server import StatusServer, UnitLayout
    from connectors.opcua_server import DiagOpcUaServer
    from connectors.registermap import RegisterMap
    from diag_plugin.diagnose.plant import Plant
    from diag_plugin.live import LiveLoop

    out = out or sys.stdout
    regmap = RegisterMap.from_csv(cfg.map)
    plant = Plant.load(cfg.units, cfg.rulebases)
    for name, problems in plant.broken.items():
        print(f"unit {name} is broken: {'; '.join(problems)}", file=out, flush=True)
    first = plant.cycle(pd.Timestamp.now(tz="UTC"), {})
    plant.reset()
    historian = None
    if cfg.historian:
        from historian.store import Historian

        historian = Historian.open(cfg.historian)
    status = None
    if cfg.modbus_port:
        status = StatusServer(
            [UnitLayout.from_status(s) for s in first], "127.0.0.1", cfg.modbus_port
        )
    opcua = DiagOpcUaServer("127.0.0.1", cfg.opcua_port) if cfg.opcua_port else None
    client = ModbusTagClient(
        regmap, cfg.host, cfg.port, device_id=cfg.device_id, timeout=cfg.timeout
    )
    try:
        if status is not None:
            await status.start()
        if opcua is not None:
            await opcua.start()
        print(
            f"diag run: {cfg.path}: polling modbus://{cfg.host}:{cfg.port} every {cfg.cycle:g} s"
            + (f", status Modbus 127.0.0.1:{cfg.modbus_port}" if status else "")
            + (f", OPC UA {opcua.endpoint}" if opcua else "")
            + (f", historian {cfg.historian}" if historian else ""),
            file=out,
            flush=True,
        )
        loop = LiveLoop(
            plant,
            client,
            historian=historian,
            opcua=opcua,
            status_server=status,
            cycle=cfg.cycle,
            flush_every=cfg.flush_every,
            duration=duration,
            tty=tty,
            out=out,
        )
        return await loop.run()
    finally:
        with contextlib.suppress(Exception):
            await client.close()
        for srv in (opcua, status):
            if srv is not None:
                with contextlib.suppress(Exception):
                    await srv.stop()
        if historian is not None:
            with contextlib.suppress(Exception):
                historian.close()
