"""``diag diagnose --json``'s text (issue 34): the intervals encoded column by column are the
bytes ``json.dumps(summary, indent=2)`` wrote from ``to_dict("records")``, for every kind of
value a column may hold; the bench's 200,000 rows: the same md5 (bench_diagnose_cli.py)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from diag_plugin.diagnose.summaryjson import summary_text

SUMMARY = {"unit": "u", "samples": 3, "message": 'é "q"', "status_share": {"NORMAL": 1.0}}


def reference(summary: dict, frame: pd.DataFrame) -> str:
    """What ``diag diagnose --json`` printed before (its code then)."""
    rows = [
        {**r, "from": r["from"].isoformat(), "to": r["to"].isoformat()}
        for r in frame.to_dict("records")
    ]
    return json.dumps({**summary, "intervals": rows}, indent=2)


def frame(n: int, tz: str | None = "UTC", **cols) -> pd.DataFrame:
    t = pd.date_range("2026-06-01", periods=n + 1, freq="180s", tz=tz)
    return pd.DataFrame({"from": t[:-1], "to": t[1:], **cols}, index=pd.RangeIndex(n))


@pytest.mark.parametrize(
    "cols",
    [
        {"status": ["NORMAL", "FAILURE", "CHECK_FUNCTION"], "samples": [1, 20, 300]},
        {"faults": ["", "f1|f2", 'ü\n\t\\"x\u2028'], "tests": ["D1,T2", "", "Y3"]},
        {"why": ["warming up", None, np.nan]},  # an object column: text, None, NaN
        {"why": [np.nan, np.nan, np.nan]},  # float: NaN only
        {"x": [0.1, -0.0, 1e300], "y": [np.inf, -np.inf, 2.5]},
        {"flag": [True, False, True], "count": np.array([1, 2, 3], np.int64)},
        {"mixed": ["a", 1, 2.0]},
        {"odd": [np.int64(1), "a", None]},  # numpy ints in an object column: json's own path
    ],
)
def test_the_intervals_are_the_bytes_json_dumps_wrote(cols):
    f = frame(3, **cols)
    assert summary_text(SUMMARY, "intervals", f) == reference(SUMMARY, f)


@pytest.mark.parametrize("tz", ["UTC", "Europe/Warsaw", None])
def test_times_in_any_zone_and_an_empty_timeline(tz):
    f = frame(4, tz=tz, status=["NORMAL"] * 4)
    f["to"] = f["to"] + pd.Timedelta("1.5s")  # fractions of a second as isoformat writes them
    assert summary_text(SUMMARY, "intervals", f) == reference(SUMMARY, f)
    empty = f.iloc[:0]
    assert summary_text(SUMMARY, "intervals", empty) == reference(SUMMARY, empty)


@pytest.mark.parametrize("unit", ["s", "ms", "us", "ns"])
@pytest.mark.parametrize("tz", ["UTC", "Europe/Warsaw", None])
def test_times_on_whole_seconds_and_off_them_in_any_unit(unit, tz):
    """UTC times on whole seconds are formatted at once (issue 34): the text ``isoformat``
    writes, in every time unit, before 1970 and far after, and a column with one time off a
    whole second (then each time as before)."""
    t = pd.DatetimeIndex(
        ["1969-12-31T23:59:59", "1970-01-01", "2026-06-01T00:03:00", "2200-02-28T23:59:59"],
        tz=tz,
    ).as_unit(unit)
    f = pd.DataFrame({"from": t, "to": t + pd.Timedelta("180s")}, index=pd.RangeIndex(4))
    assert summary_text(SUMMARY, "intervals", f) == reference(SUMMARY, f)
    if unit != "s":
        f["to"] = f["to"] + pd.Timedelta(1, unit=unit)
        assert summary_text(SUMMARY, "intervals", f) == reference(SUMMARY, f)
