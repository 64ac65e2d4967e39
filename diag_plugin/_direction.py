"""The compiled loop of :func:`diag_plugin.regressors.direction` (numba), in its own module so
that importing the regressors (every training) does not import numba."""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True)
def _direction(x, threshold, carry):  # pragma: no cover - compiled
    out = np.empty(x.shape[0])
    ref = carry[0]
    state = carry[1]
    for i in range(x.shape[0]):
        v = x[i]
        if np.isnan(v):
            out[i] = np.nan
            ref = np.nan
            state = np.nan
            continue
        if np.isnan(ref):
            ref = v
        elif v - ref > threshold:
            state = 1.0
            ref = v
        elif ref - v > threshold:
            state = -1.0
            ref = v
        out[i] = state
    carry[0] = ref
    carry[1] = state
    return out
