"""A plant-wide chemical process with recycle, for building and scoring units on many tags.

The process (all on a 1 s grid, the loop in numba, explicit Euler):

* **Fresh feed** of reactant A in a solvent (flow FI101, set by FIC101 on the feed pump's
  valve; temperature TI101 and concentration AI101 wander).
* **Mixing** with the recycle (FI102, set by FIC102 on the recycle pump's valve): the reactor
  feed FI103 at TI102, A and B from the recycle drum.
* **Feed preheater**: steam (FI104, valve moved by TIC103) heats the reactor feed to TI103.
* **Jacketed CSTR**: exothermic A → B, first order, Arrhenius rate ``k = k_ref · a ·
  exp(−E/R (1/T − 1/T_ref))`` with catalyst activity ``a``; level LI101 held by LIC101 on the
  outlet valve (outflow FI106 ∝ opening · √head), temperature TI104 held by TIC104 on the
  jacket's coolant valve (coolant flow FI105, jacket outlet TI105); AI102 analyses A in the
  outlet. Mass and energy balances (Fogler, *Elements of Chemical Reaction Engineering*,
  ch. 8): ``dC_A/dt = F/V (C_A,in − C_A) − k C_A``, ``ρc_p dT/dt = ρc_p F/V (T_in − T) +
  (−ΔH) k C_A − UA_j (T − T_j)/V``; the jacket ``dT_j/dt = F_c/V_j (T_cw − T_j) + UA_j (T −
  T_j)/(ρc_p V_j)``.
* **Product cooler** (counter-current, effectiveness–NTU): cooling water (FI107, valve moved
  by TIC107) cools the reactor outflow to TI107; water return TI108. The cooling-water
  supply TI106 (shared with the jacket) follows a daily cycle.
* **Flash drum**: the cooled stream flashes; the vapour share grows with temperature and
  falls with pressure, A is the volatile one (its vapour is enriched by a factor 2.2, B's
  depleted to 0.4). Pressure PI101 held by PIC101 on the vapour valve (to the condenser,
  condensate flow FI108); liquid level LI102 held by LIC102 on the bottoms valve (product
  FI109, purity AI103 = B's share in %).
* **Recycle drum**: the condensate (TI109) collects in a drum whose level LI103 LIC103 holds by
  the purge valve (FI110); FIC102 pumps the rest back to the mixer. So unreacted A returns to
  the reactor, and the recycle's composition depends on the conversion: a real loop.

Tags (:data:`CHEMPLANT_TAGS`, 44): 26 measurements, and every controller's output ``.OUT``
(% valve opening) and set-point ``.SP``. Disturbances, from random streams that depend only
on the seed: the feed's concentration and temperature (Ornstein–Uhlenbeck processes of hours
plus fast ripple), the feed pump's discharge pressure (seconds), the cooling water's daily
cycle and wander, set-points changed now and then to round values (production rate every
few hours, the others about daily), and measurement noise on every measured tag (the
controllers see it, so their outputs jitter as on a real plant).

Faults (:data:`FAULTS`; ``simulate_chemplant(..., fault=NAME, onset_s=, size=)``): each
starts at its onset (abrupt, or ramping from it for drifts, decay, fouling and wear); the
random streams are the same with and without a fault, so a faulty run equals the fault-free
run of its seed up to the onset.

========================= ======== ============ ============================================
fault                     kind     tag(s)       default size
========================= ======== ============ ============================================
ti104_bias                sensor   TI104        +2 °C on the reactor temperature (in loop)
fi109_bias                sensor   FI109        +0.5 m³/h on the product flow (~6 %, no loop)
ti107_drift               sensor   TI107        +4 °C/day, cooler outlet (in loop)
ai102_drift               sensor   AI102        +0.2 kmol/m³/day, reactor analyser (no loop)
tv104_stiction            actuator TIC104.OUT   5 % stick band, jacket coolant valve
tv103_stuck               actuator TIC103.OUT   steam valve frozen where it was (+0 %)
tv107_bias                actuator TIC107.OUT   −12 % opening, cooler water valve
cooler_fouling            process  TIC107.OUT   UA −50 %, reached linearly over 2 days
feed_comp_step            process  AI101        +0.25 kmol/m³ of A in the feed (+12 %)
feed_temp_step            process  TI101        +8 °C on the feed
catalyst_decay            process  AI102        activity × exp(−0.25 · days)
cw_temp_variation         process  TI106        +3 °C (s.d.) of 15-min wander, cooling water
recycle_leak              process  FI103        0.6 m³/h lost after the recycle meter
separator_leak            process  FI109        1.5 m³/h of liquid lost from the flash drum
feed_pump_degradation     process  FIC101.OUT   pump capacity −35 %, over 1 day
========================= ======== ============ ============================================

Default sizes were chosen on seeds 100–199 only, so that a plant engineer would want each
caught and PCA T² + Q catches some at once, some partly and some not at all
(``benchmarks/bench_chemplant_pca.py``, docs/reference/chemplant.md).

:func:`sample` gives the historian's view: means over each period (``how="mean"``, stamped at
the period's start) or the instantaneous reading at each period (``"last"``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np
import pandas as pd

from .smallplants import _counterflow, _daily, _ou, _pi, _seconds
from .tagtable import tag_table

__all__ = [
    "CHEMPLANT_TAGS",
    "FAULTS",
    "ChemFault",
    "fault_tags",
    "sample",
    "simulate_chemplant",
]

#: measured tags: unit, nominal range, description (order = the simulator's columns)
_MEASURED = tag_table(
    """
FI101 | m3/h    | 0  | 20  | fresh feed flow
TI101 | degC    | 0  | 50  | fresh feed temperature
AI101 | kmol/m3 | 0  | 3   | fresh feed concentration of A (analyser)
FI102 | m3/h    | 0  | 10  | recycle flow
TI102 | degC    | 0  | 60  | reactor feed temperature after mixing
FI103 | m3/h    | 0  | 30  | reactor feed flow (fresh + recycle)
TI103 | degC    | 0  | 120 | reactor feed temperature after the preheater
FI104 | t/h     | 0  | 3   | preheater steam flow
LI101 | %       | 0  | 100 | reactor level
TI104 | degC    | 0  | 150 | reactor temperature
TI105 | degC    | 0  | 120 | jacket coolant outlet temperature
TI106 | degC    | 0  | 50  | cooling-water supply temperature
FI105 | m3/h    | 0  | 25  | jacket coolant flow
AI102 | kmol/m3 | 0  | 3   | reactor outlet concentration of A (analyser)
FI106 | m3/h    | 0  | 30  | reactor outlet flow
TI107 | degC    | 0  | 100 | product cooler outlet temperature
FI107 | m3/h    | 0  | 80  | product cooler cooling-water flow
TI108 | degC    | 0  | 80  | product cooler cooling-water return temperature
PI101 | kPa     | 80 | 200 | flash drum pressure (absolute)
LI102 | %       | 0  | 100 | flash drum level
FI108 | m3/h    | 0  | 15  | flash vapour (condensate) flow
FI109 | m3/h    | 0  | 20  | bottoms product flow
AI103 | %       | 0  | 100 | product purity, share of B (analyser)
LI103 | %       | 0  | 100 | recycle drum level
FI110 | m3/h    | 0  | 10  | purge flow
TI109 | degC    | 0  | 80  | condensate (recycle) temperature
"""
)
#: controllers: what each holds and by which valve
_CONTROLLERS = tag_table(
    """
FIC101 | m3/h | 0  | 20  | fresh feed flow              | feed valve
FIC102 | m3/h | 0  | 10  | recycle flow                 | recycle valve
TIC103 | degC | 0  | 120 | preheater outlet temperature | steam valve
TIC104 | degC | 0  | 150 | reactor temperature          | jacket coolant valve
LIC101 | %    | 0  | 100 | reactor level                | reactor outlet valve
TIC107 | degC | 0  | 100 | cooler outlet temperature    | cooler water valve
PIC101 | kPa  | 80 | 200 | flash drum pressure          | vapour valve
LIC102 | %    | 0  | 100 | flash drum level             | bottoms valve
LIC103 | %    | 0  | 100 | recycle drum level           | purge valve
"""
)
#: every tag: (unit, lo, hi, description, kind) with kind "measurement", "controller output"
#: or "set-point"
CHEMPLANT_TAGS: dict[str, tuple[str, float, float, str, str]] = {
    **{k: (*v, "measurement") for k, v in _MEASURED.items()},
    **{
        f"{c}.OUT": ("%", 0.0, 100.0, f"{c} output ({valve} opening)", "controller output")
        for c, (_, _, _, _, valve) in _CONTROLLERS.items()
    },
    **{
        f"{c}.SP": (u, lo, hi, f"{c} set-point ({what})", "set-point")
        for c, (u, lo, hi, what, _) in _CONTROLLERS.items()
    },
}
_NM = len(_MEASURED)
_NC = len(_CONTROLLERS)


@dataclass(frozen=True)
class ChemFault:
    """One fault type of the chemical plant.

    ``code`` selects it in the simulation loop; ``tags`` are the tags at fault (a sensor's own
    tag, an actuator's controller output, for a process fault the tag it moves most directly);
    ``size`` is the default magnitude in ``unit``; ``ramp_s`` is how long a gradual fault takes
    to reach its size (0: abrupt; drifts and decay grow without limit at ``size`` per day).
    """

    code: int
    kind: str
    tags: tuple[str, ...]
    size: float
    unit: str
    description: str
    ramp_s: float = 0.0


#: the faults, a row each: name | code | kind | tags at fault | size | unit | ramp_s; the
#: indented lines under it: the description
_FAULT_TABLE = """
ti104_bias            | 1  | sensor   | TI104      | 2    | degC              | 0
    | reactor temperature sensor reads high (inside TIC104's loop)
fi109_bias            | 2  | sensor   | FI109      | 0.5  | m3/h              | 0
    | product flow meter reads high (no loop uses it)
ti107_drift           | 3  | sensor   | TI107      | 4    | degC/day          | 0
    | cooler outlet sensor drifts up (inside TIC107's loop)
ai102_drift           | 4  | sensor   | AI102      | 0.2  | kmol/m3/day       | 0
    | reactor analyser drifts up (no loop uses it)
tv104_stiction        | 5  | actuator | TIC104.OUT | 5    | %                 | 0
    | jacket coolant valve sticks: moves only when the demand is more than the band away, then
    | jumps to it
tv103_stuck           | 6  | actuator | TIC103.OUT | 0    | %                 | 0
    | steam valve frozen at its opening at the onset (plus size)
tv107_bias            | 7  | actuator | TIC107.OUT | -12  | %                 | 0
    | cooler water valve opens less than asked (positioner offset)
cooler_fouling        | 8  | process  | TIC107.OUT | 0.5  | share of UA       | 172800
    | product cooler fouls: UA falls linearly
feed_comp_step        | 9  | process  | AI101      | 0.25 | kmol/m3           | 0
    | more A in the fresh feed (step)
feed_temp_step        | 10 | process  | TI101      | 8    | degC              | 0
    | warmer fresh feed (step)
catalyst_decay        | 11 | process  | AI102      | 0.25 | share per day     | 0
    | catalyst activity decays exponentially
cw_temp_variation     | 12 | process  | TI106      | 3    | degC              | 0
    | cooling-water supply wanders more (15-min OU of this s.d.)
recycle_leak          | 13 | process  | FI103      | 0.6  | m3/h              | 0
    | recycle line leaks after its flow meter
separator_leak        | 14 | process  | FI109      | 1.5  | m3/h              | 0
    | flash drum leaks liquid
feed_pump_degradation | 15 | process  | FIC101.OUT | 0.35 | share of capacity | 86400
    | feed pump wears: capacity falls linearly
"""


def _read_faults(text: str) -> dict[str, ChemFault]:
    """The faults of :data:`_FAULT_TABLE`, by name."""
    rows: list[list[str]] = []
    for line in text.strip().splitlines():
        if line.startswith(" "):  # the description, continued
            rows[-1][-1] = f"{rows[-1][-1]} {line.strip(' |')}".strip()
        else:
            rows.append([c.strip() for c in line.split("|")] + [""])
    return {
        name: ChemFault(int(code), kind, tuple(tags.split()), float(size), unit, desc, float(ramp))
        for name, code, kind, tags, size, unit, ramp, desc in rows
    }


FAULTS: dict[str, ChemFault] = _read_faults(_FAULT_TABLE)

#: warm-up before the first recorded second (the plant settles from its initial state)
WARMUP_S = 6 * 3600


def fault_tags(name: str) -> tuple[str, ...]:
    """The tags at fault of fault ``name`` (for the top-ranked-tags criterion)."""
    return FAULTS[name].tags


def _hold_schedule(
    rng, n: int, lo: float, hi: float, hold_s: float, step: float, ramp_s: int = 0
) -> np.ndarray:
    """A set-point held for random times (exponential, mean ``hold_s``, at least an hour)
    between changes to random round values (multiples of ``step``) in [lo, hi], each change
    a step or, with ``ramp_s``, a ramp of that many seconds (as operators move a plant's rate)."""
    out = np.empty(n)
    i = 0
    prev = None
    while i < n:
        j = min(n, i + max(3600, int(rng.exponential(hold_s))))
        value = np.round(rng.uniform(lo, hi) / step) * step
        out[i:j] = value
        if prev is not None and ramp_s > 0:
            k = min(j - i, ramp_s)
            out[i : i + k] = prev + (value - prev) * np.arange(1, k + 1) / ramp_s
        prev = value
        i = j
    return out


@nb.njit(cache=True)
def _plant_loop(ca0, t0, tcw, pump, cwx, sp, noise_seed, code, i0, size, ramp):  # pragma: no cover
    n = ca0.shape[0]
    out = np.empty((n, 26 + 18))
    np.random.seed(noise_seed)  # noqa: NPY002 - numba's own generator, seeded per run
    sd = np.array([0.04, 0.05, 0.004, 0.03, 0.05, 0.05, 0.05, 0.008, 0.2, 0.05, 0.05, 0.05,
                   0.08, 0.004, 0.05, 0.05, 0.2, 0.05, 0.1, 0.2, 0.03, 0.04, 0.05, 0.2, 0.02,
                   0.05])  # fmt: skip
    # states
    f0, fr, fs, tpre = 10.0, 3.8, 0.8, 70.0
    v, ca, cb, t, tj, fc = 6.0, 0.75, 1.25, 85.0, 45.0, 12.0
    tco, fw, twr = 40.0, 40.0, 38.0
    p, ls, lr, car, cbr, tr = 120.0, 50.0, 50.0, 1.0, 0.6, 35.0
    a1, a2, a3 = 2.0, 0.75, 70.0
    pos4, pos3 = 50.0, 30.0
    # controller integrals (nominal outputs)
    ig = np.array([55.0, 45.0, 30.0, 45.0, 35.0, 45.0, 55.0, 45.0, 40.0])
    u = np.zeros(9)
    meas = np.zeros(26)
    # constants
    kref, ear, dh, rcp, uaj, vj = 1.0 / 1000.0, 8000.0, 120000.0, 4000.0, 7.0, 1.0
    fcmax, fwmax, ua_c = 35.0, 50.0, 42.0
    for i in range(n):
        on = code > 0 and i >= i0
        dt_f = (i - i0) if on else 0.0
        prog = 1.0
        if on and ramp > 0.0:
            prog = min(1.0, dt_f / ramp)
        # ---------------- disturbances and faults on the process
        ca0_i = ca0[i] + (size if on and code == 9 else 0.0)
        t0_i = t0[i] + (size if on and code == 10 else 0.0)
        tcw_i = tcw[i] + (size * cwx[i] if on and code == 12 else 0.0)
        act = np.exp(-size * dt_f / 86400.0) if on and code == 11 else 1.0
        ua_i = ua_c * (1.0 - size * prog) if on and code == 8 else ua_c
        pcap = max(1.0 - size * prog, 0.05) if on and code == 15 else 1.0
        leak_r = size if on and code == 13 else 0.0
        leak_s = size if on and code == 14 else 0.0
        # ---------------- derived flows for the measurements
        fr_in = max(fr - leak_r, 0.0)
        f1 = max(f0 + fr_in, 0.1)
        t1 = (f0 * t0_i + fr_in * tr) / f1
        fout = 30.0 * u[4] / 100.0 * np.sqrt(0.5 + 3.0 * v / 10.0)
        fvout = 2.2 * u[6] / 100.0 * np.sqrt(max(p - 100.0, 0.0))
        fb = 14.0 * u[7] / 100.0 * np.sqrt(max(0.5 + 2.0 * ls / 100.0 + (p - 100.0) / 10.0, 0.0))
        fp = 4.0 * u[8] / 100.0 * np.sqrt(0.5 + 1.5 * lr / 100.0)
        # ---------------- measurements (true value, noise, sensor faults)
        meas[0] = f0
        meas[1] = t0_i
        meas[2] = a1
        meas[3] = fr
        meas[4] = t1
        meas[5] = f1
        meas[6] = tpre
        meas[7] = fs
        meas[8] = v * 10.0
        meas[9] = t
        meas[10] = tj
        meas[11] = tcw_i
        meas[12] = fc
        meas[13] = a2
        meas[14] = fout
        meas[15] = tco
        meas[16] = fw
        meas[17] = twr
        meas[18] = p
        meas[19] = ls
        meas[20] = fvout
        meas[21] = fb
        meas[22] = a3
        meas[23] = lr
        meas[24] = fp
        meas[25] = tr
        for j in range(26):
            meas[j] += sd[j] * np.random.standard_normal()  # noqa: NPY002
        if on:
            if code == 1:
                meas[9] += size
            elif code == 2:
                meas[21] += size
            elif code == 3:
                meas[15] += size * dt_f / 86400.0
            elif code == 4:
                meas[13] += size * dt_f / 86400.0
        # ---------------- controllers
        u[0], ig[0] = _pi(sp[i, 0] - meas[0], 1.5, 8.0, ig[0])
        u[1], ig[1] = _pi(sp[i, 1] - meas[3], 2.0, 8.0, ig[1])
        u[2], ig[2] = _pi(sp[i, 2] - meas[6], 1.0, 90.0, ig[2])
        u[3], ig[3] = _pi(meas[9] - sp[i, 3], 4.0, 500.0, ig[3])
        u[4], ig[4] = _pi(meas[8] - sp[i, 4], 4.0, 300.0, ig[4])
        u[5], ig[5] = _pi(meas[15] - sp[i, 5], 3.0, 200.0, ig[5])
        u[6], ig[6] = _pi(meas[18] - sp[i, 6], 2.0, 60.0, ig[6])
        u[7], ig[7] = _pi(meas[19] - sp[i, 7], 4.0, 300.0, ig[7])
        u[8], ig[8] = _pi(meas[23] - sp[i, 8], 4.0, 300.0, ig[8])
        for j in range(26):
            out[i, j] = meas[j]
        for j in range(9):
            out[i, 26 + j] = u[j]
            out[i, 35 + j] = sp[i, j]
        # ---------------- actuators
        if on and code == 5:  # stick-slip: the valve jumps to the demand past the band
            if abs(u[3] - pos4) > size:
                pos4 = u[3]
        else:
            pos4 = u[3]
        if on and code == 6:
            if i == i0:
                pos3 = u[2] + size
        else:
            pos3 = u[2]
        u107 = u[5] + (size if on and code == 7 else 0.0)
        u107 = min(max(u107, 0.0), 100.0)
        # ---------------- process, one second
        f0 += (18.0 * pcap * (1.0 + pump[i]) * u[0] / 100.0 - f0) / 3.0
        frt = 10.0 * (0.85 + 0.3 * lr / 100.0) * u[1] / 100.0
        if lr < 5.0:
            frt *= max(lr, 0.0) / 5.0  # the pump loses suction
        fr += (frt - fr) / 3.0
        ca1 = (f0 * ca0_i + fr_in * car) / f1
        cb1 = fr_in * cbr / f1
        fs += (3.0 * pos3 / 100.0 - fs) / 5.0
        tpre += (t1 + fs * 525.0 / f1 - tpre) / 90.0
        k = kref * act * np.exp(-ear * (1.0 / (t + 273.15) - 1.0 / 358.15))
        r = k * ca
        qj = uaj * (t - tj)
        d = f1 / 3600.0 / v
        ca += d * (ca1 - ca) - r
        cb += d * (cb1 - cb) + r
        t += d * (tpre - t) + (dh * r - qj / v) / rcp
        v += (f1 - fout) / 3600.0
        v = min(max(v, 0.2), 10.0)
        fc += (fcmax * pos4 / 100.0 - fc) / 5.0
        tj += fc / 3600.0 / vj * (tcw_i - tj) + qj / (vj * 4180.0)
        # product cooler, counter-current
        ch = max(fout, 0.5) / 3600.0 * rcp
        cw = max(fw, 0.5) / 3600.0 * 4180.0
        eff, cmin = _counterflow(ch, cw, ua_i)
        q = eff * cmin * (t - tcw_i)
        tco += (t - q / ch - tco) / 60.0
        twr += (tcw_i + q / cw - twr) / 60.0
        fw += (fwmax * u107 / 100.0 - fw) / 5.0
        # flash drum
        vs = 0.40 * np.exp(0.035 * (tco - 40.0) - 0.01 * (p - 120.0))
        vs = min(max(vs, 0.05), 0.8)
        fv = fout * vs
        cav = ca * 2.2 / (vs * 2.2 + 1.0 - vs)
        cbv = cb * 0.4 / (vs * 0.4 + 1.0 - vs)
        cal = (ca - vs * cav) / (1.0 - vs)
        cbl = (cb - vs * cbv) / (1.0 - vs)
        p += 0.24 * (fv - fvout)
        p = max(p, 100.5)
        ls += (fout - fv - fb - leak_s) / 3600.0 / 8.0 * 100.0
        ls = min(max(ls, 0.0), 100.0)
        # recycle drum
        lr += (fvout - fr - fp) / 3600.0 / 4.0 * 100.0
        lr = min(max(lr, 0.0), 100.0)
        hold = 0.2 + 4.0 * lr / 100.0
        car += fvout / 3600.0 / hold * (cav - car)
        cbr += fvout / 3600.0 / hold * (cbv - cbr)
        tr += (tcw_i + 10.0 + 0.3 * (fvout - 5.6) - tr) / 300.0
        # analysers: first-order lags
        a1 += (ca0_i - a1) / 60.0
        a2 += (ca - a2) / 60.0
        a3 += (100.0 * cbl / max(cal + cbl, 1e-6) - a3) / 300.0
    return out


def _streams(n: int, seed: int, start: pd.Timestamp) -> tuple:
    """The disturbances and set-points of a run of ``n`` seconds (warm-up included) from
    ``start``; they depend only on ``seed``, never on the fault."""
    rng = np.random.default_rng([seed, 2525])
    ca0 = 2.0 + _ou(rng, n, 0.04, 6 * 3600.0) + _ou(rng, n, 0.008, 600.0)
    t0 = 18.0 + _daily(n, start, 3.0, 15.0) + _ou(rng, n, 1.0, 4 * 3600.0)
    tcw = 24.0 + _daily(n, start, 3.0, 16.0) + _ou(rng, n, 0.6, 6 * 3600.0)
    pump = _ou(rng, n, 0.015, 30.0)
    cwx = _ou(rng, n, 1.0, 900.0)  # the extra wander of fault cw_temp_variation
    sp = np.column_stack(
        [
            _hold_schedule(rng, n, 9.0, 11.0, 8 * 3600.0, 0.5, 3600),  # FIC101: rate
            _hold_schedule(rng, n, 3.0, 3.8, 16 * 3600.0, 0.1),  # FIC102
            _hold_schedule(rng, n, 68.0, 72.0, 16 * 3600.0, 1.0),  # TIC103
            _hold_schedule(rng, n, 84.0, 86.0, 24 * 3600.0, 0.5),  # TIC104
            _hold_schedule(rng, n, 55.0, 65.0, 24 * 3600.0, 5.0, 1800),  # LIC101
            _hold_schedule(rng, n, 38.0, 42.0, 16 * 3600.0, 1.0),  # TIC107
            _hold_schedule(rng, n, 118.0, 122.0, 24 * 3600.0, 1.0),  # PIC101
            _hold_schedule(rng, n, 45.0, 55.0, 24 * 3600.0, 5.0, 1800),  # LIC102
            _hold_schedule(rng, n, 45.0, 55.0, 24 * 3600.0, 5.0, 1800),  # LIC103
        ]
    )
    noise_seed = int(rng.integers(0, 2**31 - 1))
    return ca0, t0, tcw, pump, cwx, sp, noise_seed


def simulate_chemplant(
    days: float,
    seed: int,
    *,
    fault: str | None = None,
    onset_s: float | None = None,
    size: float | None = None,
    start: str | pd.Timestamp = "2026-01-01",
) -> pd.DataFrame:
    """The chemical plant on a 1 s grid for ``days`` from ``start`` (UTC), seed ``seed``.

    ``fault`` (a key of :data:`FAULTS`) starts ``onset_s`` seconds after ``start`` (default: a
    third into the run) with ``size`` (default: the fault's own). The frame's ``attrs["fault"]``
    holds the truth (name, kind, tags, size, onset time), ``None`` for a fault-free run.
    """
    if not days > 0:
        raise ValueError(f"days must be positive, not {days}")
    index = _seconds(days, start)
    n = len(index)
    if fault is not None and fault not in FAULTS:
        raise ValueError(f"unknown fault {fault!r}; known: {', '.join(FAULTS)}")
    w0 = index[0] - pd.Timedelta(seconds=WARMUP_S)
    ca0, t0, tcw, pump, cwx, sp, noise_seed = _streams(n + WARMUP_S, seed, w0)
    code, i0, amount, ramp = 0, n + WARMUP_S, 0.0, 0.0
    truth = None
    if fault is not None:
        f = FAULTS[fault]
        onset = n / 3.0 if onset_s is None else float(onset_s)
        if not 0 <= onset < n:
            raise ValueError(f"onset {onset:g} s is outside the run (0…{n - 1} s)")
        amount = f.size if size is None else float(size)
        code, i0, ramp = f.code, WARMUP_S + int(np.ceil(onset)), f.ramp_s
        truth = {
            "fault": fault,
            "kind": f.kind,
            "tags": list(f.tags),
            "size": amount,
            "unit": f.unit,
            "onset": (index[0] + pd.Timedelta(seconds=int(np.ceil(onset)))).isoformat(),
        }
    data = _plant_loop(ca0, t0, tcw, pump, cwx, sp, noise_seed, code, i0, amount, ramp)
    frame = pd.DataFrame(data[WARMUP_S:], index=index, columns=list(CHEMPLANT_TAGS))
    frame.attrs["fault"] = truth
    return frame


def sample(frame: pd.DataFrame, period_s: float, how: str = "mean") -> pd.DataFrame:
    """The 1 s ``frame`` as a historian keeps it every ``period_s`` seconds: the mean over
    each period stamped at its start (``how="mean"``), or the reading at each period's start
    (``"last"``, the instantaneous value). ``attrs`` are kept."""
    p = int(round(period_s))
    if p < 1 or abs(p - period_s) > 1e-9:
        raise ValueError(f"period must be a whole number of seconds ≥ 1, not {period_s}")
    if how not in ("mean", "last"):
        raise ValueError(f"how must be 'mean' or 'last', not {how!r}")
    if p == 1:
        return frame
    m = len(frame) // p
    if how == "last":
        out = frame.iloc[: m * p : p].copy()
    else:
        x = frame.to_numpy()[: m * p].reshape(m, p, frame.shape[1]).mean(axis=1)
        out = pd.DataFrame(x, index=frame.index[: m * p : p], columns=frame.columns)
    out.attrs.update(frame.attrs)
    return out
