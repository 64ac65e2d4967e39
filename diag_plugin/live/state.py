"""The live plant's state on disk: a restarted ``diag run`` goes on where it stopped.

:meth:`~diag_plugin.diagnose.plant.Plant.to_state` (filters, delays, deadbands, running
spreads, alarm holds, isolation holds, each unit's excursions, the tag history) is written as
JSON — arrays as explicit lists, no pickle — on a clean stop and every ``state_every`` cycles
(:class:`~diag_plugin.live.loop.LiveLoop`). The write is atomic: a temporary file beside the
target, flushed to disk, then renamed over it, so a crash mid-write leaves the previous state
whole. At start :func:`restore_state` loads it when every unit is the version it was saved
with (:meth:`Plant.versions`: the unit, rule-base and matrix files' SHA-256); otherwise the
plant starts fresh and the returned line says why.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

import pandas as pd


def save_state(plant: Any, path: str | Path) -> None:
    """Write ``plant.to_state()`` to ``path`` atomically (temporary file, fsync, rename)."""
    write_atomic(state_text(plant), path)


def state_text(plant: Any) -> str:
    """``plant.to_state()`` as JSON text (the snapshot: take it between cycles)."""
    return json.dumps(plant.to_state(), allow_nan=False, separators=(",", ":"))


def write_atomic(text: str, path: str | Path) -> None:
    """``text`` to ``path``: a temporary file beside it, flushed to disk, renamed over it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def restore_state(plant: Any, path: str | Path, now: pd.Timestamp | None = None) -> str:
    """Load the state at ``path`` into ``plant`` when it fits; one line saying what was done
    (restored, with the state's age, or starting fresh and why)."""
    path = Path(path)
    if not path.exists():
        return f"state {path}: none yet, units start fresh"
    try:
        state = json.loads(path.read_text(encoding="utf-8"))
        plant.load_state(state)
    except (ValueError, KeyError, TypeError, OSError) as exc:
        plant.reset()
        return f"state {path} not restored ({exc}): units start fresh (warming up)"
    age = ""
    if state.get("ts") and now is not None:
        gap = (pd.Timestamp(now) - pd.Timestamp(state["ts"])).total_seconds()
        age = f", {gap:.0f} s ago"
    return (
        f"state {path} restored: {len(plant.units)} units go on where they stopped "
        f"(saved at {state.get('ts')}{age})"
    )
