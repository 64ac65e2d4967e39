"""What every model method offers the rest of the product (training, compare, explain,
report, the Dask engine, diagnostics): scikit-learn style estimators with a declared set of
capabilities and a public, pickle-free state."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Protocol, Self, runtime_checkable

import numpy as np

REASON_OK = 0
REASON_NAN = 1
REASON_UNSUPPORTED = 2
REASON_OUTSIDE = 3
REASON_GAP = 4
REASONS = {
    REASON_OK: "",
    REASON_NAN: "an input is missing (NaN or bad quality)",
    REASON_UNSUPPORTED: "no trained rule covers this operating point",
    REASON_OUTSIDE: "an input is outside its nominal span (clipped to the span)",
    REASON_GAP: "an input is in a gap of its training data (no level bridges it)",
}


@dataclass(frozen=True)
class Capabilities:
    """What a method can do; callers use a feature only where it is declared.

    ``incremental``: ``partial_fit`` on consecutive chunks equals one ``fit``.
    ``mergeable``: ``merge`` of models trained on parts equals training on all
    (chunks trained on Dask workers). ``rule_regions``: predictions come from
    rule cells over the inputs (``regions``), so errors can be mapped per cell.
    ``free_run``: the model can simulate its output from its own past outputs
    (output-error residuals) with ``simulate(X)`` over consecutive rows: the inputs that
    are lags of the output get the model's earlier outputs instead of the measurements.
    """

    incremental: bool = False
    mergeable: bool = False
    rule_regions: bool = False
    free_run: bool = False


@dataclass(frozen=True)
class Prediction:
    """Model output with its support: ``y`` (NaN where unsupported), the firing
    weight carried by existing rules ``support`` (0–1), a ``reason`` code
    per sample (see :data:`REASONS`) and, for models with a rule grid and coarser
    levels behind it, the ``level`` that answered (0 = the fine grid, -1 = none;
    ``None`` for methods without levels) and the ``spread`` of the training outputs
    where it answered, relative to the model's typical spread (1 = typical; NaN unknown;
    ``None`` for methods that keep no spread)."""

    y: np.ndarray
    support: np.ndarray
    reason: np.ndarray
    level: np.ndarray | None = None
    spread: np.ndarray | None = None

    @property
    def coverage(self) -> float:
        """Share of samples that got a prediction."""
        return float(np.isfinite(self.y).mean()) if self.y.size else float("nan")

    def coverage_by_level(self) -> dict[int, float]:
        """Share of the samples answered at each level (level 0 only for methods without
        levels); the shares sum to :attr:`coverage`."""
        if not self.y.size:
            return {}
        if self.level is None:
            return {0: self.coverage}
        lv = self.level[np.isfinite(self.y)]
        counts = np.bincount(lv.astype(np.int64), minlength=1) if lv.size else np.zeros(1)
        return {i: float(c) / self.y.size for i, c in enumerate(counts) if c or i == 0}


def mean_stand_in(pred: np.ndarray, mean: float) -> np.ndarray:
    """``pred`` (a new array) with ``mean`` where it has no value: the stand-in of a model
    without rules to fall back on (its mean training output)."""
    y = np.asarray(pred, dtype=float)
    return np.where(np.isfinite(y), y, mean)


@runtime_checkable
class Model(Protocol):
    """A model of one output from ``d`` inputs (rows × inputs in, one value per row out)."""

    capabilities: ClassVar[Capabilities]
    n_samples_seen_: int
    #: mean training output
    output_mean_: float

    def fit(self, X: Any, y: Any) -> Self: ...

    def partial_fit(self, X: Any, y: Any) -> Self: ...

    def predict(self, X: Any) -> np.ndarray: ...

    def predict_detail(self, X: Any) -> Prediction: ...

    def extrapolate(self, X: Any, pred: np.ndarray | None = None) -> np.ndarray:
        """The prediction, and where there is none the model's best stand-in (e.g. its
        nearest rule, else its mean output): used only to score every sample. ``pred``:
        this model's prediction of ``X`` where the caller has it already (``predict(X)``,
        NaN where the model has none); every model takes it and does not predict again."""
        ...

    def merge(self, other: Self) -> Self: ...

    def to_state(self) -> dict[str, Any]: ...

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> Self: ...
