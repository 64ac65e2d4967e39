"""Process conditions around the actuator: pressures P1, P2, temperature T, flow set-point.

DAMADICS treats P1, P2 and T1 as inputs of the actuator (DABLib §5.1, Table 1);
its data generator drives them with sines (DABLib §5.5). Here they vary the way a
boiler feed-water line does over months: a daily cycle, slow random wandering
(Ornstein–Uhlenbeck), occasional steps (pump switching, load changes) and fast
pulsation. The flow controller's set-point follows a schedule of holds, steps
and ramps over the operating range plus a daily production cycle.

Everything is generated on a 1 s grid, chunk by chunk, from random streams that
depend only on the seed and the stream's role, drawn in time order. A run of N
days is therefore the first N days of any longer run with the same seed, and
adding a fault never changes the process conditions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

DAY_S = 86400.0

# stream identifiers for numpy SeedSequence (never reorder: they fix the data)
_S_P1, _S_P2, _S_T, _S_SP, _S_FNOISE, _S_P1EV, _S_P2EV, _S_PHASE = range(8)


@dataclass
class ProcessParams:
    """Process conditions (all pressures absolute)."""

    p1_mean_kpa: float = 3300.0  # valve inlet pressure (feed pump delivery)
    p1_daily_kpa: float = 70.0  # amplitude of the daily cycle
    p1_ou_sd_kpa: float = 150.0  # slow random wandering, standard deviation
    p1_ou_tau_s: float = 3 * 3600.0  # … and its correlation time
    p1_step_sd_kpa: float = 120.0  # pump switching: size of level steps
    p1_step_rate_per_day: float = 2.0  # … and how often they happen
    p1_fast_sd_kpa: float = 12.0  # pump pulsation
    p1_fast_tau_s: float = 4.0
    p2_mean_kpa: float = 2350.0  # valve outlet pressure (boiler drum)
    p2_daily_kpa: float = 60.0
    p2_ou_sd_kpa: float = 170.0
    p2_ou_tau_s: float = 6 * 3600.0
    p2_step_sd_kpa: float = 100.0
    p2_step_rate_per_day: float = 1.0
    p2_fast_sd_kpa: float = 8.0
    p2_fast_tau_s: float = 6.0
    t_mean_c: float = 100.0  # feed-water temperature
    t_daily_c: float = 1.0
    t_ou_sd_c: float = 0.6
    t_ou_tau_s: float = 4 * 3600.0
    sp_lo_th: float = 4.0  # flow set-point range, t/h
    sp_hi_th: float = 33.0
    sp_hold_mean_s: float = 5400.0  # mean time between set-point changes
    sp_hold_min_s: float = 600.0
    sp_ramp_prob: float = 0.4  # share of changes made as ramps (others are steps)
    sp_ramp_max_s: float = 1800.0
    sp_jump_sd_th: float = 8.0  # size of ordinary changes
    sp_uniform_prob: float = 0.25  # share of changes to anywhere in the range
    sp_daily_th: float = 1.5  # daily production cycle amplitude


def _ou_filter(sd: float, tau_s: float):
    """AR(1) coefficients of a stationary Ornstein–Uhlenbeck process sampled at 1 s."""
    phi = float(np.exp(-1.0 / tau_s))
    return [sd * np.sqrt(1.0 - phi * phi)], [1.0, -phi]


class _OU:
    """Stationary OU noise on the 1 s grid, continued across chunks."""

    def __init__(self, rng: np.random.Generator, sd: float, tau_s: float) -> None:
        self.rng = rng
        self.b, self.a = _ou_filter(sd, tau_s)
        self.zi = np.array([-self.a[1] * sd * rng.standard_normal()]) if sd > 0 else np.zeros(1)
        self.sd = sd

    def next(self, n: int) -> np.ndarray:
        w = self.rng.standard_normal(n)
        if self.sd <= 0:
            return np.zeros(n)
        y, self.zi = lfilter(self.b, self.a, w, zi=self.zi)
        return y


class _Steps:
    """Piecewise-constant level with random steps at Poisson times (1 s grid)."""

    def __init__(
        self,
        rng: np.random.Generator,
        rng_size: np.random.Generator,
        sd: float,
        rate_per_day: float,
    ) -> None:
        self.rng = rng  # when the steps happen
        self.rng_size = rng_size  # how big they are (a separate stream keeps runs prefix-stable)
        self.sd = sd
        self.p = rate_per_day / DAY_S
        self.level = 0.0

    def next(self, n: int) -> np.ndarray:
        u = self.rng.random(n)
        z = self.rng_size.standard_normal(n)
        if self.sd <= 0 or self.p <= 0:
            return np.zeros(n)
        jumps = u < self.p
        if not jumps.any():
            return np.full(n, self.level)
        # a step is a new level pulled back towards 0 (levels stay bounded)
        idx = np.flatnonzero(jumps)
        levels = np.empty(len(idx))
        lev = self.level
        for i, t in enumerate(idx):
            lev = 0.5 * lev + self.sd * z[t]
            levels[i] = lev
        pos = np.searchsorted(idx, np.arange(n), side="right") - 1
        out = np.where(pos >= 0, levels[np.maximum(pos, 0)], self.level)
        self.level = lev
        return out


class _Schedule:
    """Flow set-point: holds, steps and ramps between random targets (1 s grid)."""

    def __init__(self, rng: np.random.Generator, pp: ProcessParams) -> None:
        self.rng = rng
        self.pp = pp
        mid = 0.5 * (pp.sp_lo_th + pp.sp_hi_th)
        self.times = [0.0]  # breakpoints, s from the origin
        self.values = [mid]

    def _extend(self, t_end: float) -> None:
        pp = self.pp
        rng = self.rng
        while self.times[-1] < t_end:
            hold = max(pp.sp_hold_min_s, rng.exponential(pp.sp_hold_mean_s))
            ramp = rng.uniform(60.0, pp.sp_ramp_max_s) if rng.random() < pp.sp_ramp_prob else 1.0
            if rng.random() < pp.sp_uniform_prob:
                target = rng.uniform(pp.sp_lo_th, pp.sp_hi_th)
            else:
                target = self.values[-1] + pp.sp_jump_sd_th * rng.standard_normal()
            target = float(np.clip(target, pp.sp_lo_th, pp.sp_hi_th))
            t0 = self.times[-1] + hold
            self.times += [t0, t0 + ramp]
            self.values += [self.values[-1], target]

    def at(self, t: np.ndarray) -> np.ndarray:
        self._extend(float(t[-1]) + 1.0)
        return np.interp(t, self.times, self.values)


def _daily(mean: float, amplitude: float, angle: np.ndarray, n: int, parts) -> np.ndarray:
    """A slow variable: ``mean`` plus a daily sine of ``amplitude`` at ``angle`` (rad) plus the
    next ``n`` samples of each of ``parts`` (noise sources with ``next(n)``), added in order."""
    out = mean + amplitude * np.sin(angle)
    for part in parts:
        out = out + part.next(n)
    return out


class ProcessGenerator:
    """Per-second process conditions from ``origin`` (s of day of the first sample)."""

    def __init__(self, seed: int, pp: ProcessParams, f_noise_sd: float, origin_s: float) -> None:
        def rng(stream: int) -> np.random.Generator:
            return np.random.default_rng(np.random.SeedSequence([int(seed), 7771, stream]))

        self.pp = pp
        self.t = 0.0  # seconds since origin
        self.tod0 = origin_s % DAY_S  # time of day of the origin
        ph = rng(_S_PHASE).uniform(0.0, 2 * np.pi, 3)
        self.phase = ph
        # each pressure wanders slowly, steps at random events and has fast noise (added in
        # that order); the temperature only wanders
        self.p1_noise = (
            _OU(rng(_S_P1), pp.p1_ou_sd_kpa, pp.p1_ou_tau_s),
            _Steps(rng(_S_P1EV), rng(_S_P1EV + 100), pp.p1_step_sd_kpa, pp.p1_step_rate_per_day),
            _OU(rng(_S_P1 + 100), pp.p1_fast_sd_kpa, pp.p1_fast_tau_s),
        )
        self.p2_noise = (
            _OU(rng(_S_P2), pp.p2_ou_sd_kpa, pp.p2_ou_tau_s),
            _Steps(rng(_S_P2EV), rng(_S_P2EV + 100), pp.p2_step_sd_kpa, pp.p2_step_rate_per_day),
            _OU(rng(_S_P2 + 100), pp.p2_fast_sd_kpa, pp.p2_fast_tau_s),
        )
        self.t_noise = (_OU(rng(_S_T), pp.t_ou_sd_c, pp.t_ou_tau_s),)
        self.sched = _Schedule(rng(_S_SP), pp)
        self.fnoise_rng = rng(_S_FNOISE)
        self.f_noise_sd = f_noise_sd

    def next(self, n: int) -> dict[str, np.ndarray]:
        """The next ``n`` seconds: P1, P2 (kPa abs), T (°C), SP (t/h), flow noise (t/h)."""
        pp = self.pp
        t = self.t + np.arange(n, dtype=float)
        day = 2 * np.pi * (self.tod0 + t) / DAY_S
        p1 = _daily(pp.p1_mean_kpa, pp.p1_daily_kpa, day + self.phase[0], n, self.p1_noise)
        p2 = _daily(pp.p2_mean_kpa, pp.p2_daily_kpa, day + self.phase[1], n, self.p2_noise)
        tc = _daily(pp.t_mean_c, pp.t_daily_c, day + self.phase[2], n, self.t_noise)
        sp = self.sched.at(t) + pp.sp_daily_th * np.sin(day - 1.0)
        sp = np.clip(sp, pp.sp_lo_th, pp.sp_hi_th)
        fn = self.f_noise_sd * self.fnoise_rng.standard_normal(n)
        self.t += n
        return {"P1": p1, "P2": p2, "T": tc, "SP": sp, "FNOISE": fn}
