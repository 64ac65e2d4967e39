"""Two small plants unlike the valve, to show detection on data the product was not tuned on.

* :func:`tank_rig` — a laboratory two-tank rig sampled every second, in short runs (a few
  hundred samples each), as a teaching rig records them: a pump fills tank 1, which drains
  through a pipe into tank 2, which drains to a sump (Torricelli outflows, ``q = a √(2 g h)``).
  Measured: pump command ``U`` (%), pump flow ``Q`` (cm³/s), levels ``H1``, ``H2`` (cm).
* :func:`heat_exchanger` — a counter-flow heat exchanger sampled every minute for weeks, whose
  outlet temperatures depend on three interacting inputs: hot and cold flows ``FH``, ``FC``
  (kg/s) and hot inlet temperature ``THI`` (°C), through the effectiveness–NTU relation with a
  flow-dependent heat-transfer coefficient and a few minutes of thermal lag. Measured also:
  the cold inlet ``TCI`` and the outlets ``THO``, ``TCO``.

Each takes a seed and a list of :class:`RigFault` (faults are simulated, not pasted: a leak
drains the tank, fouling lowers the heat transfer from its onset); the same seed gives the same
data, with or without faults, up to the onset. Frames are indexed by UTC time on a regular grid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from diag_plugin.simulate.tagtable import tag_table

G = 981.0  # cm/s²
START = pd.Timestamp("2026-03-02", tz="UTC")

#: the tank rig's tags: (unit, lo, hi, description)
TANK_TAGS = tag_table(
    """
U  | %     | 0 | 100 | pump command
Q  | cm3/s | 0 | 120 | pump flow
H1 | cm    | 0 | 40  | tank 1 level
H2 | cm    | 0 | 40  | tank 2 level
"""
)
#: the heat exchanger's tags
HX_TAGS = tag_table(
    """
FH  | kg/s | 0  | 5   | hot flow
FC  | kg/s | 0  | 6   | cold flow
THI | degC | 50 | 110 | hot inlet temperature
TCI | degC | 0  | 40  | cold inlet temperature
THO | degC | 0  | 110 | hot outlet temperature
TCO | degC | 0  | 110 | cold outlet temperature
"""
)


@dataclass(frozen=True)
class RigFault:
    """A fault from ``onset`` (seconds after the run's start) on, of size ``strength``.

    Tank rig: ``pump`` (pump wear: flow × (1 − s)), ``leak`` (a hole in tank 1 of s cm²),
    ``clog`` (the pipe between the tanks: area × (1 − s)), ``h2_bias`` (H2 reads s cm high),
    ``q_bias`` (the flow meter reads s cm³/s high). Heat exchanger: ``fouling`` (UA × (1 − s)),
    ``tho_bias`` (THO reads s °C high), ``fc_bias`` (FC reads s · 100 % high), ``bypass`` (a
    share s of the hot flow bypasses the exchanger).
    """

    kind: str
    strength: float
    onset: float


def held_levels(
    rng: np.random.Generator, n: int, lo: float, hi: float, hold: tuple[int, int]
) -> np.ndarray:
    """``n`` samples of levels drawn uniformly from ``lo``–``hi``, each held for a number of
    samples drawn from ``hold`` (low inclusive, high exclusive): set-points an operator moves."""
    out = np.empty(n)
    i = 0
    while i < n:
        h = int(rng.integers(*hold))
        out[i : i + h] = rng.uniform(lo, hi)
        i += h
    return out


def _on(faults, kind: str, t: np.ndarray) -> np.ndarray:
    out = np.zeros_like(t, dtype=float)
    for f in faults:
        if f.kind == kind:
            out = np.where(t >= f.onset, f.strength, out)
    return out


def _index(n: int, period_s: float, start: pd.Timestamp) -> pd.DatetimeIndex:
    return pd.date_range(start, periods=n, freq=pd.Timedelta(seconds=period_s), name="ts")


def tank_rig(
    seconds: int = 600,
    *,
    seed: int = 0,
    faults: tuple[RigFault, ...] = (),
    start: pd.Timestamp = START,
) -> pd.DataFrame:
    """One run of the two-tank rig at 1 s (see module doc): the pump command steps every
    15–60 s to a random level in 25–95 %, the levels start anywhere in 2–25 cm."""
    known = {"pump", "leak", "clog", "h2_bias", "q_bias"}
    for f in faults:
        if f.kind not in known:
            raise ValueError(f"tank rig fault {f.kind!r} (known: {', '.join(sorted(known))})")
    rng = np.random.default_rng([seed, 24])
    a1, a12, a2 = 50.0, 0.5, 0.42  # tank area cm², pipe and drain areas cm²
    qmax = 100.0
    sub = 10  # integration steps per second
    n = int(seconds)
    t = np.arange(n, dtype=float)
    u = held_levels(rng, n, 25.0, 95.0, (15, 61))
    h1, h2 = rng.uniform(2.0, 25.0, 2)
    wear, leak, clog = (_on(faults, k, t) for k in ("pump", "leak", "clog"))
    q = qmax * (u / 100.0) ** 1.3 * (1.0 - wear)
    H1, H2 = np.empty(n), np.empty(n)
    dt = 1.0 / sub
    for k in range(n):
        for _ in range(sub):
            q12 = a12 * (1.0 - clog[k]) * math.sqrt(2 * G * max(h1, 0.0))
            ql = leak[k] * math.sqrt(2 * G * max(h1, 0.0))
            q2 = a2 * math.sqrt(2 * G * max(h2, 0.0))
            h1 = max(h1 + dt * (q[k] - q12 - ql) / a1, 0.0)
            h2 = max(h2 + dt * (q12 - q2) / a1, 0.0)
        H1[k], H2[k] = h1, h2
    frame = pd.DataFrame(
        {
            "U": u,
            "Q": q * (1 + 0.01 * rng.standard_normal(n)) + _on(faults, "q_bias", t),
            "H1": H1 + 0.05 * rng.standard_normal(n),
            "H2": H2 + 0.05 * rng.standard_normal(n) + _on(faults, "h2_bias", t),
        },
        index=_index(n, 1.0, start),
    )
    return frame


def heat_exchanger(
    days: float = 14.0,
    *,
    seed: int = 0,
    faults: tuple[RigFault, ...] = (),
    start: pd.Timestamp = START,
) -> pd.DataFrame:
    """The heat exchanger at 60 s (see module doc): flows follow set-points that change every
    20 min – 4 h with a daily load cycle, the hot inlet temperature wanders slowly."""
    known = {"fouling", "tho_bias", "fc_bias", "bypass"}
    for f in faults:
        if f.kind not in known:
            raise ValueError(f"heat exchanger fault {f.kind!r} (known: {', '.join(sorted(known))})")
    rng = np.random.default_rng([seed, 25])
    dt = 60.0
    n = int(round(days * 86400 / dt))
    t = np.arange(n) * dt
    day = np.sin(2 * np.pi * t / 86400.0)

    def setpoints(lo: float, hi: float) -> np.ndarray:
        return held_levels(rng, n, lo, hi, (20, 240))

    def wander(sd: float, tau_s: float) -> np.ndarray:
        a = math.exp(-dt / tau_s)
        e = rng.standard_normal(n) * sd * math.sqrt(1 - a * a)
        out = np.empty(n)
        x = 0.0
        for k in range(n):
            x = a * x + e[k]
            out[k] = x
        return out

    fh = np.clip(setpoints(0.8, 4.0) * (1 + 0.12 * day) + 0.03 * rng.standard_normal(n), 0.3, 5)
    fc = np.clip(setpoints(1.0, 5.0) + 0.04 * rng.standard_normal(n), 0.4, 6)
    thi = np.clip(85 + wander(7.0, 6 * 3600) + 3 * day, 55, 108)
    tci = 15 + 4 * np.sin(2 * np.pi * (t / 86400.0 - 0.3)) + wander(1.0, 3 * 3600)
    foul, bypass = _on(faults, "fouling", t), _on(faults, "bypass", t)
    cp = 4.18
    fhx = fh * (1 - bypass)  # the hot flow through the exchanger
    ch, cc = fhx * cp, fc * cp
    ua = 9.0 * (fhx**0.8 * fc**0.8) / (fhx**0.8 + fc**0.8) * 2.0 * (1 - foul)  # kW/K
    cmin, cmax = np.minimum(ch, cc), np.maximum(ch, cc)
    cr = cmin / cmax
    ntu = ua / cmin
    e = np.exp(-ntu * (1 - cr))
    eff = np.where(np.abs(1 - cr) < 1e-9, ntu / (1 + ntu), (1 - e) / (1 - cr * e))
    q = eff * cmin * (thi - tci)
    tho_ss = thi - q / ch
    tho_ss = (1 - bypass) * tho_ss + bypass * thi  # the bypass mixes back before the sensor
    tco_ss = tci + q / cc
    a = math.exp(-dt / 300.0)  # five minutes of thermal lag
    tho, tco = np.empty(n), np.empty(n)
    x, y = tho_ss[0], tco_ss[0]
    for k in range(n):
        x = a * x + (1 - a) * tho_ss[k]
        y = a * y + (1 - a) * tco_ss[k]
        tho[k], tco[k] = x, y
    noise = lambda sd: sd * rng.standard_normal(n)  # noqa: E731
    return pd.DataFrame(
        {
            "FH": fh + noise(0.02),
            "FC": fc * (1 + _on(faults, "fc_bias", t)) + noise(0.02),
            "THI": thi + noise(0.1),
            "TCI": tci + noise(0.1),
            "THO": tho + noise(0.1) + _on(faults, "tho_bias", t),
            "TCO": tco + noise(0.1),
        },
        index=_index(n, dt, start),
    )


def tag_info(tags: dict) -> dict:
    """The plant's tags as :class:`historian.taginfo.TagInfo` (unit, nominal range)."""
    from historian.taginfo import TagInfo

    return {
        k: TagInfo(k, unit=u, lo=lo, hi=hi, description=d) for k, (u, lo, hi, d) in tags.items()
    }


#: the units of the two plants: test → (output, inputs, sets per input; None: what the data
#: fill). The tanks' tests are their mass balances, ``A dh/dt = inflow − outflow(h)``, read
#: from the level and its rate (models of ``H[k]`` from ``H[k-1]`` are mostly the identity,
#: and the rule grid's own error, ~1 % of span, drowns a leak's 0.5 cm per second)
UNITS = {
    "tank": {
        "r_q": ("Q[k]", ["U[k]"], None),  # the pump's curve
        "r_1": ("Q[k]", ["H1[k]", "rate(H1)[k]"], None),  # tank 1: inflow = A dH1/dt + out(H1)
        "r_2": ("H1[k]", ["H2[k]", "rate(H2)[k]"], None),  # tank 2: its inflow comes from H1
    },
    "hx": {
        "r_h": ("THO[k]", ["FH[k]", "FC[k]", "THI[k]"], None),  # hot outlet
        "r_c": ("TCO[k]", ["FH[k]", "FC[k]", "THI[k]"], None),  # cold outlet
    },
}
PERIODS = {"tank": "1s", "hx": "60s"}


def build_unit(
    folder, plant: str, frame: pd.DataFrame, *, levels: int | None = None, sets: int | None = None
):
    """Rule bases of ``plant``'s models trained on ``frame`` and its unit file (no thresholds
    yet) in ``folder``; returns the unit file's path. ``levels=0``: the fine grids alone;
    ``sets``: every input's sets (default :data:`UNITS`')."""
    from pathlib import Path

    from diag_plugin.diagnose.unitfile import new_unit_text
    from diag_plugin.training.chunked import train
    from diag_plugin.workbench.model_edit import new_model

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    info = tag_info(TANK_TAGS if plant == "tank" else HX_TAGS)
    period = PERIODS[plant]
    a, b = frame.index[0], frame.index[-1] + pd.Timedelta(period)
    names = {}
    for test, (out, inputs, default) in UNITS[plant].items():
        path = folder / f"{plant}_{test}.toml"
        path.unlink(missing_ok=True)
        rb = new_model(
            path, f"{plant}_{test}", out, inputs, frame=frame, tag_info=info,
            sets=sets or default, period=period,
        )  # fmt: skip
        if levels is not None:
            rb.doc["rules"]["levels"] = levels
            rb.edited()
        res = train(rb, lambda x, y: frame[(frame.index >= x) & (frame.index < y)], a, b)
        rb.apply_training(res.model, {"from": a.isoformat(), "to": b.isoformat()})
        rb.save()
        names[test] = path.name
    unit = folder / f"{plant}.unit.toml"
    unit.write_text(new_unit_text(plant, names), encoding="utf-8")
    return unit


#: samples without data between two runs: longer than the unit's filter memory (100 samples),
#: so each run starts from rest, as on a rig switched off between runs
PAUSE = 120


def runs(plant: str, seeds, *, faults=(), length=None) -> pd.DataFrame:
    """Runs of ``plant`` (one per seed) on one time grid, :data:`PAUSE` samples without data
    (NaN) between two of them (the tank rig: runs of ``length`` s, default 600; the heat
    exchanger: runs of ``length`` days, default 7)."""
    parts = []
    t = START
    step = pd.Timedelta(PERIODS[plant])
    for i, s in enumerate(seeds):
        if i:
            gap = _index(PAUSE, step.total_seconds(), t)
            parts.append(pd.DataFrame(np.nan, index=gap, columns=parts[-1].columns))
            t = gap[-1] + step
        if plant == "tank":
            f = tank_rig(int(length or 600), seed=s, faults=tuple(faults), start=t)
        else:
            f = heat_exchanger(float(length or 7), seed=s, faults=tuple(faults), start=t)
        parts.append(f)
        t = f.index[-1] + step
    return pd.concat(parts)
