"""Many fitted Wang–Mendel models evaluated in one kernel call.

A plant of 1,000 units × 4 models whose units were each trained on their own data holds 4,000
distinct rule bases; calling each model's ``predict`` for one row per cycle costs a Python call
(~10 µs) per model. :class:`WangMendelStack` concatenates the models' partitions and sorted rule
tables once (with offsets) and evaluates row ``i`` with model ``which[i]`` in one compiled loop:
the same multilinear interpolation over the rule grid as
:meth:`WangMendelRegressor.predict_detail` (Kościelny et al., eq. 5 conclusions; cells never
seen in training are unsupported), with the same values, support and reason codes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numba as nb
import numpy as np

from diag_plugin.fuzzy import _kernels as K
from diag_plugin.fuzzy.wang_mendel import WangMendelRegressor
from diag_plugin.models.protocol import Prediction

__all__ = ["WangMendelStack"]


class WangMendelStack:
    """Fitted :class:`WangMendelRegressor` models stacked for one-call inference.

    ``WangMendelStack.from_models(models).predict_detail(which, X)``: row ``i`` of ``X``
    (``n × d_max``, columns beyond a model's inputs ignored) is evaluated by
    ``models[which[i]]``.
    """

    def __init__(
        self,
        n_inputs: np.ndarray,
        lo: np.ndarray,
        step: np.ndarray,
        plateau: np.ndarray,
        nsets: np.ndarray,
        radix: np.ndarray,
        offsets: np.ndarray,
        keys: np.ndarray,
        values: np.ndarray,
    ):
        self.n_inputs = n_inputs
        self.lo, self.step, self.plateau, self.nsets, self.radix = lo, step, plateau, nsets, radix
        self.offsets, self.keys, self.values = offsets, keys, values

    @classmethod
    def from_models(cls, models: Sequence[WangMendelRegressor]) -> WangMendelStack:
        """Stack fitted models (their rules as they are now: rebuild after retraining)."""
        grids = [mod.inference_grid() for mod in models]
        m = len(grids)
        d_max = max((g.lo.size for g in grids), default=1)
        n_inputs = np.array([g.lo.size for g in grids], np.int64)
        lo = np.zeros((m, d_max))
        step = np.ones((m, d_max))
        plateau = np.zeros((m, d_max))
        nsets = np.full((m, d_max), 2, np.int64)
        radix = np.zeros((m, d_max), np.int64)
        offsets = np.zeros(m + 1, np.int64)
        for i, g in enumerate(grids):
            d = g.lo.size
            lo[i, :d], step[i, :d], nsets[i, :d], plateau[i, :d] = g.lo, g.step, g.nsets, g.plateau
            radix[i, :d] = g.radix
            offsets[i + 1] = offsets[i] + g.keys.size
        keys = [g.keys for g in grids]
        values = [g.conclusions for g in grids]
        cat_k = np.concatenate(keys) if keys else np.empty(0, np.int64)
        cat_v = np.concatenate(values) if values else np.empty(0)
        return cls(n_inputs, lo, step, plateau, nsets, radix, offsets, cat_k, cat_v)

    @staticmethod
    def accepts(model: object) -> bool:
        """True for a fitted Wang–Mendel model (the kind this stack evaluates)."""
        return isinstance(model, WangMendelRegressor) and hasattr(model, "keys_")

    def __len__(self) -> int:
        return len(self.n_inputs)

    def predict_detail(self, which: np.ndarray, X: np.ndarray) -> Prediction:
        """Prediction, support and reason per row; row ``i`` by model ``which[i]``."""
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
        n = X.shape[0]
        out = np.empty(n)
        sup = np.empty(n)
        reason = np.empty(n, np.int8)
        _infer_stack(
            which, X, self.n_inputs, self.lo, self.step, self.plateau, self.nsets, self.radix,
            self.offsets, self.keys, self.values, out, sup, reason,
        )  # fmt: skip
        return Prediction(out, sup, reason)

    def predict(self, which: np.ndarray, X: np.ndarray) -> np.ndarray:
        """Model outputs; NaN where no trained rule covers the row."""
        return self.predict_detail(which, X).y


@nb.njit(cache=True, nogil=True)
def _infer_stack(
    which, X, n_inputs, lo, step, plateau, nsets, radix, offsets, keys, values, out, support, reason
):
    """:func:`._kernels.infer` with per-row model parameters (same arithmetic, same codes)."""
    d_max = X.shape[1]
    js = np.empty(d_max, dtype=np.int64)
    ws = np.empty(d_max, dtype=np.float64)
    for r in range(X.shape[0]):
        m = which[r]
        d = n_inputs[m]
        code = 0
        for k in range(d):
            xv = X[r, k]
            if math.isnan(xv):
                code = 1
                break
            lo_k = lo[m, k]
            hi_k = lo_k + step[m, k] * (nsets[m, k] - 1)
            if xv < lo_k:
                xv = lo_k
                code = 3
            elif xv > hi_k:
                xv = hi_k
                code = 3
            t = (xv - lo_k) * (1.0 / step[m, k])
            j = int(t)
            if j > nsets[m, k] - 2:
                j = nsets[m, k] - 2
            f = t - j
            p = plateau[m, k]
            wv = (f - 0.5 * p) / (1.0 - p)
            if wv < 0.0:
                wv = 0.0
            elif wv > 1.0:
                wv = 1.0
            js[k] = j
            ws[k] = wv
        if code == 1:
            out[r] = np.nan
            support[r] = 0.0
            reason[r] = 1
            continue
        base = 0
        for k in range(d):
            base += js[k] * radix[m, k]
        mk = keys[offsets[m] : offsets[m + 1]]
        mv = values[offsets[m] : offsets[m + 1]]
        num = 0.0
        den = 0.0
        for c in range(1 << d):
            wt = 1.0
            key = base
            for k in range(d):
                if (c >> k) & 1:
                    wt *= ws[k]
                    key += radix[m, k]
                else:
                    wt *= 1.0 - ws[k]
            if wt == 0.0:
                continue
            v = K._lookup_sparse(mk, mv, key)
            if not math.isnan(v):
                num += wt * v
                den += wt
        support[r] = den
        if den > 0.0:
            out[r] = num / den
            reason[r] = code
        else:
            out[r] = np.nan
            reason[r] = 2
