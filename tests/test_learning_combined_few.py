"""The combined test's T² is calibrated without the few-values rule (issue 34 review item 2;
learn/thresholds.py ``combined_threshold``; docs/how-to/unit-short-windows.md, "the few-values
rule on").

Each test's sides take Rice's Gaussian threshold in place of the tail fit where their window
holds fewer than ``budget.FEW_VALUES`` independent values, crosses its mean often enough to
reach ``budget.SEEN_Z`` spreads, and its top is one a Gaussian series shows. The combined T²
does not (``COMBINED_FEW`` = 0): it is a sum of squares with an exponential (χ²) tail, the tail
fit's own model. Here a month at 1 min of five slow residuals (AR(1), φ = 0.999, with fast
noise): T² holds under 100 independent values, and its tail fit stands; on T² itself the rule
would not be on (its top is beyond a Gaussian's), on √T² it would, with another threshold. A
change that wires the rule into the combined test moves this threshold and fails here.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from diag_plugin.learn.budget import FEW_VALUES, calibrate_side
from diag_plugin.learn.thresholds import COMBINED_FEW, combined_threshold
from diag_plugin.models.series import effective_samples

#: a month at 1 min, the unit's delays (3 samples each) and a combined budget per hour
N, HOURS, FAR, ON, OFF = 43200, 720.0, 0.0005, 3, 3


def _slow_t2(tests: int = 5, phi: float = 0.999, seed: int = 0) -> np.ndarray:
    """T² of ``tests`` independent slow scaled residuals (unit variance AR(1) plus noise)."""
    rng = np.random.default_rng(seed)
    z = signal.lfilter([np.sqrt(1 - phi**2)], [1, -phi], rng.standard_normal((N, tests)), axis=0)
    z += 0.3 * rng.standard_normal((N, tests))
    return (z**2).sum(axis=1)


def test_the_combined_t2_of_few_values_keeps_its_tail_fit():
    t2 = _slow_t2()
    assert COMBINED_FEW == 0.0
    assert effective_samples(t2) < FEW_VALUES  # a window the tests' rule would look at
    high, side = combined_threshold(t2, HOURS, FAR, ON, OFF)
    tail = calibrate_side(t2, HOURS, FAR, ON, OFF)
    assert side.method == "tail"
    assert high == tail.threshold
    # on T² itself the rule would not be on: its top is beyond a Gaussian series'
    on_t2 = calibrate_side(t2, HOURS, FAR, ON, OFF, FEW_VALUES)
    assert (on_t2.method, on_t2.threshold) == ("tail", high)
    # on √T² (where the combined test's Gaussian model is fitted) it would, and move it
    on_chi = calibrate_side(np.sqrt(t2), HOURS, FAR, ON, OFF, FEW_VALUES)
    assert on_chi.method == "rice"
    assert on_chi.threshold**2 == pytest.approx(26.4, abs=0.1)
    assert high == pytest.approx(21.4, abs=0.1)


def test_too_few_episodes_for_a_tail_fit_rice_on_the_distance():
    """A window too short for a tail (a day at 1 min): Rice's Gaussian rate on √T², squared."""
    t2 = _slow_t2()[:1440]
    high, side = combined_threshold(t2, 24.0, FAR, ON, OFF)
    assert calibrate_side(t2, 24.0, FAR, ON, OFF).method == "gaussian"
    assert side.method == "gaussian"
    assert high == pytest.approx(calibrate_side(np.sqrt(t2), 24.0, FAR, ON, OFF).threshold ** 2)
