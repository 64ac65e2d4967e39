"""The compiled step of a free run (:func:`~diag_plugin.models.estimation.free_run`), for the
methods whose free run is compiled (``narmax2``, ``ts-fcm``). Its own module so that importing
the estimators' shared helpers does not load numba (a one-off ``diag train`` of a Wang–Mendel
model runs without it: :func:`diag_plugin.fuzzy.wang_mendel.kernels`)."""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True, nogil=True)
def fed_row(X, k, cols, lags, yhat, x):  # pragma: no cover - compiled
    """Row ``k`` of a free run into ``x`` (for the compiled free runs of the methods, the
    step of :func:`free_run`): ``X[k]`` with each lag column ``cols[c]`` given the estimate
    ``lags[c]`` rows earlier where there is one; True when every input has a value."""
    x[:] = X[k]
    for c in range(cols.size):
        i = k - lags[c]
        if i >= 0 and np.isfinite(yhat[i]):
            x[cols[c]] = yhat[i]
    return np.isfinite(x).all()
