"""Mean-value spark-ignition engine on a dynamometer, sampled once per revolution.

The plant of Laukonen, Passino, Krishnaswami, Luh & Rizzoni, "Fault detection and
isolation for an experimental internal combustion engine via fuzzy identification",
IEEE Trans. Control Syst. Technol. 3(3), 1995 (seed 000): a Ford 3.0 L V-6 on an
electric dynamometer, driven through an IM240-like cycle with uniform random
signals added to the throttle and load inputs, every signal sampled once per
crankshaft revolution. The equations are textbook mean-value physics, written
here from the publications (no code is taken from anywhere):

* [HS90] E. Hendricks, S. C. Sorenson, "Mean value modelling of spark ignition
  engines", SAE 900616, 1990 (manifold filling, port flow, fuel film, crank).
* [GO10] L. Guzzella, C. H. Onder, *Introduction to Modeling and Control of
  Internal Combustion Engine Systems*, 2nd ed., Springer 2010, ch. 2 (mean-value
  models: throttle, receiver, volumetric efficiency, wall wetting, Willans
  torque). Cited by section topic; we give no equation numbers we could not check.
* [Hey88] J. B. Heywood, *Internal Combustion Engine Fundamentals*, McGraw-Hill
  1988 (friction mean effective pressure, fuel conversion efficiency against λ).
* [Aq81] C. F. Aquino, "Transient A/F control characteristics of the 5 liter
  central fuel injection engine", SAE 810494, 1981 (the X–τ fuel film model).

Equations (SI units inside; ``θ`` crank angle, ``ω`` crank speed, ``k`` revolution)
-------------------------------------------------------------------------------

1. Throttle, compressible orifice [GO10 ch. 2]:
   ``ṁ_th = c_d A(φ) p_a / sqrt(R T_a) Ψ(p_m/p_a)`` with
   ``Ψ(Π) = sqrt(κ) (2/(κ+1))^((κ+1)/(2(κ-1)))`` for ``Π < Π_cr = (2/(κ+1))^(κ/(κ-1))``
   (choked) and ``Ψ(Π) = Π^(1/κ) sqrt(2κ/(κ-1) (1 - Π^((κ-1)/κ)))`` above it; near
   ``Π = 1`` (above ``Π_lin``) Ψ is continued linearly to 0 at ``Π = 1`` (and below
   0 for back-flow), as [GO10] and [HS90] do to avoid the infinite slope.
   Plate area [GO10 ch. 2, Hey88]:
   ``A(φ) = (π D²/4)(1 - cos φ / cos φ_0) + A_leak``, ``φ = φ_0 + (90° - φ_0) α/100``
   (α is the opening in % of full scale, as in the seed).
2. Manifold, isothermal receiver [GO10 ch. 2, HS90]:
   ``dp_m/dt = R T_m / V_m (ṁ_th - ṁ_ap)``.
3. Port air flow, speed–density [GO10 ch. 2, HS90]:
   ``ṁ_ap = λ_l(ω, p_m) p_m V_d ω / (4π R T_m)`` with the volumetric efficiency
   ``λ_l = λ_lω(n) · λ_lp(p_m)``, ``λ_lp = ε/(ε-1) - (p_e/p_m)^(1/κ)/(ε-1)`` (residual
   gas expanding from exhaust pressure ``p_e``) and ``λ_lω = e_0 + e_1 n + e_2 n²``
   (n in 1000 rpm).
4. Fuel film (wall wetting) [Aq81, HS90, GO10 ch. 2]: of the injected flow ``ṁ_fi``
   a fraction ``X`` goes to the film ``m_ff``, which evaporates with time constant
   ``τ_f``: ``dm_ff/dt = X ṁ_fi - m_ff/τ_f``; the cylinders get
   ``ṁ_fc = (1 - X) ṁ_fi + m_ff/τ_f``. Integrated exactly over each sub-step.
5. Torque [GO10 ch. 2 Willans form; Hey88]: the charge of revolution
   ``k-1`` (air ``m_ac``, fuel ``m_fc``, ``λ = m_ac/(L_st m_fc)``) burns in
   revolution ``k`` (one-revolution induction-to-power delay, [HS90]):
   ``T_i = η_i η_λ(λ) H_l m_fc / (2π)`` (energy per revolution over 2π), with
   ``η_λ(λ) = min(1, λ) (1 - c_λ (λ - λ_0)²) / (1 - c_λ (1 - λ_0)²)`` (fuel beyond
   stoichiometric does not burn; efficiency peaks slightly lean; 1 at λ = 1 —
   our parameterisation of the shape in [Hey88]). Losses are friction and
   pumping mean effective pressures, ``T_loss = V_d/(4π) (p_f(n) + p_e - p_m)``,
   ``p_f = f_0 + f_1 n + f_2 n²`` [Hey88]. Brake torque ``T_e = T_i - T_loss``.
6. Crankshaft and dynamometer: ``(J_e + J_dy) dω/dt = T_e - T_dy`` (engine and
   dynamometer rotor on one shaft, transmission locked, ratio 1 — a
   simplification of the seed's automatic transmission; the default). The load
   cell reads the shaft torque ``T_L = T_dy + J_dy dω/dt``. With
   ``EngineParams(converter=True)`` an open torque converter (gear ratio 1) sits
   between them: ``J_e dω/dt = T_e - T_p``, ``J_dy dω_t/dt = T_t - T_dy``, pump
   torque ``T_p = (n/K)² g(SR)`` (K-factor form; ``g`` = 1 up to the coupling
   point ``SR_c``, falling linearly to 0 at speed ratio ``SR = ω_t/ω`` = 1 and to
   −1 in overrun), turbine torque ``T_t = TR(SR) T_p`` (torque ratio from
   ``tr_stall`` at stall to 1 at ``SR_c``); ω_dy is the turbine (dynamometer)
   speed and ``T_L = T_dy + J_dy dω_t/dt``. K = 130 rpm/√(N·m) slips 1–2 % in
   cruise, up to ≈ 17 % when accelerating.
7. Sensors: the mass-air-flow meter measures ``ṁ_th`` through a first-order lag
   ``τ_maf``; engine speed, manifold pressure and load-cell torque are the
   revolution means; every sensor adds Gaussian noise (``noise=``).

Integration: in the crank-angle domain, ``n_sub`` equal steps of ``2π/n_sub`` per
revolution (``dt = (2π/n_sub)/ω``), so each revolution takes exactly ``n_sub``
steps and lasts ``Δt_k = Σ dt`` — the seed's once-per-revolution sampling with
time steps that vary with speed. The manifold pressure is advanced
linearly-implicitly (stiff near wide-open throttle), the film and the MAF lag
exactly, the crank speed by explicit Euler. One compiled (numba) loop.

Inputs and the test-cell computer
---------------------------------
Per revolution ``k`` (held over the revolution):

* throttle command ``α`` (%): the test-cell computer (the seed's program that
  generated the throttle reference) follows the IM240-like reference speed
  ``n_ref(t)``: a feed-forward ``α_ss(n_ref, T_dy + J dω_ref/dt)`` — the steady
  throttle of this model at λ = 1 for that speed and torque, found by bisection —
  plus a PI controller on the error between ``n_ref`` and the true
  revolution-mean speed of revolution ``k-1`` (conditional-integration
  anti-windup), plus a uniform random signal ``U(-a_α, a_α)`` (seed §III),
  limited to 0–100 %;
* dynamometer load ``T_dy`` (N·m): road load ``T_0 + c_2 n_ref²`` plus the
  vehicle inertia the dynamometer simulates ``J_eq dω_ref/dt``, plus a uniform
  random signal ``U(-a_T, a_T)`` (seed §III), limited below at ``T_dy,min``.
  Both random amplitudes scale linearly from ``excite_floor`` of their value at
  idle to the full value at the top speed, so that idle is not stalled;
* fuel command ``m_f`` (mg per revolution): an idealised air–fuel-ratio
  controller, stoichiometric feed-forward on the cylinder air charge of the last
  revolution, ``m_f = m_ac(k-1) / (L_st λ_ref)``, times ``1 + U(-a_f, a_f)``. It
  does not compensate the fuel film, so λ swings in transients as on a real
  engine. It reads the true cylinder air charge (an ideal air-charge observer),
  so a MAF *sensor* fault does not reach the fuel command. An integral
  closed-loop trim (``lambda_trim_gain``) multiplies it, driven
  by the λ of the last charge (an ideal exhaust-oxygen sensor; the seed's
  engine had HEGO sensors and the EEC-IV's closed loop):
  ``trim(k) = trim(k-1) + g (λ(k-1) - λ_ref)``, limited to 0.5–1.5; g = 0.003 by
  default (a slow trim, ~330 revolutions; 0 turns it off).

``simulate_engine_open_loop`` takes given per-revolution throttle, load and
(optionally) fuel sequences instead (used by the tests for steps).

The speed reference: :func:`im240_like_trace` is a deterministic piecewise-linear
vehicle-speed trace with the shape of the EPA IM240 cycle over its 240 s (two
hills: up to about 33 mph, a stop at about 94 s, then up to about 57 mph and
back to rest at 240 s) — it resembles, and is not, the official table. The speed
maps linearly to engine speed, idle 800 rpm at rest to 4000 rpm at the top speed
(one fixed gear). After 240 s the cycle repeats. With the default 7,000
revolutions (the seed's length) the run ends at about 200 s into the cycle.

Signals (DataFrame columns) and the seed's symbols
--------------------------------------------------
=============  =======  =====================================================  ==========
column         unit     meaning                                                seed
=============  =======  =====================================================  ==========
``omega``      rpm      engine speed sensor, revolution mean                   ω
``omega_dy``   rpm      dynamometer tachometer, revolution mean                ω_dy
``m_a``        g/s      mass air flow sensor (air entering the manifold)       m_a
``alpha``      %        throttle command (% of full-scale opening)             α
``m_f``        mg/rev   fuel mass command for the revolution                   m_f
``T_L``        N·m      load cell: shaft torque into the dynamometer            T_L
``p_m``        kPa      manifold absolute pressure sensor                      (—)
``rev``        —        revolution number, 0 at the first recorded one         k
=============  =======  =====================================================  ==========

With ``internals=True`` also: ``t_s`` (s since start), ``omega_ref`` (rpm, the
trace), ``T_dy`` (N·m, dynamometer load command), ``alpha_act`` (%, plate opening
the engine gets), ``m_f_inj`` (mg/rev, fuel injected), ``m_fc`` (mg/rev, fuel
entering the cylinders after the film), ``m_ap`` (g/s, port air flow), ``m_ath``
(g/s, true throttle flow), ``lambda`` (air–fuel ratio of the charge inducted
in the revolution / stoichiometric),
``T_e`` (N·m, brake torque), ``omega_true`` (rpm), ``p_m_true`` (kPa).

The regression vectors of the seed (eqs. 7–11) use only ω, m_a, α, m_f, T_L and
ω_dy at lags 1–3 revolutions: ``omega``, ``m_a``, ``alpha``, ``m_f``, ``T_L``,
``omega_dy`` shifted by 1–3 rows. The hatted quantities (ω̂, m̂_a, α̂, m̂_f, T̂_L)
are the identifiers' own estimates (the FDI code builds them; the measured
column is the training target). Unit conversions to the seed's (rev/min,
lbm/s, %, lbm, lb·ft) are constant factors and irrelevant to the identifiers.

Faults (seed Table I, §III) — :class:`EngineFault`
---------------------------------------------------
A calibration fault multiplies a sensed or commanded signal by a gain from an
onset revolution on (seed: 1.2 on ω, m_a, α; 1.4 on m_f). Two kinds:

* ``"sensor"``: the recorded column is multiplied (after its noise), the engine
  is untouched — exactly ``faulty = nominal × gain`` from the onset row on.
  Default for ``omega``, ``omega_dy``, ``m_a``, ``p_m``, ``T_L``. On ``alpha`` or
  ``m_f`` this is how the seed *simulated* its actuator faults ("multiplying the
  experimental data for a specific fault by the desired calibration fault value").
* ``"actuator"``: the engine gets ``gain ×`` the command ("the throttle angle is
  1.20 times the commanded value", "the mass fuel actuator injects 1.40 times the
  commanded value"), the recorded command stays what the controller sent, and the
  closed loop reacts. Default for ``alpha`` and ``m_f``.

The speed controller reads the true speed, so an ``omega`` sensor fault changes
no dynamics. The seed's Table II marks the α residual non-zero for an ω sensor
fault although eq. 9 reads ω_dy, the dynamometer's tachometer (another instrument),
not ω; the FDI experiment multiplies ω alone, as the seed did, and isolates by the
printed table, or by the one derived from eqs. 7–11
(:func:`diag_plugin.engine.fdi.derive_table_ii`). A fault on both is
``[EngineFault("omega", 1.2, k), EngineFault("omega_dy", 1.2, k)]``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Literal

import numba as nb
import numpy as np
import pandas as pd

from diag_plugin.simulate.tagtable import tag_infos
from historian.taginfo import TagInfo

__all__ = [
    "ENGINE_TAGS",
    "EngineFault",
    "EngineParams",
    "im240_like_trace",
    "simulate_engine",
    "simulate_engine_open_loop",
]

#: the recorded signals: unit, nominal range, description (seed §II symbols)
ENGINE_TAGS: dict[str, TagInfo] = tag_infos(
    """
omega    | rpm    | 0    | 6000 | engine speed ω (sensor, revolution mean)
omega_dy | rpm    | 0    | 6000 | dynamometer speed ω_dy (tachometer)
m_a      | g/s    | 0    | 150  | mass air flow m_a into the manifold (MAF sensor)
alpha    | %      | 0    | 100  | throttle command α, % of full-scale opening
m_f      | mg/rev | 0    | 200  | fuel mass command m_f per revolution
T_L      | N·m    | -100 | 300  | load torque T_L (dynamometer load cell)
p_m      | kPa    | 0    | 110  | intake manifold absolute pressure (MAP sensor)
"""
)

SENSOR_SIGNALS = ("omega", "omega_dy", "m_a", "p_m", "T_L")
ACTUATOR_SIGNALS = ("alpha", "m_f")

# ---- parameter vector indices (filled by EngineParams.vector) ----
(
    P_PA, P_TA, P_R, P_KAPPA, P_CD, P_D, P_PHI0, P_ALEAK, P_PILIN, P_VM, P_TM, P_VD,
    P_EPS, P_PE, P_E0, P_E1, P_E2, P_X, P_TAUF, P_HL, P_LST, P_ETAI, P_CLAM, P_LAM0,
    P_F0, P_F1, P_F2, P_JE, P_JDY, P_TAUMAF, P_KP, P_KI, P_AMAX, P_T0, P_C2, P_JEQ,
    P_TMIN, P_LREF, P_WMIN, P_IDLE, P_TOP, P_UFLOOR, P_HEGO, P_CONV, P_KCONV, P_SRC, P_TR0,
    N_PRM,
) = range(48)  # fmt: skip

# ---- state vector indices ----
S_PM, S_W, S_FF, S_MAF, S_T, S_INT, S_MAC, S_MFC, S_WAVG, S_TRIM, S_WT, N_STATE = range(12)

# ---- output columns of the kernel ----
(
    O_T, O_DT, O_WAVG, O_PM, O_MTH, O_MAF, O_MAP, O_MAC, O_MFC, O_LAM, O_TE, O_TL,
    O_TDY, O_ACMD, O_AACT, O_MFCMD, O_MFINJ, O_NREF, O_WDY, N_OUT,
) = range(20)  # fmt: skip

RPM = 60.0 / (2.0 * math.pi)  # rpm per rad/s


@dataclass
class EngineParams:
    """Physical constants of the engine, dynamometer, sensors and test-cell controllers.

    Defaults: a 3.0 L V-6 port-injected SI engine like the seed's Ford Vulcan
    (displacement and compression ratio from its specification; the rest typical
    textbook values of [GO10] ch. 2, [HS90] and [Hey88], tuned so that idle is
    about 800 rpm at 25–35 kPa and 4000 rpm needs about 25 % throttle).
    """

    # --- ambient and gas [GO10 ch. 2]
    p_a: float = 101325.0  # ambient (upstream of the throttle) pressure, Pa
    T_a: float = 298.0  # ambient temperature, K
    R: float = 287.0  # gas constant of air, J/(kg K)
    kappa: float = 1.4  # ratio of specific heats
    # --- throttle [GO10 ch. 2]
    c_d: float = 0.8  # discharge coefficient
    bore_m: float = 0.050  # throttle bore D, m
    phi0_deg: float = 7.0  # closed plate angle φ_0, degrees
    a_leak_m2: float = 6.0e-6  # leakage / idle-air bypass area, m²
    pi_lin: float = 0.95  # Ψ continued linearly to 0 above this pressure ratio
    # --- manifold [GO10 ch. 2]
    v_m_m3: float = 4.0e-3  # manifold volume, m³
    T_m: float = 300.0  # manifold temperature (isothermal), K
    # --- cylinders, port flow [GO10 ch. 2]
    v_d_m3: float = 3.0e-3  # displacement, m³ (3.0 L)
    eps: float = 9.3  # compression ratio (Ford 3.0 L Vulcan)
    p_e: float = 103000.0  # exhaust pressure, Pa
    ev: tuple[float, float, float] = (0.80, 0.05, -0.01)  # λ_lω = e0 + e1 n + e2 n², n in krpm
    # --- fuel film [Aq81, HS90]
    x_film: float = 0.25  # fraction of the injected fuel into the film
    tau_film_s: float = 0.15  # film evaporation time constant, s
    # --- combustion and torque [GO10 Willans; Hey88]
    h_l: float = 43.0e6  # lower heating value of gasoline, J/kg
    l_st: float = 14.7  # stoichiometric air/fuel mass ratio
    eta_i: float = 0.36  # indicated efficiency at λ = 1 (MBT spark)
    c_lambda: float = 1.0  # curvature of η_λ(λ)
    lambda0: float = 1.05  # λ of peak fuel-conversion efficiency
    fmep_bar: tuple[float, float, float] = (0.75, 0.10, 0.05)  # p_f = f0 + f1 n + f2 n², bar
    # --- shaft [HS90]
    j_e: float = 0.15  # engine inertia (crank, flywheel), kg m²
    j_dy: float = 0.35  # dynamometer rotor and coupling inertia, kg m²
    # --- sensors
    tau_maf_s: float = 0.01  # MAF sensor time constant, s
    # --- test-cell computer: speed controller on the throttle (PI)
    kp_pct_per_rpm: float = 0.01  # % throttle per rpm of speed error
    ki_pct_per_rpm_s: float = 0.005  # % throttle per (rpm s)
    alpha_max: float = 100.0  # throttle command limit, %
    # --- dynamometer load schedule (road load + simulated vehicle inertia)
    t0_nm: float = 8.0  # load at rest (accessories, converter), N·m
    c2_nm_per_rpm2: float = 4.0e-6  # quadratic road load, N·m per rpm²
    j_eq: float = 2.0  # vehicle inertia the dynamometer simulates, kg m²
    t_dy_min: float = 0.0  # the dynamometer only absorbs (N·m lower limit)
    # --- fuel controller
    lambda_ref: float = 1.0  # λ the AFR controller aims at
    lambda_trim_gain: float = 0.003  # closed-loop λ trim per revolution per unit λ error (0: off)
    # --- numerics
    omega_min_rpm: float = 200.0  # speed floor (stall is not modelled), rpm
    n_sub: int = 24  # integration steps per revolution
    warmup_rev: int = 400  # revolutions simulated at idle before recording
    # --- IM240-like trace mapping
    idle_rpm: float = 800.0
    top_rpm: float = 4000.0
    # --- random excitation: fraction of its amplitude at idle (1 at top speed, linear)
    excite_floor: float = 0.2
    # --- automatic transmission between engine and dynamometer (the seed's test cell): off =
    # one rigid shaft at ratio 1 (the default); on = an open torque converter, gear ratio 1
    converter: bool = False
    k_converter: float = 130.0  # capacity factor K = n_pump / sqrt(T_pump), rpm/sqrt(N·m)
    sr_coupling: float = 0.85  # speed ratio of the coupling point
    tr_stall: float = 2.0  # torque ratio at stall (speed ratio 0)

    def vector(self) -> np.ndarray:
        """The kernel's parameter vector (indices ``P_*``)."""
        v = np.zeros(N_PRM)
        v[P_PA], v[P_TA], v[P_R], v[P_KAPPA] = self.p_a, self.T_a, self.R, self.kappa
        v[P_CD], v[P_D] = self.c_d, self.bore_m
        v[P_PHI0], v[P_ALEAK], v[P_PILIN] = math.radians(self.phi0_deg), self.a_leak_m2, self.pi_lin
        v[P_VM], v[P_TM], v[P_VD] = self.v_m_m3, self.T_m, self.v_d_m3
        v[P_EPS], v[P_PE] = self.eps, self.p_e
        v[P_E0], v[P_E1], v[P_E2] = self.ev
        v[P_X], v[P_TAUF] = self.x_film, self.tau_film_s
        v[P_HL], v[P_LST], v[P_ETAI] = self.h_l, self.l_st, self.eta_i
        v[P_CLAM], v[P_LAM0] = self.c_lambda, self.lambda0
        v[P_F0], v[P_F1], v[P_F2] = (1e5 * f for f in self.fmep_bar)
        v[P_JE], v[P_JDY], v[P_TAUMAF] = self.j_e, self.j_dy, self.tau_maf_s
        v[P_KP], v[P_KI], v[P_AMAX] = self.kp_pct_per_rpm, self.ki_pct_per_rpm_s, self.alpha_max
        v[P_T0], v[P_C2], v[P_JEQ] = self.t0_nm, self.c2_nm_per_rpm2, self.j_eq
        v[P_TMIN], v[P_LREF], v[P_WMIN] = self.t_dy_min, self.lambda_ref, self.omega_min_rpm / RPM
        v[P_IDLE], v[P_TOP], v[P_UFLOOR] = self.idle_rpm, self.top_rpm, self.excite_floor
        v[P_HEGO] = self.lambda_trim_gain
        v[P_CONV], v[P_KCONV] = float(self.converter), self.k_converter
        v[P_SRC], v[P_TR0] = self.sr_coupling, self.tr_stall
        return v  # fmt: skip


def _default_noise() -> dict[str, float]:
    # sensor noise, standard deviation in the column's unit
    return {"omega": 5.0, "omega_dy": 5.0, "m_a": 0.2, "p_m": 0.3, "T_L": 1.0}


@dataclass(frozen=True)
class EngineFault:
    """A calibration fault (seed Table I): ``signal`` multiplied by ``gain`` from ``onset``.

    ``onset`` is a revolution number (0 = the first recorded revolution; the seed
    counts its test window in revolutions, 3000–5000). ``kind`` None takes the
    default for the signal: ``"sensor"`` for ω, ω_dy, m_a, p_m, T_L (recorded
    column multiplied, engine untouched); ``"actuator"`` for α and m_f (the
    engine gets gain × command, the recorded command stays nominal). ``"sensor"``
    on α or m_f multiplies the recorded command instead — the way the seed
    simulated its faults on measured data.
    """

    signal: str
    gain: float
    onset: int = 0
    kind: Literal["sensor", "actuator"] | None = None

    def __post_init__(self) -> None:
        if self.signal not in SENSOR_SIGNALS + ACTUATOR_SIGNALS:
            raise ValueError(
                f"unknown engine signal {self.signal!r}: expected one of "
                f"{', '.join(SENSOR_SIGNALS + ACTUATOR_SIGNALS)}"
            )
        g = float(self.gain)
        if not (math.isfinite(g) and g > 0):
            raise ValueError(f"{self.signal}: gain must be a positive number, not {self.gain!r}")
        if int(self.onset) != self.onset or self.onset < 0:
            raise ValueError(f"{self.signal}: onset must be a revolution number >= 0")
        kind = self.kind
        if kind is None:
            kind = "actuator" if self.signal in ACTUATOR_SIGNALS else "sensor"
        if kind not in ("sensor", "actuator"):
            raise ValueError(f"{self.signal}: kind must be 'sensor' or 'actuator', not {kind!r}")
        if kind == "actuator" and self.signal not in ACTUATOR_SIGNALS:
            raise ValueError(f"{self.signal} is a measurement: only alpha and m_f are actuators")
        object.__setattr__(self, "gain", g)
        object.__setattr__(self, "onset", int(self.onset))
        object.__setattr__(self, "kind", kind)

    def to_dict(self) -> dict:
        """Plain record for ``DataFrame.attrs`` and experiment logs."""
        return asdict(self)

    def gains(self, n: int) -> np.ndarray:
        """Per-revolution multiplier over ``n`` recorded revolutions (1 before the onset)."""
        g = np.ones(n)
        g[self.onset :] = self.gain
        return g


# ------------------------------------------------------------------ the IM240-like trace

#: (time s, vehicle speed mph): the IM240 shape, not the official table
_IM240_LIKE = np.array(
    [
        (0, 0), (5, 0), (13, 15), (20, 25), (30, 30), (40, 28), (50, 24), (57, 30),
        (65, 33), (75, 25), (85, 15), (93, 0), (97, 0), (105, 15), (115, 30), (125, 40),
        (135, 45), (145, 50), (155, 54), (165, 56.7), (175, 55), (185, 52), (195, 55),
        (205, 56), (215, 45), (225, 30), (235, 10), (240, 0),
    ],
    dtype=float,
)  # fmt: skip


def im240_like_trace(
    idle_rpm: float = 800.0, top_rpm: float = 4000.0
) -> tuple[np.ndarray, np.ndarray]:
    """Breakpoints ``(t_s, n_rpm)`` of the IM240-like engine-speed reference.

    Vehicle speed (mph) of an IM240-shaped cycle (240 s, two hills, top speed
    56.7 mph as in the EPA cycle) mapped linearly to engine speed:
    ``n = idle + (top - idle) v / v_max``. Interpolate linearly between points.
    """
    t = _IM240_LIKE[:, 0].copy()
    v = _IM240_LIKE[:, 1]
    return t, idle_rpm + (top_rpm - idle_rpm) * v / v.max()


# ------------------------------------------------------------------ compiled physics


@nb.njit(cache=True, nogil=True)
def _psi(pr, kappa, pi_lin):
    """Flow function Ψ(Π) of the compressible orifice [GO10 ch. 2].

    Choked below Π_cr, the isentropic formula up to ``pi_lin``, then linear to 0
    at Π = 1 (negative beyond: back-flow), as [GO10] and [HS90] regularise it.
    """
    pcr = (2.0 / (kappa + 1.0)) ** (kappa / (kappa - 1.0))
    if pr <= pcr:
        return math.sqrt(kappa) * (2.0 / (kappa + 1.0)) ** ((kappa + 1.0) / (2.0 * (kappa - 1.0)))
    if pr < pi_lin:
        return pr ** (1.0 / kappa) * math.sqrt(
            2.0 * kappa / (kappa - 1.0) * (1.0 - pr ** ((kappa - 1.0) / kappa))
        )
    p = pi_lin
    psil = p ** (1.0 / kappa) * math.sqrt(
        2.0 * kappa / (kappa - 1.0) * (1.0 - p ** ((kappa - 1.0) / kappa))
    )
    return psil * (1.0 - pr) / (1.0 - pi_lin)


@nb.njit(cache=True, nogil=True)
def _throttle_area(alpha_pct, prm):
    """Open area A(φ) of the throttle plate plus leakage [GO10 ch. 2], m²."""
    phi0 = prm[P_PHI0]
    a = min(max(alpha_pct, 0.0), 100.0)
    phi = phi0 + (0.5 * math.pi - phi0) * a / 100.0
    d = prm[P_D]
    return 0.25 * math.pi * d * d * (1.0 - math.cos(phi) / math.cos(phi0)) + prm[P_ALEAK]


@nb.njit(cache=True, nogil=True)
def _throttle_flow(area, pm, prm):
    """Air mass flow through the throttle, kg/s [GO10 ch. 2]."""
    pa = prm[P_PA]
    return (
        prm[P_CD]
        * area
        * pa
        / math.sqrt(prm[P_R] * prm[P_TA])
        * _psi(pm / pa, prm[P_KAPPA], prm[P_PILIN])
    )


@nb.njit(cache=True, nogil=True)
def _port_flow(w, pm, prm):
    """Air mass flow into the cylinders by speed–density, kg/s [GO10 ch. 2]."""
    eps = prm[P_EPS]
    lam_p = (eps - (prm[P_PE] / pm) ** (1.0 / prm[P_KAPPA])) / (eps - 1.0)
    if lam_p < 0.0:
        lam_p = 0.0
    nk = w * RPM / 1000.0
    lam_w = prm[P_E0] + prm[P_E1] * nk + prm[P_E2] * nk * nk
    return lam_w * lam_p * pm * prm[P_VD] * w / (4.0 * math.pi * prm[P_R] * prm[P_TM])


@nb.njit(cache=True, nogil=True)
def _eta_lambda(lam, prm):
    """Relative fuel-conversion efficiency η_λ(λ), 1 at λ = 1 (shape after [Hey88])."""
    c = prm[P_CLAM]
    l0 = prm[P_LAM0]
    e = min(1.0, lam) * (1.0 - c * (lam - l0) ** 2) / (1.0 - c * (1.0 - l0) ** 2)
    return max(e, 0.0)


@nb.njit(cache=True, nogil=True)
def _loss_torque(w, pm, prm):
    """Friction plus pumping torque, N·m: V_d/(4π)(p_f(n) + p_e - p_m) [Hey88, GO10]."""
    nk = w * RPM / 1000.0
    pf = prm[P_F0] + prm[P_F1] * nk + prm[P_F2] * nk * nk
    return prm[P_VD] / (4.0 * math.pi) * (pf + prm[P_PE] - pm)


@nb.njit(cache=True, nogil=True)
def _alpha_steady(w, torque, prm):
    """Throttle (%) that holds speed ``w`` at brake torque ``torque`` in steady state, λ = 1.

    The test-cell computer's feed-forward: with λ = 1 and no film transient,
    ``T_i = η_i H_l ṁ_ap / (L_st ω)``; bisection on p_m for ``T_i - T_loss = torque``
    (increasing in p_m), then on α for ``ṁ_th(α, p_m) = ṁ_ap(ω, p_m)``.
    """
    c = prm[P_ETAI] * prm[P_HL] / (prm[P_LST] * w)
    lo = 2000.0
    hi = 0.99 * prm[P_PA]
    if c * _port_flow(w, hi, prm) - _loss_torque(w, hi, prm) < torque:
        return prm[P_AMAX]
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if c * _port_flow(w, mid, prm) - _loss_torque(w, mid, prm) < torque:
            lo = mid
        else:
            hi = mid
    pm = 0.5 * (lo + hi)
    target = _port_flow(w, pm, prm)
    alo = 0.0
    ahi = 100.0
    if _throttle_flow(_throttle_area(alo, prm), pm, prm) >= target:
        return 0.0
    for _ in range(40):
        mid = 0.5 * (alo + ahi)
        if _throttle_flow(_throttle_area(mid, prm), pm, prm) < target:
            alo = mid
        else:
            ahi = mid
    return 0.5 * (alo + ahi)


@nb.njit(cache=True, nogil=True)
def _converter(w, wt, prm):
    """Pump and turbine torque of an open torque converter (N·m), pump at ``w``, turbine at
    ``wt`` (rad/s), in the K-factor form of [GO10]-style driveline models: ``T_p = (n_p/K)² g``
    with ``g = 1`` up to the coupling point, falling linearly to 0 at speed ratio 1 and on to
    −1 in overrun; ``T_t = TR T_p``, the torque ratio falling linearly from its stall value at
    speed ratio 0 to 1 at the coupling point (1 in overrun)."""
    src = prm[P_SRC]
    sr = wt / w
    g = min(max((1.0 - sr) / (1.0 - src), -1.0), 1.0)
    n = w * RPM / prm[P_KCONV]
    t_p = n * n * g
    tr = 1.0
    if t_p > 0.0 and sr < src:
        tr = prm[P_TR0] + (1.0 - prm[P_TR0]) * max(sr, 0.0) / src
    return t_p, tr * t_p


@nb.njit(cache=True, nogil=True)
def _run(prm, n_sub, tr_t, tr_n, freeze, alpha_in, load_in, fuel_in, u_a, u_t, u_f, g_a, g_f,
         state, out):  # fmt: skip
    """Advance ``len(alpha_in)`` revolutions; one row of ``out`` per revolution.

    ``alpha_in``/``load_in``/``fuel_in`` NaN → the test-cell controllers (PI speed
    control, road-load schedule, AFR feed-forward); a number → that input.
    ``u_*`` are the uniform excitations, ``g_a``/``g_f`` the actuator gains.
    ``freeze`` holds the reference at its value for t = 0 (warm-up).
    """
    n_rev = alpha_in.shape[0]
    h = 2.0 * math.pi / n_sub
    rt = prm[P_R] * prm[P_TM] / prm[P_VM]
    j_tot = prm[P_JE] + prm[P_JDY]
    conv = prm[P_CONV] > 0.0
    t_cyc = tr_t[-1]
    for k in range(n_rev):
        t0 = state[S_T]
        tc = 0.0 if freeze else t0 % t_cyc
        n_ref = np.interp(tc, tr_t, tr_n)
        dn_ref = (np.interp(tc + 0.5, tr_t, tr_n) - np.interp(tc - 0.5, tr_t, tr_n)) / 1.0
        if freeze:
            dn_ref = 0.0
        # excitation amplitude grows with the reference speed (idle is not stalled)
        xs = (n_ref - prm[P_IDLE]) / (prm[P_TOP] - prm[P_IDLE])
        xs = prm[P_UFLOOR] + (1.0 - prm[P_UFLOOR]) * min(max(xs, 0.0), 1.0)
        # --- dynamometer load: road load + simulated inertia (or the given input)
        if math.isnan(load_in[k]):
            t_dy = prm[P_T0] + prm[P_C2] * n_ref * n_ref + prm[P_JEQ] * dn_ref / RPM + xs * u_t[k]
        else:
            t_dy = load_in[k] + u_t[k]
        t_dy = max(t_dy, prm[P_TMIN])
        # --- throttle: PI on the last revolution's mean speed (or the given input)
        if math.isnan(alpha_in[k]):
            e = n_ref - state[S_WAVG] * RPM
            dt_prev = 2.0 * math.pi / state[S_WAVG]
            w_ff = max(n_ref, prm[P_IDLE]) / RPM
            a_ff = _alpha_steady(w_ff, t_dy + j_tot * dn_ref / RPM, prm)
            a_pi = a_ff + prm[P_KP] * e + state[S_INT]
            if (
                0.0 < a_pi < prm[P_AMAX]
                or (a_pi <= 0.0 and e > 0)
                or (a_pi >= prm[P_AMAX] and e < 0)
            ):
                state[S_INT] += prm[P_KI] * e * dt_prev
            a_cmd = a_ff + prm[P_KP] * e + state[S_INT] + xs * u_a[k]
        else:
            a_cmd = alpha_in[k] + u_a[k]
        a_cmd = min(max(a_cmd, 0.0), prm[P_AMAX])
        # --- fuel: stoichiometric feed-forward on the last air charge (or the given input)
        if math.isnan(fuel_in[k]):
            if prm[P_HEGO] > 0.0 and state[S_MFC] > 0.0:
                lam_meas = state[S_MAC] / (prm[P_LST] * state[S_MFC])
                trim = state[S_TRIM] + prm[P_HEGO] * (lam_meas - prm[P_LREF])
                state[S_TRIM] = min(max(trim, 0.5), 1.5)
            mf_cmd = state[S_TRIM] * state[S_MAC] / (prm[P_LST] * prm[P_LREF]) * (1.0 + u_f[k])
        else:
            mf_cmd = fuel_in[k] * (1.0 + u_f[k])
        mf_cmd = max(mf_cmd, 0.0)
        a_act = min(max(g_a[k] * a_cmd, 0.0), 100.0)
        mf_inj = g_f[k] * mf_cmd
        area = _throttle_area(a_act, prm)
        # --- indicated torque of the charge inducted in the last revolution
        mfc_prev = state[S_MFC]
        if mfc_prev > 0.0:
            lam_prev = state[S_MAC] / (prm[P_LST] * mfc_prev)
            t_i = prm[P_ETAI] * _eta_lambda(lam_prev, prm) * prm[P_HL] * mfc_prev / (2.0 * math.pi)
        else:
            lam_prev = 10.0
            t_i = 0.0
        # --- n_sub crank-angle steps
        i_pm = 0.0
        i_mth = 0.0
        i_maf = 0.0
        i_map = 0.0
        i_te = 0.0
        i_tl = 0.0
        i_wt = 0.0
        m_air = 0.0
        m_fuel = 0.0
        x = prm[P_X]
        tauf = prm[P_TAUF]
        for _ in range(n_sub):
            w = state[S_W]
            pm = state[S_PM]
            dt = h / w
            # manifold, linearly implicit Euler [GO10 ch. 2]
            mth = _throttle_flow(area, pm, prm)
            mapf = _port_flow(w, pm, prm)
            dp = 1.0 + 1e-4 * pm
            dmth = (_throttle_flow(area, pm + dp, prm) - _throttle_flow(area, pm - dp, prm)) / (
                2.0 * dp
            )
            dmap = (_port_flow(w, pm + dp, prm) - _port_flow(w, pm - dp, prm)) / (2.0 * dp)
            f = rt * (mth - mapf)
            jac = rt * (dmth - dmap)
            pm_new = pm + dt * f / (1.0 - dt * jac)
            pm_new = min(max(pm_new, 1000.0), 1.05 * prm[P_PA])
            # fuel film, exact over the step [Aq81]
            mfi = mf_inj * w / (2.0 * math.pi)
            ef = math.exp(-dt / tauf)
            ff_new = state[S_FF] * ef + x * mfi * tauf * (1.0 - ef)
            fuel_cyl = (1.0 - x) * mfi * dt + (state[S_FF] + x * mfi * dt - ff_new)
            # torque and crank [HS90]
            t_e = t_i - _loss_torque(w, pm, prm)
            if conv:  # engine | torque converter | dynamometer, two shafts
                wt = state[S_WT]
                t_p, t_t = _converter(w, wt, prm)
                wdot = (t_e - t_p) / prm[P_JE]
                wtdot = (t_t - t_dy) / prm[P_JDY]
                t_l = t_dy + prm[P_JDY] * wtdot
                i_wt += wt * dt
                state[S_WT] = max(wt + wtdot * dt, 0.0)
            else:  # one rigid shaft
                wdot = (t_e - t_dy) / j_tot
                t_l = t_dy + prm[P_JDY] * wdot
            # MAF sensor lag
            em = math.exp(-dt / prm[P_TAUMAF])
            maf = state[S_MAF] * em + mth * (1.0 - em)
            # accumulate revolution means
            i_pm += pm * dt
            i_mth += mth * dt
            i_maf += maf * dt
            i_map += mapf * dt
            i_te += t_e * dt
            i_tl += t_l * dt
            m_air += mapf * dt
            m_fuel += fuel_cyl
            # update the state
            state[S_PM] = pm_new
            state[S_FF] = ff_new
            state[S_MAF] = maf
            state[S_W] = max(w + wdot * dt, prm[P_WMIN])
            state[S_T] += dt
        dtr = state[S_T] - t0
        state[S_WAVG] = 2.0 * math.pi / dtr
        state[S_MAC] = m_air
        state[S_MFC] = m_fuel
        out[k, O_T] = state[S_T]
        out[k, O_DT] = dtr
        out[k, O_WAVG] = state[S_WAVG]
        out[k, O_PM] = i_pm / dtr
        out[k, O_MTH] = i_mth / dtr
        out[k, O_MAF] = i_maf / dtr
        out[k, O_MAP] = i_map / dtr
        out[k, O_MAC] = m_air
        out[k, O_MFC] = m_fuel
        out[k, O_LAM] = m_air / (prm[P_LST] * m_fuel) if m_fuel > 0.0 else np.inf
        out[k, O_TE] = i_te / dtr
        out[k, O_TL] = i_tl / dtr
        out[k, O_WDY] = i_wt / dtr if conv else state[S_WAVG]
        out[k, O_TDY] = t_dy
        out[k, O_ACMD] = a_cmd
        out[k, O_AACT] = a_act
        out[k, O_MFCMD] = mf_cmd
        out[k, O_MFINJ] = mf_inj
        out[k, O_NREF] = n_ref
    return n_rev


# ------------------------------------------------------------------ driver


def _utc(ts: str | pd.Timestamp) -> pd.Timestamp:
    ts = pd.Timestamp(ts)
    return ts.tz_localize("UTC") if ts.tzinfo is None else ts.tz_convert("UTC")


def _initial_state(p: EngineParams, omega0_rpm: float | None) -> np.ndarray:
    """A rough operating point (idle unless ``omega0_rpm``); the warm-up settles it."""
    s = np.zeros(N_STATE)
    w = (p.idle_rpm if omega0_rpm is None else float(omega0_rpm)) / RPM
    s[S_PM] = 30000.0
    s[S_W] = w
    s[S_WAVG] = w
    s[S_INT] = 0.0
    s[S_MAC] = 0.2e-3  # kg per revolution
    s[S_MFC] = s[S_MAC] / p.l_st
    s[S_FF] = 0.0
    s[S_TRIM] = 1.0
    s[S_WT] = w
    return s


def _check_faults(faults: Sequence[EngineFault]) -> None:
    for f in faults:
        if not isinstance(f, EngineFault):
            raise TypeError(f"faults must be EngineFault objects, not {type(f).__name__}")


def _simulate(
    n_rev: int,
    *,
    alpha_in: np.ndarray,
    load_in: np.ndarray,
    fuel_in: np.ndarray,
    u_a: np.ndarray,
    u_t: np.ndarray,
    u_f: np.ndarray,
    seed: int,
    start: str | pd.Timestamp,
    faults: Sequence[EngineFault],
    params: EngineParams,
    noise: dict[str, float] | None,
    internals: bool,
    omega0_rpm: float | None = None,
) -> pd.DataFrame:
    p = params
    _check_faults(faults)
    if p.n_sub < 4:
        raise ValueError("n_sub must be at least 4 steps per revolution")
    prm = p.vector()
    tr_t, tr_n = im240_like_trace(p.idle_rpm, p.top_rpm)
    g_a = np.ones(n_rev)
    g_f = np.ones(n_rev)
    for f in faults:
        if f.kind == "actuator":
            (g_a if f.signal == "alpha" else g_f)[:] *= f.gains(n_rev)
    state = _initial_state(p, omega0_rpm)
    # warm-up at the first revolution's inputs, no excitation, reference frozen at t = 0
    nw = int(p.warmup_rev)
    if nw > 0:
        ones = np.ones(nw)
        zeros = np.zeros(nw)
        _run(prm, p.n_sub, tr_t, tr_n, True, alpha_in[0] * ones, load_in[0] * ones,
             fuel_in[0] * ones, zeros, zeros, zeros, ones, ones, state,
             np.zeros((nw, N_OUT)))  # fmt: skip
    state[S_T] = 0.0
    out = np.zeros((n_rev, N_OUT))
    _run(prm, p.n_sub, tr_t, tr_n, False, alpha_in, load_in, fuel_in, u_a, u_t, u_f, g_a, g_f,
         state, out)  # fmt: skip

    sd = _default_noise() if noise is None else {**_default_noise(), **noise}
    # one noise stream per sensor: a longer run extends a shorter one unchanged
    eps = {
        c: np.random.default_rng([int(seed), 240, i]).standard_normal(n_rev)
        for i, c in enumerate(SENSOR_SIGNALS)
    }
    w_rpm = out[:, O_WAVG] * RPM
    cols: dict[str, np.ndarray] = {
        "omega": w_rpm + sd.get("omega", 0.0) * eps["omega"],
        "omega_dy": out[:, O_WDY] * RPM + sd.get("omega_dy", 0.0) * eps["omega_dy"],
        "m_a": 1e3 * out[:, O_MAF] + sd.get("m_a", 0.0) * eps["m_a"],
        "alpha": out[:, O_ACMD].copy(),
        "m_f": 1e6 * out[:, O_MFCMD],
        "T_L": out[:, O_TL] + sd.get("T_L", 0.0) * eps["T_L"],
        "p_m": 1e-3 * out[:, O_PM] + sd.get("p_m", 0.0) * eps["p_m"],
    }
    for f in faults:
        if f.kind == "sensor":
            cols[f.signal] = cols[f.signal] * f.gains(n_rev)
    cols["rev"] = np.arange(n_rev, dtype=np.int64)
    if internals:
        cols.update(
            t_s=out[:, O_T].copy(),
            omega_ref=out[:, O_NREF].copy(),
            T_dy=out[:, O_TDY].copy(),
            alpha_act=out[:, O_AACT].copy(),
            m_f_inj=1e6 * out[:, O_MFINJ],
            m_fc=1e6 * out[:, O_MFC],
            m_ap=1e3 * out[:, O_MAP],
            m_ath=1e3 * out[:, O_MTH],
            **{"lambda": out[:, O_LAM].copy()},
            T_e=out[:, O_TE].copy(),
            omega_true=w_rpm,
            p_m_true=1e-3 * out[:, O_PM],
        )
    start_ts = _utc(start)
    index = pd.DatetimeIndex(start_ts + pd.to_timedelta(out[:, O_T], unit="s"), name="ts")
    df = pd.DataFrame(cols, index=index)
    df.attrs["faults"] = [f.to_dict() for f in faults]
    df.attrs["seed"] = int(seed)
    df.attrs["units"] = {c: ENGINE_TAGS[c].unit for c in ENGINE_TAGS}
    df.attrs["sampling"] = "one row per crankshaft revolution, stamped at its end"
    return df


def simulate_engine(
    n_rev: int = 7000,
    *,
    seed: int = 0,
    start: str | pd.Timestamp = "2026-01-01",
    faults: Sequence[EngineFault] = (),
    params: EngineParams | None = None,
    noise: dict[str, float] | None = None,
    excitation: tuple[float, float, float] = (2.0, 10.0, 0.03),
    hold_rev: int = 4,
    internals: bool = False,
) -> pd.DataFrame:
    """Drive the engine through ``n_rev`` revolutions of the IM240-like cycle.

    The seed's experiment (§III): the test-cell computer follows the speed trace
    with the throttle (PI) and loads the dynamometer with road load plus
    simulated inertia; uniform random signals ``U(-a, a)`` with
    ``excitation = (a_α in %, a_T in N·m, a_f relative)`` are added to the
    throttle, the load and the fuel command, each held for ``hold_rev``
    revolutions. Default 7,000 revolutions as in the seed.

    Returns a DataFrame, one row per revolution, indexed by a UTC DatetimeIndex
    "ts" (irregular: the end time of each revolution, from ``start``), with the
    columns of :data:`ENGINE_TAGS` (ω, ω_dy rpm; m_a g/s; α %; m_f mg/rev; T_L N·m;
    p_m kPa) and ``rev``; ``internals=True`` adds the true signals (see the module
    docstring). ``faults`` are :class:`EngineFault` calibration faults. The
    result depends only on the arguments (``seed`` seeds a numpy Generator):
    same seed, same data; a fault changes nothing before its onset.
    """
    p = params or EngineParams()
    n_rev = _check_n(n_rev)
    if hold_rev < 1:
        raise ValueError("hold_rev must be >= 1")
    u = [
        _held_uniform(np.random.default_rng([int(seed), 7, i]), a, n_rev, int(hold_rev))
        for i, a in enumerate(excitation)
    ]
    nan = np.full(n_rev, np.nan)
    return _simulate(
        n_rev, alpha_in=nan, load_in=nan, fuel_in=nan, u_a=u[0], u_t=u[1], u_f=u[2],
        seed=seed, start=start, faults=faults, params=p, noise=noise, internals=internals,
    )  # fmt: skip


def simulate_engine_open_loop(
    alpha: np.ndarray,
    load_nm: np.ndarray,
    fuel_mg: np.ndarray | None = None,
    *,
    seed: int = 0,
    start: str | pd.Timestamp = "2026-01-01",
    faults: Sequence[EngineFault] = (),
    params: EngineParams | None = None,
    noise: dict[str, float] | None = None,
    internals: bool = True,
    omega0_rpm: float | None = None,
) -> pd.DataFrame:
    """The engine under given per-revolution throttle ``alpha`` (%) and load ``load_nm`` (N·m).

    ``fuel_mg`` (mg/rev) None uses the stoichiometric AFR feed-forward; an array
    gives the fuel command directly. No random excitation, no speed control: the
    warm-up (``params.warmup_rev``) settles at the first revolution's inputs,
    starting from ``omega0_rpm`` (default the idle speed) — with a large
    ``params.j_dy`` the speed stays there, as on a speed-controlled dynamometer.
    Same columns as :func:`simulate_engine` (internals on by default).
    """
    p = params or EngineParams()
    a = np.asarray(alpha, dtype=float)
    n_rev = _check_n(a.shape[0])
    ld = np.broadcast_to(np.asarray(load_nm, dtype=float), (n_rev,)).copy()
    if fuel_mg is None:
        fu = np.full(n_rev, np.nan)
    else:
        fu = 1e-6 * np.broadcast_to(np.asarray(fuel_mg, dtype=float), (n_rev,))
    if not (np.isfinite(a).all() and np.isfinite(ld).all()):
        raise ValueError("alpha and load_nm must be finite")
    z = np.zeros(n_rev)
    return _simulate(
        n_rev, alpha_in=a.copy(), load_in=ld, fuel_in=np.array(fu, dtype=float), u_a=z, u_t=z,
        u_f=z, seed=seed, start=start, faults=faults, params=p, noise=noise, internals=internals,
        omega0_rpm=omega0_rpm,
    )  # fmt: skip


def _check_n(n_rev: int) -> int:
    if int(n_rev) != n_rev or n_rev < 1:
        raise ValueError(f"n_rev must be a positive whole number, not {n_rev!r}")
    return int(n_rev)


def _held_uniform(rng: np.random.Generator, amp: float, n: int, hold: int) -> np.ndarray:
    """Uniform ``U(-amp, amp)`` values, each held for ``hold`` revolutions."""
    m = -(-n // hold)
    v = rng.uniform(-amp, amp, m) if amp > 0 else np.zeros(m)
    return np.repeat(v, hold)[:n]
