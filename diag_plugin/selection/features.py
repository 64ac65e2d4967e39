"""Candidate feature columns over an aligned frame, computed once and lagged by slicing."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd

from diag_plugin.regressors import InputSpec, feature


class Features:
    """Unlagged feature columns over the frame, computed once, lagged by slicing."""

    def __init__(self, frame: pd.DataFrame, spans: Mapping[str, tuple[float, float]]):
        self.frame = frame
        self.spans = spans
        self.cache: dict[str, np.ndarray] = {}

    def column(self, spec: InputSpec) -> np.ndarray:
        base = spec.base
        if base not in self.cache:
            self.cache[base] = feature(self.frame, spec, self.spans)
        v = self.cache[base]
        if spec.lag:
            v = np.r_[np.full(min(spec.lag, v.size), np.nan), v[: max(v.size - spec.lag, 0)]]
        return v
