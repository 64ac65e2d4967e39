"""Two small plants unlike the valve, for the tour on data nobody tuned the product on.

* :func:`simulate_tank` — a buffer tank whose level controller LIC101 throttles the outflow
  valve: the outflow FI102 depends on the valve opening *and* on the level (hydrostatic
  head), the inflow FI101 is a disturbance (pump switching, daily cycle, wandering).
* :func:`simulate_heat_exchanger` — a process cooler: TIC202 moves the cooling-water valve to
  hold the process outlet temperature TI202; the process flow FI201, its inlet temperature
  TI201 and the cooling-water inlet temperature TI203 are disturbances; the cooling water
  FI202 follows the valve with a lag, TI202 answers with a lag and a dead time.

Both run on a 1 s grid (the loops in numba) from random streams that depend only on the seed.
:func:`export` samples such a run the way a plant's historian export does: every ``period``
on the whole grid, with jitter, irregularly, with a clock offset, and with instantaneous
readings (not averages).
"""

from __future__ import annotations

import numba as nb
import numpy as np
import pandas as pd
from scipy.signal import lfilter

from diag_plugin.simulate.tagtable import tag_table

#: tags of each plant: unit, nominal range, description
TANK_TAGS = tag_table(
    """
LT101      | %    | 0 | 100 | tank level
FI101      | m3/h | 0 | 80  | inflow (disturbance)
FI102      | m3/h | 0 | 80  | outflow through the level control valve
LIC101.OUT | %    | 0 | 100 | level controller output (valve opening)
LIC101.SP  | %    | 0 | 100 | level set-point
"""
)
HEATEX_TAGS = tag_table(
    """
TI201      | degC | 0 | 150 | process inlet temperature
TI202      | degC | 0 | 150 | process outlet temperature (controlled)
TI203      | degC | 0 | 50  | cooling-water inlet temperature
FI201      | t/h  | 0 | 60  | process flow
FI202      | t/h  | 0 | 120 | cooling-water flow
TIC202.OUT | %    | 0 | 100 | temperature controller output (cooling valve)
TIC202.SP  | degC | 0 | 150 | outlet temperature set-point
"""
)
PLANTS = {"tank": TANK_TAGS, "heatex": HEATEX_TAGS}


def _ou(rng: np.random.Generator, n: int, sd: float, tau_s: float) -> np.ndarray:
    """An Ornstein–Uhlenbeck process on a 1 s grid (standard deviation ``sd``, correlation
    time ``tau_s``), by a first-order filter of white noise."""
    a = np.exp(-1.0 / tau_s)
    x = lfilter([np.sqrt(1 - a * a) * sd], [1.0, -a], rng.standard_normal(n))
    return x


def _steps(rng: np.random.Generator, n: int, rate_per_day: float, sd: float) -> np.ndarray:
    """Piecewise-constant level changes at random times (Poisson, ``rate_per_day``)."""
    jumps = np.zeros(n)
    k = rng.poisson(rate_per_day * n / 86400.0)
    jumps[rng.integers(0, n, k)] = rng.normal(0.0, sd, k)
    return np.cumsum(jumps)


def _schedule(rng: np.random.Generator, n: int, lo: float, hi: float, hold_s: float):
    """A set-point held for random times (exponential, mean ``hold_s``) between changes to
    random values in [lo, hi]."""
    out = np.empty(n)
    i = 0
    while i < n:
        j = min(n, i + max(60, int(rng.exponential(hold_s))))
        out[i:j] = rng.uniform(lo, hi)
        i = j
    return out


def _seconds(days: float, start: str | pd.Timestamp) -> pd.DatetimeIndex:
    """The 1 s grid of a run: ``days`` long from ``start`` (naive: UTC)."""
    t0 = pd.Timestamp(start)
    t0 = t0.tz_localize("UTC") if t0.tzinfo is None else t0.tz_convert("UTC")
    n = int(round(days * 86400))
    return pd.DatetimeIndex(t0 + pd.to_timedelta(np.arange(n), unit="s"), name="ts")


def _grid(days: float, start: str | pd.Timestamp, stream: list[int]):
    """A run's 1 s index, its first time, its length and its random stream (``stream``: the
    seed and the plant's own number, so plants of one seed draw independently)."""
    index = _seconds(days, start)
    return index, index[0], len(index), np.random.default_rng(stream)


def _measured(index: pd.DatetimeIndex, rng: np.random.Generator, rows: int, noisy: dict,
              exact: dict) -> pd.DataFrame:  # fmt: skip
    """The tags as measured: ``noisy`` tag -> (true signal, noise s.d.), white noise from
    ``rng`` (``rows`` × n draws, a row per noisy tag in order), then the ``exact`` tags
    (controller outputs and set-points)."""
    noise = rng.standard_normal((rows, len(index)))
    cols = {tag: x + sd * noise[k] for k, (tag, (x, sd)) in enumerate(noisy.items())}
    return pd.DataFrame({**cols, **exact}, index=index)


def _daily(n: int, start: pd.Timestamp, amplitude: float, peak_hour: float) -> np.ndarray:
    s0 = (start - start.normalize()).total_seconds()
    t = s0 + np.arange(n)
    return amplitude * np.cos(2 * np.pi * (t / 86400.0 - peak_hour / 24.0))


@nb.njit(cache=True)
def _pi(e, kp, ti, integ):  # pragma: no cover - numba
    """Positional PI with conditional integration (anti-windup): output %, new integral."""
    out = kp * e + integ
    if out > 100.0:
        out = 100.0
    elif out < 0.0:
        out = 0.0
    else:
        integ += kp * e / ti
    return out, integ


@nb.njit(cache=True)
def _counterflow(c1, c2, ua):  # pragma: no cover - numba
    """A counter-flow exchanger's effectiveness (ε–NTU) for heat-capacity rates ``c1``,
    ``c2`` and conductance ``ua`` (same units), and the smaller rate C_min."""
    cmin = min(c1, c2)
    cmax = max(c1, c2)
    r = cmin / cmax
    ntu = ua / cmin
    if abs(1.0 - r) < 1e-6:
        eff = ntu / (1.0 + ntu)
    else:
        ex = np.exp(-ntu * (1.0 - r))
        eff = (1.0 - ex) / (1.0 - r * ex)
    return eff, cmin


@nb.njit(cache=True)
def _tank_loop(fin, sp, kv, area_m2, height_m, kp, ti_s, level0, leak):  # pragma: no cover
    n = fin.shape[0]
    level = np.empty(n)
    u = np.empty(n)
    fout = np.empty(n)
    x = level0
    integ = 50.0
    for i in range(n):
        e = x - sp[i]  # reverse acting: a high level opens the valve
        out, integ = _pi(e, kp, ti_s, integ)
        head = max(x, 0.0) / 100.0 * height_m + 0.5  # m of liquid above the valve
        q = kv * (out / 100.0) * np.sqrt(head)  # m3/h
        level[i] = x
        u[i] = out
        fout[i] = q
        x += (fin[i] - q - leak[i]) / 3600.0 / area_m2 / height_m * 100.0
        x = min(max(x, 0.0), 100.0)
    return level, u, fout


def simulate_tank(
    days: float, *, seed: int = 0, start: str | pd.Timestamp = "2026-03-02"
) -> pd.DataFrame:
    """A buffer tank with a level controller on its outflow valve, on a 1 s grid."""
    index, start, n, rng = _grid(days, start, [seed, 101])
    fin = (
        38.0
        + _daily(n, start, 6.0, 14.0)
        + _ou(rng, n, 4.0, 2 * 3600.0)
        + _steps(rng, n, 3.0, 5.0)
        + _ou(rng, n, 0.8, 20.0)
    )
    fin = np.clip(fin, 5.0, 75.0)
    sp = _schedule(rng, n, 35.0, 70.0, 4 * 3600.0)
    return tank_run(index, fin, sp, rng)


def tank_run(
    index: pd.DatetimeIndex,
    inflow: np.ndarray,
    set_point: np.ndarray,
    rng: np.random.Generator,
    leak: np.ndarray | None = None,
) -> pd.DataFrame:
    """The tank's level loop on a 1 s ``index`` for a given ``inflow`` (m³/h) and the
    operators' ``set_point`` schedule (%), with its tags as measured (noise from ``rng``): the
    level LT101, inflow FI101, outflow FI102 and the controller's output and set-point.
    ``leak``: liquid lost from the tank (m³/h, per sample; no meter sees it), none by
    default."""
    fin = np.asarray(inflow, float)
    sp = np.asarray(set_point, float)
    lost = np.zeros_like(fin) if leak is None else np.broadcast_to(leak, fin.shape).astype(float)
    level, u, fout = _tank_loop(fin, sp, 60.0, 12.0, 4.0, 4.0, 900.0, 50.0, lost)
    noisy = {"LT101": (level, 0.15), "FI101": (fin, 0.3), "FI102": (fout, 0.3)}
    return _measured(index, rng, 4, noisy, {"LIC101.OUT": u, "LIC101.SP": sp})


@nb.njit(cache=True)
def _heatex_loop(fp, tp_in, tw_in, sp, ua, kp, ti_s, lag_s, valve_s, dead_s):  # pragma: no cover
    n = fp.shape[0]
    tout = np.empty(n)
    u = np.empty(n)
    fw = np.empty(n)
    cp_p, cp_w = 2.6, 4.18  # kJ/(kg K): an oil cooled by water
    y = 45.0
    flow_w = 40.0
    integ = 40.0
    hist = np.full(dead_s + 1, 45.0)
    for i in range(n):
        measured = hist[i % (dead_s + 1)]  # the outlet temperature dead_s seconds ago
        e = measured - sp[i]  # direct acting: too hot opens the cooling valve
        out, integ = _pi(e, kp, ti_s, integ)
        flow_w += (120.0 * out / 100.0 - flow_w) / valve_s
        cp_hot = fp[i] * 1000.0 / 3600.0 * cp_p  # kW/K
        cw = max(flow_w, 0.5) * 1000.0 / 3600.0 * cp_w
        eff, cmin = _counterflow(cp_hot, cw, ua)
        target = tp_in[i] - eff * cmin / cp_hot * (tp_in[i] - tw_in[i])
        y += (target - y) / lag_s
        tout[i] = measured
        u[i] = out
        fw[i] = flow_w
        hist[i % (dead_s + 1)] = y
    return tout, u, fw


def simulate_heat_exchanger(
    days: float, *, seed: int = 0, start: str | pd.Timestamp = "2026-03-02"
) -> pd.DataFrame:
    """A process cooler whose temperature controller moves the cooling-water valve, 1 s."""
    index, start, n, rng = _grid(days, start, [seed, 202])
    fp = np.clip(30.0 + _ou(rng, n, 4.0, 3 * 3600.0) + _steps(rng, n, 2.0, 4.0), 12.0, 55.0)
    tp_in = np.clip(88.0 + _ou(rng, n, 3.0, 5 * 3600.0) + _ou(rng, n, 0.3, 60.0), 70.0, 110.0)
    tw_in = 21.0 + _daily(n, start, 4.0, 15.0) + _ou(rng, n, 1.0, 6 * 3600.0)
    sp = _schedule(rng, n, 40.0, 50.0, 8 * 3600.0)
    tout, u, fw = _heatex_loop(fp, tp_in, tw_in, sp, 60.0, 3.0, 600.0, 180.0, 20.0, 30)
    noisy = {"TI201": (tp_in, 0.1), "TI202": (tout, 0.1), "TI203": (tw_in, 0.1)}
    noisy |= {"FI201": (fp, 0.2), "FI202": (fw, 0.4)}
    return _measured(index, rng, 5, noisy, {"TIC202.OUT": u, "TIC202.SP": sp})


def export(
    frame: pd.DataFrame,
    period_s: float,
    *,
    timing: str = "grid",
    offset_s: float = 0.0,
    seed: int = 0,
) -> pd.DataFrame:
    """Readings of a 1 s run every ``period_s`` as a plant export gives them: ``timing``
    ``"grid"`` (on whole periods, shifted by ``offset_s``), ``"jitter"`` (±3 % of the period
    around them, and a clock that gains 50 ppm) or ``"irregular"`` (spacings uniform in
    0.5–1.5 periods); each reading is the instantaneous value at its time."""
    n_base = len(frame)
    rng = np.random.default_rng([seed, 7])
    t0 = offset_s
    count = int((n_base - 1 - offset_s) // period_s)
    k = np.arange(count)
    if timing == "grid":
        t = t0 + k * period_s
    elif timing == "jitter":
        t = t0 + k * period_s * (1 + 50e-6) + rng.uniform(-0.03, 0.03, count) * period_s
    elif timing == "irregular":
        t = t0 + np.cumsum(rng.uniform(0.5, 1.5, count) * period_s) - period_s
    else:
        raise ValueError(f"timing must be grid, jitter or irregular, not {timing!r}")
    t = np.sort(t[(t >= 0) & (t <= n_base - 1)])
    rows = np.floor(t).astype(np.int64)
    out = frame.iloc[rows].copy()
    us = np.round(t * 1e6).astype(np.int64)
    out.index = pd.DatetimeIndex(frame.index[0] + pd.to_timedelta(us, unit="us"), name="ts")
    return out
