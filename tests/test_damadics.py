"""The real DAMADICS hour loads with the documented physics (fail-open valve, X lags CV)."""

import numpy as np
import pytest

from diag_plugin.damadics import find_file, load_hour

PATH = find_file()
pytestmark = pytest.mark.skipif(
    PATH is None, reason="real DAMADICS data not present (../shared/data/damadics; CI has it)"
)


def test_hour_loads_with_its_physics():
    f = load_hour(PATH)
    assert len(f) == 3600 and list(f.columns) == ["P1", "P2", "T1", "F", "CV", "X"]
    assert (f.index[1] - f.index[0]).total_seconds() == 1
    assert np.corrcoef(f["X"], f["F"])[0, 1] < -0.5  # F falls as X rises (fail-open valve)
    lags = [
        np.corrcoef(f["CV"].to_numpy()[: -k or None], f["X"].to_numpy()[k:])[0, 1] for k in range(4)
    ]
    assert int(np.argmax(lags)) == 1  # X follows CV about 1 s later
    g = load_hour(PATH, "10s")
    assert len(g) == 360 and g["F"].mean() == pytest.approx(f["F"].mean())
