"""Public plants nobody in this project built: loaders, and which runs are for what.

Each loader returns a :class:`PublicPlant`: the runs every method learns from (``train``),
the fault-free runs the matched limits are set on (``calibration``), other fault-free runs
to count false alarms out of sample (``free``), the faulty runs that are scored
(``faults``) and those set aside for choosing changes (``tuning``, never scored by the
benchmark). The split is fixed here, in code and in the results pages, not chosen after
looking at results. Data are read from where a user keeps them, never from the repository:

* **Tennessee Eastman, the classic data set** (Braatz group, as shipped inside the PyPI wheel
  of ``bibmon`` 1.2.0): ``$DIAG_TEP_BRAATZ_DIR`` or ``~/.cache/diag-plugin/tep-braatz``
  (``make public-data`` downloads the wheel with ``pip download --no-deps`` and unpacks the
  ``.dat`` files). ``d00.dat`` is stored transposed (52 × 500) and is read either way;
  ``dXX.dat`` (480 samples) are faulty *from their first sample* — the fault was introduced
  an hour into the simulation and only later samples kept (XMEAS(1) in ``d01.dat`` leaves
  its normal band by the 8th sample; in ``d06.dat`` the A feed is zero from the first) — so
  they serve for tuning; ``dXX_te.dat`` (960 samples) carry the fault from sample 160 (8 h).
* **Tennessee Eastman, tep-studio** (Ricker's modified TEP with his decentralised control):
  the CSV runs and ``manifest.json`` that ``benchmarks/tep_studio_runs.py`` writes into
  ``$DIAG_TEP_STUDIO_DIR`` or ``~/.cache/diag-plugin/tep-studio``.
* **SKAB** (Skoltech Anomaly Benchmark, a 1 s water-circulation rig, 8 sensors):
  ``$DIAG_SKAB_DIR``, a ``git clone https://github.com/waico/SKAB`` (its ``data/`` folder),
  or a bare mirror of it (read with ``git show``; the team's is at
  ``/work/.mirror/waico+SKAB/repo``). Its protocol learns from the first 400 samples of each
  run and scores the rest against the ``anomaly`` labels.

A loader whose data are absent raises :class:`DataMissing` with the reason and what to do,
so tests and benchmarks skip with it.
"""

from __future__ import annotations

import io
import json
import os
import subprocess
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

__all__ = [
    "DataMissing",
    "PlantRun",
    "PublicPlant",
    "TEP_FAULTS",
    "TEP_TAGS",
    "braatz_dir",
    "load_braatz",
    "load_skab",
    "load_tep_studio",
    "skab_source",
    "tep_studio_dir",
]

CACHE = Path("~/.cache/diag-plugin").expanduser()
#: where the team keeps a mirror of the SKAB repository (read-only, a bare git directory)
SKAB_MIRROR = Path("/work/.mirror/waico+SKAB/repo")


class DataMissing(RuntimeError):
    """A public data set is not on this machine (the message says where it was looked for
    and how to get it)."""


@dataclass
class PlantRun:
    """One run: an aligned frame (timestamp index, one column per tag), and for a faulty run
    the sample of the onset, the fault and the tags at fault; SKAB runs carry their per-sample
    ``labels`` (1 anomalous) and the protocol's training rows ``learn``."""

    name: str
    frame: pd.DataFrame
    fault: str | None = None
    onset: int | None = None
    tags: tuple[str, ...] = ()
    labels: np.ndarray | None = None
    learn: int = 0  # the first rows a per-run protocol learns from


@dataclass
class PublicPlant:
    name: str
    title: str
    period_s: float
    tags: list[str]
    tag_info: dict[str, tuple[str, str]]  # tag → (unit, description)
    train: list[PlantRun]
    calibration: list[PlantRun]
    free: list[PlantRun]
    faults: list[PlantRun]
    tuning: list[PlantRun] = field(default_factory=list)
    fault_info: dict[str, str] = field(default_factory=dict)
    per_run: bool = False  # the protocol learns from each run's first ``learn`` rows
    source: str = ""
    split: list[str] = field(default_factory=list)  # the runs and what each is for, in words
    #: control loops declared to ``diag unit build`` as ``PV=SP:OUT`` (the tags CSV's loop and
    #: role columns, docs/how-to/unit-loops.md)
    loops: list[str] = field(default_factory=list)


# ---------------------------------------------------------------- Tennessee Eastman

_XMEAS = [
    ("kscmh", "A feed (stream 1)"),
    ("kg/h", "D feed (stream 2)"),
    ("kg/h", "E feed (stream 3)"),
    ("kscmh", "A and C feed (stream 4)"),
    ("kscmh", "recycle flow (stream 8)"),
    ("kscmh", "reactor feed rate (stream 6)"),
    ("kPa", "reactor pressure"),
    ("%", "reactor level"),
    ("°C", "reactor temperature"),
    ("kscmh", "purge rate (stream 9)"),
    ("°C", "product separator temperature"),
    ("%", "product separator level"),
    ("kPa", "product separator pressure"),
    ("m³/h", "product separator underflow (stream 10)"),
    ("%", "stripper level"),
    ("kPa", "stripper pressure"),
    ("m³/h", "stripper underflow (stream 11)"),
    ("°C", "stripper temperature"),
    ("kg/h", "stripper steam flow"),
    ("kW", "compressor work"),
    ("°C", "reactor cooling water outlet temperature"),
    ("°C", "separator cooling water outlet temperature"),
    *[("mol%", f"reactor feed analysis {c} (stream 6)") for c in "ABCDEF"],
    *[("mol%", f"purge gas analysis {c} (stream 9)") for c in "ABCDEFGH"],
    *[("mol%", f"product analysis {c} (stream 11)") for c in "DEFGH"],
]
_XMV = [
    "D feed flow (stream 2)",
    "E feed flow (stream 3)",
    "A feed flow (stream 1)",
    "A and C feed flow (stream 4)",
    "compressor recycle valve",
    "purge valve (stream 9)",
    "separator pot liquid flow (stream 10)",
    "stripper liquid product flow (stream 11)",
    "stripper steam valve",
    "reactor cooling water flow",
    "condenser cooling water flow",
]
#: the 52 tags of the classic data sets: XMEAS(1)…(41), XMV(1)…(11)
TEP_TAGS: dict[str, tuple[str, str]] = {
    **{f"XMEAS{i + 1}": v for i, v in enumerate(_XMEAS)},
    **{f"XMV{i + 1}": ("%", d) for i, d in enumerate(_XMV)},
}

#: IDV(k): what it is (Downs & Vogel 1993, Table 8), and the tags it enters at — the measured
#: stream or loop where the disturbance acts, or the valve that must compensate it; empty
#: where the disturbance is unknown (16–20) or enters where nothing is measured (naming is
#: then not counted)
TEP_FAULTS: dict[str, tuple[str, tuple[str, ...]]] = {
    "IDV1": ("A/C feed ratio, B composition constant (stream 4): step", ("XMEAS4", "XMV4")),
    "IDV2": ("B composition, A/C ratio constant (stream 4): step", ("XMEAS4", "XMV4")),
    "IDV3": ("D feed temperature (stream 2): step", ("XMEAS2", "XMV1")),
    "IDV4": ("reactor cooling water inlet temperature: step", ("XMV10", "XMEAS9", "XMEAS21")),
    "IDV5": ("condenser cooling water inlet temperature: step", ("XMV11", "XMEAS22", "XMEAS11")),
    "IDV6": ("A feed loss (stream 1): step", ("XMEAS1", "XMV3")),
    "IDV7": ("C header pressure loss, reduced availability (stream 4): step", ("XMEAS4", "XMV4")),
    "IDV8": ("A, B, C feed composition (stream 4): random variation", ("XMEAS4", "XMV4")),
    "IDV9": ("D feed temperature (stream 2): random variation", ("XMEAS2", "XMV1")),
    "IDV10": ("C feed temperature (stream 4): random variation", ("XMEAS4", "XMV4")),
    "IDV11": (
        "reactor cooling water inlet temperature: random variation",
        ("XMV10", "XMEAS9", "XMEAS21"),
    ),
    "IDV12": (
        "condenser cooling water inlet temperature: random variation",
        ("XMV11", "XMEAS22", "XMEAS11"),
    ),
    "IDV13": ("reaction kinetics: slow drift", ("XMEAS7", "XMEAS9")),
    "IDV14": ("reactor cooling water valve: sticking", ("XMV10", "XMEAS9", "XMEAS21")),
    "IDV15": ("condenser cooling water valve: sticking", ("XMV11", "XMEAS22")),
    "IDV16": ("unknown", ()),
    "IDV17": ("unknown", ()),
    "IDV18": ("unknown", ()),
    "IDV19": ("unknown", ()),
    "IDV20": ("unknown", ()),
    "IDV21": ("valve for stream 4 fixed at the steady-state position", ("XMV4", "XMEAS4")),
}


#: tep-studio's IDV(16)–(20) (Ricker's modified TEP defines what the classic set calls unknown)
TEP_STUDIO_FAULTS: dict[str, tuple[str, tuple[str, ...]]] = {
    **TEP_FAULTS,
    "IDV16": ("stripper heat transfer: random variation", ("XMEAS18", "XMV9", "XMEAS19")),
    "IDV17": ("reactor heat transfer: random variation", ("XMV10", "XMEAS9", "XMEAS21")),
    "IDV18": ("condenser heat transfer: random variation", ("XMV11", "XMEAS22", "XMEAS11")),
    "IDV19": ("valve stiction, a group of valves", ()),
    "IDV20": ("unknown random disturbance", ()),
}


#: the classic set's loop whose set-point is known from the plant's description: the reactor
#: temperature held at its base-case 120.4 °C (Downs & Vogel 1993, Table 1) by the reactor
#: cooling water flow; the set-point is not one of the 52 tags, so it is declared as a number
TEP_LOOPS = ("XMEAS9=120.4:XMV10",)


#: tep-studio's loops whose set-points are fixed: Ricker's Mode-1 decentralised control as
#: tep-studio 0.2.0 runs it (``tep_studio/control/registry.py``, ``RICKER_MODE1``: which loop
#: holds which measurement and drives what; ``tep_studio/control/controller.py``,
#: ``RickerMultiLoopController.compute_action`` and ``_default_setpoints``: the set-points are
#: the Mode-1 initial measurements, the same for every seed, held for the whole run as
#: ``benchmarks/tep_studio_runs.py`` gives no set-point schedule). Each is ``PV=SP:OUT`` with
#: the valve the loop finally moves (through Ricker's cascades: reactor pressure → purge ratio
#: r5 → purge flow → XMV6; reactor level → the separator-temperature set-point → XMV11), or
#: ``PV=SP`` where the output is no valve (the production rate → the production index Fp,
#: which scales every feed). Not declared: the separator temperature (its set-point is the
#: reactor-level loop's output, not recorded), the feed and flow loops (set-points ratio × Fp),
#: the yA / yAC trims (computed measurements), %G (its feedback is off in tep-studio), and the
#: separator and stripper levels (``XMEAS12=50:XMV7``, ``XMEAS15=50:XMV8``, through r6, r7 and
#: the underflows): on the tuning runs (IDV1–20, seed 101, at 1 % of the calibration samples)
#: declaring them too took the unit's mean detection from 77.6 % to 70.9 % (IDV19, the valve
#: stiction group, 98 → 23 %: the underflow valves' tests lose the level they follow), below
#: the 73.2 % with no loop declared; these four give 77.6 % (the reactor temperature's alone
#: 76.9 %; PCA 71.0 %, DPCA 74.9 %).
TEP_STUDIO_LOOPS = (
    "XMEAS9=120.4:XMV10",  # reactor temperature → reactor cooling water valve
    "XMEAS7=2705:XMV6",  # reactor pressure → purge ratio → purge valve
    "XMEAS8=75:XMV11",  # reactor level → separator temperature set-point → condenser valve
    "XMEAS17=22.9487",  # production rate (stripper underflow) → production index Fp
)


def braatz_dir(path: str | Path | None = None) -> Path:
    """The folder of ``d00.dat`` … (``path``, ``$DIAG_TEP_BRAATZ_DIR``, or the cache)."""
    p = path or os.environ.get("DIAG_TEP_BRAATZ_DIR")
    base = Path(p).expanduser() if p else CACHE / "tep-braatz"
    for cand in (base, base / "bibmon" / "tennessee_eastman"):
        if (cand / "d00.dat").exists():
            return cand
    raise DataMissing(
        f"Tennessee Eastman (Braatz) data not found in {base} (set DIAG_TEP_BRAATZ_DIR, or "
        "run `make public-data`, which unpacks them from the bibmon 1.2.0 wheel)"
    )


def _read_dat(path: Path) -> np.ndarray:
    a = np.loadtxt(path)
    if a.shape[0] == 52 and a.shape[1] != 52:  # d00.dat is stored 52 × 500
        a = a.T
    if a.ndim != 2 or a.shape[1] != 52:
        raise ValueError(f"{path}: expected 52 columns (41 XMEAS + 11 XMV), got {a.shape}")
    return a


#: the sample period of both Tennessee Eastman data sets (3 min)
TEP_PERIOD_S = 180.0


def _tep_frame(a: np.ndarray, start: pd.Timestamp, period_s: float = TEP_PERIOD_S) -> pd.DataFrame:
    idx = pd.date_range(start, periods=len(a), freq=pd.Timedelta(seconds=period_s))
    return pd.DataFrame(a, index=idx, columns=list(TEP_TAGS))


def _tep_plant(
    name: str,
    title: str,
    runs: dict[str, list[PlantRun]],
    fault_info: dict[str, str],
    source: Path,
    split: list[str],
    loops: Sequence[str] = (),
) -> PublicPlant:
    """A Tennessee Eastman data set: the plant's tags at its 3-min period, its ``runs`` by
    role (``train``, ``calibration``, ``free``, ``fault``, ``tuning``)."""
    return PublicPlant(
        name=name,
        title=title,
        period_s=TEP_PERIOD_S,
        tags=list(TEP_TAGS),
        tag_info=TEP_TAGS,
        train=runs["train"],
        calibration=runs["calibration"],
        free=runs["free"],
        faults=runs["fault"],
        tuning=runs["tuning"],
        fault_info=fault_info,
        source=str(source),
        loops=list(loops),
        split=split,
    )


def load_braatz(path: str | Path | None = None, faults: Sequence[str] | None = None) -> PublicPlant:
    """The classic TEP data (3 min): learn on ``d00.dat`` (500 samples, 25 h), set the matched
    limits on ``d00_te.dat`` (960, 48 h, another run), count false alarms out of sample on
    the 160 fault-free samples before the onset of each ``dXX_te.dat`` (8 h each; a piece
    that repeats an earlier one value for value is counted once: ``d05_te``'s first 160
    samples are ``d04_te``'s), score the faults on ``d01_te`` … ``d21_te`` (onset at sample
    160); ``d01.dat`` … ``d21.dat`` (faulty throughout) are for tuning."""
    d = braatz_dir(path)
    day = pd.Timedelta(days=3)
    t0 = pd.Timestamp("2001-01-01", tz="UTC")
    train = [PlantRun("d00", _tep_frame(_read_dat(d / "d00.dat"), t0))]
    cal = [PlantRun("d00_te", _tep_frame(_read_dat(d / "d00_te.dat"), t0 + day))]
    names = list(faults) if faults else list(TEP_FAULTS)
    bad = [f for f in names if f not in TEP_FAULTS]
    if bad:
        raise ValueError(f"unknown fault(s) {', '.join(bad)}; known: IDV1 … IDV21")
    fault_runs, free, tuning = [], [], []
    seen: list[np.ndarray] = []
    for k, idv in enumerate(names):
        n = int(idv[3:])
        te = _read_dat(d / f"d{n:02d}_te.dat")
        frame = _tep_frame(te, t0 + day * (2 + k))
        tags = TEP_FAULTS[idv][1]
        fault_runs.append(PlantRun(f"d{n:02d}_te", frame, idv, 160, tags))
        if not any(np.array_equal(te[:160], p) for p in seen):  # one piece, counted once
            free.append(PlantRun(f"d{n:02d}_te[:160]", frame.iloc[:160]))
            seen.append(te[:160])
        tr = _read_dat(d / f"d{n:02d}.dat")
        tuning.append(PlantRun(f"d{n:02d}", _tep_frame(tr, t0 + day * (40 + k)), idv, 0, tags))
    return _tep_plant(
        "tep",
        "Tennessee Eastman, the classic data set (Braatz; as shipped in bibmon 1.2.0)",
        {"train": train, "calibration": cal, "free": free, "fault": fault_runs, "tuning": tuning},
        {k: v[0] for k, v in TEP_FAULTS.items()},
        d,
        loops=TEP_LOOPS,
        split=[
            "train: d00.dat (500 samples at 3 min, 25 h, fault-free)",
            "calibration (the matched limits): d00_te.dat (960 samples, 48 h, fault-free)",
            "fault-free scoring: the first 160 samples (8 h) of each d01_te … d21_te, before "
            "the onset (each run its own noise; d05_te's first 160 samples repeat d04_te's "
            "value for value and are counted once)",
            "fault scoring: d01_te … d21_te, the fault from sample 160 (8 h) to the end (40 h)",
            "tuning (not scored here): d01.dat … d21.dat, faulty from their first sample",
            "loop declared to the unit build (issue 34, docs/how-to/unit-loops.md): "
            + ", ".join(TEP_LOOPS),
        ],
    )


_TEN_YEARS = pd.Timestamp("2030-01-01") - pd.Timestamp("2020-01-01")


def tep_studio_dir(path: str | Path | None = None) -> Path:
    p = path or os.environ.get("DIAG_TEP_STUDIO_DIR")
    d = Path(p).expanduser() if p else CACHE / "tep-studio"
    if not (d / "manifest.json").exists():
        raise DataMissing(
            f"tep-studio runs not found in {d} (set DIAG_TEP_STUDIO_DIR, or run "
            "`make tep-studio-data`, which builds tep-studio 0.2.0 in its own environment "
            "and simulates them)"
        )
    return d


def load_tep_studio(
    path: str | Path | None = None,
    faults: Sequence[str] | None = None,
    need: Sequence[str] = ("train", "calibration", "free", "fault"),
) -> PublicPlant:
    """tep-studio runs (see ``benchmarks/tep_studio_runs.py`` for the seeds and roles);
    :class:`DataMissing` when a role in ``need`` has none (a tuning check needs no scoring
    runs: ``need=("train", "calibration", "tuning")``)."""
    d = tep_studio_dir(path)
    man = json.loads((d / "manifest.json").read_text())["runs"]
    want = set(faults) if faults else None
    roles: dict[str, list[PlantRun]] = {
        r: [] for r in ("train", "calibration", "free", "fault", "tuning")
    }
    for name, m in sorted(man.items()):
        f = d / f"{name}.csv"
        if not f.exists():
            continue
        idv = f"IDV{m['idv']}" if m.get("idv") else None
        if idv and want is not None and idv not in want:
            continue
        frame = pd.read_csv(f, index_col="ts", parse_dates=["ts"])
        # a run that trips the shutdown records its last step too: on the 3-min grid it can
        # fall on the sample before it
        frame = frame[~frame.index.duplicated(keep="first")]
        if frame.index[0].year >= 2030:  # the first runs were dated from 2030; a historian
            frame.index = frame.index - _TEN_YEARS  # refuses times a year ahead
        onset = None
        if idv:
            onset = int(round(m["onset_h"] * 3600 / TEP_PERIOD_S))
        tags = TEP_STUDIO_FAULTS[idv][1] if idv else ()
        roles[m["role"]].append(PlantRun(name, frame[list(TEP_TAGS)], idv, onset, tags))
    missing = [r for r in need if not roles[r]]
    if missing:
        raise DataMissing(f"tep-studio runs in {d}: none for {', '.join(missing)}")
    return _tep_plant(
        "tep-studio",
        "Tennessee Eastman, tep-studio 0.2.0 (Ricker's modified TEP, decentralised control)",
        roles,
        {k: v[0] for k, v in TEP_STUDIO_FAULTS.items() if k != "IDV21"},
        d,
        loops=TEP_STUDIO_LOOPS,
        split=[
            "train: fault-free seeds 1 and 2, 5 days each (10 days at 3 min)",
            "calibration (the matched limits): fault-free seeds 11, 12, 13, 3 days each",
            "fault-free scoring: seeds 21, 22, 23, 2 days each",
            "fault scoring: IDV(1) … IDV(20), seeds 201 and 202, 48 h, the fault from hour 8",
            "tuning (not scored here): IDV(1) … IDV(20), seed 101",
            "loops declared to the unit build (Ricker's control with fixed set-points, "
            "docs/how-to/unit-loops.md): " + ", ".join(TEP_STUDIO_LOOPS),
        ],
    )


# ---------------------------------------------------------------- SKAB

SKAB_TAGS: dict[str, tuple[str, str]] = {
    "Accelerometer1RMS": ("g", "vibration acceleration 1 (RMS)"),
    "Accelerometer2RMS": ("g", "vibration acceleration 2 (RMS)"),
    "Current": ("A", "motor current"),
    "Pressure": ("bar", "pressure after the pump"),
    "Temperature": ("°C", "motor body temperature"),
    "Thermocouple": ("°C", "fluid temperature in the loop"),
    "Voltage": ("V", "motor voltage"),
    "Volume Flow RateRMS": ("l/min", "circulation flow rate"),
}
#: the experiment folders and the tags a fault there acts on (for naming), per the SKAB
#: data README: valve1 closes the valve at the pump's inlet, valve2 the one at its outlet;
#: other/1–4 leaks and additions of fluid, 5–9 rotor imbalance, 10–11 more water in the
#: circuit, 12–13 cavitation, 14 hotter water
_SKAB_KIND = {
    "valve1": ("inlet valve closing", ("Volume Flow RateRMS", "Pressure")),
    "valve2": ("outlet valve closing", ("Volume Flow RateRMS", "Pressure")),
}
_SKAB_OTHER = {
    **{k: ("fluid leak or addition", ("Volume Flow RateRMS", "Pressure")) for k in (1, 2, 3, 4)},
    **{k: ("rotor imbalance", ("Accelerometer1RMS", "Accelerometer2RMS")) for k in (5, 6, 7, 8, 9)},
    **{k: ("more water in the circuit", ("Pressure",)) for k in (10, 11)},
    **{k: ("cavitation", ("Volume Flow RateRMS", "Pressure")) for k in (12, 13)},
    14: ("hotter water supply", ("Thermocouple",)),
}
#: the SKAB protocol's training rows per run
SKAB_LEARN = 400
#: rows per calibration run cut from anomaly-free.csv (about a SKAB run's length)
SKAB_CHUNK = 1150


class _Source:
    """Files under ``data/`` of a SKAB clone, or of a bare mirror (``git show``)."""

    def __init__(self, root: Path, bare: bool):
        self.root, self.bare = root, bare

    def list(self) -> list[str]:
        if self.bare:
            out = subprocess.run(
                ["git", "-C", str(self.root), "ls-tree", "-r", "--name-only", "HEAD", "data/"],
                capture_output=True, text=True, check=True, timeout=60,
            ).stdout  # fmt: skip
            return [p[len("data/") :] for p in out.split() if p.endswith(".csv")]
        base = self.root
        return sorted(str(p.relative_to(base)) for p in base.rglob("*.csv"))

    def read(self, rel: str) -> pd.DataFrame:
        if self.bare:
            text = subprocess.run(
                ["git", "-C", str(self.root), "show", f"HEAD:data/{rel}"],
                capture_output=True, text=True, check=True, timeout=60,
            ).stdout  # fmt: skip
            buf = io.StringIO(text)
        else:
            buf = self.root / rel
        return pd.read_csv(buf, sep=";", index_col="datetime", parse_dates=["datetime"])

    def __str__(self) -> str:
        return f"{self.root} ({'git mirror' if self.bare else 'folder'})"


def skab_source(path: str | Path | None = None) -> _Source:
    """Where SKAB is: ``path``, ``$DIAG_SKAB_DIR`` (a clone or its ``data/``), else the team's
    mirror."""
    p = path or os.environ.get("DIAG_SKAB_DIR")
    cands = [Path(p).expanduser()] if p else [SKAB_MIRROR]
    for c in cands:
        if (c / "data" / "anomaly-free").is_dir():
            return _Source(c / "data", False)
        if (c / "anomaly-free").is_dir():
            return _Source(c, False)
        if (c / "HEAD").exists() and (c / "objects").is_dir():
            return _Source(c, True)
    raise DataMissing(
        f"SKAB not found at {cands[0]} (set DIAG_SKAB_DIR to a `git clone "
        "https://github.com/waico/SKAB`)"
    )


def _skab_split(folder: str, number: int, order: int) -> str:
    """Tuning or scoring, fixed before any result: every third run of a folder (by number,
    from the first) is for tuning, the others are scored."""
    return "tuning" if order % 3 == 0 else "fault"


def load_skab(path: str | Path | None = None) -> PublicPlant:
    """SKAB v0.9: 34 labelled runs of 1 s (valve1 16, valve2 4, other 14) and one fault-free
    run of 9,405 s. Per the protocol each run's first 400 rows are learned from and the rest
    scored against its ``anomaly`` labels. Calibration: ``anomaly-free.csv`` cut into runs of
    1,150 rows, each learned from on its first 400, and the tuning runs' samples before their
    anomaly.
    Tuning: every third run of each folder (valve1 0, 3, 6, 9, 12, 15; valve2 0, 3; other 1,
    4, 7, 10, 13); the other 21 are scored."""
    src = skab_source(path)
    files = src.list()
    if "anomaly-free/anomaly-free.csv" not in files:
        raise DataMissing(f"SKAB at {src}: no anomaly-free/anomaly-free.csv")
    tags = list(SKAB_TAGS)
    free_all = src.read("anomaly-free/anomaly-free.csv")[tags]
    cal = []
    for k in range(len(free_all) // SKAB_CHUNK):
        part = free_all.iloc[k * SKAB_CHUNK : (k + 1) * SKAB_CHUNK]
        cal.append(PlantRun(f"anomaly-free[{k}]", part, learn=SKAB_LEARN))
    roles: dict[str, list[PlantRun]] = {"fault": [], "tuning": []}
    for folder in ("valve1", "valve2", "other"):
        nums = sorted(int(Path(f).stem) for f in files if f.startswith(folder + "/"))
        for order, n in enumerate(nums):
            df = src.read(f"{folder}/{n}.csv")
            kind, ftags = _SKAB_KIND.get(folder) or _SKAB_OTHER.get(n, ("other", ()))
            labels = df["anomaly"].to_numpy(float)
            after = np.flatnonzero(labels[SKAB_LEARN:] > 0)
            onset = SKAB_LEARN + int(after[0]) if after.size else len(df)
            run = PlantRun(
                f"{folder}/{n}", df[tags], f"{folder}: {kind}", onset, ftags, labels, SKAB_LEARN
            )
            roles[_skab_split(folder, n, order)].append(run)
    # the tuning runs' normal samples after their first 400 calibrate too: anomaly-free.csv
    # alone (recorded on another day) left PCA at 9.7 % false alarms on the scoring runs at
    # every target from 0.1 % to 5 %
    cal += roles["tuning"]
    return PublicPlant(
        name="skab",
        title="SKAB v0.9 (Skoltech Anomaly Benchmark, water-circulation rig, 1 s)",
        period_s=1.0,
        tags=tags,
        tag_info=SKAB_TAGS,
        train=[],
        calibration=cal,
        free=[],
        faults=roles["fault"],
        tuning=roles["tuning"],
        per_run=True,
        source=str(src),
        split=[
            "per run, the protocol's: learn on the first 400 samples, score the rest",
            f"calibration (the matched limits): anomaly-free.csv cut into "
            f"{len(cal) - len(roles['tuning'])} runs of {SKAB_CHUNK} samples, each learned "
            "from on its first 400, and the tuning runs' samples after their first 400 and "
            "before their anomaly (added after a first run: anomaly-free.csv alone, recorded "
            "on another day, left PCA at 9.7 % false alarms on the scoring runs at every "
            "target; the label-0 samples after an anomaly were counted until 2026-12-02: the "
            "fault's own alarm held by the off-delay, which set every method's limits at "
            "0.001–0.02 at the largest tuning faults seen to their end)",
            "scoring: valve1 1, 2, 4, 5, 7, 8, 10, 11, 13, 14; valve2 1, 2; other 2, 3, 5, 6, "
            "8, 9, 11, 12, 14 (21 runs); false alarms in the matched tables are their samples "
            "after the first 400 and before the anomaly; SKAB's own FAR (every label-0 sample "
            "after the first 400, the recovery after the anomaly included) is in its table",
            "tuning (not scored here): valve1 0, 3, 6, 9, 12, 15; valve2 0, 3; other 1, 4, 7, "
            "10, 13",
        ],
    )
