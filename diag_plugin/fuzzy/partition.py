"""Uniform fuzzy partitions of a variable's nominal span.

A partition of ``[lo, hi]`` into ``n`` sets has its set centres at
``c_i = lo + i·h`` with ``h = (hi − lo)/(n − 1)``. Neighbouring sets cross at
membership ½ and the memberships of any point sum to one (a Ruspini partition),
so inference with such partitions is interpolation between rule conclusions.

Shapes
------
``triangular``
    ``μ_i(x) = max(0, 1 − |x − c_i| / h)``.
``trapezoidal``
    A core (plateau) of half-width ``a = plateau·h/2`` around each centre, linear
    flanks reaching zero at the neighbour's core edge. ``plateau = 0`` is the
    triangular partition. The outermost sets are shoulders: values beyond the
    span take full membership of the end set (Kościelny et al., Sect. 4.4: "the
    extents of the inputs and output were defined by the ranges of the
    measurement transducers").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SHAPES = ("triangular", "trapezoidal")
#: plateau fraction of the trapezoidal shape (core width / set spacing)
DEFAULT_PLATEAU = 0.5


@dataclass(frozen=True)
class UniformPartition:
    """``n`` uniformly distributed fuzzy sets over ``[lo, hi]``."""

    lo: float
    hi: float
    n: int = 31
    shape: str = "trapezoidal"
    plateau: float = DEFAULT_PLATEAU

    def __post_init__(self) -> None:
        if not (np.isfinite(self.lo) and np.isfinite(self.hi)) or self.hi <= self.lo:
            raise ValueError(f"span must satisfy lo < hi, got [{self.lo}, {self.hi}]")
        if int(self.n) != self.n or self.n < 2:
            raise ValueError(f"a partition needs at least 2 sets, got {self.n}")
        if self.shape not in SHAPES:
            raise ValueError(f"shape must be one of {SHAPES}, got {self.shape!r}")
        if not 0.0 <= self.plateau < 1.0:
            raise ValueError(f"plateau must be in [0, 1), got {self.plateau}")

    @property
    def step(self) -> float:
        """Distance ``h`` between neighbouring set centres."""
        return (self.hi - self.lo) / (self.n - 1)

    @property
    def span(self) -> float:
        return self.hi - self.lo

    @property
    def core_halfwidth(self) -> float:
        """Half-width ``a`` of the plateau where a set has membership 1."""
        return 0.0 if self.shape == "triangular" else 0.5 * self.plateau * self.step

    @property
    def centers(self) -> np.ndarray:
        return self.lo + self.step * np.arange(self.n)

    def nearest(self, x: np.ndarray) -> np.ndarray:
        """Index of the set with maximal membership (Kościelny et al., eq. 3)."""
        i = np.floor((np.asarray(x, dtype=float) - self.lo) / self.step + 0.5)
        return np.clip(i, 0, self.n - 1).astype(np.int64)

    def membership(self, x: np.ndarray, i: np.ndarray | int) -> np.ndarray:
        """Membership ``μ_i(x)`` of ``x`` in set ``i`` (shoulders at both ends)."""
        x = np.asarray(x, dtype=float)
        i = np.asarray(i)
        h, a = self.step, self.core_halfwidth
        c = self.lo + h * i
        d = np.abs(x - c)
        mu = np.clip((h - a - d) / (h - 2 * a), 0.0, 1.0)
        mu = np.where((i == 0) & (x <= c), 1.0, mu)
        mu = np.where((i == self.n - 1) & (x >= c), 1.0, mu)
        return mu

    def upper_weight(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Lower neighbour index ``j`` and membership ``μ_{j+1}(x)`` of the upper one.

        Because the partition is Ruspini, ``μ_j(x) = 1 − μ_{j+1}(x)``; only sets
        ``j`` and ``j + 1`` fire. This is the basis of fast inference.
        """
        x = np.clip(np.asarray(x, dtype=float), self.lo, self.hi)
        t = (x - self.lo) / self.step
        j = np.minimum(np.floor(t), self.n - 2).astype(np.int64)
        f = t - j
        p = self.plateau if self.shape == "trapezoidal" else 0.0
        w = np.clip((f - p / 2) / (1 - p), 0.0, 1.0)
        return j, w

    def breakpoints(self, i: int) -> tuple[float, float, float, float]:
        """Corner points (a, b, c, d) of set ``i`` as a trapezoid (b = c for triangles)."""
        h, a = self.step, self.core_halfwidth
        c = self.lo + h * i
        left = c - h + a if i > 0 else self.lo - h
        right = c + h - a if i < self.n - 1 else self.hi + h
        core_l = c - a if i > 0 else self.lo - h
        core_r = c + a if i < self.n - 1 else self.hi + h
        return (left, core_l, core_r, right)

    def labels(self, prefix: str) -> list[str]:
        """Set labels ``prefix`` + zero-padded index, e.g. ``U00 … U30``."""
        width = max(2, len(str(self.n - 1)))
        return [f"{prefix}{i:0{width}d}" for i in range(self.n)]
