"""Servomotor–valve assembly simulator after the DAMADICS benchmark actuator.

The plant: a flow controller (PI, set-point schedule) drives CV; the actuator —
positioner (input filter, P controller, E/P transducer), pneumatic chamber,
spring-diaphragm servomotor with stick–slip friction, equal-percentage valve
with choked flow, a bypass valve — sets the flow F from the process pressures
P1, P2 and temperature T; transducers measure everything with their ranges and
noise. Physics: Bartyś & de las Heras, "Actuator simulation of the DAMADICS
benchmark actuator system", IFAC SAFEPROCESS 2003, and the Hull January 2002
slides; faults f1–f19: DABLib v1.22 Tables 3–22 (see :mod:`.faults`).
The compiled loop is in :mod:`._kernel`, the valve physics in :mod:`.physics`,
the process conditions in :mod:`.process`.

Conventions (chosen for this simulator, documented here once):

* ``X`` is the valve opening in % (0 closed, 100 fully open) and the valve is
  air-to-open (fail-closed): more chamber pressure opens it and ``F`` rises with
  ``X``. The real Lublin actuator 3 is fail-open and its X reads as closing (F
  falls as X rises); DAMADICS equations written for the closing ``X`` are
  converted (``1 - X``) where that matters (f2, f3, f8).
* Pressures P1, P2 are absolute (kPa), P0 and Pch gauge (kPa).
* The ``X`` tag is the positioner's displacement sensor (the Lublin X comes from
  the positioner), so f13 (sensor gain) and f15 (feedback backlash) act both on
  the positioner's feedback and on the ``X`` tag. ``ValveParams.f13_mode =
  "measurement"`` instead applies f13 to the ``X`` tag only (the X-transducer
  fault of Kościelny, Syfert & Bartyś's diagnostic matrix, which leaves F(U)
  unchanged).
* ``P0`` is the E/P output pressure as read by the positioner's pressure sensor
  (f14 acts on the reading only, DABLib Table 17).
* CV is the controller's digital output: no transducer noise.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import pandas as pd

from historian.taginfo import TagInfo

from . import _kernel as K
from .faults import FAULTS, N_FAULTS, FaultSpec, fault_index, fault_truth
from .process import ProcessGenerator, ProcessParams
from .tagtable import tag_infos

__all__ = [
    "TAGS",
    "FaultSpec",
    "ValveParams",
    "fault_truth",
    "simulate_valve",
]

#: metadata of the output tags: unit, nominal (transducer) range, description. Ranges:
#: DABLib Table 2 (P1, P2 0–4 MPa, T1 0–200 °C, X 0–100 %, F 0–40 t/h) and Table 23
#: (chamber and supply pressure 0–0.6 MPa).
TAGS: dict[str, TagInfo] = tag_infos(
    """
CV  | %   | 0 | 100  | controller output to the positioner
P1  | kPa | 0 | 4000 | valve inlet pressure (absolute)
P2  | kPa | 0 | 4000 | valve outlet pressure (absolute)
T1  | °C  | 0 | 200  | medium temperature at the valve
X   | %   | 0 | 100  | rod travel, % open (positioner displacement sensor)
F   | t/h | 0 | 40   | flow through the valve (and the bypass)
P0  | kPa | 0 | 600  | E/P transducer output pressure (gauge)
Pch | kPa | 0 | 600  | servomotor chamber pressure (gauge)
"""
)


def _default_spans() -> dict[str, tuple[float, float]]:
    return {k: v.span for k, v in TAGS.items()}


def _default_noise() -> dict[str, float]:
    # transducer noise, standard deviation in % of span
    return {"CV": 0.0, "P1": 0.2, "P2": 0.2, "T1": 0.1, "X": 0.2, "F": 0.5, "P0": 0.2, "Pch": 0.2}


@dataclass
class ValveParams:
    """Every physical constant and option of the simulated plant (units in comments).

    Defaults describe a feed-water valve like the Lublin sugar factory's actuator 3
    (DN50 equal-percentage valve, type-37-like spring-diaphragm servomotor, P
    positioner) with realistic but clearly visible friction. Friction (hysteresis)
    is set by ``hysteresis`` (open-loop width, DABLib Table 7 ``Db``) and
    ``stick_ratio``; the closed-loop hysteresis of X against CV is about
    ``hysteresis·(1 + stick_ratio)/2 / (1 + positioner stiffness / spring stiffness)``,
    ≈ 1.1 % of travel with the defaults; raise ``hysteresis`` or lower
    ``positioner_gain`` for more.
    """

    # --- numerics
    dt_s: float = 0.1  # internal time step, s; must divide 1 s and the output period
    warmup_s: float = 1800.0  # simulated before the start and discarded, s
    # --- positioner (Bartyś & de las Heras 2003 §6.1)
    input_tau_s: float = 0.7  # input low-pass filter time constant, s
    # P controller gain, CVI per unit travel error; 0: no positioner, CV drives the E/P
    # converter open-loop (the chain U -> P0 -> X -> F of Kościelny et al.'s Table 4)
    positioner_gain: float = 10.0
    supply_kpa: float = 500.0  # positioner supply pressure Pz = E/P full scale, kPa gauge
    dead_time_s: float = 0.0  # extra transport delay between CV and the positioner, s
    # --- pneumatic chamber (2003 eq. 6): tau = V / (R T0 Cq)
    chamber_tau_s: float = 0.5  # s
    # --- servomotor (2003 eq. 1)
    diaphragm_area_m2: float = 0.04  # effective diaphragm area Ae, m²
    spring_n_per_m: float = 310000.0  # spring constant ks, N/m
    diaphragm_n_per_m: float = 5000.0  # diaphragm constant kd, N/m
    stroke_m: float = 0.0381  # nominal travel (DABLib Table 7: 0.0381 m)
    spring_preload_m: float = 0.0127  # initial spring compression x0, m (≈100 kPa bench set)
    moving_mass_kg: float = 15.0  # rod, plug and diaphragm plate, kg (weight only)
    unbalanced_area_m2: float = 4e-4  # plug area the pressure drop pushes open, m²
    # --- friction (2003 "Model of friction", Karnopp stick–slip)
    hysteresis: float = 0.12  # open-loop hysteresis width Db0, fraction of travel
    stick_ratio: float = 1.3  # static / Coulomb friction force
    rest_speed: float = 0.002  # below this speed (travel/s) the rod sticks again, 1/s
    # --- valve (2003 eqs. 7–9)
    kvs: float = 16.0  # Kv at full opening, m³/h
    rangeability: float = 50.0  # equal-percentage rangeability R
    km0: float = 0.8  # recovery coefficient Km = km0 - km1·X
    km1: float = 0.2
    bypass_kvs: float = 8.0  # bypass valve Kv fully open (linear), m³/h
    # --- flow controller (PI, 1 s period)
    ctrl_gain: float = 0.5  # % CV per t/h
    ctrl_ti_s: float = 15.0  # integral time, s
    # --- fault details
    f7_rise0_c: float = 120.0  # f7: temperature rise as soon as fs > 0, K (Table 10: 200)
    f7_rise_c: float = 100.0  # f7: further rise per unit strength, K (Table 10: 100)
    leak_per_kpa: float = 2e-3  # f9/f10: leak/positioner conductance per kPa per fs (Table 12)
    f13_mode: Literal["feedback", "measurement"] = "feedback"
    # --- transducers
    spans: dict[str, tuple[float, float]] = field(default_factory=_default_spans)
    noise_pct: dict[str, float] = field(default_factory=_default_noise)  # sd, % of span
    noise_scale: float = 1.0  # multiplies every noise level (0: noise-free)
    # --- process conditions around the valve
    process: ProcessParams = field(default_factory=ProcessParams)

    def stiffness_n(self) -> float:
        """(ks + kd)·stroke: spring force per unit relative travel, N."""
        return (self.spring_n_per_m + self.diaphragm_n_per_m) * self.stroke_m

    def calibration(self) -> tuple[float, float]:
        """Positioner zero/span (a0, a1) so that a healthy actuator settles at X = CV.

        From the quasi-static force balance (2003 eq. 1 without friction) at the
        nominal pressure drop: the chamber pressure needed at travel x is
        ``c0 + c1 x``; the P positioner gives ``P0 = Pz (1 + Kp (SP - x)) / 2``, and
        without a positioner (``positioner_gain = 0``) ``P0 = Pz (1 + SP) / 2``.
        """
        k = self.stiffness_n()
        dp = (self.process.p1_mean_kpa - self.process.p2_mean_kpa) * 1000.0
        x0r = self.spring_preload_m / self.stroke_m
        mg = self.moving_mass_kg * 9.81
        area = self.diaphragm_area_m2 * 1000.0  # N per kPa
        c0 = (k * x0r + mg - self.unbalanced_area_m2 * dp) / area
        c1 = (k + self.unbalanced_area_m2 * dp) / area
        kp = self.positioner_gain
        if kp <= 0:  # no positioner: P0 = Pz (1 + SP) / 2 must equal c0 + c1·CV
            return 2 * c0 / self.supply_kpa - 1, 2 * c1 / self.supply_kpa
        return (2 * c0 / self.supply_kpa - 1) / kp, 1 + 2 * c1 / (self.supply_kpa * kp)

    def vector(self) -> np.ndarray:
        """The kernel's parameter vector (see ``_kernel.P_*``)."""
        a0, a1 = self.calibration()
        prm = np.zeros(K.N_PRM)
        prm[K.P_DT] = self.dt_s
        tau_f = self.input_tau_s
        prm[K.P_ALPHA_F] = 1.0 - math.exp(-self.dt_s / tau_f) if tau_f > 0 else 1.0
        prm[K.P_TAU_CH] = self.chamber_tau_s
        prm[K.P_KP] = self.positioner_gain
        prm[K.P_PZ] = self.supply_kpa
        prm[K.P_A0] = a0
        prm[K.P_A1] = a1
        prm[K.P_AE] = self.diaphragm_area_m2
        prm[K.P_KS] = self.spring_n_per_m
        prm[K.P_KD] = self.diaphragm_n_per_m
        prm[K.P_L] = self.stroke_m
        prm[K.P_X0] = self.spring_preload_m
        prm[K.P_MG] = self.moving_mass_kg * 9.81
        prm[K.P_AU] = self.unbalanced_area_m2
        prm[K.P_H0] = self.hysteresis
        prm[K.P_STICK] = self.stick_ratio
        prm[K.P_VMIN] = self.rest_speed
        prm[K.P_KVS] = self.kvs
        prm[K.P_RANGE] = self.rangeability
        prm[K.P_KM0] = self.km0
        prm[K.P_KM1] = self.km1
        prm[K.P_KVS_BP] = self.bypass_kvs
        prm[K.P_KC] = self.ctrl_gain
        prm[K.P_TI] = self.ctrl_ti_s
        prm[K.P_F_SPAN] = self.spans["F"][1]
        prm[K.P_F7_DT0] = self.f7_rise0_c
        prm[K.P_F7_DT1] = self.f7_rise_c
        prm[K.P_LEAK] = self.leak_per_kpa
        return prm  # fmt: skip


def _steps(total: float, dt: float, what: str) -> int:
    n = round(total / dt)
    if n < 1 or abs(n * dt - total) > 1e-9 * max(1.0, total):
        raise ValueError(f"{what} ({total:g} s) must be a whole multiple of dt_s ({dt:g} s)")
    return n


def _utc(ts: str | pd.Timestamp) -> pd.Timestamp:
    ts = pd.Timestamp(ts)
    return ts.tz_localize("UTC") if ts.tzinfo is None else ts.tz_convert("UTC")


def simulate_valve(
    days: float,
    *,
    period_s: float = 10.0,
    start: str | pd.Timestamp = "2026-01-01",
    seed: int = 0,
    faults: Sequence[FaultSpec] = (),
    params: ValveParams | None = None,
    internals: bool = False,
) -> pd.DataFrame:
    """Simulate ``days`` of the actuator and return the measured tags every ``period_s``.

    Returns a DataFrame indexed by a UTC DatetimeIndex "ts" (first sample at
    ``start``) with float columns CV, P1, P2, T1, X, F, P0, Pch (see :data:`TAGS`):
    instantaneous transducer readings with noise, limited to the transducer
    ranges. The fault truth is in ``df.attrs["faults"]`` (list of dicts; use
    :func:`fault_truth` for the strengths at each sample). ``internals=True`` adds
    the true travel ``X_true`` (%), the true flow ``F_true`` (t/h) and the flow
    set-point ``SP`` (t/h). The result depends only on the arguments: same seed,
    same data; a fault changes nothing before its onset.
    """
    p = params or ValveParams()
    if not (days > 0 and math.isfinite(days)):
        raise ValueError(f"days must be a positive number, not {days!r}")
    for spec in faults:
        if not isinstance(spec, FaultSpec):
            raise TypeError(f"faults must be FaultSpec objects, not {type(spec).__name__}")
    dt = float(p.dt_s)
    sps = _steps(1.0, dt, "one second")
    spo = _steps(float(period_s), dt, "period_s")
    start_ts = _utc(start)
    n_out = int(round(days * 86400.0 / period_s))
    if n_out < 1:
        raise ValueError(f"{days} days at {period_s} s gives no samples")
    n_warm = int(math.ceil(p.warmup_s / period_s))
    n_total = n_warm + n_out
    origin_s = -n_warm * period_s  # seconds relative to start

    # chunk: whole seconds and whole output periods, about one day
    unit = sps * spo // math.gcd(sps, spo)
    per_chunk = unit * max(1, round(86400.0 / dt / unit))

    prm = p.vector()
    state = np.zeros(K.N_STATE)
    x_init = 0.5
    state[K.S_SPF] = x_init
    state[K.S_X] = x_init
    state[K.S_XB] = x_init
    state[K.S_CV] = 50.0
    state[K.S_I] = 50.0
    # chamber pressure that holds x_init (quasi-static force balance)
    kn = p.stiffness_n()
    dp0 = (p.process.p1_mean_kpa - p.process.p2_mean_kpa) * 1000.0
    state[K.S_P] = (
        kn * (x_init + p.spring_preload_m / p.stroke_m)
        + p.moving_mass_kg * 9.81
        - p.unbalanced_area_m2 * dp0 * (1 - x_init)
    ) / (p.diaphragm_area_m2 * 1000.0)
    n_dead = int(round(p.dead_time_s / dt))
    buf = np.full(n_dead + 1 if n_dead > 0 else 1, 50.0)

    f_span = p.spans["F"][1] - p.spans["F"][0]
    f_sd = p.noise_pct.get("F", 0.0) / 100.0 * f_span * p.noise_scale
    gen = ProcessGenerator(seed, p.process, f_sd, (start_ts.value / 1e9) + origin_s)

    kernel_faults = list(faults)
    out = np.zeros((n_total, K.N_OUT))
    row = 0
    t_fine = 0  # fine steps done since the origin
    while row < n_total:
        rows = min(per_chunk // spo, n_total - row)
        n_fine = rows * spo
        n_sec = -(-n_fine // sps)
        inputs = gen.next(n_sec)
        secs = origin_s + t_fine * dt + np.arange(n_sec, dtype=float)  # rel. to start
        fv = np.zeros((N_FAULTS, n_sec))
        for spec in kernel_faults:
            fv[fault_index(spec.name)] += spec.profile(secs, start_ts)
        for name, info in FAULTS.items():
            i = fault_index(name)
            np.clip(fv[i], info.lo, info.hi, out=fv[i])
        fv[fault_index("f14")] = 0.0  # measurement-only: applied below
        if p.f13_mode == "measurement":
            fv[fault_index("f13")] = 0.0
        done = K.run_chunk(
            prm,
            n_fine,
            sps,
            spo,
            inputs["P1"],
            inputs["P2"],
            inputs["T"],
            inputs["SP"],
            inputs["FNOISE"],
            fv,
            state,
            buf,
            out[row : row + rows],
        )
        assert done == rows
        row += rows
        t_fine += n_fine

    out = out[n_warm:]
    index = pd.date_range(start_ts, periods=n_out, freq=pd.Timedelta(seconds=period_s), name="ts")
    truth = fault_truth(index, faults, start_ts) if faults else pd.DataFrame(index=index)

    def noise(tag: str, n: int) -> np.ndarray:
        lo, hi = p.spans[tag]
        sd = p.noise_pct.get(tag, 0.0) / 100.0 * (hi - lo) * p.noise_scale
        ss = np.random.SeedSequence([int(seed), 9001, list(TAGS).index(tag)])
        rng = np.random.default_rng(ss)
        return sd * rng.standard_normal(n) if sd > 0 else np.zeros(n)

    def clip(tag: str, v: np.ndarray) -> np.ndarray:
        lo, hi = p.spans[tag]
        return np.clip(v, lo, hi)

    x_tag = out[:, K.O_XS]
    if p.f13_mode == "measurement" and "f13" in truth:
        x_tag = np.clip(out[:, K.O_X] * (1.0 + 1.25 * truth["f13"].to_numpy()), 0.0, 1.0)
    p0 = out[:, K.O_P0]
    if "f14" in truth:  # DABLib Table 17, on the relative reading
        lo, hi = p.spans["P0"]
        f14 = truth["f14"].to_numpy()
        rel_p0 = np.clip((p0 - lo) / (hi - lo) * (1.0 + f14), 0.0, 1.0)
        p0 = np.where(f14 != 0.0, lo + rel_p0 * (hi - lo), p0)
    cols = {
        "CV": clip("CV", out[:, K.O_CV] + noise("CV", n_out)),
        "P1": clip("P1", out[:, K.O_P1] + noise("P1", n_out)),
        "P2": clip("P2", out[:, K.O_P2] + noise("P2", n_out)),
        "T1": clip("T1", out[:, K.O_T] + noise("T1", n_out)),
        "X": clip("X", 100.0 * x_tag + noise("X", n_out)),
        "F": clip("F", out[:, K.O_FM]),
        "P0": clip("P0", p0 + noise("P0", n_out)),
        "Pch": clip("Pch", out[:, K.O_PCH] + noise("Pch", n_out)),
    }
    if internals:
        cols["X_true"] = 100.0 * out[:, K.O_X]
        cols["F_true"] = out[:, K.O_F].copy()
        cols["SP"] = out[:, K.O_SP].copy()
    df = pd.DataFrame(cols, index=index)
    df.attrs["faults"] = [spec.to_dict() for spec in faults]
    df.attrs["seed"] = int(seed)
    df.attrs["period_s"] = float(period_s)
    return df
