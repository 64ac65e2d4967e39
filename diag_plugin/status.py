"""Unit status as the HMI reads it: NE 107 and the diagnosis quality (DESIGN.md, plant conventions).

A :class:`UnitStatus` is what one unit reports after one evaluation: its NE 107 status, a
certainty in [0, 1] per fault, the residual (% of span) and symptom per test, the models'
coverage and the quality of the diagnosis itself. Connectors publish it as tags; nothing here
does I/O.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

import numpy as np
import pandas as pd


class NE107(IntEnum):
    """NAMUR NE 107 status as in the OPC UA device model (DeviceHealthEnumeration)."""

    NORMAL = 0
    FAILURE = 1
    CHECK_FUNCTION = 2
    OFF_SPEC = 3
    MAINTENANCE_REQUIRED = 4


class Quality(IntEnum):
    """Quality of the diagnosis itself (OPC UA StatusCode severity: Good, Uncertain, Bad)."""

    GOOD = 0
    UNCERTAIN = 1
    BAD = 2


def _num(x: float) -> float | None:
    x = float(x)
    return x if np.isfinite(x) else None


@dataclass
class UnitStatus:
    """One unit's diagnosis at one time (what connectors publish).

    ``residuals`` and ``symptoms`` are per test (symptom: 1/-1 active with sign, 0 none, NaN
    unknown); ``certainties`` per fault in [0, 1]; ``detected`` is None when every test is
    unknown. ``message`` says why the status is CHECK_FUNCTION or FAILURE of the unit itself.
    """

    unit: str
    ts: pd.Timestamp
    status: NE107
    quality: Quality
    residuals: dict[str, float] = field(default_factory=dict)
    symptoms: dict[str, float] = field(default_factory=dict)
    certainties: dict[str, float] = field(default_factory=dict)
    coverage: dict[str, float] = field(default_factory=dict)
    detected: bool | None = None
    faults: list[str] = field(default_factory=list)
    message: str = ""
    #: the tags that explain an alarm, best first, with their share of the combined statistic
    #: (units with ``isolation = "tags"`` or ``combined = true``; empty otherwise)
    tags: list[tuple[str, float]] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict (NaN → null, enums by name and number)."""
        return {
            "unit": self.unit,
            "ts": self.ts.isoformat(),
            "status": int(self.status),
            "status_name": self.status.name,
            "quality": self.quality.name,
            "detected": self.detected,
            "faults": list(self.faults),
            "certainties": {k: _num(v) for k, v in self.certainties.items()},
            "residuals": {k: _num(v) for k, v in self.residuals.items()},
            "symptoms": {k: _num(v) for k, v in self.symptoms.items()},
            "coverage": {k: _num(v) for k, v in self.coverage.items()},
            "message": self.message,
            **({"tags": [[t, _num(v)] for t, v in self.tags]} if self.tags else {}),
        }
