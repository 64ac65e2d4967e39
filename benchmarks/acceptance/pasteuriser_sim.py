"""HTST milk pasteuriser, ~10 m³/h: written for acceptance pass 10 and scored once; from now on
a tuning plant (docs/explanation/acceptance-pasteuriser.md, issue 34 items 3-7).

Standard library only. Balance tank (level PI on the inlet valve), feed pump on a VFD (flow
PI), regeneration (raw milk heated by the pasteurised), heating by a hot-water circuit (steam
valve; cascade: the product-outlet PI sets the hot-water set-point), a 15 s holding tube, a
flow-diversion valve (divert under 72 °C at the holding tube's end), cooling by chilled water
(valve PI). Production runs of 6-10 h, then CIP (rinse 2 / caustic 3 / acid 4), then idle 0;
MODE 1 is production. Integrated every 1 s, sampled at the export period with jittered stamps.
Faults (``--fault``) start 60 min into the first production run after ``--onset-after``.

The pass's commands (written once, in /tmp/qa12, before any result was looked at)::

    python3 pasteuriser_sim.py x --tags-csv tags.csv   # the tags CSV (MODE: role state)
    # 10 s build, two weeks, seed 1
    python3 pasteuriser_sim.py train10s.csv --seed 1 --start 2026-03-02T00:00:00 --days 14 \
        --period 10 --jitter 2 --gap 2026-03-09T06:00:00:3 --repeat 50000
    # 1 s build, one day, seed 3
    python3 pasteuriser_sim.py train1s.csv --seed 3 --start 2026-03-16T00:00:00 --days 1 \
        --period 1 --jitter 0.2
    # 10 s judged runs, 4 days: fault-free 101 102 103; faults on seeds 1<i><j>, i = 1..6 in
    # FAULTS' order, j = 1, 2 (111/112 hold_drift ... 161/162 pinhole):
    python3 pasteuriser_sim.py r111.csv --seed 111 --start 2026-03-16T00:00:00 --days 4 \
        --period 10 --jitter 2 --fault hold_drift --onset-after 2026-03-17T08:00:00
    # a new production rate: 171, 172 (10 s, 4 days) with --rate 12:13
    # 1 s judged runs, 1 day from 2026-03-17T00:00:00, --jitter 0.2: fault-free 201, 202;
    # faults 211 ... 261 (one seed each, FAULTS' order) with --onset-after 2026-03-17T02:00:00;
    # a new rate 271, 272 with --rate 12:13

Units built with ``--far 0.01 --loops-from tags.csv --loop BT_LEVEL=50:BT_INLET_VLV --loop
FEED_FLOW=FEED_FLOW_SP:FEED_VFD --loop HEAT_OUT_TEMP=HEAT_OUT_SP:HW_TEMP_SP --loop
HW_TEMP=HW_TEMP_SP:STEAM_VLV --loop COOL_OUT_TEMP=4:CHW_VLV`` (10 s: 2-16 March; 1 s: 16
March; the short window 2026-03-03T04:00Z-05:06:40Z of the 10 s database).
"""

import argparse
import csv
import math
import random
from collections import deque
from datetime import UTC, datetime, timedelta

FAULTS = ("hold_drift", "regen_foul", "hw_stiction", "pump_wear", "chw_step", "pinhole")


class OU:
    """Ornstein-Uhlenbeck walk: time constant tau (s), stationary sigma."""

    def __init__(self, rng, tau, sigma):
        self.rng, self.a, self.s, self.x = rng, math.exp(-1.0 / tau), sigma, 0.0
        self.b = sigma * math.sqrt(1 - self.a**2)

    def step(self):
        self.x = self.a * self.x + self.b * self.rng.gauss(0, 1)
        return self.x


class PI:
    def __init__(self, k, ti, lo, hi, out):
        self.k, self.ti, self.lo, self.hi, self.i = k, ti, lo, hi, out

    def step(self, err, dt=1.0):
        u = self.k * err + self.i
        if (
            self.lo < u < self.hi
            or (u >= self.hi and self.k * err < 0)
            or (u <= self.lo and self.k * err > 0)
        ):
            self.i += self.k * err * dt / self.ti
        return min(self.hi, max(self.lo, self.k * err + self.i))


def eps_cf(ua, c1, c2):
    """Counterflow effectiveness (NTU method)."""
    cmin, cmax = min(c1, c2), max(c1, c2)
    if cmin <= 1e-6:
        return 0.0
    ntu, cr = ua / cmin, cmin / cmax
    if abs(1 - cr) < 1e-3:
        return ntu / (1 + ntu)
    e = math.exp(-ntu * (1 - cr))
    return (1 - e) / (1 - cr * e)


def schedule(rng, t_end, rate_lo, rate_hi):
    """(start_s, mode, flow_sp) segments: production 6-10 h, CIP 80 min, idle 1-3 h."""
    seg, t = [], rng.uniform(0, 2) * 3600
    seg.append((0.0, 0, 0.0))
    while t < t_end:
        seg.append((t, 1, round(rng.uniform(rate_lo, rate_hi), 1)))
        t += rng.uniform(6, 10) * 3600
        for mode, mins in ((2, 10), (3, 30), (2, 10), (4, 20), (2, 10)):
            seg.append((t, mode, 14.0))
            t += mins * 60
        seg.append((t, 0, 0.0))
        t += rng.uniform(1, 3) * 3600
    return seg


def q(x, step):
    return round(round(x / step) * step, 6)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--start", default="2026-03-02T00:00:00")
    ap.add_argument("--days", type=float, default=1.0)
    ap.add_argument("--period", type=float, default=1.0)
    ap.add_argument("--jitter", type=float, default=0.0, help="stamp jitter, +- s")
    ap.add_argument("--rate", default="8.5:11", help="production flow range, m3/h")
    ap.add_argument("--fault", choices=FAULTS)
    ap.add_argument("--onset-after", help="the fault starts 60 min into the first run after this")
    ap.add_argument("--gap", help="START:HOURS missing")
    ap.add_argument("--repeat", type=int, help="row index written twice")
    ap.add_argument("--tags-csv", help="write the tags CSV to this file and stop")
    a = ap.parse_args()
    if a.tags_csv:
        with open(a.tags_csv, "w", newline="") as f:
            f.write(TAGS_CSV)
        return
    rng = random.Random(a.seed)
    t0 = datetime.fromisoformat(a.start).replace(tzinfo=UTC)
    warm = 6 * 3600
    n = int(a.days * 86400) + warm
    lo, hi = (float(v) for v in a.rate.split(":"))
    segs = schedule(rng, n, lo, hi)
    onset = None
    if a.fault:
        after = datetime.fromisoformat(a.onset_after).replace(tzinfo=UTC) - t0
        after_s = after.total_seconds() + warm
        onset = next(s for s, m, _ in segs if m == 1 and s >= after_s) + 3600
        print("onset", (t0 + timedelta(seconds=onset - warm)).isoformat())
    # disturbances
    amb_w, raw_w, chw_w, sup_w = (
        OU(rng, 4 * 3600, 1.0),
        OU(rng, 2 * 3600, 0.3),
        OU(rng, 3600, 0.1),
        OU(rng, 600, 0.05),
    )
    stp = OU(rng, 300, 0.01)
    # state
    lvl, lv, n_vfd, flow = 50.0, 40.0, 0.0, 0.0
    t_reg, t_heat, t_hw, t_p2, t_cool = 20.0, 20.0, 70.0, 20.0, 20.0
    sv, cv, cv_pos, sv_pos = 30.0, 0.0, 0.0, 30.0
    hold_hist = deque([20.0] * 400, maxlen=400)
    fdv, fat, next_batch = 0, 3.8, 0.0
    lvl_pi = PI(2.0, 120, 0, 100, 40)
    flow_pi = PI(2.0, 8, 0, 100, 0)
    prod_pi = PI(1.5, 60, 30, 95, 76)
    hw_pi = PI(4.0, 40, 0, 100, 30)
    cool_pi = PI(-6.0, 60, 0, 100, 0)
    si, mode, fsp = 0, 0, 0.0
    rows, next_sample, k = [], float(warm), 0
    ua_reg0, ua_heat0, ua_cool0 = 100.0, 40.0, 50.0
    noise = rng.gauss
    for t in range(n):
        while si + 1 < len(segs) and segs[si + 1][0] <= t:
            si += 1
            _, mode, fsp = segs[si]
        h = ((t - warm) / 3600.0) % 24
        f_on = onset is not None and t >= onset
        dt_f = (t - onset) / 86400.0 if f_on else 0.0
        t_amb = 20 + 4 * math.sin(2 * math.pi * (h - 9) / 24) + amb_w.step()
        if mode == 1:
            if t >= next_batch:  # a new raw-milk silo
                fat, next_batch = rng.uniform(3.3, 4.6), t + rng.uniform(2, 4) * 3600
            t_in = 4.5 + 1.0 * math.sin(2 * math.pi * (h - 15) / 24) + raw_w.step()
            visc, cp, rho = math.exp(0.25 * (fat - 3.8)), 3.93 - 0.02 * (fat - 3.8), 1030.0
            heat_sp = 74.0
        else:
            raw_w.step()
            visc, cp, rho = 1.0, 4.18, 1000.0 + (15 if mode == 3 else 0)
            t_in = {0: t_amb, 2: 14 + 0.3 * t_amb / 20, 3: 62.0, 4: 52.0}[mode]
            heat_sp = {0: 74.0, 2: 40.0, 3: 75.0, 4: 65.0}[mode]
        t_chw = 1.5 + 0.4 * math.sin(2 * math.pi * (h - 14) / 24) + chw_w.step()
        if a.fault == "chw_step" and f_on:
            t_chw += 2.0
        # feed pump and flow loop
        wear = 1.0 - (min(0.2, 0.12 * dt_f) if a.fault == "pump_wear" else 0.0)
        if mode == 0:
            n_vfd = 0.0
            flow_pi.i = 0.0
        else:
            n_vfd = flow_pi.step(fsp - flow)
        head = 5.0 * (n_vfd / 100) ** 2 * wear - 1.5
        q_ss = math.sqrt(head / (0.004 + 0.0055 * visc)) if head > 0 else 0.0
        flow += (q_ss - flow) / 3.0
        m = flow * rho / 3600.0  # kg/s
        c_p = m * cp
        # regeneration (balanced counterflow, hot side = holding-tube outlet)
        foul = 1.0 - (min(0.5, 0.15 * dt_f) if a.fault == "regen_foul" else 0.0)
        fq = max(flow, 0.5) / 10.0
        ua_r = ua_reg0 * fq**0.6 * visc**-0.3 * foul
        e_r = eps_cf(ua_r, c_p, c_p)
        tau = 150.0 / max(flow, 0.3)  # holding tube, 15 s at 10 m3/h
        idx = min(399, int(tau))
        t_hold_true = hold_hist[-1 - idx] - 0.015 * (hold_hist[-1 - idx] - t_amb)
        reg_ss = t_in + e_r * (t_hold_true - t_in) if m > 0 else t_amb
        t_reg += (reg_ss - t_reg) / (15.0 if m > 0 else 1800.0)
        p2_ss = t_hold_true - e_r * (t_hold_true - t_in) if m > 0 else t_amb
        t_p2 += (p2_ss - t_p2) / (15.0 if m > 0 else 1800.0)
        # hot-water circuit and heating section
        c_hw = 4.0 * 4.18
        e_h = eps_cf(ua_heat0 * fq**0.6 * visc**-0.3, c_p, c_hw)
        q_heat = e_h * min(c_p, c_hw) * (t_hw - t_reg) if m > 0 else 0.0
        heat_ss = t_reg + q_heat / c_p if m > 0 else t_amb
        t_heat += (heat_ss - t_heat) / (8.0 if m > 0 else 1800.0)
        hold_hist.append(t_heat)
        if mode == 0:
            hw_sp = 70.0
            prod_pi.i = 76.0
        else:
            hw_sp = prod_pi.step(heat_sp - t_heat)
        sv = hw_pi.step(hw_sp - t_hw)
        if a.fault == "hw_stiction" and f_on:
            if abs(sv - sv_pos) > 3.0:
                sv_pos = sv
        else:
            sv_pos += (sv - sv_pos) / 4.0
        q_steam = 250.0 * sv_pos / 100 * (1 + stp.step())
        t_hw += (q_steam - q_heat - 0.3 * (t_hw - t_amb)) / 1254.0
        # holding-tube sensor and the flow-diversion valve
        t_hold_meas = t_hold_true + (min(1.5, 0.8 * dt_f) if a.fault == "hold_drift" else 0.0)
        if mode == 1:
            if fdv == 0 and t_hold_meas >= 72.3:
                fdv = 1
            elif fdv == 1 and t_hold_meas < 72.0:
                fdv = 0
        else:
            fdv = 1 if mode in (2, 3, 4) else 0
        # cooling section
        if mode == 1:
            cv = cool_pi.step(4.0 - t_cool)
        else:
            cv, cool_pi.i = 0.0, 30.0
        cv_pos += (cv - cv_pos) / 5.0
        c_c = 6.0 * cv_pos / 100 * 4.19
        e_c = eps_cf(ua_cool0 * fq**0.6, c_p, c_c) if m > 0 else 0.0
        cool_ss = t_p2 - e_c * min(c_p, c_c) * (t_p2 - t_chw) / c_p if m > 0 else t_amb
        t_cool += (cool_ss - t_cool) / (10.0 if m > 0 else 1800.0)
        # balance tank and its level loop
        q_div = flow if (mode == 1 and fdv == 0) else 0.0
        q_in = 18.0 * lv / 100 * (1 + sup_w.step())
        lvl += (q_in + q_div - flow) / 3600.0 / 0.3 * 100
        lvl = min(100.0, max(0.0, lvl))
        lv = lvl_pi.step(50.0 - lvl) if mode != 0 else 0.0
        # regen pressures: the booster keeps the pasteurised side higher
        p_raw = 0.8 + 0.004 * flow**2 * visc if m > 0 else 0.3
        p_past = p_raw + 0.5 + 0.002 * flow**2 if m > 0 else 0.3
        if a.fault == "pinhole" and f_on:
            leak = min(0.35, 0.35 * dt_f * 4) * (p_past - p_raw)
            p_past, p_raw = p_past - 0.7 * leak, p_raw + 0.3 * leak
        if t < warm or t < next_sample:
            continue
        next_sample += a.period
        k += 1
        if a.gap:
            gs, gh = a.gap.rsplit(":", 1)
            g0 = (datetime.fromisoformat(gs).replace(tzinfo=UTC) - t0).total_seconds() + warm
            if g0 <= t < g0 + float(gh) * 3600:
                continue
        stamp = t0 + timedelta(seconds=t - warm + rng.uniform(-a.jitter, a.jitter))
        row = [
            stamp.strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z",
            mode,
            q(lvl + noise(0, 0.2), 0.1),
            q(lv, 0.1),
            q(flow + noise(0, 0.05), 0.01),
            fsp,
            q(n_vfd, 0.1),
            q(t_in + noise(0, 0.03), 0.01),
            q(t_reg + noise(0, 0.03), 0.01),
            q(t_heat + noise(0, 0.03), 0.01),
            heat_sp,
            q(t_hw + noise(0, 0.03), 0.01),
            q(hw_sp, 0.01),
            q(sv, 0.1),
            q(t_hold_meas + noise(0, 0.02), 0.01),
            fdv,
            q(t_p2 + noise(0, 0.03), 0.01),
            q(t_cool + noise(0, 0.03), 0.01),
            q(cv, 0.1),
            q(p_raw + noise(0, 0.005), 0.001),
            q(p_past + noise(0, 0.005), 0.001),
        ]
        rows.append(row)
        if a.repeat is not None and len(rows) == a.repeat:
            rows.append(list(row))
    with open(a.out, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(HEADER)
        w.writerows(rows)


HEADER = [
    "time",
    "MODE",
    "BT_LEVEL",
    "BT_INLET_VLV",
    "FEED_FLOW",
    "FEED_FLOW_SP",
    "FEED_VFD",
    "RAW_TEMP",
    "REGEN_RAW_OUT",
    "HEAT_OUT_TEMP",
    "HEAT_OUT_SP",
    "HW_TEMP",
    "HW_TEMP_SP",
    "STEAM_VLV",
    "HOLD_TEMP",
    "FDV_FORWARD",
    "REGEN_PAST_OUT",
    "COOL_OUT_TEMP",
    "CHW_VLV",
    "P_RAW_REGEN",
    "P_PAST_REGEN",
]

TAGS_CSV = """\
name,unit,lo,hi,description,loop,role,set_point
MODE,,0,4,"plant mode: 0 idle, 1 production, 2 CIP rinse, 3 CIP caustic, 4 CIP acid",,state,
BT_LEVEL,%,0,100,balance tank level,,,
BT_INLET_VLV,%,0,100,balance tank inlet valve,,,
FEED_FLOW,m3/h,0,20,feed flow,,,
FEED_FLOW_SP,m3/h,0,20,feed flow set-point,,,
FEED_VFD,%,0,100,feed pump speed,,,
RAW_TEMP,degC,0,100,raw milk inlet temperature,,,
REGEN_RAW_OUT,degC,0,100,raw milk out of regeneration,,,
HEAT_OUT_TEMP,degC,0,100,product out of heating section,,,
HEAT_OUT_SP,degC,0,100,pasteurisation set-point,,,
HW_TEMP,degC,0,100,hot water temperature,,,
HW_TEMP_SP,degC,0,100,hot water set-point (cascade),,,
STEAM_VLV,%,0,100,steam valve to hot water,,,
HOLD_TEMP,degC,0,100,holding tube outlet temperature (legal),,,
FDV_FORWARD,,0,1,flow diversion valve 1 forward 0 divert,,,
REGEN_PAST_OUT,degC,0,100,pasteurised out of regeneration,,,
COOL_OUT_TEMP,degC,0,100,product out of cooling,,,
CHW_VLV,%,0,100,chilled water valve,,,
P_RAW_REGEN,bar,0,4,raw side pressure regeneration,,,
P_PAST_REGEN,bar,0,4,pasteurised side pressure regeneration,,,
"""

if __name__ == "__main__":
    main()
