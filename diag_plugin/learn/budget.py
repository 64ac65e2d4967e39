"""Thresholds held to a false-alarm budget: alarms per hour of operation, counted as the unit
counts them (filtered residual, on/off delays), from a fault-free series of residuals.

A unit raises an alarm when a test's filtered residual stays beyond its threshold for
``on_delay`` samples; the alarm ends after ``off_delay`` samples back inside
(:class:`~diag_plugin.diagnose.symptoms.OnOffDelay`). So a false alarm is an *episode*, not a
sample: a filtered residual stays correlated for hours and crosses a threshold in bursts, and
the share of samples beyond a threshold says little about how often an operator is called.
:func:`calibrate` therefore counts alarm episodes directly: for each side of each test it runs
the delay logic at a ladder of thresholds over the fault-free series and reads off the
threshold whose episode rate is the budget.

* **Empirical** when the window holds at least :data:`MIN_EPISODES` episodes at the budget: the
  threshold is where the observed count is the budgeted one.
* **Tail fit** when the budget asks for rarer alarms than the window shows: the episodes'
  peaks above a high level are taken as exponential (the generalised Pareto tail of shape 0,
  the limit for Gaussian-like residuals; Davison & Smith, 1990, peaks over threshold with
  declustering), their mean excess ``β`` estimated from the episode counts up the ladder, and
  the threshold put at ``u + β ln(E(u) / c*)``. Never below a level the window itself
  crosses :data:`MIN_EPISODES` times or more and more often than the budget explains
  (:func:`_seen`; the Gaussian model's likewise).
* **Gaussian** when the window holds fewer than :data:`TAIL_EPISODES` episodes even at a
  moderate level (a window of a few hundred samples, a residual correlated for hours): Rice's
  formula for a stationary Gaussian series, ``E(u) = E(μ) exp(−(u − μ)² / 2σ²)``, with ``E(μ)``
  the episodes counted at the mean and ``σ`` the spread on that side of the mean. Mean and
  spread rest on few independent values (:func:`effective_samples`), so the density ratio is
  that of the predictive Student t with ``n − 1`` degrees of freedom, ``(1 + z²/ν)^(−(ν+1)/2)``,
  scaled by ``√(1 + 1/n)``: the fewer values, the wider (the normal case as ``n`` grows).
* **Rice** (the Gaussian model, said ``"rice"``) in place of the tail fit where the series
  holds fewer than :data:`FEW_VALUES` independent values and its largest excursion is one a
  Gaussian series shows (:func:`gaussian_top`): there the tail's top episodes are a handful
  of excursions of a slow residual, and the tail fit extrapolates their mean excess alone.

Each result says which, how many independent values the series holds
(:func:`~diag_plugin.models.series.effective_samples`), whether the window *supports* the
budget (observes it :data:`MIN_EPISODES` times) and, if not, how long a window would.
The budget of a unit is split evenly over its tests and the two sides of each (``2 T`` shares):
the unit's alarm rate is at most the sum of its tests' (an alarm on any test is the unit's).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numba
import numpy as np
import pandas as pd

from diag_plugin.models.series import effective_samples

#: episodes at the budgeted rate a window must show for the threshold to be read off directly
MIN_EPISODES = 5
#: the tail fit starts where this many episodes remain; a window without so many uses the
#: Gaussian model
TAIL_EPISODES = 30
#: the tail's mean excess is taken at this one-sided normal quantile above its estimate
TAIL_Z = 0.84
#: thresholds tried per side
LADDER = 96
#: an extrapolated threshold is raised where the window shows more episodes above it than
#: a Poisson count of the budget's reaches but with this probability (:func:`_seen`)
SEEN_P = 0.01
#: a side whose window holds fewer independent values than this (and whose largest excursion
#: a Gaussian series explains, :data:`GAUSS_P`) gets Rice's Gaussian threshold, not a tail fit:
#: its top :data:`TAIL_EPISODES` episodes are a handful of excursions (:func:`calibrate_side`).
#: 0, off, by default: at 100 (chemplant's tuning choice) the fan plant's unit judged only in
#: production alarms in its morning starts (tests/test_unit_running_modes.py); ``calibrate``'s
#: ``few`` turns it on
FEW_VALUES = 0.0
#: the window's largest excursion is taken as beyond a Gaussian series where Rice's rate gives
#: it less than this probability (``P(max > z) ≈ E(μ) exp(−z²/2)``)
GAUSS_P = 0.05


@numba.njit(cache=True)
def _episodes(x, levels, on_delay, off_delay, window, long):  # pragma: no cover - numba
    """Alarm onsets of ``x > level`` for every level, with on/off delays; NaNs are skipped (an
    unknown sample counts neither as on nor as off, as :class:`OnOffDelay` does). An onset
    within ``window`` samples of the last episode's end (0: never) is held ``long`` samples,
    not ``off_delay`` (the re-alarm hold, :class:`~diag_plugin.diagnose.unitloops.AlarmHold`)."""
    out = np.zeros(levels.shape[0], np.int64)
    for li in range(levels.shape[0]):
        u = levels[li]
        on = False
        c = 0
        k = 0
        off = off_delay
        gone = window  # samples since the last episode's end (window: none to count)
        for i in range(x.shape[0]):
            v = x[i]
            if np.isnan(v):
                continue
            above = v > u
            if not on:
                c = c + 1 if above else 0
                if c >= on_delay:
                    on = True
                    k += 1
                    off = long if gone < window else off_delay
                    c = 0
                elif gone < window:
                    gone += 1
            else:
                c = 0 if above else c + 1
                if c >= off:
                    on = False
                    c = 0
                    gone = 0
        out[li] = k
    return out


def episodes(
    x: np.ndarray,
    levels: np.ndarray,
    on_delay: int = 1,
    off_delay: int = 1,
    realarm: tuple[int, int] = (0, 0),
):
    """Number of alarm episodes of ``x > level`` per level (on/off delays in samples;
    ``realarm``: the re-alarm hold's window and hold in samples, ``(0, 0)``: none, an alarm
    raised again within the window of its last end held the longer hold)."""
    window, long = realarm
    return _episodes(
        np.ascontiguousarray(x, np.float64),
        np.ascontiguousarray(levels, np.float64),
        int(on_delay),
        int(off_delay),
        int(window),
        max(int(long), int(off_delay)),
    )


@dataclass
class SideThreshold:
    """The threshold of one side of one test and what it rests on."""

    threshold: float
    #: expected false alarms per hour of operation at this threshold (this side)
    rate: float
    #: "empirical", "tail" or "gaussian" (see the module doc), or "rice": Rice's Gaussian
    #: model where a tail could be fitted, on a series of few independent values whose top
    #: a Gaussian series explains (not "gaussian": the window holds the episodes a tail
    #: needs, and ``diag unit accept`` keeps such a band as it keeps a tail's)
    method: str
    #: episodes the window shows at the threshold and at the tail's base level
    episodes: int
    #: the window observes the budgeted rate MIN_EPISODES times
    supported: bool
    #: hours of operation a window needs to support the budget
    hours_needed: float


def calibrate_side(
    x: np.ndarray,
    hours: float,
    rate: float,
    on_delay: int = 1,
    off_delay: int = 1,
    few: float = 0.0,
    realarm: tuple[int, int] = (0, 0),
) -> SideThreshold:
    """The threshold ``K`` of ``x > K`` whose alarm episodes come at ``rate`` per hour, from a
    fault-free series ``x`` covering ``hours`` of operation (NaN = unknown, skipped).

    ``few``: where the tail fit would extrapolate and the series holds fewer independent
    values than this, Rice's Gaussian threshold (:func:`rice_parts`)
    stands in for the tail fit when the window's largest excursion is one a Gaussian series
    shows (:func:`gaussian_top`): the tail fit's top :data:`TAIL_EPISODES` episodes are then
    a handful of excursions, and its mean excess, extrapolated ``ln(E(u)/c*)`` ≈ 9 times on a
    month at the unit's budget, rests on them alone, where the Gaussian one rests on the mean
    and spread of every value and the episodes at the mean (issue 34: chemplant's analyser
    test AI101, 37 values in 30 days, 6.6 and 7.7 spreads out by the tail, 5.3 by Rice)."""
    v = x[np.isfinite(x)]
    if v.size < 3 or hours <= 0:
        raise ValueError("too few known values to learn a threshold from")
    want = rate * hours  # episodes the budget allows in this window
    needed = MIN_EPISODES / rate
    levels = ladder(v)
    counts = episodes(x, levels, on_delay, off_delay, realarm)
    got = from_counts(levels, counts, want)
    n_eff = effective_samples(v) if few > 0 and got is not None and got[1] == "tail" else math.inf
    if n_eff < few:
        g = rice_parts(x, hours, rate, on_delay, off_delay, n_eff=n_eff, realarm=realarm)
        if gaussian_top(v, g):
            k = _seen(g.threshold, levels, counts, want)
            return SideThreshold(float(k), rate, "rice", g.episodes, False, needed)
    if got is not None:
        k, method, seen = got
        return SideThreshold(k, rate, method, seen, method == "empirical", needed)
    # too few episodes for a tail: a Gaussian series (Rice)
    g = rice_parts(x, hours, rate, on_delay, off_delay, realarm=realarm)
    k = _seen(g.threshold, levels, counts, want)
    return SideThreshold(float(k), rate, "gaussian", g.episodes, False, needed)


def gaussian_top(v: np.ndarray, g: RiceParts, p: float = GAUSS_P) -> bool:
    """Whether the largest of the known values ``v`` is one a stationary Gaussian series with
    :func:`rice_parts` ``g`` shows: by Rice, its maximum passes ``μ + zσ`` with probability
    about ``E(μ) exp(−z²/2)``, so the window's top, in spreads above the mean, is taken as
    Gaussian up to ``√(2 ln(E(μ)/p))`` (3.99 at 148 episodes and ``p`` = 0.05; chemplant's
    LIC102.OUT loop test, 7.7 at 129: a heavier tail, fitted as one)."""
    if not g.spread > 0:
        return False
    top = (float(v.max()) - g.mean) / g.spread
    return top <= math.sqrt(2.0 * math.log(max(g.episodes / p, 1.0)))


def ladder(v: np.ndarray) -> np.ndarray:
    """The levels :func:`calibrate_side` tries on the known values ``v``: from their median
    to their largest, closer together near the median."""
    top = float(v.max())
    lo = float(np.median(v))
    span = max(top - lo, 1e-12 * max(abs(top), 1.0))
    return lo + span * np.linspace(0.0, 1.0, LADDER) ** 1.5


def from_counts(
    levels: np.ndarray, counts: np.ndarray, want: float
) -> tuple[float, str, int] | None:
    """The level at which ``want`` episodes come, from the episode ``counts`` at increasing
    ``levels``: read off (``"empirical"``) where the window shows at least
    :data:`MIN_EPISODES` at it, else by the exponential tail fitted above the highest level
    :data:`TAIL_EPISODES` remain (``"tail"``, raised by :func:`_seen`); None where no level
    holds so many (the caller's Gaussian model). Returns the level, the method and the
    episodes it rests on."""
    if want >= MIN_EPISODES:
        # the first level with no more episodes than allowed, interpolated on log counts
        i = int(np.argmax(counts <= want))
        k = levels[i]
        if i > 0 and counts[i] < want:
            c0, c1 = math.log(counts[i - 1]), math.log(max(counts[i], 0.5))
            f = (c0 - math.log(want)) / (c0 - c1)
            k = levels[i - 1] + f * (levels[i] - levels[i - 1])
        return float(k), "empirical", int(round(want))
    # the tail: from the highest level where TAIL_EPISODES remain
    many = np.flatnonzero(counts >= TAIL_EPISODES)
    if many.size:
        j = int(many[-1])
        u, e_u = float(levels[j]), int(counts[j])
        # mean excess of the episodes' peaks: the area under their survival curve / E(u)
        beta = float(np.trapezoid(counts[j:].astype(float), levels[j:])) / e_u
        beta *= e_u / max(e_u - TAIL_Z * math.sqrt(e_u), 1.0)  # upper confidence bound
        if beta > 0:
            k = _seen(u + beta * math.log(e_u / want), levels, counts, want)
            return float(k), "tail", e_u
    return None


@dataclass
class RiceParts:
    """What :func:`calibrate_side`'s Gaussian (Rice) threshold rests on (the module doc):
    ``threshold = mean + spread · √(1 + 1/n) · z`` before the window's own episodes
    (:func:`_seen`) can raise it."""

    #: the series' mean and its spread on the upper side of it
    mean: float
    spread: float
    #: the series' independent values (:func:`effective_samples`), at least 2
    n_eff: float
    #: alarm episodes counted at the mean (at least 1)
    episodes: int
    #: the predictive Student t's distance (ν = n − 1) at which Rice's rate is the budget's
    z: float
    threshold: float


def rice_parts(
    x: np.ndarray,
    hours: float,
    rate: float,
    on_delay: int = 1,
    off_delay: int = 1,
    n_eff: float | None = None,
    realarm: tuple[int, int] = (0, 0),
) -> RiceParts:
    """Rice's Gaussian threshold of ``x > K`` at ``rate`` episodes per hour over ``hours``
    (NaN skipped) and its parts: episodes counted at the mean, the spread on this side of it
    (a skewed residual has two); mean and spread rest on few independent values, so the
    predictive (Student t, ``ν = n − 1``) density stands in for the normal one in Rice's
    ratio, ``(1 + z²/ν)^(−(ν+1)/2) = c*/E(μ)``: the fewer values, the larger ``z`` (at a
    ratio of 24,000, SKAB's combined test over 300 held-out samples of 1 s at 0.0005 an
    hour: 4.5 as ``n`` grows, 5.1 at 37 values, 9.9 at 7, 17 at 4.6). ``n_eff``: the
    independent values to take instead of the series' own (a what-if; None: its own)."""
    v = x[np.isfinite(x)]
    mu = float(v.mean())
    e_mu = max(int(episodes(x, np.array([mu]), on_delay, off_delay, realarm)[0]), 1)
    above = v[v > mu] - mu
    sd = float(np.sqrt(np.mean(above**2))) if above.size else float(v.std())
    n_eff = max(effective_samples(v) if n_eff is None else n_eff, 2.0)
    nu = n_eff - 1.0
    ratio = e_mu / (rate * hours)
    z = math.sqrt(nu * (ratio ** (2.0 / (nu + 1.0)) - 1.0)) if ratio > 1 else 1.0
    k = mu + sd * math.sqrt(1.0 + 1.0 / n_eff) * z
    return RiceParts(mu, sd, float(n_eff), e_mu, float(z), float(k))


def most_episodes(want: float, p: float = SEEN_P) -> int:
    """The most episodes a window expecting ``want`` (Poisson) shows but with probability
    ``p``: the smallest ``c`` with ``P(N > c) <= p``."""
    # each term from its logarithm: exp(-want) underflows to 0 past want ~745 (a year's
    # window at a loose budget), and a running product from it never grew: the loop never ended
    c, total = 0, math.exp(-want)
    log_want = math.log(want) if want > 0 else -math.inf
    while 1.0 - total > p:
        c += 1
        total += math.exp(c * log_want - want - math.lgamma(c + 1))
    return c


def _seen(k: float, levels: np.ndarray, counts: np.ndarray, want: float) -> float:
    """An extrapolated threshold ``k`` (tail or Gaussian), raised to the lowest ``levels``
    where the window's own episode ``counts`` are no more than the budget's ``want`` explains
    (:func:`most_episodes`): a fit to the bulk of a series does not see a cluster of episodes
    far above it (the twin chillers' morning hour, chiller A alone at the whole load before
    B has started and settled: nine episodes of T² 1,000-38,000 in ten days, a tail fitted
    below them at 3,558 where the budget allows 1.2), and a threshold the window itself
    crosses more often than the budget allows is not held to it. Fewer than
    :data:`MIN_EPISODES` episodes above it never raise it (a short window's few, which the
    fit weighs)."""
    ok = np.flatnonzero(counts <= max(most_episodes(want), MIN_EPISODES - 1))
    if not ok.size:
        return k
    return max(k, float(levels[ok[0]]))


@dataclass
class TestBudget:
    """One test's thresholds (``low`` < 0 < ``high`` in the residual's unit) and their story."""

    test: str
    low: float
    high: float
    #: expected false alarms per hour of operation, both sides
    rate: float
    method: str
    supported: bool
    hours: float
    hours_needed: float
    samples: int
    independent: int
    #: share of the window the test was unknown
    unknown: float

    def as_dict(self) -> dict:
        return asdict(self)


def calibrate(
    residuals: pd.DataFrame,
    period: pd.Timedelta | str,
    far: float,
    *,
    on_delay: int = 1,
    off_delay: int = 1,
    mapper: Callable[[Callable[..., Any], Sequence[Any], tuple], list[Any]] | None = None,
    few: float = FEW_VALUES,
    realarm: tuple[int, int] = (0, 0),
) -> dict[str, TestBudget]:
    """Thresholds per test (column) holding the unit's false alarms to ``far`` per hour of
    operation, all tests together: each side of each test gets ``far / (2 T)``.

    ``residuals``: the fault-free filtered residuals the unit would threshold (NaN unknown),
    one column per test, one row per sampling ``period``. ``mapper(fn, items, args)``:
    ``[fn(item, *args) for item in items]`` in any number of processes, in order (each
    test's thresholds are its own; ``diag unit build`` passes its worker pool's). ``few``:
    :func:`calibrate_side`'s, Rice's threshold for a side of fewer independent values whose
    window top a Gaussian series explains (:data:`FEW_VALUES`). ``realarm``: the unit's
    re-alarm hold (window, hold; samples), so a false alarm raised again within the window
    is counted as the unit holds it (:func:`episodes`).
    """
    if not far > 0:
        raise ValueError(f"the false-alarm budget must be > 0 per hour, got {far}")
    dt_h = pd.Timedelta(period) / pd.Timedelta(hours=1)
    share = far / (2 * residuals.shape[1])
    names = list(residuals.columns)
    args = (residuals, dt_h, share, on_delay, off_delay, few, tuple(realarm))
    if mapper is None:
        got = [_test_budget(name, *args) for name in names]
    else:
        got = mapper(_test_budget, names, args)
    return {b.test: b for b in got}


def _test_budget(
    name: Any,
    residuals: pd.DataFrame,
    dt_h: float,
    share: float,
    on_delay: int,
    off_delay: int,
    few: float = 0.0,
    realarm: tuple[int, int] = (0, 0),
) -> TestBudget:
    """One test's :class:`TestBudget` (:func:`calibrate`'s share of one column)."""
    x = residuals[name].to_numpy(float)
    known = np.isfinite(x)
    hours = float(known.sum()) * dt_h
    hi = calibrate_side(x, hours, share, on_delay, off_delay, few, realarm)
    lo = calibrate_side(-x, hours, share, on_delay, off_delay, few, realarm)
    both = (hi, lo)
    return TestBudget(
        test=str(name),
        low=-lo.threshold,
        high=hi.threshold,
        rate=hi.rate + lo.rate,
        method=hi.method if hi.method == lo.method else f"{hi.method}/{lo.method}",
        supported=all(s.supported for s in both),
        hours=hours,
        hours_needed=max(s.hours_needed for s in both),
        samples=int(known.sum()),
        independent=int(effective_samples(x)),
        unknown=float(1.0 - known.mean()) if x.size else 1.0,
    )


def observed_rate(
    residuals: pd.DataFrame,
    limits: dict[str, tuple[float, float]],
    period: pd.Timedelta | str,
    on_delay: int = 1,
    off_delay: int = 1,
) -> float:
    """False alarms per hour of operation a unit with ``limits`` raises on ``residuals``
    (episodes of any test beyond its limits, with the delays) — to check a budget."""
    from diag_plugin.diagnose.symptoms import FixedThresholds, OnOffDelay

    cols = list(residuals.columns)
    lo = np.array([limits[c][0] for c in cols])
    hi = np.array([limits[c][1] for c in cols])
    raw = FixedThresholds(high=hi, low=lo).transform(residuals.to_numpy(float))
    s = OnOffDelay(on_delay, off_delay).transform(raw)
    active = (np.nan_to_num(s) != 0).any(axis=1)
    onsets = int(np.count_nonzero(active[1:] & ~active[:-1]) + (active[0] if active.size else 0))
    known = np.isfinite(residuals.to_numpy(float)).any(axis=1)
    hours = float(known.sum()) * (pd.Timedelta(period) / pd.Timedelta(hours=1))
    return onsets / hours if hours else float("nan")
