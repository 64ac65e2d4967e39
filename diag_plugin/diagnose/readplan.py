"""What ``diag diagnose`` reads of the historian for a unit, remembered from its last run, so
that the next run starts reading before the unit is loaded (issue 34, "Speed").

The read needs the unit's tags, its period and its lead-in; knowing them needs the unit
loaded, and loading it imports the replay's libraries (numba, the unit's modules: ~0.3 of
a 200,000-row run's ~0.9 CPU s of start-up, one core working alone). The historian's
queries run outside the GIL, so a read started before those imports runs on the other core
meanwhile. A :class:`Plan` is kept per unit file (its path and bytes) in the model cache's
folder (:mod:`~diag_plugin.diagnose.modelcache`: ``$DIAG_MODEL_CACHE``, ``off`` keeps none),
a few hundred bytes of JSON. It is only a guess: once the unit is loaded the command
compares it with the unit's own plan and, where they differ (a rule base edited, a file
replaced), drops what was read and reads again; so the frames replayed are always the
unit's own.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: the files' layout; another value is not read
FORMAT = "diag-read-plan 1"


@dataclass(frozen=True)
class Plan:
    """What a replay reads: the unit's ``name`` (its messages), ``tags`` (the plant's
    names, in the unit's order: the frames' columns), ``period`` and ``lead`` (the samples
    read before ``--from``, :func:`~diag_plugin.diagnose.leadin.lead_in`). It stands in
    for the unit in :func:`~diag_plugin.diagnose.cli.unit_frames`."""

    name: str
    tags: tuple[str, ...]
    period: str
    lead: int

    @classmethod
    def of(cls, unit: Any) -> Plan:
        """The plan of a loaded :class:`~diag_plugin.diagnose.unit.Unit`."""
        from diag_plugin.diagnose.leadin import lead_in

        return cls(unit.name, tuple(unit.tags), str(unit.period), int(lead_in(unit)))


def plan_file(unit_file: Path) -> Path | None:
    """Where the plan of ``unit_file`` as it is now is kept (None: no cache, one not to be
    trusted, or the file unreadable): named by its path and bytes, read and hashed once per
    command (the command asks :func:`remembered` and, where the unit reads otherwise now,
    :func:`remember` of it; each hashed the file again before)."""
    from diag_plugin.diagnose.modelcache import ModelCache

    try:
        store = ModelCache.default()
        if store is None or not store.usable():
            return None
        path = Path(unit_file).resolve()
        key = hashlib.sha256(str(path).encode() + b"\0" + path.read_bytes()).hexdigest()
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return store.folder / f"plan-{key}.json"


def remembered(where: Path | None) -> Plan | None:
    """The plan kept at ``where`` (:func:`plan_file`) by the last :func:`remember`, or None
    (none kept, unreadable, or another layout)."""
    if where is None:
        return None
    try:
        got = json.loads(where.read_text("utf-8"))
        if got.get("format") != FORMAT:
            return None
        return Plan(str(got["name"]), tuple(map(str, got["tags"])), str(got["period"]),
                    int(got["lead"]))  # fmt: skip
    except (OSError, ValueError, KeyError, TypeError):
        return None


def remember(where: Path | None, plan: Plan) -> None:
    """Keep ``plan`` at ``where`` (:func:`plan_file`; None: nowhere), written whole, then
    moved in place; errors are ignored (a read-only home: the next run reads after the
    load, as without a plan)."""
    from diag_plugin.diagnose.modelcache import replace_with

    if where is None:
        return
    try:
        text = json.dumps({"format": FORMAT, "name": plan.name, "tags": list(plan.tags),
                           "period": plan.period, "lead": plan.lead})  # fmt: skip
        where.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        replace_with(where, lambda f: f.write(text.encode("utf-8")))
    except (OSError, ValueError):
        pass
