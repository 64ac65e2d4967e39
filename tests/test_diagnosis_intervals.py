"""The timeline ``diag diagnose`` prints (:meth:`Diagnosis.intervals`) for a unit with the
combined test (issue 38's mutation check of ``diagnose/unit.py``): a run names the combined
test ``T2`` only where it was on, never where it was unknown or off."""

from __future__ import annotations

import numpy as np
import pandas as pd

from diag_plugin.diagnose.unit import Diagnosis, Unit
from diag_plugin.status import NE107, Quality
from tests.test_diagnosis_guards import GROUP_MATRIX, frame, make_unit


def _diagnosis(status, s1, s_t2) -> Diagnosis:
    n = len(status)
    idx = pd.date_range("2026-06-01", periods=n, freq="10s", tz="UTC")
    nan = float("nan")
    t2 = np.where(np.isnan(s_t2), nan, 3.0 + 10.0 * np.nan_to_num(s_t2))
    return Diagnosis(
        unit="u",
        residuals=pd.DataFrame({"r1": np.zeros(n)}, index=idx),
        symptoms=pd.DataFrame({"r1": np.asarray(s1, float)}, index=idx),
        certainties=pd.DataFrame(index=idx),
        detected=pd.Series(np.zeros(n), index=idx),
        status=pd.Series([int(s) for s in status], index=idx),
        quality=pd.Series(np.full(n, int(Quality.GOOD)), index=idx),
        faults=pd.Series([""] * n, index=idx),
        combined=pd.DataFrame({"T2": t2, "s_T2": np.asarray(s_t2, float)}, index=idx),
    )


def test_a_run_names_the_combined_test_only_where_it_was_on():
    N, F, C = NE107.NORMAL, NE107.FAILURE, NE107.CHECK_FUNCTION
    nan = np.nan
    d = _diagnosis(
        [N, N, C, C, F, F, N, N],
        [0, 0, nan, nan, 1, 0, 0, 0],
        [0, 0, nan, nan, 0, 1, nan, 0],
    )
    runs = d.intervals()
    assert list(runs["status"]) == ["NORMAL", "CHECK_FUNCTION", "FAILURE", "NORMAL"]
    assert list(runs["samples"]) == [2, 2, 2, 2]
    # T² unknown (CHECK_FUNCTION, and the last run's first sample) is not a symptom
    assert list(runs["tests"]) == ["", "", "r1,T2", ""]
    assert runs["to"].iloc[-1] == d.status.index[-1] + pd.Timedelta("10s")


def test_detected_is_one_with_a_symptom_zero_with_none_and_unknown_otherwise(tmp_path):
    """``detected`` (published beside the status): 1 while any test shows a symptom, 0 when
    every test answered without one, NaN when some test could not answer."""
    r1 = np.r_[np.zeros(4), np.full(8, 5.0), np.zeros(8)]
    data = frame(20, r1=r1)
    data.loc[data.index[17:], "Y3"] = np.nan  # r3 unknown at the end
    for matrix in (GROUP_MATRIX, None):
        folder = tmp_path / ("plain" if matrix is None else "matrix")
        folder.mkdir()
        d = Unit.load(make_unit(folder, matrix)).evaluate(data)
        on = d.symptoms.fillna(0).ne(0).any(axis=1).to_numpy()
        assert on.sum() >= 5  # the symptom is on after its on-delay
        assert (d.detected.to_numpy()[on] == 1.0).all()
        quiet = ~on & d.symptoms.notna().all(axis=1).to_numpy()
        assert quiet.sum() >= 3 and (d.detected.to_numpy()[quiet] == 0.0).all()
        assert np.isnan(d.detected.to_numpy()[~on & ~quiet]).all() and (~on & ~quiet).any()


def test_a_check_function_run_splits_where_its_reason_changes_not_its_values():
    """After a gap in the data (SKAB's valve1 run, a user's walk, issue 37) the unit is
    unknown first for a missing lag, then for an input outside what it learned; the timeline
    read "without a value" for all 127 s. A value moving on within one reason stays one run."""
    C = NE107.CHECK_FUNCTION
    d = _diagnosis([C] * 7, [np.nan] * 7, [np.nan] * 7)
    since = "since 2020-03-09T10:34:35+00:00"
    d.why = pd.Series(
        ["T[k-2], FT1 without a value"] * 3
        + [
            f"T[k-2] = {v} outside what the unit learned (86 … 94) {since}"
            for v in (75.5, 75.6, 75.63, 76)
        ],
        index=d.status.index,
    )
    runs = d.intervals()
    assert list(runs["samples"]) == [3, 4]
    assert runs["why"].iloc[1].startswith("T[k-2] = 75.5 outside")
