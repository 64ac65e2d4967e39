"""The DAMADICS actuator faults f1–f19: specification, CLI syntax, time profile.

The fault set, the strength limits and the simulation equations are those of
Bartyś & Syfert, "Using Damadics Actuator Benchmark Library (DABLib)", v1.22,
2002, Table 3 (fault list) and Tables 4–22 (one table per fault). Where a fault
enters the physics is documented beside each entry of :data:`FAULTS` and
implemented in ``_kernel.py`` (in-loop faults) and ``valve.py`` (measurement
faults). The time development follows DABLib §5.3 (FGEN, Fig. 10) and
Table 28: *abrupt* — the full strength from the onset; *incipient* — the
strength rises linearly from 0 at the onset to its full value after ``ramp_s``
(DABLib Table 29 presets: 1 day "low", 1 hour "medium", 15 min "high" speed).

Where each fault enters (fs = signed strength; X = relative opening; DAMADICS
writes X as relative *closing*, converted with 1 - X where it matters):

====  =========  ==============================================================
f1    Table 4    upper travel bound H = H0 (1 - fs)
f2    Table 5    H = H0 (1 - 0.2 fs); opening seen by the flow X - 0.2 fs; Kv (1 - 0.2 fs)
f3    Table 6    H = H0 (1 + 0.1 fs); opening seen by the flow X + 0.1 fs; Kv (1 + 0.1 fs)
f4    Table 7    open-loop hysteresis Db = max(0, Db0 + fs) → Coulomb friction Db (ks+kd) L / 2
f5    Table 8    flow reaching the meter F (1 - 0.05 fs)
f6    Table 9    Kv (1 + 0.1 fs)
f7    Table 10   fluid temperature T + ΔT0 + ΔT1 fs (Table: 200 + 100 fs) → vapour
                 pressure, choked flow (Bartyś & de las Heras 2003 eqs. 8–9); T1 shows it
f8    Table 11   Db (1 + 0.5 fs X), limited to the full travel
f9    Table 12   chamber leak: outflow conductance 2·10⁻⁶ fs Ps[Pa] × the positioner's
f10   Table 13   leak as f9 and diaphragm area Ae (1 - fs)
f11   Table 14   spring constant ks (1 - fs)
f12   Table 15   E/P transducer current i0 (1 - fs)
f13   Table 16   positioner displacement sensor X (1 + 1.25 fs), limited to 0..1
f14   Table 17   E/P output pressure reading P0' (1 + fs), limited to 0..1 (reading only)
f15   Table 18   backlash of width fs (× nominal travel) in the positioner feedback
f16   Table 19   supply pressure Pz0 (1 - fs) caps the E/P output
f17   Table 20   fs < 0: P1 (1 + fs); fs > 0: P2 (1 - fs) (the table's interpretation row)
f18   Table 21   bypass valve opening fs (closing 1 - fs)
f19   Table 22   flow reading F' (1 + fs), limited to 0..1; the flow controller uses it
====  =========  ==============================================================

CLI syntax (``diag simulate --fault …``)::

    NAME:STRENGTH[@ONSET][/abrupt | /incipient[=DURATION]]

    f17:0.5@2026-03-01T10:00              abrupt, from 10:00 UTC
    f2:1@2026-03-01/incipient=1d          rises to 1.0 over one day
    f19:-0.2                              abrupt, from the start of the run
    f6:0.8@2026-01-02T00:00/incipient     ramp of the default 1 day

``STRENGTH`` is the signed fault value ``f = fd·fs`` of DABLib (the sign is the
direction). ``ONSET`` is an ISO 8601 time, UTC unless it carries an offset.
``DURATION`` is seconds (``3600``) or a pandas time-delta (``90min``, ``6h``, ``1d``).
"""

from __future__ import annotations

import re
from dataclasses import asdict, dataclass
from typing import Literal

import numpy as np
import pandas as pd

N_FAULTS = 19

#: default incipient development time, s (DABLib Table 29 note 1: 100 % per day)
DEFAULT_RAMP_S = 86400.0


@dataclass(frozen=True)
class FaultInfo:
    """One row of DABLib Table 3 plus where this simulator applies it."""

    name: str
    description: str
    lo: float  # lower strength limit (DABLib Table 3)
    hi: float  # upper strength limit
    table: str  # DABLib table with the simulation technique
    entry: str  # how the simulator applies it


#: DABLib Table 3, a row a fault: name | description | strength limits | DABLib table with the
#: simulation technique; the indented line under it: how this simulator applies it
_TABLE_3 = """
f1  | valve clogging                                | 0  | 1 | Table 4
    | upper travel bound H = H0 (1 - fs)
f2  | valve plug or valve seat sedimentation        | 0  | 1 | Table 5
    | H = H0 (1 - 0.2 fs); effective opening X - 0.2 fs; Kv (1 - 0.2 fs)
f3  | valve plug or valve seat erosion              | 0  | 1 | Table 6
    | H = H0 (1 + 0.1 fs); effective opening X + 0.1 fs; Kv (1 + 0.1 fs)
f4  | increased valve or bushing friction           | -1 | 1 | Table 7
    | open-loop hysteresis width Db = max(0, Db0 + fs) (friction force)
f5  | external leakage                              | 0  | 1 | Table 8
    | outflow reaching the flow meter F (1 - 0.05 fs)
f6  | internal leakage (valve tightness)            | 0  | 1 | Table 9
    | Kv (1 + 0.1 fs)
f7  | medium evaporation or critical flow           | 0  | 1 | Table 10
    | fluid temperature T + dT0 + dT1 fs (choked flow via pv(T)); T1 shows it
f8  | twisted servomotor piston rod                 | 0  | 1 | Table 11
    | hysteresis width Db (1 + 0.5 fs X), X = opening (1 - closing)
f9  | servomotor housing or terminals tightness     | 0  | 1 | Table 12
    | chamber air leak, conductance 2e-6 fs Ps[Pa] of the positioner's
f10 | servomotor diaphragm perforation              | 0  | 1 | Table 13
    | chamber air leak as f9 and diaphragm area Ae (1 - fs)
f11 | servomotor spring fault                       | 0  | 1 | Table 14
    | spring constant ks (1 - fs)
f12 | electro-pneumatic transducer fault            | -1 | 1 | Table 15
    | E/P transducer current i0 (1 - fs)
f13 | rod displacement sensor fault                 | -1 | 1 | Table 16
    | positioner displacement sensor X (1 + 1.25 fs), clipped to 0..1
f14 | pressure sensor fault                         | -1 | 1 | Table 17
    | measured E/P output pressure P0 (1 + fs), clipped to its range
f15 | positioner feedback fault                     | 0  | 1 | Table 18
    | backlash of width fs·(nominal travel) in the positioner feedback
f16 | positioner supply pressure drop               | 0  | 1 | Table 19
    | supply pressure Pz = Pz0 (1 - fs) limits the E/P output
f17 | unexpected pressure change across the valve   | -1 | 1 | Table 20
    | fs < 0: P1 (1 + fs); fs > 0: P2 (1 - fs) (P1/P2 tags show it)
f18 | fully or partly opened bypass valve           | 0  | 1 | Table 21
    | bypass valve opening fs (closing 1 - fs)
f19 | flow rate sensor fault                        | -1 | 1 | Table 22
    | measured relative flow F' (1 + fs), clipped to 0..1 (controller sees it)
"""


def _read_table_3(text: str) -> dict[str, FaultInfo]:
    """The faults of :data:`_TABLE_3`, by name."""
    lines = text.strip().splitlines()
    out = {}
    for head, how in zip(lines[::2], lines[1::2], strict=True):
        name, description, lo, hi, table = (c.strip() for c in head.split("|"))
        out[name] = FaultInfo(name, description, int(lo), int(hi), table, how.strip(" |"))
    return out


FAULTS: dict[str, FaultInfo] = _read_table_3(_TABLE_3)


def fault_index(name: str) -> int:
    """0-based position of fault ``name`` ("f1" … "f19") in the fault vector."""
    if name not in FAULTS:
        raise ValueError(f"unknown fault {name!r}: expected one of f1 … f19")
    return int(name[1:]) - 1


@dataclass(frozen=True)
class FaultSpec:
    """One simulated fault: DABLib fault ``name`` with signed ``strength`` (fd·fs).

    ``onset`` None means from the start of the simulation; ``end`` None means to
    its end. ``development`` "abrupt" applies the full strength at the onset;
    "incipient" ramps it linearly from 0 over ``ramp_s`` seconds (DABLib §5.3).
    """

    name: str
    strength: float
    onset: pd.Timestamp | None = None
    development: Literal["abrupt", "incipient"] = "abrupt"
    ramp_s: float = DEFAULT_RAMP_S
    end: pd.Timestamp | None = None

    def __post_init__(self) -> None:
        info = FAULTS.get(self.name)
        if info is None:
            raise ValueError(f"unknown fault {self.name!r}: expected one of f1 … f19")
        s = float(self.strength)
        if not np.isfinite(s) or s < info.lo or s > info.hi:
            raise ValueError(
                f"{self.name} strength {self.strength} outside its limits "
                f"[{info.lo:g}, {info.hi:g}] (DABLib Table 3)"
            )
        if self.development not in ("abrupt", "incipient"):
            raise ValueError(
                f"{self.name}: development must be 'abrupt' or 'incipient', "
                f"not {self.development!r}"
            )
        if not (self.ramp_s > 0 and np.isfinite(self.ramp_s)):
            raise ValueError(f"{self.name}: ramp_s must be a positive number of seconds")
        object.__setattr__(self, "strength", s)
        object.__setattr__(self, "onset", _utc(self.onset))
        object.__setattr__(self, "end", _utc(self.end))

    def to_dict(self) -> dict:
        """Plain record (ISO times) for ``DataFrame.attrs`` and experiment logs."""
        d = asdict(self)
        d["onset"] = None if self.onset is None else self.onset.isoformat()
        d["end"] = None if self.end is None else self.end.isoformat()
        d["description"] = FAULTS[self.name].description
        d["table"] = FAULTS[self.name].table
        return d

    def profile(self, t: pd.DatetimeIndex | np.ndarray, start: pd.Timestamp) -> np.ndarray:
        """Signed strength at times ``t`` (DABLib §5.3 FGEN, Fig. 10 / Table 28).

        ``t`` is a DatetimeIndex or seconds since ``start`` (float array).
        """
        if isinstance(t, pd.DatetimeIndex):
            secs = (t - start).total_seconds().to_numpy()
        else:
            secs = np.asarray(t, dtype=float)
        t_on = 0.0 if self.onset is None else (self.onset - start).total_seconds()
        t_off = np.inf if self.end is None else (self.end - start).total_seconds()
        if self.development == "abrupt":
            level = (secs >= t_on).astype(float)
        else:
            level = np.clip((secs - t_on) / self.ramp_s, 0.0, 1.0)
        level = np.where(secs < t_off, level, 0.0)
        return self.strength * level


def _utc(ts) -> pd.Timestamp | None:
    if ts is None:
        return None
    ts = pd.Timestamp(ts)
    return ts.tz_localize("UTC") if ts.tzinfo is None else ts.tz_convert("UTC")


_FAULT_RE = re.compile(
    r"^\s*(?P<name>[fF]\d{1,2})\s*:\s*(?P<strength>[^@/\s]+)"
    r"(?:@(?P<onset>[^/]+))?"
    r"(?:/(?P<dev>[A-Za-z]+)(?:=(?P<ramp>.+))?)?\s*$"
)


def parse_duration_s(text: str) -> float:
    """Seconds from ``"3600"``, ``"90min"``, ``"6h"``, ``"1d"`` … (pandas Timedelta syntax)."""
    text = text.strip()
    try:
        return float(text)
    except ValueError:
        pass
    try:
        return pd.Timedelta(text).total_seconds()
    except (ValueError, TypeError) as exc:
        raise ValueError(f"bad duration {text!r}: use seconds or e.g. 90min, 6h, 1d") from exc


def parse_fault(text: str) -> FaultSpec:
    """Parse ``NAME:STRENGTH[@ONSET][/abrupt|/incipient[=DURATION]]`` into a FaultSpec.

    Raises ValueError with a message that says what is wrong and shows the syntax.
    """
    syntax = (
        "expected NAME:STRENGTH[@ONSET][/abrupt|/incipient[=DURATION]], "
        "e.g. f17:0.5@2026-03-01T10:00"
    )
    m = _FAULT_RE.match(text or "")
    if not m:
        raise ValueError(f"bad fault {text!r}: {syntax}")
    name = m["name"].lower()
    if name not in FAULTS:
        raise ValueError(f"bad fault {text!r}: unknown fault {name!r} (f1 … f19)")
    try:
        strength = float(m["strength"])
    except ValueError:
        bad = m["strength"]
        raise ValueError(f"bad fault {text!r}: strength {bad!r} is not a number") from None
    onset = None
    if m["onset"] is not None:
        try:
            onset = pd.Timestamp(m["onset"].strip())
        except (ValueError, TypeError):
            raise ValueError(
                f"bad fault {text!r}: onset {m['onset']!r} is not an ISO 8601 time"
            ) from None
        if onset is pd.NaT or pd.isna(onset):
            raise ValueError(f"bad fault {text!r}: onset {m['onset']!r} is not a time")
    dev = (m["dev"] or "abrupt").lower()
    if dev not in ("abrupt", "incipient"):
        raise ValueError(f"bad fault {text!r}: development {m['dev']!r} is not abrupt/incipient")
    ramp_s = DEFAULT_RAMP_S
    if m["ramp"] is not None:
        if dev != "incipient":
            raise ValueError(f"bad fault {text!r}: a duration only goes with /incipient")
        try:
            ramp_s = parse_duration_s(m["ramp"])
        except ValueError as exc:
            raise ValueError(f"bad fault {text!r}: {exc}") from None
    try:
        return FaultSpec(name, strength, onset, dev, ramp_s)  # type: ignore[arg-type]
    except ValueError as exc:
        raise ValueError(f"bad fault {text!r}: {exc}") from None


def fault_truth(index: pd.DatetimeIndex, faults, start: pd.Timestamp | None = None) -> pd.DataFrame:
    """Signed strength of every fault in ``faults`` at each time of ``index``.

    One column per fault name (strengths of repeated names add up, clipped to the
    DABLib limits, as the simulator does). ``start`` only matters for faults
    without an onset (default: the first time of ``index``).
    """
    if start is None:
        start = index[0] if len(index) else pd.Timestamp(0, tz="UTC")
    out: dict[str, np.ndarray] = {}
    for spec in faults:
        prof = spec.profile(index, start)
        out[spec.name] = out.get(spec.name, 0.0) + prof
    for name, v in out.items():
        out[name] = np.clip(v, FAULTS[name].lo, FAULTS[name].hi)
    return pd.DataFrame(out, index=index)
