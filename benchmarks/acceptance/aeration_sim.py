"""A two-zone activated-sludge aeration basin (docs/explanation/acceptance-aeration2.md).

Written once from its physics for the eleventh acceptance pass (issue 34), standard library and
numpy only, and never tuned against the unit. Two aerated zones of 2,000 m³ in parallel share
the influent (60 / 40 %); each zone's dissolved oxygen (DO) is held by a PI loop on its air
valve; the valves are fed by one blower header whose pressure is held by a PI on the blower's
speed (valves move → header pressure → blower). Per zone, a lumped oxygen balance::

    dC/dt = kLa(air) (Csat(T) − C) − OUR · C / (0.4 + C)
    kLa = α (air / 1000)^0.85,   air = 460 · valve/100 · √(P − 450)   [Nm³/h, P mbar]
    OUR = share · Q (4.57 · 0.8 · NH4 + 60) / V  (lagged 1 h: the biomass) + 8 mg/l/h

``Csat(T)`` the usual cubic in the water temperature. The header: ``C_h dP/dt = Qb − Σ air``,
``Qb = 115 · speed − 4 (P − 500)``. The influent has a daily cycle, weekends at 85 %, a slow
walk and rain events (×1.8–2.6 for 3–8 h, the ammonia diluted): a measured disturbance.

Simulated every ``--dt`` s, sampled instantaneously at stamps jittered ±20 % of ``--period``,
written as CSV in UTC (``2026-03-02T08:18:03.393Z``)::

    python benchmarks/acceptance/aeration_sim.py train1m.csv --start 2026-03-02 --days 14 \\
        --period 60 --seed 1 --gap 2026-03-09T02:00,2026-03-09T04:00 --tags tags.csv
    python benchmarks/acceptance/aeration_sim.py r211.csv --start 2026-03-16 --days 3 \\
        --period 60 --seed 211 --fault do1_drift --onset 2026-03-17T00:00

Faults (``--fault``, from ``--onset``): ``do1_drift`` the zone 1 probe +0.6 mg/l over a day
(fouled membrane; inside its loop), ``vlv2_stiction`` zone 2's valve moves only when the
command is 3 % away, ``air1_bias`` ``AIR1`` reads +250 Nm³/h, ``diffuser1`` zone 1's α −30 %
over a day (the valve opens more for the same DO), ``sp_move`` no fault: both DO set-points
moved 2.0 → 1.5 mg/l by the operator.
"""

from __future__ import annotations

import argparse
import math
from datetime import UTC, datetime, timedelta

import numpy as np

TAGS = ["INF_FLOW", "NH4_IN", "TEMP", "DO1", "DO1_SP", "DO1_VLV", "AIR1", "DO2", "DO2_SP",
        "DO2_VLV", "AIR2", "HDR_P", "HDR_P_SP", "BLW_SPEED"]  # fmt: skip
TAG_ROWS = [  # name, unit, lo, hi, description, loop, role
    ("INF_FLOW", "m3/h", 0, 6000, "influent flow", "", "disturbance"),
    ("NH4_IN", "mg/l", 0, 80, "influent ammonia analyser", "", ""),
    ("TEMP", "degC", 0, 30, "basin water temperature", "", ""),
    ("DO1", "mg/l", 0, 10, "zone 1 dissolved oxygen", "do1", "pv"),
    ("DO1_SP", "mg/l", 0, 10, "zone 1 DO set-point", "do1", "sp"),
    ("DO1_VLV", "%", 0, 100, "zone 1 air valve output", "do1", "out"),
    ("AIR1", "Nm3/h", 0, 8000, "zone 1 air flow", "", ""),
    ("DO2", "mg/l", 0, 10, "zone 2 dissolved oxygen", "do2", "pv"),
    ("DO2_SP", "mg/l", 0, 10, "zone 2 DO set-point", "do2", "sp"),
    ("DO2_VLV", "%", 0, 100, "zone 2 air valve output", "do2", "out"),
    ("AIR2", "Nm3/h", 0, 8000, "zone 2 air flow", "", ""),
    ("HDR_P", "mbar", 400, 800, "air header pressure", "hdr", "pv"),
    ("HDR_P_SP", "mbar", 400, 800, "air header pressure set-point", "hdr", "sp"),
    ("BLW_SPEED", "%", 0, 100, "blower speed", "hdr", "out"),
]
FAULTS = ("do1_drift", "vlv2_stiction", "air1_bias", "diffuser1", "sp_move")


def csat(t: float) -> float:
    """Oxygen saturation in fresh water, mg/l, at ``t`` °C (the usual cubic)."""
    return 14.62 - 0.3898 * t + 0.006969 * t * t - 5.897e-5 * t**3


def simulate(
    start: datetime,
    days: float,
    period: float,
    dt: float,
    seed: int,
    fault: str | None,
    onset: datetime | None,
) -> tuple[list[datetime], np.ndarray]:
    """Simulate and sample; return the jittered stamps and the (n, 14) samples."""
    rng = np.random.default_rng(seed)
    warm = 6 * 3600.0
    n_steps = int((days * 86400 + warm) / dt) + 1
    t0 = start - timedelta(seconds=warm)
    # the sampling instants: a jittered grid, then the nearest step
    n_out = int(days * 86400 / period)
    grid = np.arange(n_out) * period + rng.uniform(-0.2, 0.2, n_out) * period
    grid = np.clip(grid, 0, days * 86400 - dt)
    steps = np.round((grid + warm) / dt).astype(int)
    want: dict[int, list[int]] = {}
    for i, s in enumerate(steps):
        want.setdefault(int(s), []).append(i)
    out = np.zeros((n_out, len(TAGS)))
    on_s = (onset - t0).total_seconds() if onset is not None else math.inf
    # rain events: start times (s from t0), durations, peaks
    rains = []
    t = rng.exponential(3.5 * 86400)
    while t < n_steps * dt:
        rains.append((t, rng.uniform(3, 8) * 3600, rng.uniform(0.8, 1.6)))
        t += rng.exponential(3.5 * 86400)
    vol, share, alpha = 2000.0, (0.6, 0.4), [3.3, 3.6]
    walk_q = walk_t = walk_n = 0.0
    do = [2.0, 2.0]
    do_meas = [2.0, 2.0]
    read = [2.0, 2.0]
    our_lag = [50.0, 35.0]
    vlv = [45.0, 40.0]
    vpos = [45.0, 40.0]
    integ = [45.0, 40.0]
    p = 600.0
    speed = 50.0
    integ_b = 50.0
    sq = math.sqrt(dt)
    for k in range(n_steps):
        ts = k * dt
        now = t0 + timedelta(seconds=ts)
        hod = now.hour + now.minute / 60 + now.second / 3600
        doy = (now - datetime(2026, 1, 1, tzinfo=UTC)).total_seconds() / 86400
        walk_q += -walk_q * dt / 86400 + 0.05 * sq / math.sqrt(86400) * rng.standard_normal()
        walk_t += (
            -walk_t * dt / (3 * 86400) + 0.4 * sq / math.sqrt(3 * 86400) * rng.standard_normal()
        )
        walk_n += -walk_n * dt / 7200 + 0.08 * sq / math.sqrt(7200) * rng.standard_normal()
        dry = 1200 * (1 + 0.35 * math.sin(2 * math.pi * (hod - 8) / 24)) * (1 + walk_q)
        if now.weekday() >= 5:
            dry *= 0.85
        rain = sum(a * math.sin(math.pi * (ts - r0) / d) for r0, d, a in rains if r0 <= ts < r0 + d)
        q = dry * (1 + rain)
        nh4 = 32 * (1 + 0.25 * math.sin(2 * math.pi * (hod - 10) / 24) + walk_n) * dry / q
        temp = (
            14
            + 2.0 * math.sin(2 * math.pi * doy / 40)
            + 0.3 * math.sin(2 * math.pi * (hod - 15) / 24)
            + walk_t
        )
        faulty = ts >= on_s
        ramp = min(1.0, (ts - on_s) / 86400) if faulty else 0.0
        sp = 1.5 if fault == "sp_move" and faulty else 2.0
        cs = csat(temp)
        air = [0.0, 0.0]
        for z in range(2):
            # the valve: a 10 s actuator, stiction in zone 2 when faulted
            if z == 1 and fault == "vlv2_stiction" and faulty:
                if abs(vlv[z] - vpos[z]) > 3.0:
                    vpos[z] = vlv[z]
            else:
                vpos[z] += (vlv[z] - vpos[z]) * min(1.0, dt / 10)
            air[z] = 460 * max(vpos[z], 0.0) / 100 * math.sqrt(max(p - 450, 0.0))
            a = alpha[z] * (1 - 0.3 * ramp if z == 0 and fault == "diffuser1" else 1.0)
            kla = a * (air[z] / 1000) ** 0.85
            demand = share[z] * q * (4.57 * 0.8 * nh4 + 60) / vol
            our_lag[z] += (demand - our_lag[z]) * dt / 3600
            our = (our_lag[z] + 8) * do[z] / (0.4 + do[z])
            do[z] = max(0.0, do[z] + (kla * (cs - do[z]) - our) * dt / 3600)
            do_meas[z] += (do[z] - do_meas[z]) * min(1.0, dt / 30)
            read[z] = do_meas[z] + (0.6 * ramp if z == 0 and fault == "do1_drift" else 0.0)
            # PI: 12 %/(mg/l), integral 600 s, anti-windup by clamping
            e = read[z] - sp
            integ[z] = min(100.0, max(0.0, integ[z] - 12 * e * dt / 600))
            vlv[z] = min(100.0, max(0.0, integ[z] - 12 * e))
        qb = 115 * speed - 4 * (p - 500)
        p += (qb - air[0] - air[1]) / 150 * dt
        eb = p - 600.0
        integ_b = min(100.0, max(10.0, integ_b - 0.15 * eb * dt / 60))
        speed = min(100.0, max(10.0, integ_b - 0.15 * eb))
        if k in want:
            a1 = air[0] + (250 if fault == "air1_bias" and faulty else 0.0)
            row = [
                q,
                nh4,
                temp,
                read[0],
                sp,
                vlv[0],
                a1,
                read[1],
                sp,
                vlv[1],
                air[1],
                p,
                600.0,
                speed,
            ]
            noise = [8, 0.3, 0.02, 0.02, 0, 0, 30, 0.02, 0, 0, 30, 1.0, 0, 0]
            quant = [1, 0.1, 0.01, 0.01, 0.1, 0.1, 1, 0.01, 0.1, 0.1, 1, 0.1, 1, 0.1]
            vals = [
                round((v + s * rng.standard_normal()) / qq) * qq
                for v, s, qq in zip(row, noise, quant, strict=True)
            ]
            for i in want[k]:
                out[i] = vals
    stamps = [start + timedelta(seconds=float(g)) for g in grid]
    return stamps, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out")
    ap.add_argument("--start", required=True)
    ap.add_argument("--days", type=float, required=True)
    ap.add_argument("--period", type=float, default=60)
    ap.add_argument("--dt", type=float, default=2.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--fault", choices=FAULTS)
    ap.add_argument("--onset")
    ap.add_argument("--gap", help="FROM,TO: an outage of the historian (no rows)")
    ap.add_argument("--tags", help="also write the tags CSV here")
    a = ap.parse_args()
    utc = UTC
    start = datetime.fromisoformat(a.start).replace(tzinfo=utc)
    onset = datetime.fromisoformat(a.onset).replace(tzinfo=utc) if a.onset else None
    stamps, vals = simulate(start, a.days, a.period, a.dt, a.seed, a.fault, onset)
    gap = (
        [datetime.fromisoformat(g).replace(tzinfo=utc) for g in a.gap.split(",")] if a.gap else None
    )
    with open(a.out, "w") as f:
        f.write("time," + ",".join(TAGS) + "\n")
        for s, v in zip(stamps, vals, strict=True):
            if gap and gap[0] <= s < gap[1]:
                continue
            txt = s.strftime("%Y-%m-%dT%H:%M:%S.") + f"{s.microsecond // 1000:03d}Z"
            f.write(txt + "," + ",".join(f"{x:.6g}" for x in v) + "\n")
    if a.tags:
        with open(a.tags, "w") as f:
            f.write("name,unit,lo,hi,description,loop,role\n")
            for r in TAG_ROWS:
                f.write(",".join(str(x) for x in r) + "\n")


if __name__ == "__main__":
    main()
