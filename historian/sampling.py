"""How a tag is sampled, the grid period a model takes from it, and the one alignment rule.

Plants deliver data at any period (1 s to an hour), with jitter, clocks that drift, gaps and
tags recorded only on change. The product puts every tag on one regular grid per model, the
grid points ``t_k = k · period`` counted from the Unix epoch (UTC), by one rule
(:func:`historian.window.align`):

* A grid point takes the mean (``how="mean"``) or the last (``how="last"``) of the tag's usable
  samples within half a period of it, ``[t_k − period/2, t_k + period/2)``: timestamps with
  jitter or a constant offset up to half a period land on the nearest grid point, and a faster
  tag is averaged over each period.
* A grid point with no usable sample there takes the tag's last sample before it, if that
  sample is usable and no older than the tag's *hold* (:func:`hold_us`): a tag sampled slower
  than the grid, irregularly or only on change keeps its last value that long; otherwise the
  grid point is a gap (NaN).

A model's period comes from its tags (:func:`model_period`): the longest typical spacing
among them, rounded to a whole unit (:func:`nice_period_us`), so every tag contributes at
least one real sample to most grid points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

US = 1_000_000
#: roundings tried for a period, coarsest first: 1 h, 1 min, 1 s, 0.1 s, 10 ms, 1 ms
ROUNDINGS_US = (3600 * US, 60 * US, US, 100_000, 10_000, 1_000)
#: a rounding is accepted when it moves the measured spacing by at most this share
ROUND_TOLERANCE = 0.02
#: a tag whose 95th-percentile spacing exceeds this many grid periods is held (slower than
#: the grid, irregular or recorded on change)
HOLD_WHEN = 1.25
#: ... for this many of its 95th-percentile spacings
HOLD_FACTOR = 1.5
#: samples read to measure a tag's sampling for the hold
SAMPLING_ROWS = 20_000


@dataclass(frozen=True)
class Sampling:
    """A tag's sampling: how many samples were measured, the median spacing between them and
    the 95th percentile (both µs; 0 when fewer than two samples)."""

    tag: str
    samples: int
    median_us: int
    q95_us: int

    @property
    def regular(self) -> bool:
        """Spacings within 25 % of the median for 95 % of the samples."""
        return self.median_us > 0 and self.q95_us <= 1.25 * self.median_us

    def describe(self) -> str:
        """``every 10 s`` / ``irregular, typically every 7.3 s`` / ``too few samples``."""
        if self.median_us <= 0:
            return f"too few samples ({self.samples})"
        tol = ROUND_TOLERANCE if self.regular else 0.05
        text = f"every {format_period(nice_period_us(self.median_us, tol))}"
        return text if self.regular else f"irregular, typically {text}"


def sampling_of(tag: str, ts: np.ndarray) -> Sampling:
    """The :class:`Sampling` of sorted sample times ``ts`` (int µs); repeated times count
    once."""
    ts = np.asarray(ts, dtype=np.int64)
    if not (ts[1:] > ts[:-1]).all():  # strictly increasing (as read) is unique and sorted:
        ts = np.unique(ts)  # the sort cost 0.12 CPU s for 46 tags' 20,000 (issue 34)
    if len(ts) < 2:
        return Sampling(tag, len(ts), 0, 0)
    d = np.diff(ts)
    med, q95 = np.quantile(d, [0.5, 0.95])
    return Sampling(tag, len(ts), int(round(med)), int(round(q95)))


def nice_period_us(us: float, tolerance: float = ROUND_TOLERANCE) -> int:
    """``us`` rounded to the coarsest whole unit (1 h, 1 min, 1 s, 100 ms, 10 ms, 1 ms) that
    moves it by at most ``tolerance`` (2 %): 10.02 s → 10 s, 180.4 s → 3 min, 2.5 s → 2.5 s."""
    if us <= 0:
        raise ValueError(f"a period must be positive, got {us} µs")
    for r in ROUNDINGS_US:
        q = round(us / r) * r
        if q > 0 and abs(q - us) <= tolerance * us:
            return int(q)
    return max(1, int(round(us)))


def format_period(us: int) -> str:
    """A period as pandas writes it and reads it back: ``10s``, ``3min``, ``1h``, ``2.5s``."""
    for unit, size in (("h", 3600 * US), ("min", 60 * US), ("s", US)):
        if us % size == 0:
            return f"{us // size}{unit}"
    if us >= US:
        return f"{us / US:g}s"
    return f"{us // 1000}ms" if us % 1000 == 0 else f"{us}us"


def model_period(samplings: list[Sampling]) -> int:
    """The grid period (µs) of a model reading these tags: the longest typical (median)
    spacing among them, rounded by :func:`nice_period_us`. Raises ValueError when no tag has
    two samples."""
    known = [s for s in samplings if s.median_us > 0]
    if not known:
        names = ", ".join(s.tag for s in samplings)
        raise ValueError(f"too few samples of {names} to tell how often they are sampled")
    slowest = max(known, key=lambda s: s.median_us)
    # an irregular tag's median spacing is a noisy figure: round it more boldly
    return nice_period_us(slowest.median_us, ROUND_TOLERANCE if slowest.regular else 0.05)


def hold_us(s: Sampling, period_us: int) -> int:
    """How long a tag's last sample stands in for later grid points (µs; 0: never): tags
    whose 95th-percentile spacing exceeds 1.25 grid periods (slower than the grid, irregular,
    recorded on change) are held for 1.5 × that spacing; tags sampled at the grid's period or
    faster are not held, so a missing sample stays a gap."""
    if s.q95_us > HOLD_WHEN * period_us:
        return int(HOLD_FACTOR * s.q95_us)
    return 0


def snap_up(t_us: int, period_us: int) -> int:
    """The first grid point at or after ``t_us``."""
    return -((-int(t_us)) // period_us) * period_us


def snap_near(t_us: int, period_us: int) -> int:
    """The grid point nearest to ``t_us`` (a sample's own grid point, half a period up)."""
    return ((int(t_us) + period_us // 2) // period_us) * period_us
