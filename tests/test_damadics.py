"""The real DAMADICS hour loads with the documented physics (fail-open valve, X lags CV)."""

import numpy as np
import pytest
from helpers import DAMADICS_HOW, damadics_file, requires

from diag_plugin.examples.damadics import load_hour

PATH = damadics_file()
pytestmark = requires("real DAMADICS data", PATH is not None, DAMADICS_HOW)


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


def test_the_package_finds_the_hour_beside_the_repository():
    """``find_file`` looks in ``../shared/data/damadics`` from the repository root (the
    example build reads the hour from there)."""
    from helpers import REPO

    from diag_plugin.examples.damadics import DEFAULT_PATH

    assert DEFAULT_PATH == REPO.parent / "shared" / "data" / "damadics"
