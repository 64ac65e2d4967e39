"""``plant.toml`` for ``diag run --config``: the plant, its tag sources, the outputs.

Example (paths are relative to the file; docs/reference/live.md explains every key)::

    [plant]
    cycle = 1.0                                   # seconds per cycle
    historian = "sqlite:///plant.db"              # optional; no historian when absent
    flush_every = 20                              # historian write every N cycles
    units = ["rulebases/valve_unit.unit.toml"]    # unit files
    rulebases = "rulebases"                       # optional; default: the first unit's folder
    stale_after = 30                              # optional; default: from each tag's history
    spill = "plant.db.spill"                      # optional; default: beside the database
    buffer_samples = 2000000                      # samples held in memory before spilling
    roll_months = true                            # closed months to the Parquet cold store
    state = "plant.state.json"                    # the units' state; default: beside this file
    state_every = 60                              # cycles between saves (and on stop)
    catch_up_max = 604800                         # s: gaps since the state diagnosed at start
    catch_up_timeout = 30                         # s the first cycle waits for it (or, with
                                                  # no state, the warm-up) at most

    [[source]]                                    # one table per PLC or server
    name = "plc1"
    type = "modbus"
    host = "127.0.0.1"
    port = 502
    device_id = 1
    map = "plc.csv"                               # register map CSV (docs/reference/connectors.md)
    timeout = 1.0                                 # s, at most the cycle (default: 1 s or the cycle)

    [[source]]
    name = "scada"
    type = "opcua"
    url = "opc.tcp://127.0.0.1:4841"
    mode = "subscription"                         # or "poll"
    period = 1.0                                  # publishing interval (subscription)
    timeout = 1.0                                 # s, at most the cycle (default: 4 s or the cycle)
    nodes = { T1 = "ns=2;s=Line.T1", T2 = "ns=2;s=Line.T2" }  # or a CSV "tag,node"

    [outputs]
    modbus_port = 5020                            # Modbus status server; 0: none
    opcua_port = 4840                             # OPC UA server; 0: none

    [opcua]                                       # our OPC UA server's security (optional)
    security = ["SignAndEncrypt", "Sign"]         # Basic256Sha256; "None" only on loopback
    certificate = "pki/own/diag-server.pem"       # created on first start when absent
    private_key = "pki/own/diag-server.key.pem"
    trusted = "pki/trusted"                       # client certificates allowed to connect
    anonymous = false                             # anonymous sessions (read-only)
    max_shelve = 3600                             # longest shelving, seconds
    confirm = false                               # true: alarms also wait for Confirm
    max_sessions = 40                             # default: 10 per user (+10 anonymous), 20-1000
    max_logins = 4                                # logins checked at once; default 4 per thread

    [[user]]
    name = "alice"
    role = "operator"                             # anonymous/viewer: read; operator: alarms
    password_hash = "scrypt$16384$8$1$..."        # `diag run --hash-password`

A single ``[source]`` table is read as a one-element list. Tag names must be unique across
sources. Every error names the file, line and key (``plant.toml:12: source[2].port: ...``).
Certificates, keys and trust folders are read at load (an unreadable one is an error there);
:func:`commission` checks what needs the units and the machine: every unit input read by a
source, the output ports free.
"""

from __future__ import annotations

import csv
import math
import os
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from diag_plugin.tomllines import line_of, syntax_error
from historian.errors import UserError


class ConfigError(UserError, ValueError):
    """A plant.toml problem; the message is ``file:line: key: what``."""


@dataclass
class SourceConfig:
    """One tag source: a Modbus TCP device (``host``…``map``) or an OPC UA server (``url``…)."""

    name: str
    type: str = "modbus"
    timeout: float = 1.0
    #: s without an answer in time before a source is down (shorter: late, not down); the
    #: connectors raise it to at least twice ``timeout``
    silent_after: float = 5.0
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
    trusted: Path | None = None
    username: str | None = None
    password: str | None = None

    @property
    def where(self) -> str:
        return self.url if self.type == "opcua" else f"modbus://{self.host}:{self.port}"


@dataclass
class ServerConfig:
    """``[opcua]``: our OPC UA server's security, and ``[[user]]`` tables."""

    host: str = "127.0.0.1"
    security: tuple[str, ...] = ("SignAndEncrypt",)
    certificate: Path | None = None
    private_key: Path | None = None
    trusted: Path | None = None
    anonymous: bool = False
    max_shelve: float = 3600.0
    confirm: bool = False
    application_uri: str = "urn:diag-plugin:server"
    users: list[Any] = field(default_factory=list)  # connectors.opcua_access.OpcUaUser
    #: sessions at once and logins checked at once (None: derived, LoginLimits.derive)
    max_sessions: int | None = None
    max_logins: int | None = None


@dataclass
class LiveConfig:
    path: Path
    cycle: float = 1.0
    historian: str | None = None
    flush_every: int = 20
    units: list[Path] = field(default_factory=list)
    rulebases: Path | None = None
    stale_after: float | None = None
    spill: Path | None = None
    buffer_samples: int = 2_000_000
    roll_months: bool = True
    state: Path | None = None
    state_every: int = 60
    catch_up_max: float = 7 * 86_400.0
    catch_up_timeout: float = 30.0
    sources: list[SourceConfig] = field(default_factory=list)
    modbus_port: int = 5020
    opcua_port: int = 4840
    server: ServerConfig | None = None
    lines: list[str] = field(default_factory=list, repr=False)

    def line(self, section: str, key: str | None = None, index: int = 0) -> int:
        """The line of ``key`` in the ``index``-th ``[section]`` of the file."""
        return _line_of(self.lines, section, key, index)


_NAMES = {
    int: "an integer",
    float: "a number",
    str: "a string",
    list: "a list",
    dict: "a table",
    bool: "true or false",
}

_COMMON = {"name", "type", "timeout", "silent_after"}
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
        "trusted",
        "username",
        "password_env",
    },
}
_KEYS = {
    "plant": {
        "cycle",
        "historian",
        "flush_every",
        "units",
        "rulebases",
        "stale_after",
        "spill",
        "buffer_samples",
        "roll_months",
        "state",
        "state_every",
        "catch_up_max",
        "catch_up_timeout",
    },
    "source": set().union(*_SOURCE_KEYS.values()),
    "outputs": {"modbus_port", "opcua_port"},
    "opcua": {
        "host",
        "security",
        "certificate",
        "private_key",
        "trusted",
        "anonymous",
        "max_shelve",
        "confirm",
        "application_uri",
        "max_sessions",
        "max_logins",
    },
    "user": {"name", "role", "password_hash", "certificate"},
}
#: tables that may repeat ([[source]], [[user]])
_LISTS = ("source", "user")
#: node ids as OPC 10000-6 §5.3.1.10 writes them: [ns=<index>;|nsu=<uri>;]<i|s|g|b>=<id>
_NODE_ID = re.compile(
    r"^(?:ns=\d+;|nsu=[^;]+;)?(?:i=\d+|s=.+|g=[0-9a-fA-F]{8}(?:-[0-9a-fA-F]{4}){3}-[0-9a-fA-F]{12}"
    r"|b=[A-Za-z0-9+/]+=*)$",
    re.S,
)


def _line_of(lines: list[str], section: str, key: str | None, index: int = 0) -> int:
    return line_of(lines, section, key, index, subtables=True)


def utf8_text(path: Path, raw: bytes) -> str:
    """``raw`` decoded as UTF-8 (TOML files are UTF-8 by definition; a BOM is dropped), or
    :class:`ConfigError` naming the file, line, column and byte offset of the first byte that
    is not."""
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        at = exc.start
        line = raw.count(b"\n", 0, at) + 1
        col = at - (raw.rfind(b"\n", 0, at) + 1) + 1
        raise ConfigError(
            f"{path}:{line}: not UTF-8 text: byte 0x{raw[at]:02x} at offset {at} (line {line}, "
            f"column {col}); save the file as UTF-8"
        ) from None


def load_config(path: str | Path) -> LiveConfig:
    """Read and check ``plant.toml`` (files it names must exist)."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{path}:0: cannot read: {exc.strerror or exc}") from None
    text = utf8_text(path, raw)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(syntax_error(path, exc)) from None
    lines = text.splitlines()
    base = path.parent
    many = {k for k in _LISTS if isinstance(doc.get(k), list) and len(doc[k]) > 1}

    def label(section: str, index: int) -> str:
        return f"{section}[{index + 1}]" if section in many else section

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
        tables[section] = v if isinstance(v, list) and section in _LISTS else [v]
        if (isinstance(v, list) and not v) or not all(isinstance(t, dict) for t in tables[section]):
            raise fail(
                section,
                None,
                "must be a table" + (f" or [[{section}]] tables" * (section in _LISTS)),
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
    cfg = LiveConfig(path, lines=lines)

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
    stale = get("plant", "stale_after", (int, float), None)
    cfg.stale_after = None if stale is None else float(positive("plant", "stale_after", stale))
    spill = get("plant", "spill", str, None)
    cfg.spill = (base / spill).resolve() if spill else None
    cfg.buffer_samples = int(
        positive("plant", "buffer_samples", get("plant", "buffer_samples", int, 2_000_000))
    )
    cfg.roll_months = get("plant", "roll_months", bool, True)
    state = get("plant", "state", str, None)
    cfg.state = (base / state).resolve() if state else path.resolve().with_suffix(".state.json")
    cfg.state_every = int(positive("plant", "state_every", get("plant", "state_every", int, 60)))
    cfg.catch_up_max = float(get("plant", "catch_up_max", (int, float), 7 * 86_400))
    if cfg.catch_up_max < 0:
        raise fail(
            "plant", "catch_up_max", f"must be 0 (no catch-up) or more, not {cfg.catch_up_max!r}"
        )
    cfg.catch_up_timeout = float(
        positive("plant", "catch_up_timeout", get("plant", "catch_up_timeout", (int, float), 30))
    )

    for i in range(len(tables["source"])):
        cfg.sources.append(_source(i, get, positive, port, existing, fail, base))
        s = cfg.sources[-1]
        if "timeout" not in tables["source"][i]:
            s.timeout = min(s.timeout, cfg.cycle)  # the default never outlasts a cycle
        elif s.timeout > cfg.cycle:
            raise fail(
                "source",
                "timeout",
                f"{s.timeout:g} s is longer than the cycle ({cfg.cycle:g} s): one slow "
                "answer would hold the cycle; give at most the cycle",
                i,
            )
    seen_names: dict[str, int] = {}
    for i, s in enumerate(cfg.sources):
        if s.name in seen_names:
            raise fail("source", "name", f"{s.name!r} is also source {seen_names[s.name] + 1}", i)
        seen_names[s.name] = i
    _check_tags(cfg, fail)
    cfg.modbus_port = port("outputs", "modbus_port", get("outputs", "modbus_port", int, 5020), True)
    cfg.opcua_port = port("outputs", "opcua_port", get("outputs", "opcua_port", int, 4840), True)
    if "user" in tables and "opcua" not in tables:
        raise fail("user", None, "users need an [opcua] table (its security)")
    if "opcua" in tables:
        cfg.server = _server(get, positive, fail, base)
        n_users = len(tables.get("user", []))
        cfg.server.users = [_user(i, get, fail, base) for i in range(n_users)]
        names = [u.name for u in cfg.server.users]
        for i, name in enumerate(names):
            if name in names[:i]:
                raise fail("user", "name", f"{name!r} is also user {names.index(name) + 1}", i)
    return cfg


def _readable_cert(fail, section: str, key: str, p: Path, i: int = 0) -> None:
    from connectors.certs import certificate_der

    try:
        certificate_der(p)
    except ValueError as exc:
        raise fail(section, key, f"unreadable certificate: {exc}", i) from None


def _readable_key(fail, section: str, key: str, p: Path, i: int = 0) -> None:
    from connectors.certs import check_private_key

    try:
        check_private_key(p)
    except ValueError as exc:
        raise fail(section, key, f"unreadable private key: {exc}", i) from None


def _readable_folder(fail, section: str, key: str, folder: Path, i: int = 0) -> None:
    from connectors.certs import trusted_ders

    if not folder.is_dir():
        raise fail(section, key, f"{folder}: not a folder", i)
    try:
        trusted_ders(folder)
    except ValueError as exc:
        raise fail(section, key, f"unreadable certificate in the trust folder: {exc}", i) from None


def _server(get, positive, fail, base: Path) -> ServerConfig:
    """``[opcua]``: our server's security (see the module doc)."""
    from connectors.opcua_server import LOOPBACK, POLICIES

    def g(key: str, typ: type | tuple, default: Any) -> Any:
        return get("opcua", key, typ, default)

    sc = ServerConfig()
    sc.host = g("host", str, sc.host)
    sec = g("security", list, ["SignAndEncrypt"])
    if not sec or not all(isinstance(x, str) and x in POLICIES for x in sec):
        raise fail("opcua", "security", f"must list some of {list(POLICIES)}, not {sec!r}")
    if "None" in sec and sc.host not in LOOPBACK:
        raise fail("opcua", "security", f"'None' only on a loopback host, not {sc.host!r}")
    sc.security = tuple(dict.fromkeys(sec))
    sc.certificate = (base / g("certificate", str, "pki/own/diag-server.pem")).resolve()
    sc.private_key = (base / g("private_key", str, "pki/own/diag-server.key.pem")).resolve()
    if sc.certificate.exists():
        _readable_cert(fail, "opcua", "certificate", sc.certificate)
        if not sc.private_key.exists():
            raise fail(
                "opcua",
                "private_key",
                f"{sc.private_key}: no such file (the "
                "certificate exists; a key is created only with a new certificate)",
            )
        _readable_key(fail, "opcua", "private_key", sc.private_key)
    elif sc.private_key.exists():
        raise fail(
            "opcua",
            "certificate",
            f"{sc.certificate}: no such file, but the private key exists: restore the "
            "certificate or remove the key (both are created on first start)",
        )
    sc.trusted = (base / g("trusted", str, "pki/trusted")).resolve()
    if sc.trusted.exists():
        _readable_folder(fail, "opcua", "trusted", sc.trusted)
    sc.anonymous = g("anonymous", bool, False)
    sc.max_shelve = float(positive("opcua", "max_shelve", g("max_shelve", (int, float), 3600.0)))
    sc.confirm = g("confirm", bool, False)
    sc.application_uri = g("application_uri", str, sc.application_uri)
    for key in ("max_sessions", "max_logins"):
        v = g(key, int, None)
        if v is not None and not 1 <= v <= 10_000:
            raise fail("opcua", key, f"must be 1-10000, not {v!r}")
        setattr(sc, key, v)
    return sc


def _user(i: int, get, fail, base: Path) -> Any:
    """The ``i``-th ``[[user]]`` table."""
    from connectors.certs import certificate_der
    from connectors.opcua_access import ROLES, OpcUaUser
    from connectors.passwords import hash_problem

    def g(key: str, typ: type | tuple, default: Any, required: bool = False) -> Any:
        return get("user", key, typ, default, required, i)

    name = g("name", str, None, required=True)
    role = g("role", str, None, required=True)
    if role not in ROLES:
        raise fail("user", "role", f"expected one of {', '.join(ROLES)}, not {role!r}", i)
    ph = g("password_hash", str, None)
    cert = g("certificate", str, None)
    if ph is None and cert is None:
        raise fail("user", "name", f"user {name!r} needs password_hash or certificate", i)
    if ph is not None and (why := hash_problem(ph)):
        raise fail("user", "password_hash", why, i)
    der = None
    if cert is not None:
        p = (base / cert).resolve()
        if not p.exists():
            raise fail("user", "certificate", f"{cert!r}: no such file ({p})", i)
        try:
            der = certificate_der(p)
        except ValueError as exc:
            raise fail("user", "certificate", f"unreadable certificate: {exc}", i) from None
    return OpcUaUser(name, role, ph, der)


def _source(i: int, get, positive, port, existing, fail, base: Path) -> SourceConfig:
    """The ``i``-th source table, checked (see the module doc for its keys)."""

    def g(key: str, typ: type | tuple, default: Any, required: bool = False) -> Any:
        return get("source", key, typ, default, required, i)

    typ = g("type", str, "modbus")
    if typ not in _SOURCE_KEYS:
        raise fail("source", "type", f"expected 'modbus' or 'opcua', not {typ!r}", i)
    s = SourceConfig(name="", type=typ)
    s.silent_after = float(
        positive("source", "silent_after", g("silent_after", (int, float), 5.0), i)
    )
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
        for key in ("certificate", "private_key", "server_certificate", "trusted"):
            v = g(key, str, None)
            setattr(s, key, existing("source", key, v, i) if v is not None else None)
        for key in ("certificate", "server_certificate"):
            if getattr(s, key) is not None:
                _readable_cert(fail, "source", key, getattr(s, key), i)
        if s.private_key is not None:
            _readable_key(fail, "source", "private_key", s.private_key, i)
        if s.trusted is not None:
            _readable_folder(fail, "source", "trusted", s.trusted, i)
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
        for tag, node in v.items():
            if not _NODE_ID.match(node):
                raise fail("source", "nodes", f"tag {tag}: {node!r} is not a node id ({_FORMS})", i)
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
            if not _NODE_ID.match(row[1].strip()):
                raise ConfigError(
                    f"{p}:{n}: tag {tag}: {row[1].strip()!r} is not a node id ({_FORMS})"
                )
            out[tag] = row[1].strip()
    if not out:
        raise ConfigError(f"{p}:1: no nodes listed")
    return out


_FORMS = "expected [ns=<index>;|nsu=<uri>;]i=<number>|s=<text>|g=<guid>|b=<base64>"


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
                ModbusTagClient(
                    regmap,
                    s.host,
                    s.port,
                    device_id=s.device_id,
                    timeout=s.timeout,
                    silent_after=s.silent_after,
                )
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
                trusted_dir=s.trusted,
            )
        reader = OpcUaReader(
            OpcUaConfig(
                s.url,
                s.nodes,
                mode=s.mode,
                period=s.period,
                timeout=s.timeout,
                silent_after=s.silent_after,
                security=security,
            )
        )
        clients.append(OpcUaSource(reader, s.name))
    return SourceSet(clients, [s.name for s in cfg.sources])


def load_plant(cfg: LiveConfig) -> Any:
    """The plant's units; a unit or rule-base file that does not load refuses the start
    (:class:`ConfigError` with each problem as ``file:line: what``, the unit named), never a
    start with that unit stuck in CHECK_FUNCTION."""
    from diag_plugin.diagnose.plant import Plant

    plant = Plant.load(cfg.units, cfg.rulebases)
    if plant.broken:
        by_name = {p.name.removesuffix(".unit.toml").removesuffix(".toml"): p for p in cfg.units}
        lines = []
        for name, problems in plant.broken.items():
            head = (
                f"{cfg.path}:{cfg.line('plant', 'units')}: plant.units: "
                f"{by_name.get(name, name)}: unit {name} does not load"
            )
            lines.append(head + ":")
            lines.extend(f"  {p}" for p in problems)
        raise ConfigError("\n".join(lines))
    return plant


def check_config(cfg: LiveConfig) -> str:
    """``diag run --check``: everything :func:`run_config` checks before it starts except
    that the output ports are free (the running plug-in may hold them); raises
    :class:`ConfigError`, else returns a one-line summary."""
    plant = load_plant(cfg)
    commission(cfg, plant, ports=False)
    tags = sum(len(s.regmap.names if s.regmap else s.nodes) for s in cfg.sources)
    return "\n".join(
        [
            *period_warnings(cfg, plant),
            f"{cfg.path}: sound: {len(plant.units)} units, {len(cfg.sources)} sources, "
            f"{tags} tags" + (f", historian {cfg.historian}" if cfg.historian else ""),
        ]
    )


def period_warnings(cfg: LiveConfig, plant: Any) -> list[str]:
    """A line per unit whose period is not the cycle: the loop gives a unit one sample a
    cycle and :meth:`~diag_plugin.diagnose.plant.Plant.cycle` takes consecutive calls as
    consecutive periods, so its lags, rates, filters and delays count cycles — a 1 min unit
    polled every second reads ``FLOW[k-18]`` 18 s back, not 18 min. Said, not refused: a
    faster cycle replays a unit quickly on a test bench."""
    by_name = {p.name.removesuffix(".unit.toml").removesuffix(".toml"): p for p in cfg.units}
    out = []
    for name, unit in plant.units.items():
        period = float(unit.period_s)
        if not math.isclose(period, cfg.cycle, rel_tol=1e-6):
            out.append(
                f"{cfg.path}:{cfg.line('plant', 'cycle')}: warning: plant.cycle {cfg.cycle:g} s "
                f"is not the period of unit {name} ({by_name.get(name, name)}: {period:g} s): "
                f"each cycle is taken as one {period:g} s sample, so its lags, rates and "
                f"delays count cycles, not time; set cycle = {period:g} to diagnose in real time"
            )
    return out


def commission(cfg: LiveConfig, plant: Any, *, ports: bool = True) -> None:
    """Checks that need the loaded units and this machine, refused like the file's own errors
    (``plant.toml:<line>: <key>: ...``): every unit's input tags are read by some source; the
    output ports are free on 127.0.0.1. All problems at once, one per line."""
    read = {t for s in cfg.sources for t in (s.regmap.names if s.regmap else s.nodes)}
    problems: list[str] = []
    by_name = {p.name.removesuffix(".unit.toml").removesuffix(".toml"): p for p in cfg.units}
    for name, unit in plant.units.items():
        missing = [t for t in unit.tags if t not in read]
        if missing:
            where = by_name.get(name, name)
            problems.append(
                f"{cfg.path}:{cfg.line('plant', 'units')}: plant.units: {where}: input tags "
                f"{', '.join(missing)} are read by no source (add them to a register map or "
                "a nodes table)"
            )
    host = cfg.server.host if cfg.server else "127.0.0.1"
    for key, port, h in (
        ("modbus_port", cfg.modbus_port, "127.0.0.1"),
        ("opcua_port", cfg.opcua_port, host),
    ):
        if ports and port and (why := port_busy(h, port)):
            problems.append(
                f"{cfg.path}:{cfg.line('outputs', key)}: outputs.{key}: {h}:{port} {why}"
            )
    if problems:
        raise ConfigError("\n".join(problems))


def port_busy(host: str, port: int) -> str:
    """Why ``host:port`` cannot be listened on ("" when it can)."""
    import socket

    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as asyncio's servers do
        try:
            sock.bind((host, port))
        except OSError as exc:
            return f"is busy ({exc.strerror or exc}; another diag run?)"
    return ""


def build_server(cfg: LiveConfig) -> Any:
    """Our OPC UA server as ``[outputs]`` and ``[opcua]`` say (None when opcua_port is 0)."""
    from connectors.opcua_server import DiagOpcUaServer, ServerSecurity

    if not cfg.opcua_port:
        return None
    sc = cfg.server
    if sc is None:
        return DiagOpcUaServer("127.0.0.1", cfg.opcua_port)
    assert sc.certificate is not None and sc.private_key is not None
    from dataclasses import replace

    from connectors.opcua_logins import LoginLimits

    limits = LoginLimits.derive(len(sc.users), sc.anonymous)
    if sc.max_sessions is not None:
        limits = replace(limits, max_sessions=sc.max_sessions)
    if sc.max_logins is not None:
        limits = replace(limits, max_activations=sc.max_logins)
    security = ServerSecurity(
        sc.certificate,
        sc.private_key,
        sc.trusted,
        tuple(sc.users),
        sc.anonymous,
        sc.security,
        sc.application_uri,
        logins=limits,
    )
    return DiagOpcUaServer(
        sc.host,
        cfg.opcua_port,
        security=security,
        max_shelve=sc.max_shelve,
        confirmation=sc.confirm,
    )


def spill_dir(cfg: LiveConfig) -> Path:
    """``plant.spill``, else beside a SQLite database, else beside plant.toml."""
    if cfg.spill is not None:
        return cfg.spill
    if cfg.historian and cfg.historian.startswith("sqlite:///"):
        return Path(cfg.historian.removeprefix("sqlite:///") + ".spill")
    return cfg.path.parent / "historian.spill"


async def run_config(
    cfg: LiveConfig,
    *,
    duration: float = 0.0,
    tty: bool | None = None,
    out=None,
    after: Any = None,
) -> int:
    """``diag run --config``: poll every source, store, diagnose, publish. ``after``: the
    :class:`~diag_plugin.live.loop.LiveLoop` hook run after each cycle's publishing.
    Commissioning problems (:func:`commission`) raise :class:`ConfigError` before anything
    starts; a port taken in the meantime too."""
    import asyncio
    import sys

    import pandas as pd

    from connectors.modbus_server import StatusServer, UnitLayout
    from diag_plugin.live.catchup import CatchUpPlan
    from diag_plugin.live.loop import LiveLoop, close_all
    from diag_plugin.live.stale import StaleDetector
    from diag_plugin.live.writer import HistorianWriter
    from historian.livestore import history_runs

    out = out or sys.stdout

    def say(text: str) -> None:
        print(text, file=out, flush=True)

    from diag_plugin.live.state import restore_state

    plant = load_plant(cfg)
    commission(cfg, plant)
    for line in period_warnings(cfg, plant):
        say(line)
    first = plant.cycle(pd.Timestamp.now(tz="UTC"), {})
    plant.reset()
    say(restore_state(plant, cfg.state, pd.Timestamp.now(tz="UTC")))
    status = None
    if cfg.modbus_port:
        status = StatusServer(
            [UnitLayout.from_status(s) for s in first], "127.0.0.1", cfg.modbus_port
        )
    opcua = build_server(cfg)
    sources = build_sources(cfg)
    writer = None
    if cfg.historian:
        writer = HistorianWriter(
            cfg.historian,
            sources.names,
            spill_dir=spill_dir(cfg),
            flush_every=cfg.flush_every,
            cycle=cfg.cycle,
            memory_rows=cfg.buffer_samples,
            roll_months=cfg.roll_months,
        )
    try:
        for server, key in ((status, "modbus_port"), (opcua, "opcua_port")):
            if server is None:
                continue
            try:
                await server.start()
            except TimeoutError:  # an OSError too: say it is the time-out, not the port
                raise ConfigError(
                    f"{cfg.path}:{cfg.line('outputs', key)}: outputs.{key}: the server did not "
                    "start in time (its start-up time-out ran out; is the machine overloaded?)"
                ) from None
            except OSError as exc:
                raise ConfigError(
                    f"{cfg.path}:{cfg.line('outputs', key)}: outputs.{key}: cannot listen: "
                    f"{exc.strerror or exc}"
                ) from None
        if opcua is not None:  # the address space at start, not in the first cycle
            for st in first:
                await opcua.add_unit(st.unit, st.certainties, st.residuals, st.coverage)
        if opcua is not None and opcua.fingerprint:
            made = "created now" if opcua.certificate_created else "existing"
            say(
                f"OPC UA server certificate {opcua.security.certificate} ({made}), SHA-256 "
                f"{opcua.fingerprint}; policies {', '.join(opcua.security.policies)}"
            )
        await sources.start()
        history = None
        if writer is not None:
            await writer.start()
            for text in writer.notes:  # a crashed run's journal, damaged spill files
                say(text)
            history = asyncio.ensure_future(
                asyncio.to_thread(history_runs, cfg.historian, sources.names)
            )
        say(
            f"diag run: {cfg.path}: polling "
            + ", ".join(f"{s.name} ({s.where})" for s in cfg.sources)
            + f" every {cfg.cycle:g} s"
            + (f", status Modbus 127.0.0.1:{cfg.modbus_port}" if status else "")
            + (f", OPC UA {opcua.endpoint}" if opcua else "")
            + (f", historian {cfg.historian} (spill {spill_dir(cfg)})" if writer else "")
        )
        loop = LiveLoop(
            plant,
            sources,
            historian=writer,
            opcua=opcua,
            status_server=status,
            cycle=cfg.cycle,
            duration=duration,
            stale=StaleDetector(sources.names, cfg.stale_after),
            stale_history=history,
            tty=tty,
            out=out,
            after=after,
            state=cfg.state,
            state_every=cfg.state_every,
            catch_up=CatchUpPlan(cfg.historian, cfg.catch_up_timeout, cfg.catch_up_max)
            if cfg.historian and cfg.catch_up_max > 0
            else None,
        )
        return await loop.run()
    finally:
        await close_all(sources, opcua, status, writer)
