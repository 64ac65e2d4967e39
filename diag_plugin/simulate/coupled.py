"""A synthetic multi-tag process of known structure, for ``diag unit build``'s tests and
benchmark: coupled first-order dynamics with dead times.

Drivers (measured disturbances) move in random steps with a little wander; every other tag
answers one or two parents (drivers or earlier tags) through a first-order lag
``y[k] = a·y[k-1] + (1-a)·Σ g·u[k-d]`` plus measurement noise. Two tags stay constant, one
is a copy of another in other units (``DUP``: 1.8·x + 32, the same measurement) and one is
a set-point (``FIC1.SP``, a driver of its own). The structure (parents, dead times) is
drawn from ``structure_seed``, the signals from ``seed``: runs of other seeds are the same
plant on other days.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.signal import lfilter

#: the operating point each kind of tag moves about (a parent acts by its deviation from it)
NOMINAL = {"D": 50.0, "FIC1.SP": 60.0, "Y": 40.0}


@dataclass(frozen=True)
class Link:
    parent: str
    dead: int  # samples
    gain: float


@dataclass(frozen=True)
class Structure:
    drivers: list[str]
    links: dict[str, list[Link]]  # tag -> its parents
    poles: dict[str, float]
    duplicate: tuple[str, str]  # (copy, original)
    constants: list[str]
    set_point: str


def structure(n_tags: int = 30, structure_seed: int = 0) -> Structure:
    """The plant: ``n_tags`` tags in all (drivers, dependent tags, a set-point, two
    constants and a duplicate)."""
    rng = np.random.default_rng(structure_seed)
    n_dep = n_tags - 4
    n_drv = max(2, n_dep // 3)
    drivers = [f"D{i + 1}" for i in range(n_drv)]
    deps = [f"Y{i + 1}" for i in range(n_dep - n_drv)]
    links: dict[str, list[Link]] = {}
    poles: dict[str, float] = {}
    pool = list(drivers) + ["FIC1.SP"]
    for y in deps:
        k = 1 if rng.random() < 0.6 else 2
        parents = rng.choice(pool, size=k, replace=False)
        links[y] = [
            Link(
                str(p), int(rng.integers(0, 7)), float(rng.choice([-1, 1]) * rng.uniform(0.6, 1.5))
            )
            for p in parents
        ]
        poles[y] = float(rng.uniform(0.2, 0.5))
        pool.append(y)
    return Structure(drivers, links, poles, ("DUP", deps[2]), ["C1", "C2"], "FIC1.SP")


def _steps(rng: np.random.Generator, n: int, hold: float) -> np.ndarray:
    """Random levels held for geometric durations of mean ``hold`` samples, plus wander."""
    change = rng.random(n) < 1.0 / hold
    levels = rng.normal(0.0, 1.0, change.sum() + 1)
    x = levels[np.cumsum(change)]
    wander = lfilter([0.05], [1, -0.95], rng.normal(0, 1, n))
    return x + wander


def simulate(
    days: float = 10.0,
    *,
    period_s: float = 180.0,
    n_tags: int = 30,
    seed: int = 1,
    structure_seed: int = 0,
    start: str = "2026-03-02",
    noise: float = 0.03,
    disturbance: float = 0.5,
) -> tuple[pd.DataFrame, Structure]:
    """A run of the plant on a ``period_s`` grid, and its structure."""
    st = structure(n_tags, structure_seed)
    rng = np.random.default_rng(seed)
    n = int(days * 86400 / period_s)
    sig: dict[str, np.ndarray] = {}
    for d in st.drivers:
        sig[d] = NOMINAL["D"] + 10.0 * _steps(rng, n, 15.0)
    sig[st.set_point] = NOMINAL["FIC1.SP"] + 5.0 * np.round(_steps(rng, n, 60.0))
    for y, links in st.links.items():
        u = np.zeros(n)
        for ln in links:
            p = sig[ln.parent] - (NOMINAL.get(ln.parent) or NOMINAL[ln.parent[0]])
            u += ln.gain * np.r_[np.full(ln.dead, p[0]), p[: n - ln.dead]]
        # an unmeasured disturbance of its own: a child or a sibling carries it, so only
        # the true parents predict a tag as well as they do
        u += disturbance * lfilter([0.3], [1, -0.7], rng.normal(0, 1, n)) * np.std(u)
        a = st.poles[y]
        sig[y] = NOMINAL["Y"] + lfilter([1 - a], [1, -a], u)
    meas = {t: v + noise * np.std(v) * rng.normal(0, 1, n) for t, v in sig.items()}
    meas[st.set_point] = sig[st.set_point]  # a set-point is exact
    copy, orig = st.duplicate
    meas[copy] = 1.8 * meas[orig] + 32.0 + 1e-3 * rng.normal(0, 1, n)
    for i, c in enumerate(st.constants):
        meas[c] = np.full(n, 10.0 * (i + 1))
    idx = pd.date_range(start, periods=n, freq=pd.Timedelta(seconds=period_s), tz="UTC")
    return pd.DataFrame(meas, index=idx), st
