"""Edges of the residual and symptom stages a mutation check found untested (issue 28): the
limits a user may set (cut-off, quantile, fuzzy ramp width) are accepted up to and including
their documented ends and refused beyond, and the signal-maximum scaler survives its JSON
state. Public interfaces only."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from diag_plugin.diagnose.residuals import LowPass, MaxScaler
from diag_plugin.diagnose.symptoms import FuzzyThreeValued, LearnedThresholds


@pytest.mark.parametrize("wn", [0.0, -0.2, 1.0])
def test_a_cut_off_outside_zero_to_nyquist_is_refused_by_name(wn):
    with pytest.raises(ValueError, match="wn must be in"):
        LowPass(wn=wn)


def test_quantile_one_is_the_largest_fault_free_residual():
    """quantile = 1 (the documented upper end) takes max |r| of the window, times the margin."""
    r = pd.DataFrame({"r1": [0.5, -3.0, 1.0, 2.0]})
    lt = LearnedThresholds(quantile=1.0, margin=1.5).fit(r)
    assert lt.thresholds_["r1"] == pytest.approx(4.5)
    with pytest.raises(ValueError, match="quantile"):
        LearnedThresholds(quantile=1.01)


def test_a_fuzzy_ramp_up_to_twice_the_threshold_is_accepted_whatever_the_threshold():
    """Width may reach 2·K (N and P then just touch); with K = 4 % a 6 % wide ramp is valid
    and its memberships are mirror images: P at +K and N at −K are both ½."""
    fz = FuzzyThreeValued(threshold=4.0, width=6.0)
    mn, mz, mp = fz.transform(np.array([-4.0, 0.0, 4.0, 8.0]))
    np.testing.assert_allclose(mp, [0.0, 0.0, 0.5, 1.0])
    np.testing.assert_allclose(mn, [0.5, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(mz, [0.5, 1.0, 0.5, 0.0])
    FuzzyThreeValued(threshold=4.0, width=8.0).transform(np.zeros(1))  # the end, 2·K
    with pytest.raises(ValueError, match="width"):
        FuzzyThreeValued(threshold=4.0, width=8.5).transform(np.zeros(1))


def test_the_signal_maximum_survives_its_json_state():
    sc = MaxScaler().fit(pd.DataFrame({"a": [1.0, -4.0], "b": [10.0, 5.0]}))
    again = MaxScaler.from_state(json.loads(json.dumps(sc.to_state())))
    np.testing.assert_array_equal(again.transform(np.array([[2.0, -1.0]])), [[0.5, -0.1]])
    fresh = MaxScaler.from_state(json.loads(json.dumps(MaxScaler().to_state())))
    with pytest.raises(RuntimeError, match="not fitted"):
        fresh.transform(np.zeros((1, 2)))


def test_a_malformed_matrix_row_is_named_by_its_position():
    from diag_plugin.diagnose.matrix import MatrixError, parse_matrix

    text = (
        '[matrix]\ntests = ["r1", "r2"]\nfaults = ["f_A"]\nrows = [\n'
        '  { test = "r1", row = ["1"] },\n  { row = ["0"] },\n]\n'
    )
    with pytest.raises(MatrixError) as e:
        parse_matrix(text, "m.toml")
    assert any("m.toml:4: row 2: needs test" in p for p in e.value.problems), e.value.problems


def test_learned_thresholds_keep_their_counts_and_window_through_json():
    idx = pd.date_range("2026-01-01", periods=50, freq="10s", tz="UTC")
    r = pd.DataFrame({"r1": np.linspace(-2, 2, 50)}, index=idx)
    lt = LearnedThresholds(quantile=1.0, margin=1.0).fit(r)
    again = LearnedThresholds.from_state(json.loads(json.dumps(lt.to_state())))
    assert again.thresholds_["r1"] == pytest.approx(2.0)
    assert again.n_samples_["r1"] == 50
    assert again.window_ == (idx[0].isoformat(), idx[-1].isoformat())


@pytest.mark.parametrize("threshold", [0.0, -1.0])
def test_a_fuzzy_threshold_must_be_positive(threshold):
    with pytest.raises(ValueError, match="threshold > 0"):
        FuzzyThreeValued(threshold=threshold, width=0.0).transform(np.zeros(1))
