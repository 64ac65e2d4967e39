"""Compiled inner loop of the actuator simulator (numba).

One call advances the plant over a chunk of fine time steps ``dt`` and records
the instantaneous signals at every output sample. Exogenous inputs (process
pressures, temperature, flow set-point, flow-transmitter noise) and the fault
vector arrive on a 1 s grid and are held within each second; the flow
controller also runs once per second. State is carried between chunks in
``state`` and the dead-time ring buffer ``buf``.

Physics per fine step (Bartyś & de las Heras, IFAC SAFEPROCESS 2003, §6;
Hull Jan 2002 slides):

* Positioner (2003 §6.1, Figs. 4–5): low-pass input filter on CV, proportional
  controller ``CVI = Kp (SP - x_fb)`` limited to ±1 (``Kp = 0``: no positioner,
  ``CVI = SP`` drives the E/P converter open-loop), E/P transducer
  ``P0 = Pz_nom (1 + CVI) / 2`` (current ``i = (1 + CVI) / 2``) limited to the supply
  pressure. SP is CV after the zero/span calibration done at commissioning
  (``a0 + a1·CV``), so a healthy actuator settles at X = CV.
* Pneumatic chamber (2003 eq. 6, Hull "Pneumatic chamber model" eq. 4,
  isothermal): ``dp/dt = (RT/V) ṁ`` with the positioner's air flow
  ``ṁ = Cq (P0 - p)`` gives a first-order lag of time constant
  ``τ = V / (R T Cq)``; leaks (f9, f10) add an outflow ``λ·ṁ-scale·p``.
* Servomotor (2003 eq. 1, Hull "force balance"): the mass and viscous terms act
  on millisecond scales and are dropped (quasi-static), leaving
  ``Ae p = (ks + kd)(x + x0) + Fvc - m g ± Ff``. The friction ``Ff`` is Karnopp's
  stick–slip model (2003 "Model of friction"; Hull "Model of stick-slip effect"):
  a rod at rest stays put while ``|F_ext| <= Fs`` (static friction); once it moves
  it slides to where ``F_ext = ±Fc`` (Coulomb). A rod that moved less than
  ``v_min·dt`` in the last step counts as at rest again. ``Fc`` is set from the
  open-loop hysteresis width ``Db`` (DABLib Table 7: ``Fc = Db (ks + kd) / 2``).
  The slip position is solved implicitly together with the chamber pressure and
  the positioner's pressure (safeguarded Newton on a piecewise-linear monotone
  function), which keeps the stiff positioner loop stable at any ``dt``.
* Plug force ``Fvc = -Au (P1 - P2)(1 - x)``: flow under the plug pushes it open.
* Valve and flow: :mod:`.physics` (2003 eqs. 7–9) plus the bypass valve.
* Flow controller (not part of the actuator; the plant around it): PI on the
  measured flow, CV limited to 0–100 % with conditional-integration anti-windup.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .physics import allowed_pressure_drop_kpa, kv_relative, liquid_flow_th, water_density

# ---- indices into the parameter vector ``prm`` (filled by valve.py) ----
P_DT = 0  # fine step, s
P_ALPHA_F = 1  # input-filter update factor 1 - exp(-dt/tau_f)
P_TAU_CH = 2  # chamber time constant, s
P_KP = 3  # positioner proportional gain, 1 per unit travel error (0: no positioner)
P_PZ = 4  # nominal supply pressure (E/P full scale), kPa
P_A0 = 5  # positioner calibration: SP = a0 + a1 * CV
P_A1 = 6
P_AE = 7  # effective diaphragm area, m^2
P_KS = 8  # spring constant, N/m
P_KD = 9  # diaphragm constant, N/m
P_L = 10  # nominal travel, m
P_X0 = 11  # initial spring compression, m
P_MG = 12  # weight of moving parts, N
P_AU = 13  # unbalanced plug area, m^2
P_H0 = 14  # open-loop hysteresis width, relative to travel
P_STICK = 15  # static / Coulomb friction ratio
P_VMIN = 16  # rest-detection speed, travel/s
P_KVS = 17  # valve Kvs, m^3/h
P_RANGE = 18  # rangeability R of the equal-percentage characteristic
P_KM0 = 19  # recovery coefficient Km = km0 - km1 X
P_KM1 = 20
P_KVS_BP = 21  # bypass valve Kvs (linear characteristic), m^3/h
P_KC = 22  # flow controller gain, % CV per t/h
P_TI = 23  # flow controller integral time, s
P_F_SPAN = 24  # flow transmitter span, t/h
P_F7_DT0 = 25  # f7: temperature rise at fs -> 0+, K
P_F7_DT1 = 26  # f7: temperature rise per unit strength, K
P_LEAK = 27  # f9/f10: leak conductance per unit strength per kPa (2e-6 per Pa)
N_PRM = 28

# ---- indices into the state vector ----
S_SPF = 0  # filtered set-point (relative)
S_P = 1  # chamber pressure, kPa gauge
S_X = 2  # rod travel, relative opening
S_MOV = 3  # direction of motion in the last step (-1, 0, 1)
S_XB = 4  # positioner feedback after the backlash (f15)
S_I = 5  # controller integral term, %
S_CV = 6  # controller output, %
S_BI = 7  # write position in the dead-time ring buffer
S_FM = 8  # last measured flow seen by the controller, t/h
N_STATE = 9

# ---- columns of the output block ----
O_CV = 0
O_XS = 1  # positioner displacement sensor (relative)
O_P1 = 2
O_P2 = 3
O_T = 4
O_FM = 5  # measured flow (transmitter, incl. f19 and noise), t/h
O_P0 = 6  # E/P output pressure, kPa gauge
O_PCH = 7  # chamber pressure, kPa gauge
O_X = 8  # true travel (relative)
O_F = 9  # true flow reaching the flow meter, t/h
O_SP = 10  # flow set-point, t/h
N_OUT = 11


@nb.njit(cache=True, nogil=True)
def total_flow(x, p1, p2, tc, fv, prm):
    """Flow reaching the flow meter, t/h: control valve + bypass, with f2, f3, f5, f6, f18.

    DABLib Tables 5, 6 (effective opening and Kv), 9 (Kv), 21 (bypass opening),
    8 (external leakage); valve flow after Bartyś & de las Heras 2003, eqs. 7–9.
    """
    f2 = fv[1]
    f3 = fv[2]
    f5 = fv[4]
    f6 = fv[5]
    f18 = fv[17]
    km0 = prm[P_KM0]
    km1 = prm[P_KM1]
    rho = water_density(tc)
    xe = x - 0.2 * f2 + 0.1 * f3
    if xe < 0.0:
        xe = 0.0
    kv = prm[P_KVS] * kv_relative(xe, prm[P_RANGE]) * (1.0 - 0.2 * f2) * (1.0 + 0.1 * f3)
    kv *= 1.0 + 0.1 * f6
    dp = p1 - p2
    dpa = allowed_pressure_drop_kpa(xe, p1, tc, km0, km1)
    f = liquid_flow_th(kv, min(dp, dpa), rho)
    if f18 > 0.0:
        dpb = allowed_pressure_drop_kpa(f18, p1, tc, km0, km1)
        f += liquid_flow_th(prm[P_KVS_BP] * f18, min(dp, dpb), rho)
    return f * (1.0 - 0.05 * f5)


@nb.njit(cache=True, nogil=True)
def _e_p(xn, xb, sens_gain, half_d, s_pos, kp, i_gain, pz, pzf):
    """E/P output pressure for rod position ``xn``; returns (P0, dP0/dx, x_fb).

    Positioner of Bartyś & de las Heras 2003 §6.1 with the faults f12 (Table 15,
    current i0 (1 - fs)), f13 (Table 16, sensor X (1 + 1.25 fs)), f15 (Table 18,
    feedback backlash) and f16 (Table 19, supply limit).
    """
    xs = xn * sens_gain
    dxs = sens_gain
    if xs < 0.0:
        xs = 0.0
        dxs = 0.0
    elif xs > 1.0:
        xs = 1.0
        dxs = 0.0
    xbn = xb
    dxb = 0.0
    if xbn < xs - half_d:
        xbn = xs - half_d
        dxb = dxs
    elif xbn > xs + half_d:
        xbn = xs + half_d
        dxb = dxs
    if kp > 0.0:
        cvi = kp * (s_pos - xbn)
        dcvi = -kp * dxb
    else:  # no positioner: the calibrated CV drives the E/P converter directly
        cvi = s_pos
        dcvi = 0.0
    if cvi > 1.0:
        cvi = 1.0
        dcvi = 0.0
    elif cvi < -1.0:
        cvi = -1.0
        dcvi = 0.0
    p0 = pz * 0.5 * (1.0 + cvi) * i_gain
    dp0 = pz * 0.5 * dcvi * i_gain
    if p0 > pzf:
        p0 = pzf
        dp0 = 0.0
    elif p0 < 0.0:
        p0 = 0.0
        dp0 = 0.0
    return p0, dp0, xbn


@nb.njit(cache=True, nogil=True)
def run_chunk(prm, n_fine, sps, spo, p1s, p2s, tcs, spfs, fnoise, fv, state, buf, out):
    """Advance ``n_fine`` fine steps; write a row of ``out`` every ``spo`` steps.

    ``sps`` fine steps make one second (the grid of the per-second inputs and of
    the flow controller). ``fv`` is (19, n_seconds) signed fault strengths.
    """
    dt = prm[P_DT]
    alpha_f = prm[P_ALPHA_F]
    tau_ch = prm[P_TAU_CH]
    kp = prm[P_KP]
    pz = prm[P_PZ]
    a0 = prm[P_A0]
    a1 = prm[P_A1]
    ae = prm[P_AE]
    ks = prm[P_KS]
    kd = prm[P_KD]
    stroke = prm[P_L]
    x0r = prm[P_X0] / stroke
    mg = prm[P_MG]
    au = prm[P_AU]
    h0 = prm[P_H0]
    stick = prm[P_STICK]
    vmin_dx = prm[P_VMIN] * dt
    kc = prm[P_KC]
    ti = prm[P_TI]
    fspan = prm[P_F_SPAN]
    beta0 = 1.0 - math.exp(-dt / tau_ch)
    kn = (ks + kd) * stroke  # nominal stiffness, N per unit travel

    spf = state[S_SPF]
    p = state[S_P]
    x = state[S_X]
    mov = state[S_MOV]
    xb = state[S_XB]
    integ = state[S_I]
    cv = state[S_CV]
    bi = int(state[S_BI])
    fm = state[S_FM]
    nbuf = buf.shape[0]
    fcur = np.zeros(19)

    # per-second quantities (set at j % sps == 0)
    p1 = 0.0
    p2 = 0.0
    tc = 0.0
    dp = 0.0
    hb = 1.0
    kf = kn
    aef = ae
    fc = 0.0
    fs_ = 0.0
    lam_k = 0.0
    pzf = pz
    i_gain = 1.0
    sens_gain = 1.0
    half_d = 0.0
    k = -1
    row = 0
    for j in range(n_fine):
        if j % sps == 0:
            k = j // sps
            for q in range(19):
                fcur[q] = fv[q, k]
            p1 = p1s[k]
            p2 = p2s[k]
            tc = tcs[k]
            f17 = fcur[16]
            if f17 < 0.0:  # DABLib Table 20
                p1 = p1 * (1.0 + f17)
            elif f17 > 0.0:
                p2 = p2 * (1.0 - f17)
            if fcur[6] > 0.0:  # DABLib Table 10
                tc = tc + prm[P_F7_DT0] + prm[P_F7_DT1] * fcur[6]
            dp = max(p1 - p2, 0.0)
            # travel bound: DABLib Tables 4, 5, 6
            hb = (1.0 - fcur[0]) * (1.0 - 0.2 * fcur[1]) * (1.0 + 0.1 * fcur[2])
            # spring: Table 14; diaphragm area: Table 13
            kf = (ks * (1.0 - fcur[10]) + kd) * stroke
            aef = ae * (1.0 - fcur[9])
            # friction from the hysteresis width: Table 7 (f4) and Table 11 (f8)
            db = max(0.0, h0 + fcur[3])
            db = min(1.0, max(0.0, db * (1.0 + 0.5 * fcur[7] * x)))
            fc = 0.5 * db * kn
            fs_ = stick * fc
            lam_k = prm[P_LEAK] * (fcur[8] + fcur[9])  # Tables 12, 13
            pzf = pz * (1.0 - fcur[15])  # Table 19
            i_gain = 1.0 - fcur[11]  # Table 15
            sens_gain = 1.0 + 1.25 * fcur[12]  # Table 16
            half_d = 0.5 * abs(fcur[14])  # Table 18
            # flow, its measurement (Table 22) and the PI flow controller
            ftrue = total_flow(x, p1, p2, tc, fcur, prm)
            fm = ftrue * (1.0 + fcur[18]) + fnoise[k]
            fm = min(max(fm, 0.0), fspan)
            e = spfs[k] - fm
            inc = kc / ti * e  # 1 s controller period
            u = kc * e + integ + inc
            if u > 100.0:
                if inc < 0.0:
                    integ += inc
                u = 100.0
            elif u < 0.0:
                if inc > 0.0:
                    integ += inc
                u = 0.0
            else:
                integ += inc
            cv = u
        # dead time between the controller and the positioner
        if nbuf > 1:
            buf[bi] = cv
            bi = (bi + 1) % nbuf
            c = buf[bi] * 0.01
        else:
            c = cv * 0.01
        if j % spo == 0:
            ftrue = total_flow(x, p1, p2, tc, fcur, prm)
            fmo = ftrue * (1.0 + fcur[18]) + fnoise[k]
            xs = min(max(x * sens_gain, 0.0), 1.0)
            out[row, O_CV] = cv
            out[row, O_XS] = xs
            out[row, O_P1] = p1
            out[row, O_P2] = p2
            out[row, O_T] = tc
            out[row, O_FM] = min(max(fmo, 0.0), fspan)
            p0r, _, _ = _e_p(x, xb, sens_gain, half_d, a0 + a1 * spf, kp, i_gain, pz, pzf)
            out[row, O_P0] = p0r
            out[row, O_PCH] = p
            out[row, O_X] = x
            out[row, O_F] = ftrue
            out[row, O_SP] = spfs[k]
            row += 1
        # positioner input filter and calibration
        spf += alpha_f * (c - spf)
        s_pos = a0 + a1 * spf
        # chamber: leak-dependent update factor
        lam = lam_k * p if p > 0.0 else 0.0
        if lam > 0.0:
            beta = (1.0 - math.exp(-dt * (1.0 + lam) / tau_ch)) / (1.0 + lam)
        else:
            beta = beta0
        # beta_bar multiplies P0; the old pressure decays with (1 - beta * (1 + lam))
        keep = 1.0 - beta * (1.0 + lam)
        if x > hb:
            x = hb
        if x < 0.0:
            x = 0.0
        # stick test at the current position
        p0s, _, xbs = _e_p(x, xb, sens_gain, half_d, s_pos, kp, i_gain, pz, pzf)
        ps = keep * p + beta * p0s
        fn = aef * 1000.0 * ps - kf * (x + x0r) - mg + au * 1000.0 * dp * (1.0 - x)
        thr = fs_
        if mov != 0.0 and fn * mov > 0.0:
            thr = fc
        if abs(fn) <= thr:
            p = ps
            xb = xbs
            mov = 0.0
            continue
        sgn = 1.0 if fn > 0.0 else -1.0
        target = sgn * fc
        # solve g(xn) = Fnet(xn, p(xn)) - target = 0, g decreasing, on [0, hb]
        lo = 0.0
        hi = hb
        p0l, _, _ = _e_p(lo, xb, sens_gain, half_d, s_pos, kp, i_gain, pz, pzf)
        gl = aef * 1000.0 * (keep * p + beta * p0l) - kf * x0r - mg + au * 1000.0 * dp - target
        if gl <= 0.0:
            xn = lo
        else:
            p0h, _, _ = _e_p(hi, xb, sens_gain, half_d, s_pos, kp, i_gain, pz, pzf)
            gh = (
                aef * 1000.0 * (keep * p + beta * p0h)
                - kf * (hi + x0r)
                - mg
                + au * 1000.0 * dp * (1.0 - hi)
                - target
            )
            if gh >= 0.0:
                xn = hi
            else:
                xn = min(max(x, lo), hi)
                for _it in range(40):
                    p0n, dp0n, _ = _e_p(xn, xb, sens_gain, half_d, s_pos, kp, i_gain, pz, pzf)
                    g = (
                        aef * 1000.0 * (keep * p + beta * p0n)
                        - kf * (xn + x0r)
                        - mg
                        + au * 1000.0 * dp * (1.0 - xn)
                        - target
                    )
                    if g > 0.0:
                        lo = xn
                    else:
                        hi = xn
                    dg = aef * 1000.0 * beta * dp0n - kf - au * 1000.0 * dp
                    xt = xn - g / dg if dg < 0.0 else 0.5 * (lo + hi)
                    if not (lo < xt < hi):
                        xt = 0.5 * (lo + hi)
                    if abs(xt - xn) < 1e-12 or hi - lo < 1e-12:
                        xn = xt
                        break
                    xn = xt
        p0n, _, xbn = _e_p(xn, xb, sens_gain, half_d, s_pos, kp, i_gain, pz, pzf)
        p = keep * p + beta * p0n
        xb = xbn
        d = xn - x
        if d > vmin_dx:
            mov = 1.0
        elif d < -vmin_dx:
            mov = -1.0
        else:
            mov = 0.0
        x = xn

    state[S_SPF] = spf
    state[S_P] = p
    state[S_X] = x
    state[S_MOV] = mov
    state[S_XB] = xb
    state[S_I] = integ
    state[S_CV] = cv
    state[S_BI] = bi
    state[S_FM] = fm
    return row
