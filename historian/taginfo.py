"""Tag metadata — one type for the historian's tags table, the simulators, the real
DAMADICS hour and the workbench."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from historian.jsonable import finite_float


@dataclass(frozen=True)
class TagInfo:
    """A tag's unit, nominal range (``lo``–``hi``, engineering units) and description."""

    name: str
    unit: str = ""
    lo: float | None = None
    hi: float | None = None
    description: str = ""

    @property
    def span(self) -> tuple[float, float] | None:
        """The nominal range when both ends are known and ``lo < hi``, else None."""
        if self.lo is None or self.hi is None:
            return None
        lo, hi = float(self.lo), float(self.hi)
        return (lo, hi) if math.isfinite(lo) and math.isfinite(hi) and hi > lo else None

    @classmethod
    def from_mapping(cls, name: str, m: Mapping[str, object]) -> TagInfo:
        """From a plain mapping with any of ``unit``, ``lo``, ``hi``, ``description``."""
        return cls(
            name,
            unit=str(m.get("unit") or ""),
            lo=finite_float(m.get("lo")),
            hi=finite_float(m.get("hi")),
            description=str(m.get("description") or ""),
        )


def tag_infos(info: Mapping[str, TagInfo | Mapping[str, object]] | None) -> dict[str, TagInfo]:
    """Tag metadata as :class:`TagInfo`, from TagInfo values or plain mappings (user input)."""
    return {
        t: v if isinstance(v, TagInfo) else TagInfo.from_mapping(t, v)
        for t, v in (info or {}).items()
    }


def tag_name_problem(name: str) -> str | None:
    """Why ``name`` cannot be a tag that an input spec names (None when it can): empty or
    blank at an end, or a double quote, a square bracket or a control character in it. Any
    other name works, in double quotes when it is not a plain word (``"Flow (t/h)"[k]``)."""
    if not name or name != name.strip():
        return "empty or blank at an end"
    if '"' in name:
        return "a double quote in it"
    if "[" in name or "]" in name:
        return "a square bracket in it"
    if any(not c.isprintable() for c in name):
        return "a control character in it"
    return None
