"""Modbus register maps: CSV parsing, read planning (coalescing) and vectorised decoding.

A register map is a CSV file with one tag per row (DESIGN.md, plant conventions)::

    tag,table,address,type,word_order,scale,offset,unit
    F,ir,0,float32,ABCD,1,0,t/h
    CV,hr,10,int16,,0.01,0,%
    PUMP_ON,co,3,bool,,,,
    ALARM_HI,hr,20.3,bool,,,,

Columns ``tag``, ``table`` (co, di, ir, hr), ``address`` (0-based, PDU addressing) and
``type`` (float32, int16, uint16, int32, bool) are required (``ALARM_HI`` above is bit 3,
LSB = 0, of holding register 20); ``word_order`` (ABCD, the
Modbus big-endian default, or CDAB: low word first), ``scale`` (default 1), ``offset``
(default 0) and ``unit`` are optional. The engineering value is ``raw · scale + offset``.
A ``bool`` in a register table names one bit of a bit-packed status word as ``REG.BIT``.
Blank lines and lines starting with ``#`` are ignored. Every error names ``file:line`` and
the column.

:meth:`RegisterMap.plan` coalesces the tags of each table into read blocks of at most 125
registers (2000 bits for coils and discrete inputs); :class:`ReadPlan` decodes all tags at
once from the raw words with numpy (no per-tag Python loop), and :func:`encode` turns an
engineering value back into registers for writes.
"""

from __future__ import annotations

import csv
import io
import itertools
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = [
    "BIT_TABLES",
    "MAX_BITS",
    "MAX_REGISTERS",
    "TABLES",
    "TYPES",
    "ReadBlock",
    "ReadPlan",
    "RegisterMap",
    "RegisterMapError",
    "TagSpec",
    "encode",
    "unpack_bits",
]

#: Modbus tables: coils, discrete inputs, input registers, holding registers.
TABLES = ("co", "di", "ir", "hr")
BIT_TABLES = frozenset({"co", "di"})
#: Register width of each type (a bool is one bit, in a bit table or inside a register).
TYPES = {"float32": 2, "int32": 2, "int16": 1, "uint16": 1, "bool": 1}
WORD_ORDERS = ("ABCD", "CDAB")
#: Protocol limits of one read request (Modbus application protocol v1.1b3, 6.1–6.4).
MAX_REGISTERS = 125
MAX_BITS = 2000
REQUIRED = ("tag", "table", "address", "type")
OPTIONAL = ("word_order", "scale", "offset", "unit")


class RegisterMapError(ValueError):
    """A bad register map: the message starts with ``file:line:`` and names the column."""


@dataclass(frozen=True)
class TagSpec:
    """One row of a register map."""

    tag: str
    table: str
    address: int
    type: str
    word_order: str = "ABCD"
    scale: float = 1.0
    offset: float = 0.0
    unit: str = ""
    bit: int | None = None  #: bit (0 = LSB) of a register, for a ``bool`` in ir/hr
    line: int = 0

    @property
    def width(self) -> int:
        """Registers (or bits, in co/di) the tag occupies."""
        return TYPES[self.type]

    @property
    def end(self) -> int:
        return self.address + self.width

    @property
    def writable(self) -> bool:
        return self.table in ("co", "hr")


@dataclass(frozen=True)
class ReadBlock:
    """One read request: ``count`` registers/bits of ``table`` from ``start``."""

    table: str
    start: int
    count: int
    #: where the block's words start in the plan's buffer
    buf_offset: int
    #: indices (into the map's tags) of the tags this block carries
    tags: tuple[int, ...] = ()


@dataclass
class RegisterMap:
    """The tags of one Modbus device (or of our own server's output), in file order."""

    tags: list[TagSpec]
    source: str = "<map>"
    _by_name: dict[str, TagSpec] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._by_name = {t.tag: t for t in self.tags}
        self._check()

    # ---------------------------------------------------------------- loading
    @classmethod
    def from_csv(cls, path: str | Path) -> RegisterMap:
        """Read a register map CSV file (errors name ``file:line`` and the column)."""
        p = Path(path)
        return cls.parse(p.read_text(encoding="utf-8"), source=str(p))

    @classmethod
    def parse(cls, text: str, source: str = "<map>") -> RegisterMap:
        """Parse register map CSV text; ``source`` is used in error messages."""
        rows = [
            (n, r)
            for n, r in _rows(text)
            if r and any(c.strip() for c in r) and not r[0].lstrip().startswith("#")
        ]
        if not rows:
            raise RegisterMapError(f"{source}:1: empty register map (no header row)")
        hline, header = rows[0]
        cols = [c.strip().lower() for c in header]
        for c in REQUIRED:
            if c not in cols:
                raise RegisterMapError(
                    f"{source}:{hline}: column '{c}': missing from the header "
                    f"(required: {', '.join(REQUIRED)})"
                )
        unknown = [c for c in cols if c not in REQUIRED + OPTIONAL]
        if unknown:
            raise RegisterMapError(
                f"{source}:{hline}: column '{unknown[0]}': unknown column "
                f"(known: {', '.join(REQUIRED + OPTIONAL)})"
            )
        tags = []
        for n, r in rows[1:]:
            if len(r) > len(cols) and any(c.strip() for c in r[len(cols) :]):
                raise RegisterMapError(
                    f"{source}:{n}: column '{cols[-1]}': {len(r)} fields, the header has "
                    f"{len(cols)}"
                )
            tags.append(_parse_row(source, n, dict(zip(cols, _pad(r, len(cols)), strict=True))))
        return cls(tags, source=source)

    def to_csv(self) -> str:
        """The map as CSV text (parses back to an equal map)."""
        out = io.StringIO()
        w = csv.writer(out, lineterminator="\n")
        w.writerow(REQUIRED + OPTIONAL)
        for t in self.tags:
            addr = f"{t.address}.{t.bit}" if t.bit is not None else str(t.address)
            w.writerow(
                [
                    t.tag,
                    t.table,
                    addr,
                    t.type,
                    t.word_order,
                    f"{t.scale:g}",
                    f"{t.offset:g}",
                    t.unit,
                ]
            )
        return out.getvalue()

    # ------------------------------------------------------------- checking
    def _check(self) -> None:
        seen: dict[str, TagSpec] = {}
        for t in self.tags:
            if t.tag in seen:
                raise RegisterMapError(
                    f"{self.source}:{t.line}: column 'tag': duplicate tag {t.tag!r} "
                    f"(first on line {seen[t.tag].line})"
                )
            seen[t.tag] = t
        for table in TABLES:
            ts = sorted((t for t in self.tags if t.table == table), key=lambda t: t.address)
            for a, b in itertools.pairwise(ts):
                if b.address >= a.end:
                    continue
                if a.bit is not None and b.bit is not None and a.address == b.address:
                    if a.bit != b.bit:
                        continue
                raise RegisterMapError(
                    f"{self.source}:{b.line}: column 'address': {b.tag} at {table} "
                    f"{_addr(b)} overlaps {a.tag} ({table} {_addr(a)}, line {a.line})"
                )

    # --------------------------------------------------------------- access
    def __len__(self) -> int:
        return len(self.tags)

    def __getitem__(self, tag: str) -> TagSpec:
        return self._by_name[tag]

    def __contains__(self, tag: object) -> bool:
        return tag in self._by_name

    @property
    def names(self) -> list[str]:
        return [t.tag for t in self.tags]

    def plan(
        self,
        *,
        max_registers: int = MAX_REGISTERS,
        max_bits: int = MAX_BITS,
        max_gap: int = 0,
    ) -> ReadPlan:
        """Coalesce the tags into read blocks.

        Tags of one table whose addresses are contiguous (or at most ``max_gap`` unused
        registers/bits apart) share a block while it stays within ``max_registers`` (125)
        or ``max_bits`` (2000). ``max_gap`` > 0 reads the unused addresses between tags,
        which some PLCs refuse with an exception reply; the default 0 reads only mapped
        addresses.
        """
        if not 1 <= max_registers <= MAX_REGISTERS or not 1 <= max_bits <= MAX_BITS:
            raise ValueError("block size beyond the Modbus limits (125 registers, 2000 bits)")
        blocks: list[ReadBlock] = []
        buf = 0
        index = {t.tag: i for i, t in enumerate(self.tags)}
        for table in TABLES:
            limit = max_bits if table in BIT_TABLES else max_registers
            ts = sorted((t for t in self.tags if t.table == table), key=lambda t: t.address)
            cur: list[TagSpec] = []
            start = end = 0
            for t in ts:
                if cur and t.address - end <= max_gap and max(end, t.end) - start <= limit:
                    cur.append(t)
                    end = max(end, t.end)
                    continue
                if cur:
                    blocks.append(ReadBlock(table, start, end - start, buf, _ids(cur, index)))
                    buf += end - start
                cur, start, end = [t], t.address, t.end
            if cur:
                blocks.append(ReadBlock(table, start, end - start, buf, _ids(cur, index)))
                buf += end - start
        return ReadPlan(self, blocks, buf)


@dataclass
class ReadPlan:
    """Read blocks of a map and the index arrays that decode all tags at once.

    The raw words of every block go into one ``uint16`` buffer (bits of co/di blocks as
    0/1, one per word) at the block's ``buf_offset``; :meth:`decode` turns the buffer into
    engineering values with a handful of numpy operations.
    """

    regmap: RegisterMap
    blocks: list[ReadBlock]
    size: int

    def __post_init__(self) -> None:
        tags = self.regmap.tags
        n = len(tags)
        pos = np.zeros(n, dtype=np.int64)
        self.tag_block = np.full(n, -1, dtype=np.int64)
        for b_i, b in enumerate(self.blocks):
            for i in b.tags:
                pos[i] = b.buf_offset + tags[i].address - b.start
                self.tag_block[i] = b_i
        self.pos = pos
        self.scale = np.array([t.scale for t in tags], dtype=np.float64)
        self.offset = np.array([t.offset for t in tags], dtype=np.float64)
        kind = np.array([t.type for t in tags], dtype=object)
        cdab = np.array([t.word_order == "CDAB" for t in tags], dtype=bool)
        self._u16 = np.flatnonzero(kind == "uint16")
        self._i16 = np.flatnonzero(kind == "int16")
        self._bit = np.flatnonzero(kind == "bool")
        self._bitshift = np.array([tags[i].bit or 0 for i in self._bit], dtype=np.uint16)
        w32 = (kind == "float32") | (kind == "int32")
        self._w32 = np.flatnonzero(w32)
        self._w32_float = (kind[self._w32] == "float32").astype(bool)
        self._w32_cdab = cdab[self._w32]

    def new_buffer(self) -> np.ndarray:
        """A zeroed buffer to fill with the blocks' raw words."""
        return np.zeros(max(self.size, 1), dtype=np.uint16)

    def decode(self, buf: np.ndarray) -> np.ndarray:
        """Engineering values (float64, map order) from the raw-word buffer.

        float32/int32 words are joined as ``hi << 16 | lo`` (hi first for ABCD, second for
        CDAB) and reinterpreted with a numpy view; int16 via a view as ``int16``; a bool
        bit by ``(word >> bit) & 1`` (bit 0 = LSB).
        """
        buf = np.asarray(buf, dtype=np.uint16)
        raw = np.empty(len(self.pos), dtype=np.float64)
        p = self.pos
        raw[self._u16] = buf[p[self._u16]]
        raw[self._i16] = buf[p[self._i16]].view(np.int16)
        raw[self._bit] = (buf[p[self._bit]] >> self._bitshift) & 1
        if len(self._w32):
            a = buf[p[self._w32]].astype(np.uint32)
            b = buf[p[self._w32] + 1].astype(np.uint32)
            hi = np.where(self._w32_cdab, b, a)
            lo = np.where(self._w32_cdab, a, b)
            u32 = (hi << 16) | lo
            raw[self._w32] = np.where(self._w32_float, u32.view(np.float32), u32.view(np.int32))
        return raw * self.scale + self.offset

    def encode(self, values: np.ndarray, buf: np.ndarray | None = None) -> np.ndarray:
        """Raw words of all tags from engineering ``values`` (map order); inverse of decode.

        ``raw = (value − offset) / scale``; integer types are rounded and clipped to their
        range (NaN → 0), a float32 keeps NaN; a bool sets or clears its bit in ``buf``
        (other bits of a shared status word are kept).
        """
        buf = self.new_buffer() if buf is None else buf
        raw = (np.asarray(values, dtype=np.float64) - self.offset) / self.scale
        p = self.pos

        def ints(idx: np.ndarray, lo: float, hi: float) -> np.ndarray:
            r = np.nan_to_num(np.rint(raw[idx]), nan=0.0, posinf=hi, neginf=lo)
            return np.clip(r, lo, hi).astype(np.int64)

        buf[p[self._u16]] = ints(self._u16, 0, 65535).astype(np.uint16)
        buf[p[self._i16]] = ints(self._i16, -32768, 32767).astype(np.int16).view(np.uint16)
        if len(self._bit):
            on = (np.nan_to_num(raw[self._bit]) != 0).astype(np.uint16)
            mask = (np.uint16(1) << self._bitshift).astype(np.uint16)
            np.bitwise_and.at(buf, p[self._bit], ~mask)
            np.bitwise_or.at(buf, p[self._bit], on << self._bitshift)
        if len(self._w32):
            r = raw[self._w32]
            f = r.astype(np.float32).view(np.uint32)
            i = ints(self._w32, -(2**31), 2**31 - 1).astype(np.int32).view(np.uint32)
            u32 = np.where(self._w32_float, f, i)
            hi, lo = (u32 >> 16).astype(np.uint16), (u32 & 0xFFFF).astype(np.uint16)
            buf[p[self._w32]] = np.where(self._w32_cdab, lo, hi)
            buf[p[self._w32] + 1] = np.where(self._w32_cdab, hi, lo)
        return buf


def unpack_bits(words: Sequence[int] | np.ndarray, nbits: int = 16) -> np.ndarray:
    """Bits of bit-packed status words, shape ``(len(words), nbits)``, bit 0 = LSB first."""
    w = np.asarray(words, dtype=np.uint32)
    return ((w[:, None] >> np.arange(nbits, dtype=np.uint32)) & 1).astype(bool)


def pack_bits(bits: Iterable[bool]) -> int:
    """One word from bits, bit 0 = LSB first (inverse of :func:`unpack_bits`)."""
    b = np.asarray(list(bits), dtype=np.uint32)
    return int(np.sum(b << np.arange(len(b), dtype=np.uint32))) if len(b) else 0


def encode(spec: TagSpec, value: float, current: int = 0) -> list[int] | list[bool]:
    """Registers (or ``[bool]`` for co/di) that hold the engineering ``value`` of ``spec``.

    ``raw = (value − offset) / scale``, rounded for the integer types; a value outside the
    type's range raises :class:`ValueError`. A ``bool`` bit inside a register needs the
    register's ``current`` word and returns the word with that bit set or cleared.
    """
    if spec.table in BIT_TABLES:
        return [bool(value)]
    if spec.type == "bool":
        bit = 1 << (spec.bit or 0)
        return [(current | bit) if value else (current & ~bit & 0xFFFF)]
    raw = (float(value) - spec.offset) / spec.scale
    if spec.type == "float32":
        u32 = int(np.array([raw], dtype=np.float32).view(np.uint32)[0])
    else:
        lo, hi = {"int16": (-32768, 32767), "uint16": (0, 65535), "int32": (-(2**31), 2**31 - 1)}[
            spec.type
        ]
        if not np.isfinite(raw) or not lo <= round(raw) <= hi:
            raise ValueError(f"{spec.tag}: {value} is outside the range of {spec.type}")
        r = round(raw)
        if spec.width == 1:
            return [r & 0xFFFF]
        u32 = r & 0xFFFFFFFF
    hi_w, lo_w = u32 >> 16, u32 & 0xFFFF
    return [lo_w, hi_w] if spec.word_order == "CDAB" else [hi_w, lo_w]


def encode_many(regmap: RegisterMap, values: Mapping[str, float]) -> dict[str, list]:
    """:func:`encode` for several tags of ``regmap`` (bits inside registers start from 0)."""
    return {tag: encode(regmap[tag], v) for tag, v in values.items()}


# ------------------------------------------------------------------ helpers
def _rows(text: str) -> Iterable[tuple[int, list[str]]]:
    reader = csv.reader(io.StringIO(text))
    start = 1
    for row in reader:
        yield start, row
        start = reader.line_num + 1


def _pad(row: list[str], n: int) -> list[str]:
    return (row + [""] * n)[:n]


def _addr(t: TagSpec) -> str:
    return f"{t.address}.{t.bit}" if t.bit is not None else str(t.address)


def _ids(ts: list[TagSpec], index: dict[str, int]) -> tuple[int, ...]:
    return tuple(index[t.tag] for t in ts)


def _parse_row(source: str, line: int, row: dict[str, str]) -> TagSpec:
    def err(col: str, msg: str) -> RegisterMapError:
        return RegisterMapError(f"{source}:{line}: column '{col}': {msg}")

    tag = row["tag"].strip()
    if not tag:
        raise err("tag", "empty tag name")
    table = row["table"].strip().lower()
    if table not in TABLES:
        raise err("table", f"unknown table {row['table']!r} (expected one of {', '.join(TABLES)})")
    typ = row["type"].strip().lower()
    if typ not in TYPES:
        raise err("type", f"unknown type {row['type']!r} (expected one of {', '.join(TYPES)})")
    if table in BIT_TABLES and typ != "bool":
        raise err("type", f"table {table} holds bits; type must be bool, not {typ}")
    a = row["address"].strip()
    bit = None
    try:
        if "." in a:
            reg, b = a.split(".", 1)
            address, bit = int(reg), int(b)
        else:
            address = int(a)
    except ValueError:
        raise err("address", f"not an address: {a!r} (0-based integer, or REG.BIT)") from None
    if bit is not None and (typ != "bool" or table in BIT_TABLES):
        raise err("address", f"REG.BIT addressing is for bool in ir/hr, not {typ} in {table}")
    if bit is not None and not 0 <= bit <= 15:
        raise err("address", f"bit {bit} outside 0..15")
    if typ == "bool" and table not in BIT_TABLES and bit is None:
        raise err("address", "a bool in a register table needs REG.BIT (e.g. 20.3)")
    if not 0 <= address or address + TYPES[typ] > 65536:
        raise err("address", f"{address} outside 0..65535")
    wo = (row.get("word_order") or "").strip().upper() or "ABCD"
    if wo not in WORD_ORDERS:
        raise err("word_order", f"unknown word order {wo!r} (expected ABCD or CDAB)")
    nums = {}
    for col, default in (("scale", 1.0), ("offset", 0.0)):
        s = (row.get(col) or "").strip()
        try:
            nums[col] = float(s) if s else default
        except ValueError:
            raise err(col, f"not a number: {s!r}") from None
        if not np.isfinite(nums[col]):
            raise err(col, f"not a finite number: {s!r}")
    if nums["scale"] == 0:
        raise err("scale", "scale must not be 0")
    return TagSpec(
        tag=tag,
        table=table,
        address=address,
        type=typ,
        word_order=wo,
        scale=nums["scale"],
        offset=nums["offset"],
        unit=(row.get("unit") or "").strip(),
        bit=bit,
        line=line,
    )
