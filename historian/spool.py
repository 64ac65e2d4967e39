"""The spill: samples and events the historian could not take yet, in files beside it.

When the database is away (locked, slow, stopped) longer than the live loop's memory holds,
its oldest blocks go to numbered segment files in a folder (``<database>.spill/`` for SQLite;
one named in plant.toml otherwise). A segment is a NumPy ``.npz`` without pickled objects:
``tags`` (text), ``ts`` (int64 µs, one per cycle), ``values`` (float64, cycles × tags),
``quality`` (uint8, the same shape) and ``events`` (JSON text). Each is written to a temporary
name and renamed, so a crash leaves whole segments only; they are read back oldest first and
removed once stored. Storing is idempotent, so a segment stored just before a crash and read
again at the next start adds nothing twice.

A segment that cannot be read back (truncated, overwritten, not a segment at all) is
*quarantined*: renamed ``<name>.corrupt`` beside it, kept for inspection, and named in the
log and in :attr:`Spool.quarantined`; the others are read as usual.
"""

from __future__ import annotations

import json
import logging
import os
import re
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

_NAME = re.compile(r"^spill-(\d{8})\.npz$")
_SEQ = re.compile(r"^spill-(\d{8})\.npz(?:\.corrupt)?$")
#: what reading a damaged segment raises (zip, npy header, JSON, missing member)
_DAMAGE = (zipfile.BadZipFile, ValueError, KeyError, EOFError, OSError)

log = logging.getLogger(__name__)


class SegmentCorrupt(Exception):
    """A spill segment could not be read; it has been renamed ``.corrupt``."""

    def __init__(self, path: Path, moved: Path, why: str) -> None:
        super().__init__(f"{path}: {why}; renamed {moved.name}")
        self.path, self.moved, self.why = path, moved, why


@dataclass
class Block:
    """Samples of consecutive cycles (``ts`` µs; ``values``/``quality`` cycles × tags) and
    the events that came with them."""

    tags: list[str]
    ts: np.ndarray
    values: np.ndarray
    quality: np.ndarray
    events: list[dict[str, Any]] = field(default_factory=list)

    @property
    def rows(self) -> int:
        return int(self.values.size)


class Spool:
    """Spill segments in ``folder`` (created on the first write)."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        #: (segment, its new name, why) of every segment quarantined by this object
        self.quarantined: list[tuple[Path, Path, str]] = []

    def segments(self) -> list[Path]:
        """Segment files, oldest first."""
        if not self.folder.is_dir():
            return []
        return sorted(p for p in self.folder.iterdir() if _NAME.match(p.name))

    def rows(self) -> int:
        """Samples waiting in the segments (from the arrays' headers: cheap); a segment
        that cannot be read is quarantined and not counted."""
        n = 0
        for p in self.segments():
            try:
                with np.load(p, allow_pickle=False) as z:
                    n += int(np.prod(z["values"].shape))
            except _DAMAGE as exc:
                self.quarantine(p, exc)
        return n

    def quarantine(self, path: Path, exc: BaseException | str) -> Path:
        """Rename a damaged segment ``<name>.corrupt`` (kept for inspection), log it."""
        why = exc if isinstance(exc, str) else f"{type(exc).__name__}: {exc}"
        moved = path.with_name(path.name + ".corrupt")
        try:
            os.replace(path, moved)
        except OSError as err:
            log.error("spill segment %s is damaged (%s) and cannot be renamed: %s", path, why, err)
            moved = path
        else:
            log.error(
                "spill segment %s is damaged (%s): renamed %s, its samples are not stored",
                path,
                why,
                moved.name,
            )
        self.quarantined.append((path, moved, why))
        return moved

    def write(self, block: Block) -> Path:
        """Append ``block`` as the newest segment (atomic: temporary name, then rename)."""
        self.folder.mkdir(parents=True, exist_ok=True)
        seqs = [int(m.group(1)) for p in self.folder.iterdir() if (m := _SEQ.match(p.name))]
        seq = max(seqs, default=0) + 1  # never the number of a quarantined segment
        path = self.folder / f"spill-{seq:08d}.npz"
        tmp = self.folder / f".spill-{seq:08d}.tmp.npz"
        with open(tmp, "wb") as f:
            np.savez(
                f,
                tags=np.array(block.tags, dtype=np.str_),
                ts=np.asarray(block.ts, np.int64),
                values=np.asarray(block.values, np.float64),
                quality=np.asarray(block.quality, np.uint8),
                events=np.array(json.dumps(block.events, default=float), dtype=np.str_),
            )
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
        return path

    def read(self, path: Path) -> Block:
        """The block in segment ``path``; a damaged one is quarantined and
        :class:`SegmentCorrupt` raised."""
        try:
            with np.load(path, allow_pickle=False) as z:
                block = Block(
                    [str(t) for t in z["tags"]],
                    z["ts"].astype(np.int64),
                    z["values"].astype(np.float64),
                    z["quality"].astype(np.uint8),
                    json.loads(str(z["events"])),
                )
            if block.values.shape != (len(block.ts), len(block.tags)):
                raise ValueError(f"values {block.values.shape} for {len(block.ts)} cycles")
            if block.quality.shape != block.values.shape:
                raise ValueError(f"quality {block.quality.shape} for values {block.values.shape}")
        except _DAMAGE as exc:
            if isinstance(exc, FileNotFoundError):
                raise
            why = f"{type(exc).__name__}: {exc}"
            raise SegmentCorrupt(path, self.quarantine(path, why), why) from None
        return block

    @staticmethod
    def remove(path: Path) -> None:
        path.unlink(missing_ok=True)
