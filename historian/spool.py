"""The spill: samples and events the historian could not take yet, in files beside it.

When the database is away (locked, slow, stopped) longer than the live loop's memory holds,
its oldest blocks go to numbered segment files in a folder (``<database>.spill/`` for SQLite;
one named in plant.toml otherwise). A segment is a NumPy ``.npz`` without pickled objects:
``tags`` (text), ``ts`` (int64 µs, one per cycle), ``values`` (float64, cycles × tags),
``quality`` (uint8, the same shape) and ``events`` (JSON text). Each is written to a temporary
name and renamed, so a crash leaves whole segments only; they are read back oldest first and
removed once stored. Storing is idempotent, so a segment stored just before a crash and read
again at the next start adds nothing twice.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

_NAME = re.compile(r"^spill-(\d{8})\.npz$")


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

    def segments(self) -> list[Path]:
        """Segment files, oldest first."""
        if not self.folder.is_dir():
            return []
        return sorted(p for p in self.folder.iterdir() if _NAME.match(p.name))

    def rows(self) -> int:
        """Samples waiting in the segments (from the file sizes' headers: cheap)."""
        n = 0
        for p in self.segments():
            with np.load(p, allow_pickle=False) as z:
                n += int(np.prod(z["values"].shape))
        return n

    def write(self, block: Block) -> Path:
        """Append ``block`` as the newest segment (atomic: temporary name, then rename)."""
        self.folder.mkdir(parents=True, exist_ok=True)
        last = self.segments()
        seq = int(_NAME.match(last[-1].name).group(1)) + 1 if last else 1
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

    @staticmethod
    def read(path: Path) -> Block:
        with np.load(path, allow_pickle=False) as z:
            return Block(
                [str(t) for t in z["tags"]],
                z["ts"].astype(np.int64),
                z["values"].astype(np.float64),
                z["quality"].astype(np.uint8),
                json.loads(str(z["events"])),
            )

    @staticmethod
    def remove(path: Path) -> None:
        path.unlink(missing_ok=True)
