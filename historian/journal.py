"""The live writer's journal: every cycle on disk before it waits in memory.

The live loop keeps up to ``flush_every`` cycles (and, with the database away, far more) in
memory before they are stored; a process killed with SIGKILL would lose them all. So each
cycle is first appended to a journal file in the spill folder — one ``write`` of a few bytes
per tag, no ``fsync``: the operating system keeps what a killed process wrote (a power cut is
what the spill's ``fsync`` and the database's own journal are for). The file rotates every
``rotate_every`` cycles, and a file is deleted once every cycle in it is stored or in a spill
segment. At the next start the files left over are read back — the cycles of a crashed run —
and handed to the spill, whose replay stores them (idempotently: a cycle stored just before
the crash is not stored twice). At most the record being written at the kill is lost: it is
torn, detected by its length and CRC-32, and dropped.

Events (alarm transitions, operator actions: the audit) are journaled the same way, so a kill
loses none that was reported.

Format of ``journal-<seq>.bin``: the magic ``DIAGJNL1``, a little-endian ``uint32`` length and
that many bytes of JSON (``tags``, ``cycle`` in seconds); then records, each ``uint32`` payload
length, ``uint32`` CRC-32 of the payload, and the payload: ``S``, ``int64`` time (µs UTC),
``float64`` values and ``uint8`` qualities, one per tag (a cycle); or ``E`` and the event as
JSON text. No pickle anywhere.
"""

from __future__ import annotations

import json
import logging
import os
import re
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

log = logging.getLogger(__name__)

MAGIC = b"DIAGJNL1"
_NAME = re.compile(r"^journal-(\d{8})\.bin$")
_REC = struct.Struct("<II")


@dataclass
class Replay:
    """What one journal file held: ``ts`` (µs), ``values``/``quality`` (cycles × tags)."""

    path: Path
    tags: list[str]
    cycle: float
    ts: np.ndarray
    values: np.ndarray
    quality: np.ndarray
    events: list[dict[str, Any]]
    torn: int = 0  #: bytes of a torn last record, dropped


class JournalCorrupt(Exception):
    """A journal file whose header cannot be read (it is renamed ``.corrupt``)."""


class Journal:
    """Journal files of one writer in ``folder`` (module doc). ``tags``: the order of every
    record's values; ``cycle``: seconds per cycle (recorded, for the restart gap)."""

    def __init__(self, folder: str | Path, tags: list[str], cycle: float) -> None:
        self.folder = Path(folder)
        self.tags = list(tags)
        self.cycle = float(cycle)
        self._fd: int | None = None
        self.seq = 0  #: the file being appended to (0: none yet)
        self.cycles = 0  #: records in it
        self.created: set[int] = set()  #: the files this object made

    # ------------------------------------------------------------------ writing
    def files(self) -> list[Path]:
        """Journal files, oldest first."""
        if not self.folder.is_dir():
            return []
        return sorted(p for p in self.folder.iterdir() if _NAME.match(p.name))

    def path(self, seq: int) -> Path:
        return self.folder / f"journal-{seq:08d}.bin"

    def rotate(self) -> int:
        """Close the current file and start a new one (numbered after every file there)."""
        self._close_fd()
        self.folder.mkdir(parents=True, exist_ok=True)
        seqs = [int(m.group(1)) for p in self.folder.iterdir() if (m := _NAME.match(p.name))]
        self.seq = max([*seqs, self.seq]) + 1
        head = json.dumps({"tags": self.tags, "cycle": self.cycle}).encode()
        path = self.path(self.seq)
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        self.created.add(self.seq)
        try:
            os.write(fd, MAGIC + struct.pack("<I", len(head)) + head)
        except OSError:
            os.close(fd)
            path.unlink(missing_ok=True)
            raise
        self._fd, self.cycles = fd, 0
        return self.seq

    def append(self, ts_us: int, values: np.ndarray, quality: np.ndarray) -> int:
        """Append one cycle (one ``write`` call); returns the number of its file."""
        if self._fd is None:
            self.rotate()
        payload = (
            b"S"
            + struct.pack("<q", int(ts_us))
            + np.ascontiguousarray(values, "<f8").tobytes()
            + np.ascontiguousarray(quality, np.uint8).tobytes()
        )
        self._write(payload)
        self.cycles += 1
        return self.seq

    def append_event(self, event: dict[str, Any]) -> int:
        """Append one event (a JSON-able dict); returns the number of its file."""
        if self._fd is None:
            self.rotate()
        self._write(b"E" + json.dumps(event, default=float).encode())
        return self.seq

    def _write(self, payload: bytes) -> None:
        assert self._fd is not None
        os.write(self._fd, _REC.pack(len(payload), zlib.crc32(payload)) + payload)

    def remove(self, seq: int) -> None:
        """Delete file ``seq`` (its cycles are stored or spilled); the current one is closed
        first, so the next append starts a new file."""
        if seq == self.seq:
            self._close_fd()
        self.path(seq).unlink(missing_ok=True)

    def close(self) -> None:
        self._close_fd()

    def _close_fd(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    # ------------------------------------------------------------------ reading back
    @staticmethod
    def read(path: Path) -> Replay:
        """The cycles in ``path``; a torn last record is dropped (counted in ``torn``), a
        header that cannot be read raises :class:`JournalCorrupt`."""
        raw = path.read_bytes()
        try:
            if raw[:8] != MAGIC:
                raise ValueError("not a journal file (magic)")
            (n,) = struct.unpack_from("<I", raw, 8)
            head = json.loads(raw[12 : 12 + n].decode())
            tags = [str(t) for t in head["tags"]]
            cycle = float(head.get("cycle", 0.0))
        except (ValueError, KeyError, TypeError, struct.error) as exc:
            raise JournalCorrupt(f"{path}: {type(exc).__name__}: {exc}") from None
        k = len(tags)
        width = 9 + 9 * k
        pos, ts, vals, qual, events = 12 + n, [], [], [], []
        while pos + _REC.size <= len(raw):
            size, crc = _REC.unpack_from(raw, pos)
            body = raw[pos + _REC.size : pos + _REC.size + size]
            if len(body) != size or zlib.crc32(body) != crc:
                break  # torn by the kill (or damaged): the rest is not trusted
            if body[:1] == b"S" and size == width:
                ts.append(struct.unpack_from("<q", body, 1)[0])
                vals.append(np.frombuffer(body, "<f8", k, 9))
                qual.append(np.frombuffer(body, np.uint8, k, 9 + 8 * k))
            elif body[:1] == b"E":
                try:
                    events.append(json.loads(body[1:].decode()))
                except ValueError:
                    break
            else:
                break
            pos += _REC.size + size
        return Replay(
            path,
            tags,
            cycle,
            np.array(ts, np.int64),
            np.array(vals, np.float64).reshape(-1, k),
            np.array(qual, np.uint8).reshape(-1, k),
            events,
            torn=len(raw) - pos,
        )

    def quarantine(self, path: Path, why: str) -> Path:
        moved = path.with_name(path.name + ".corrupt")
        try:
            os.replace(path, moved)
        except OSError as err:
            log.error("journal file %s is damaged (%s) and cannot be renamed: %s", path, why, err)
            return path
        log.error("journal file %s is damaged (%s): renamed %s", path, why, moved.name)
        return moved
