"""The compressed-air station of docs/explanation/acceptance-compressors.md, REBUILT from that
page's "The plant" section (the pass's own simulator, ``/tmp/qa9/sim.py``, was lost): a tuning
plant now, not the plant the acceptance pass judged. Its figures are a rebuild's, not the
pass's; the page says which is which.

Three oil-injected screw compressors on lead / lag / standby, loading and unloading on the
header transmitter's pressure bands, the lead rotated every midnight (``day number mod 3``,
30 June 2026 C1), a receiver, a refrigerated dryer and a plant whose draw follows two shifts.
Simulated every ``--dt`` s and sampled at ``--period`` s (instantaneous samples, transmitter
noise, stamps jittered by ``--jitter`` s), written as CSV (``time`` and the 20 tags); ``--tags
FILE`` writes the tags CSV (``name,unit,lo,hi,description,loop,role``) beside it::

    python benchmarks/acceptance/compressors_sim.py train3m.csv --start 2026-06-01 --days 28 \\
        --seed 1 --period 180 --jitter 20 --dt 2 --gap 2026-06-10T03:00,2026-06-10T09:00 \\
        --tags tags.csv
    python benchmarks/acceptance/compressors_sim.py r131.csv --start 2026-06-29 --days 4 \\
        --period 180 --jitter 20 --dt 2 --seed 131 --fault td_bias --onset 2026-06-30T08:00

Faults (``--fault``, from ``--onset``): ``leak`` 2.5 m³/min at 7 bar upstream of the flow
meter, ``pdp_drift`` the dew-point sensor +2 K a day, ``td_bias`` ``C2_TD`` +8 K, ``tac_foul``
C1's aftercooler approach ×2.4 over two days, ``hdr_bias`` ``PT_HDR`` +0.25 bar (inside the
load/unload loop). ``--out-of C2 --out-from … --out-to …``: a compressor out for maintenance
(the rotation skips it).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numba
import numpy as np
import pandas as pd

TAGS = ["FT_PLANT", "T_AMB", "PT_RCV", "PT_HDR", "DRY_PDP"] + [
    f"C{n}_{k}" for n in (1, 2, 3) for k in ("RUN", "AMPS", "KW", "TD", "TAC")
]
#: name, unit, lo, hi, description, role (no loop: a load/unload band has no continuous output)
TAG_ROWS = [
    ("FT_PLANT", "m3/min", 0, 40, "flow to the plant", "disturbance"),
    ("T_AMB", "degC", 0, 50, "compressor-room temperature", "disturbance"),
    ("PT_RCV", "bar(g)", 0, 10, "receiver pressure", ""),
    ("PT_HDR", "bar(g)", 0, 10, "header pressure after the dryer", ""),
    ("DRY_PDP", "degC", -10, 30, "dryer pressure dew point", ""),
] + [
    row
    for n in (1, 2, 3)
    for row in (
        (f"C{n}_RUN", "", 0, 1, f"compressor {n} running", ""),
        (f"C{n}_AMPS", "A", 0, 150, f"compressor {n} motor current", ""),
        (f"C{n}_KW", "kW", 0, 80, f"compressor {n} power", ""),
        (f"C{n}_TD", "degC", 0, 120, f"compressor {n} discharge temperature", ""),
        (f"C{n}_TAC", "degC", 0, 80, f"compressor {n} aftercooler outlet", ""),
    )
]
FAULTS = ("leak", "pdp_drift", "td_bias", "tac_foul", "hdr_bias")
#: the rotation's day 0: Tuesday 30 June 2026, lead C1
ROTATION_DAY0 = pd.Timestamp("2026-06-30", tz="UTC")
#: load below / unload above, bar(g) on the header transmitter: lead, lag, standby
BANDS = np.array([[6.8, 7.4], [6.6, 7.2], [6.4, 7.0]])
BANDS_LO = BANDS[:, 0].copy()
BANDS_HI = BANDS[:, 1].copy()


def _ou(rng: np.random.Generator, n: int, dt: float, tau_s: float) -> np.ndarray:
    """A unit-variance Ornstein–Uhlenbeck walk of time constant ``tau_s``."""
    from scipy.signal import lfilter

    a = math.exp(-dt / tau_s)
    x = lfilter([1.0], [1.0, -a], rng.standard_normal(n) * math.sqrt(1 - a * a))
    return x


def demand(t: pd.DatetimeIndex, rng: np.random.Generator, dt: float) -> np.ndarray:
    """The plant's draw of free air, m³/min (the page's "Demand")."""
    h = (t.hour + t.minute / 60 + t.second / 3600).to_numpy(float)
    wd = t.day_of_week.to_numpy()
    weekday = wd < 5
    up = np.clip((h - 5.75) / 0.5, 0, 1)
    down = 1 - np.clip((h - 21.75) / 0.5, 0, 1)
    occ = np.where(weekday, np.minimum(up, down), 0.0)
    sat = 0.55 * np.minimum(np.clip((h - 5.75) / 0.5, 0, 1), 1 - np.clip((h - 13.75) / 0.5, 0, 1))
    occ = np.where(wd == 5, sat, occ)
    surge = np.where(weekday, 8 * np.exp(-(((h - 6.25) / 0.2) ** 2)), 0.0)
    brk = np.where(weekday & (h >= 12) & (h < 12.5), -3.0, 0.0)
    n = (0.3 + occ) * _ou(rng, h.size, dt, 3600) + 0.5 * occ * _ou(rng, h.size, dt, 120)
    return np.maximum(2.2 + 12.5 * occ + surge + brk + n, 0.8)


def room_base(t: pd.DatetimeIndex, rng: np.random.Generator, dt: float) -> np.ndarray:
    """The room's temperature before the motors' heat, °C."""
    h = (t.hour + t.minute / 60 + t.second / 3600).to_numpy(float)
    return 24 + 4 * np.cos(2 * np.pi * (h - 15) / 24) + 2 * _ou(rng, h.size, dt, 3 * 86400)


def roles(t: pd.DatetimeIndex, out: np.ndarray) -> np.ndarray:
    """Per step each compressor's role (0 lead, 1 lag, 2 standby, 3 out): the lead ``day
    number mod 3``, the lag the next, the standby the third; one out: the rotation skips it."""
    day = ((t.normalize() - ROTATION_DAY0) // pd.Timedelta("1D")).to_numpy()
    lead = np.mod(day, 3)
    r = np.empty((t.size, 3), np.int64)
    for k in range(3):
        r[:, k] = np.mod(k - lead, 3)
    for i in np.flatnonzero(out >= 0):  # the two left: lead and lag by the same order
        o = out[i]
        left = [k for k in np.argsort(r[i]) if k != o]
        r[i, left[0]], r[i, left[1]], r[i, o] = 0, 1, 3
    return r


# not cached on disk: the simulator is run as a script and loaded by tests under other module
# names, and numba's cache read back under another name fails ("No module named '<dynamic>'")
@numba.njit(cache=False)
def _run(dt, dem, room0, role, leak_on, hdr_bias, foul, p0):  # pragma: no cover - numba
    n = dem.size
    p = p0
    running = np.zeros(3, np.bool_)
    running[:] = role[0] <= 1
    loaded = running.copy()
    valve = np.where(loaded, 1.0, 0.0)
    kw = np.zeros(3)
    td = np.full(3, 30.0)
    tac = np.full(3, 25.0)
    since_start = np.full(3, 1e9)
    unloaded_for = np.zeros(3)
    room = room0[0]
    t_in = 30.0
    pdp = 4.0
    out_p = np.empty(n)
    out_hdr = np.empty(n)
    out_q = np.empty(n)
    out_room = np.empty(n)
    out_pdp = np.empty(n)
    out_run = np.empty((n, 3))
    out_kw = np.empty((n, 3))
    out_td = np.empty((n, 3))
    out_tac = np.empty((n, 3))
    for i in range(n):
        q_users = dem[i] * math.sqrt(max(p + 1.013, 0.0) / 8.0)
        p_hdr = p - 0.03 - 0.22 * (q_users / 20.0) ** 2
        reading = p_hdr + hdr_bias[i]
        q_in = 0.0
        kw_sum = 0.0
        for k in range(3):
            r = role[i, k]
            if r == 3:
                running[k] = False
            elif not running[k] and reading < BANDS_LO[r]:
                running[k] = True
                since_start[k] = 0.0
                unloaded_for[k] = 0.0
            if running[k]:
                since_start[k] += dt
                if since_start[k] < 12.0:
                    loaded[k] = False
                elif reading < BANDS_LO[r]:
                    loaded[k] = True
                elif reading > BANDS_HI[r]:
                    loaded[k] = False
                unloaded_for[k] = 0.0 if loaded[k] else unloaded_for[k] + dt
                if r > 0 and unloaded_for[k] >= 600.0:
                    running[k] = False
                    loaded[k] = False
            else:
                loaded[k] = False
            target = 1.0 if loaded[k] else 0.0
            valve[k] += (target - valve[k]) * (1 - math.exp(-dt / 3.0))
            full = 55.0 * (1 + 0.07 * (p - 7))
            want = (0.25 + 0.75 * valve[k]) * full if running[k] else 0.0
            tau = 2.0 if want > kw[k] else 25.0
            kw[k] += (want - kw[k]) * (1 - math.exp(-dt / tau))
            if not running[k]:
                kw[k] = 0.0 if kw[k] < 0.5 else kw[k]
            q_in += valve[k] * 10.0 * (1 - 0.03 * (p - 7)) if running[k] else 0.0
            kw_sum += kw[k]
            if running[k]:
                td[k] += (room + 40 + 14 * valve[k] + 1.5 * (p - 7) - td[k]) * (
                    1 - math.exp(-dt / 150.0)
                )
                appr = 9 * math.sqrt(max(valve[k], 0.0)) * (foul[i] if k == 0 else 1.0)
                tac_t = room + max(appr, 0.5)
                tac[k] += (tac_t - tac[k]) * (1 - math.exp(-dt / 90.0))
            else:
                td[k] += (room - td[k]) * (1 - math.exp(-dt / 1500.0))
                tac[k] += (room - tac[k]) * (1 - math.exp(-dt / 300.0))
        q_leak = leak_on[i] * 2.5 * math.sqrt(max(p + 1.013, 0.0) / 8.013)
        p += 1.013 / 12.0 * (q_in - q_users - q_leak) / 60.0 * dt
        room += (room0[i] + kw_sum / 40.0 - room) * (1 - math.exp(-dt / 900.0))
        # the dryer's inlet: the loaded compressors' aftercooler outlets mixed by flow
        w = 0.0
        mix = 0.0
        for k in range(3):
            if running[k] and valve[k] > 0.05:
                w += valve[k]
                mix += valve[k] * tac[k]
        inlet = mix / w if w > 0 else room
        t_in += (inlet - t_in) * (1 - math.exp(-dt / 300.0))
        pdp_t = 3 + 0.18 * max(t_in - 30, 0.0) + 2.2 * (q_users / 25.0) ** 1.5 + 0.04 * (room - 25)
        pdp += (pdp_t - pdp) * (1 - math.exp(-dt / 600.0))
        out_p[i], out_hdr[i], out_q[i], out_room[i], out_pdp[i] = p, p_hdr, q_users, room, pdp
        for k in range(3):
            out_run[i, k] = 1.0 if running[k] else 0.0
            out_kw[i, k] = kw[k] if running[k] else 0.0
            out_td[i, k] = td[k]
            out_tac[i, k] = tac[k]
    return out_p, out_hdr, out_q, out_room, out_pdp, out_run, out_kw, out_td, out_tac


def simulate(
    start: str, days: float, seed: int, period: float = 180.0, jitter: float = 20.0,
    dt: float = 2.0, fault: str | None = None, onset: str | None = None,
    out_of: str | None = None, out_from: str | None = None, out_to: str | None = None,
) -> pd.DataFrame:  # fmt: skip
    """``days`` from ``start`` (UTC) sampled every ``period`` s, stamps jittered ±``jitter``
    s; ``fault`` from ``onset``; compressor ``out_of`` (``C2``) out over ``out_from`` …
    ``out_to``."""
    if fault is not None and fault not in FAULTS:
        raise ValueError(f"fault {fault}: one of {', '.join(FAULTS)}")
    rng = np.random.default_rng(seed)
    t0 = pd.Timestamp(start, tz="UTC")
    n = int(round(days * 86400 / dt))
    t = t0 + pd.to_timedelta(np.arange(n) * dt, unit="s")
    dem = demand(t, rng, dt)
    room0 = room_base(t, rng, dt)
    out = np.full(n, -1, np.int64)
    if out_of is not None:
        k = int(out_of.removeprefix("C")) - 1
        out[(t >= pd.Timestamp(out_from, tz="UTC")) & (t < pd.Timestamp(out_to, tz="UTC"))] = k
    role = roles(t, out)
    since = np.zeros(n)
    if fault is not None:
        since = np.maximum((t - pd.Timestamp(onset, tz="UTC")).total_seconds().to_numpy(), -1.0)
    on = since >= 0
    leak = np.where(on & (fault == "leak"), 1.0, 0.0)
    hdr = np.where(on & (fault == "hdr_bias"), 0.25, 0.0)
    foul = np.where(on & (fault == "tac_foul"), 1 + 1.4 * np.minimum(since / 172800, 1), 1.0)
    p, p_hdr, q, room, pdp, run, kw, td, tac = _run(dt, dem, room0, role, leak, hdr, foul, 7.0)
    if fault == "pdp_drift":
        pdp = pdp + np.where(on, 2.0 * since / 86400, 0.0)
    if fault == "td_bias":
        td[:, 1] = td[:, 1] + np.where(on, 8.0, 0.0)
    if fault == "hdr_bias":
        p_hdr = p_hdr + hdr
    # instantaneous samples at jittered stamps
    m = int(days * 86400 // period)
    stamp = np.arange(m) * period + rng.uniform(-jitter, jitter, m)
    stamp = np.clip(stamp, 0, (n - 1) * dt)
    i = np.clip(np.rint(stamp / dt).astype(int), 0, n - 1)
    pf = 0.5 + 0.36 * kw[i] / 55

    def noisy(x: np.ndarray, sd: float) -> np.ndarray:
        return x + rng.standard_normal(x.shape) * sd

    cols = {
        "FT_PLANT": noisy(q[i], 0.15),
        "T_AMB": noisy(room[i], 0.10),
        "PT_RCV": noisy(p[i], 0.01),
        "PT_HDR": noisy(p_hdr[i], 0.01),
        "DRY_PDP": noisy(pdp[i], 0.12),
    }
    for k in range(3):
        r = run[i, k]
        amps = kw[i, k] * 1000 / (math.sqrt(3) * 400 * pf[:, k])
        cols[f"C{k + 1}_RUN"] = r
        cols[f"C{k + 1}_AMPS"] = np.where(r > 0, noisy(amps, 0.8), 0.0)
        cols[f"C{k + 1}_KW"] = np.where(r > 0, noisy(kw[i, k], 0.4), 0.0)
        cols[f"C{k + 1}_TD"] = noisy(td[i, k], 0.15)
        cols[f"C{k + 1}_TAC"] = noisy(tac[i, k], 0.12)
    frame = pd.DataFrame(cols, index=t0 + pd.to_timedelta(stamp, unit="s")).round(3)
    frame.index.name = "time"
    return frame[TAGS]


def tags_frame() -> pd.DataFrame:
    """The tags CSV: ``name,unit,lo,hi,description,loop,role``."""
    rows = [(n, u, lo, hi, d, "", r) for n, u, lo, hi, d, r in TAG_ROWS]
    return pd.DataFrame(rows, columns=["name", "unit", "lo", "hi", "description", "loop", "role"])


def main(argv: list[str] | None = None) -> None:
    """The command line of the module doc."""
    a = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    a.add_argument("out", type=Path)
    a.add_argument("--start", required=True)
    a.add_argument("--days", type=float, required=True)
    a.add_argument("--seed", type=int, required=True)
    a.add_argument("--period", type=float, default=180.0)
    a.add_argument("--jitter", type=float, default=20.0)
    a.add_argument("--dt", type=float, default=2.0)
    a.add_argument("--gap", help="FROM,TO: a historian gap left out of the export")
    a.add_argument("--fault", choices=FAULTS)
    a.add_argument("--onset")
    a.add_argument("--out-of")
    a.add_argument("--out-from")
    a.add_argument("--out-to")
    a.add_argument("--tags", type=Path, help="write the tags CSV here too")
    o = a.parse_args(argv)
    frame = simulate(o.start, o.days, o.seed, o.period, o.jitter, o.dt, o.fault, o.onset,
                     o.out_of, o.out_from, o.out_to)  # fmt: skip
    if o.gap:
        g0, g1 = (pd.Timestamp(x, tz="UTC") for x in o.gap.split(","))
        frame = frame[(frame.index < g0) | (frame.index >= g1)]
    frame.index = frame.index.strftime("%Y-%m-%dT%H:%M:%SZ")
    frame.to_csv(o.out)
    if o.tags:
        tags_frame().to_csv(o.tags, index=False)


if __name__ == "__main__":
    main()
