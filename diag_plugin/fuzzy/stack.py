"""Many fitted Wang–Mendel models evaluated in one kernel call.

A plant of 1,000 units × 4 models whose units were each trained on their own data holds 4,000
distinct rule bases; calling each model's ``predict`` for one row per cycle costs a Python call
(~10 µs) per model. :class:`WangMendelStack` concatenates the models' partitions and sorted rule
tables of every level once (with offsets) and evaluates row ``i`` with model ``which[i]`` in one
compiled loop: the same kernel as :meth:`WangMendelRegressor.predict_detail`
(:func:`diag_plugin.fuzzy._kernels.infer_levels`: Kościelny et al., eq. 5 conclusions, the
coarser levels behind the fine grid), so the values, support, reason codes and levels are the
same. Rules are searched in their sorted keys (no dense tables: 4,000 of them would not fit).
A coarse level's answer in a gap of an input no level bridges is withdrawn as the model's own
:meth:`~WangMendelRegressor.predict_detail` withdraws it (reason *gap*).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from diag_plugin.fuzzy.wang_mendel import (
    WangMendelRegressor,
    pack,
    rows_in_gap,
    run_kernel,
    withdraw,
)
from diag_plugin.models.protocol import Prediction

__all__ = ["WangMendelStack"]


class WangMendelStack:
    """Fitted :class:`WangMendelRegressor` models stacked for one-call inference.

    ``WangMendelStack.from_models(models).predict_detail(which, X)``: row ``i`` of ``X``
    (``n × d_max``, columns beyond a model's inputs ignored) is evaluated by
    ``models[which[i]]``.
    """

    def __init__(self, packed: tuple, gaps: dict[int, list[np.ndarray]] | None = None):
        self.packed = packed
        self.n_inputs = packed[0]
        #: per stacked model with a gap no level bridges, its gaps per input
        #: (:meth:`WangMendelRegressor.input_gaps`)
        self.gaps = dict(gaps or {})

    @classmethod
    def from_models(cls, models: Sequence[WangMendelRegressor]) -> WangMendelStack:
        """Stack fitted models (their rules as they are now: rebuild after retraining)."""
        packed = pack([mod.inference_grid() for mod in models], dense=False)  # fitted ones
        gaps = {}
        for i, mod in enumerate(models):
            g = mod.unbridged_gaps() if mod.keys_.size else []
            if any(x.size for x in g):
                gaps[i] = g
        return cls(packed, gaps)

    @staticmethod
    def accepts(model: object) -> bool:
        """True for a fitted Wang–Mendel model (the kind this stack evaluates)."""
        return isinstance(model, WangMendelRegressor) and hasattr(model, "keys_")

    def __len__(self) -> int:
        return len(self.n_inputs)

    def predict_detail(self, which: np.ndarray, X: np.ndarray) -> Prediction:
        """Prediction, support, reason, level and spread per row; row ``i`` by model
        ``which[i]``."""
        which = np.ascontiguousarray(which, np.int64)
        X = np.ascontiguousarray(X, np.float64)
        if X.ndim != 2 or X.shape[0] != which.shape[0]:
            raise ValueError(
                f"X must be rows × inputs with one row per entry of which, got {X.shape}"
            )
        if which.size and (which.min() < 0 or which.max() >= len(self)):
            raise ValueError(f"which must index the {len(self)} stacked models")
        need = int(self.n_inputs[which].max()) if which.size else 0
        if X.shape[1] < need:
            raise ValueError(f"X has {X.shape[1]} columns, a model needs {need}")
        if not which.size:
            n = X.shape[0]
            e = np.empty(n)
            return Prediction(e, e, np.empty(n, np.int8), np.empty(n, np.int8), e)
        det = run_kernel(self.packed, which, X)
        self._no_bridge(which, X, det)
        return det

    def _no_bridge(self, which: np.ndarray, X: np.ndarray, det: Prediction) -> None:
        """Withdraw, in place, a coarse level's answer in a gap of an input of its model."""
        if not self.gaps:
            return
        lo, step, nsets = self.packed[1], self.packed[2], self.packed[4]
        rows = np.flatnonzero(det.level > 0)  # a coarse level answered: few rows, most calls
        rows = rows[np.isin(which[rows], list(self.gaps))]
        for m in np.unique(which[rows]).tolist():
            mine = rows[which[rows] == m]
            d = int(self.n_inputs[m])
            hit = rows_in_gap(X[mine, :d], lo[m, :d], step[m, :d], nsets[m, :d], self.gaps[m])
            withdraw(det, mine[hit])

    def predict(self, which: np.ndarray, X: np.ndarray) -> np.ndarray:
        """Model outputs; NaN where no trained rule covers the row."""
        return self.predict_detail(which, X).y
