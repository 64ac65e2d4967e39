"""``plant.toml`` for ``diag run --config``: the plant, its tag sources, the outputs.

Example (paths are relative to the file; docs/live.md explains every key)::

    [plant]
    cycle = 1.0                                   # seconds per cycle
    historian = "sqlite:///plant.db"              # optional; no historian when absent
    flush_every = 20                              # historian write every N cycles
    units = ["rulebases/valve_unit.unit.toml"]    # unit files
    rulebases = "rulebases"                       # optional; default: the first unit's folder

    [[source]]                                    # one table per PLC or server
    name = "plc1"
    type = "modbus"
    host = "127.0.0.1"
    port = 502
    device_id = 1
    map = "plc.csv"                               # register map CSV (docs/connectors.md)
    timeout = 1.0

    [[source]]
    name = "scada"
    type = "opcua"
    url = "opc.tcp://127.0.0.1:4841"
    mode = "subscription"                         # or "poll"
    period = 1.0                                  # publishing interval (subscription)
    timeout = 4.0
    nodes = { T1 = "ns=2;s=Line.T1", T2 = "ns=2;s=Line.T2" }  # or a CSV "tag,node"

    [outputs]
    modbus_port = 5020                            # Modbus status server; 0: none
    opcua_port = 4840                             # OPC UA server; 0: none

A single ``[source]`` table is read as a one-element list. Tag names must be unique across
sources. Every error names the file, line and key (``plant.toml:12: source[2].port: ...``).
"""

from __future__ import annotations

import csv
import os
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from diag_plugin.tomllines import line_of
from historian.errors import UserError


class ConfigError(UserError, ValueError):
    """A plant.toml problem; the message is ``file:line: key: what``."""


@dataclass
class SourceConfig:
    """One tag source: a Modbus TCP device (``host``…``map``) or an OPC UA server (``url``…)."""

    name: str
    type: str = "modbus"
    timeout: float = 1.0
    # modbus
    host: str = "127.0.0.1"
    port: int = 502
    device_id: int = 1
    map: Path | None = None
    regmap: Any = None  # the parsed map (a RegisterMap), read once by load_config
    # opcua
    url: str = ""
    nodes: dict[str, str] = field(default_factory=dict)
    mode: str = "poll"
    period: float = 1.0
    certificate: Path | None = None
    private_key: Path | None = None
    application_uri: str = "urn:diag-plugin:client"
    server_certificate: Path | None = None
    username: str | None = None
    password: str | None = None

    @property
    def where(self) -> str:
        return self.url if self.type == "opcua" else f"modbus://{self.host}:{self.port}"


@dataclass
class LiveConfig:
    path: Path
    cycle: float = 1.0
    historian: str | None = None
    flush_every: int = 20
    units: list[Path] = field(default_factory=list)
    rulebases: Path | None = None
    sources: list[SourceConfig] = field(default_factory=list)
    modbus_port: int = 5020
    opcua_port: int = 4840


_NAMES = {int: "an integer", float: "a number", str: "a string", list: "a list", dict: "a table"}

_COMMON = {"name", "type", "timeout"}
_SOURCE_KEYS = {
    "modbus": _COMMON | {"host", "port", "device_id", "map"},
    "opcua": _COMMON
    | {
        "url",
        "nodes",
        "mode",
        "period",
        "certificate",
        "private_key",
        "application_uri",
        "server_certificate",
        "username",
        "password_env",
    },
}
_KEYS = {
    "plant": {"cycle", "historian", "flush_every", "units", "rulebases"},
    "source": set().union(*_SOURCE_KEYS.values()),
    "outputs": {"modbus_port", "opcua_port"},
}


def _line_of(lines: list[str], section: str, key: str | None, index: int = 0) -> int:
    return line_of(lines, section, key, index, subtables=True)


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
    raw_sources = doc.get("source")
    many = isinstance(raw_sources, list) and len(raw_sources) > 1

    def label(section: str, index: int) -> str:
        return f"{section}[{index + 1}]" if section == "source" and many else section

    def fail(section: str, key: str | None, msg: str, index: int = 0) -> ConfigError:
        name = f"{label(section, index)}.{key}" if key else f"[{label(section, index)}]"
        return ConfigError(f"{path}:{_line_of(lines, section, key, index)}: {name}: {msg}")

    for section in doc:
        if section not in _KEYS:
            raise ConfigError(
                f"{path}:{_line_of(lines, section, None)}: [{section}]: unknown table "
                f"(expected {', '.join(f'[{s}]' for s in _KEYS)})"
            )
    for section in ("plant", "source"):
        if section not in doc:
            raise ConfigError(f"{path}:1: [{section}]: missing table")
    tables: dict[str, list[dict]] = {}
    for section, v in doc.items():
        tables[section] = v if isinstance(v, list) and section == "source" else [v]
        if (isinstance(v, list) and not v) or not all(isinstance(t, dict) for t in tables[section]):
            raise fail(
                section, None, "must be a table" + (" or [[source]] tables" * (section == "source"))
            )
    for section, ts in tables.items():
        for i, t in enumerate(ts):
            allowed = _KEYS[section]
            if section == "source":
                allowed = _SOURCE_KEYS.get(t.get("type", "modbus"), _KEYS["source"])
            for key in t:
                if key not in allowed:
                    raise fail(
                        section, key, f"unknown key (expected {', '.join(sorted(allowed))})", i
                    )
    cfg = LiveConfig(path)

    def get(
        section: str, key: str, typ: type | tuple, default: Any, required: bool = False, i: int = 0
    ):
        t = tables.get(section, [{}])[i]
        if key not in t:
            if required:
                raise fail(section, key, "missing", i)
            return default
        v = t[key]
        ok = isinstance(v, typ) and not (isinstance(v, bool) and typ is not bool)
        if not ok:
            want = "a number" if isinstance(typ, tuple) else _NAMES[typ]
            raise fail(section, key, f"must be {want}, not {v!r}", i)
        return v

    def positive(section: str, key: str, v: float, i: int = 0) -> float:
        if not v > 0:
            raise fail(section, key, f"must be positive, not {v!r}", i)
        return v

    def port(section: str, key: str, v: int, zero_ok: bool, i: int = 0) -> int:
        if not (0 if zero_ok else 1) <= v <= 65535:
            raise fail(
                section, key, f"must be a TCP port (1-65535{', 0: none' if zero_ok else ''})", i
            )
        return v

    def existing(section: str, key: str, v: str, i: int = 0) -> Path:
        p = (base / v).resolve()
        if not p.exists():
            raise fail(section, key, f"{v!r}: no such file ({p})", i)
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

    for i in range(len(tables["source"])):
        cfg.sources.append(_source(i, get, positive, port, existing, fail, base))
    seen_names: dict[str, int] = {}
    for i, s in enumerate(cfg.sources):
        if s.name in seen_names:
            raise fail("source", "name", f"{s.name!r} is also source {seen_names[s.name] + 1}", i)
        seen_names[s.name] = i
    _check_tags(cfg, fail)
    cfg.modbus_port = port("outputs", "modbus_port", get("outputs", "modbus_port", int, 5020), True)
    cfg.opcua_port = port("outputs", "opcua_port", get("outputs", "opcua_port", int, 4840), True)
    return cfg


def _source(i: int, get, positive, port, existing, fail, base: Path) -> SourceConfig:
    """The ``i``-th source table, checked (see the module doc for its keys)."""

    def g(key: str, typ: type | tuple, default: Any, required: bool = False) -> Any:
        return get("source", key, typ, default, required, i)

    typ = g("type", str, "modbus")
    if typ not in _SOURCE_KEYS:
        raise fail("source", "type", f"expected 'modbus' or 'opcua', not {typ!r}", i)
    s = SourceConfig(name="", type=typ)
    if typ == "modbus":
        s.host = g("host", str, "127.0.0.1")
        s.port = port("source", "port", g("port", int, 502), False, i)
        s.device_id = g("device_id", int, 1)
        if not 0 <= s.device_id <= 255:
            raise fail("source", "device_id", "must be 0-255", i)
        s.map = existing("source", "map", g("map", str, None, required=True), i)
        s.timeout = float(positive("source", "timeout", g("timeout", (int, float), 1.0), i))
    else:
        s.url = g("url", str, None, required=True)
        if not re.match(r"^opc\.tcp://[^/:]+(:\d+)?(/.*)?$", s.url):
            raise fail("source", "url", f"expected opc.tcp://host:port[/path], not {s.url!r}", i)
        s.mode = g("mode", str, "poll")
        if s.mode not in ("poll", "subscription"):
            raise fail("source", "mode", f"expected 'poll' or 'subscription', not {s.mode!r}", i)
        s.period = float(positive("source", "period", g("period", (int, float), 1.0), i))
        s.timeout = float(positive("source", "timeout", g("timeout", (int, float), 4.0), i))
        s.nodes = _nodes(i, g("nodes", (dict, str), None, required=True), existing, fail)
        for key in ("certificate", "private_key", "server_certificate"):
            v = g(key, str, None)
            setattr(s, key, existing("source", key, v, i) if v is not None else None)
        s.application_uri = g("application_uri", str, s.application_uri)
        if (s.certificate is None) != (s.private_key is None):
            key = "private_key" if s.private_key is None else "certificate"
            raise fail("source", key, "certificate and private_key go together", i)
        s.username = g("username", str, None)
        env = g("password_env", str, None)
        if s.username is not None and s.certificate is None:
            raise fail(
                "source",
                "username",
                "needs certificate and private_key (a password is sent only SignAndEncrypt)",
                i,
            )
        if env is not None:
            if env not in os.environ:
                raise fail("source", "password_env", f"environment variable {env} is not set", i)
            s.password = os.environ[env]
    s.name = g("name", str, s.where)
    return s


def _nodes(i: int, v: dict | str, existing, fail) -> dict[str, str]:
    """``nodes``: a table tag → node id, or a CSV file with the columns ``tag,node``."""
    if isinstance(v, dict):
        bad = [k for k, n in v.items() if not isinstance(n, str) or not n]
        if bad or not v:
            raise fail("source", "nodes", f"must map tag names to node id strings (bad: {bad})", i)
        return dict(v)
    p = existing("source", "nodes", v, i)
    out: dict[str, str] = {}
    with p.open(encoding="utf-8", newline="") as f:
        rows = csv.reader(f)
        head = [h.strip().lower() for h in next(rows, [])]
        if head[:2] != ["tag", "node"]:
            raise ConfigError(f"{p}:1: expected the header 'tag,node', not {','.join(head)!r}")
        for n, row in enumerate(rows, start=2):
            if not row or not "".join(row).strip():
                continue
            if len(row) < 2 or not row[0].strip() or not row[1].strip():
                raise ConfigError(f"{p}:{n}: expected 'tag,node', not {','.join(row)!r}")
            tag = row[0].strip()
            if tag in out:
                raise ConfigError(f"{p}:{n}: tag {tag!r} listed twice")
            out[tag] = row[1].strip()
    if not out:
        raise ConfigError(f"{p}:1: no nodes listed")
    return out


def _check_tags(cfg: LiveConfig, fail) -> None:
    """Register maps parse, and no tag is read from two sources."""
    from connectors.registermap import RegisterMap

    owner: dict[str, int] = {}
    for i, s in enumerate(cfg.sources):
        if s.type == "modbus":
            try:
                s.regmap = RegisterMap.from_csv(s.map)
            except (ValueError, OSError) as exc:
                raise fail("source", "map", str(exc), i) from None
            tags = s.regmap.names
        else:
            tags = list(s.nodes)
        for t in tags:
            if t in owner:
                raise fail(
                    "source",
                    "map" if s.type == "modbus" else "nodes",
                    f"tag {t!r} is also read from source {cfg.sources[owner[t]].name!r}",
                    i,
                )
            owner[t] = i


def build_sources(cfg: LiveConfig) -> Any:
    """The configured sources as one :class:`connectors.sources.SourceSet`."""
    from connectors.modbus import ModbusTagClient
    from connectors.opcua_client import ClientSecurity, OpcUaConfig, OpcUaReader
    from connectors.registermap import RegisterMap
    from connectors.sources import OpcUaSource, SourceSet

    clients: list[Any] = []
    for s in cfg.sources:
        if s.type == "modbus":
            regmap = s.regmap if s.regmap is not None else RegisterMap.from_csv(s.map)
            clients.append(
                ModbusTagClient(regmap, s.host, s.port, device_id=s.device_id, timeout=s.timeout)
            )
            continue
        security = None
        if s.certificate is not None:
            security = ClientSecurity(
                s.certificate,
                s.private_key,
                s.application_uri,
                username=s.username,
                password=s.password,
                server_certificate=s.server_certificate,
            )
        reader = OpcUaReader(
            OpcUaConfig(
                s.url,
                s.nodes,
                mode=s.mode,
                period=s.period,
                timeout=s.timeout,
                security=security,
            )
        )
        clients.append(OpcUaSource(reader, s.name))
    return SourceSet(clients, [s.name for s in cfg.sources])


async def run_config(
    cfg: LiveConfig,
    *,
    duration: float = 0.0,
    tty: bool | None = None,
    out=None,
    after: Any = None,
) -> int:
    """``diag run --config``: poll every source, store, diagnose, publish. ``after``: the
    :class:`~diag_plugin.live.loop.LiveLoop` hook run after each cycle's publishing."""
    import sys

    import pandas as pd

    from connectors.modbus_server import StatusServer, UnitLayout
    from connectors.opcua_server import DiagOpcUaServer
    from diag_plugin.diagnose.plant import Plant
    from diag_plugin.live.loop import LiveLoop, close_all

    out = out or sys.stdout
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
    sources = build_sources(cfg)
    try:
        if status is not None:
            await status.start()
        if opcua is not None:
            await opcua.start()
        await sources.start()
        print(
            f"diag run: {cfg.path}: polling "
            + ", ".join(f"{s.name} ({s.where})" for s in cfg.sources)
            + f" every {cfg.cycle:g} s"
            + (f", status Modbus 127.0.0.1:{cfg.modbus_port}" if status else "")
            + (f", OPC UA {opcua.endpoint}" if opcua else "")
            + (f", historian {cfg.historian}" if historian else ""),
            file=out,
            flush=True,
        )
        loop = LiveLoop(
            plant,
            sources,
            historian=historian,
            opcua=opcua,
            status_server=status,
            cycle=cfg.cycle,
            flush_every=cfg.flush_every,
            duration=duration,
            tty=tty,
            out=out,
            after=after,
        )
        return await loop.run()
    finally:
        await close_all(sources, opcua, status, historian)
