"""The replay's memory-lean paths give what the whole arrays gave, bit for bit (issue 34,
replay speed: a first pass pays the first touch of every new page, so the replay makes fewer
arrays of its rows' size).

- :class:`~diag_plugin.diagnose.operating.LaggedColumns` reads single rows and the outside
  test of a lagged input from the carried tail and the piece, never joining them into a new
  column unless a whole one is asked for;
- :meth:`~diag_plugin.diagnose.unittags.CombinedModel.evaluate` over more than
  ``LAZY_Z_ROWS`` rows makes the scaled residuals per block of rows.
"""

from __future__ import annotations

import numpy as np
import pytest

from diag_plugin.diagnose import unittags
from diag_plugin.diagnose.operating import LaggedColumns, OutsideLearned, Range
from diag_plugin.diagnose.unittags import CombinedModel


def _joined(tail: np.ndarray, x: np.ndarray, lag: int) -> np.ndarray:
    """The column a model reading ``x`` at ``lag`` sees, the tail before it (the old way)."""
    d = tail.size
    return np.concatenate([tail, x])[d - lag : d - lag + x.size]


@pytest.mark.parametrize("n", [1, 3, 7, 50])
def test_lagged_columns_read_what_the_joined_column_holds(n):
    """Rows before and after the lag, the last row, the outside test (NaN: not outside)
    and the whole column agree with the tail and the piece joined, for a piece shorter and
    longer than the lag."""
    rng = np.random.default_rng(n)
    d = 5
    tail = rng.normal(size=d)
    tail[1] = np.nan
    x = rng.normal(size=n)
    x[n // 2] = np.nan
    cols = LaggedColumns(
        {"A": x, "B": x * 2}, {"A": tail}, [("A", 0), ("A", 2), ("A", 5), ("B", 0)]
    )
    assert set(cols) == {("A", 0), ("A", 2), ("A", 5), ("B", 0)}
    rows = np.arange(n)
    for lag in (0, 2, 5):
        want = _joined(tail, x, lag)
        key = ("A", lag)
        np.testing.assert_array_equal(cols.at(key, rows), want)
        np.testing.assert_array_equal(cols.at(key, rows[::-1]), want[::-1])
        assert np.array_equal([cols.last(key)], [want[-1]], equal_nan=True)
        with np.errstate(invalid="ignore"):
            np.testing.assert_array_equal(
                cols.outside(key, -0.5, 0.5), (want < -0.5) | (want > 0.5)
            )
        np.testing.assert_array_equal(cols[key], want)
    np.testing.assert_array_equal(cols.at(("B", 0), rows), x * 2)
    with pytest.raises(KeyError):
        cols.at(("A", 3), rows)


def test_a_lagged_input_is_named_the_same_in_pieces_as_in_one_pass():
    """An input read 3 samples back leaves its range at a piece's end: the reasons (value and
    since when) and the carried tails are those of one pass, piece by piece of 2 rows."""
    ranges = [Range(0, "A", 0.0, 5.0, lag=3), Range(0, "B", 0.0, 5.0)]
    x = np.array([1.0, 2.0, 9.0, 9.5, 3.0, 8.0, 1.0, 2.0, 7.0, 1.0])
    b = np.full(x.size, 1.0)
    idx = [np.datetime64("2026-01-01T00:00") + np.timedelta64(i, "m") for i in range(x.size)]
    unknown = np.ones((x.size, 1), bool)
    report = np.ones(x.size, bool)
    one = OutsideLearned(ranges).reset()
    whole = one.columns(one.lagged({"A": x, "B": b}), idx, unknown, report)
    pieces = OutsideLearned(ranges).reset()
    parts = []
    for s in range(0, x.size, 2):
        cols = pieces.lagged({"A": x[s : s + 2], "B": b[s : s + 2]})
        parts.append(pieces.columns(cols, idx[s : s + 2], unknown[s : s + 2], report[s : s + 2]))
    assert list(np.concatenate(parts)) == list(whole)
    assert "A[k-3] = 9 outside" in whole[5]
    np.testing.assert_array_equal(pieces.tails["A"], one.tails["A"])
    np.testing.assert_array_equal(one.tails["A"], x[-3:])


def test_the_combined_test_over_many_rows_is_the_whole_arrays_bit_for_bit(monkeypatch):
    """T² (tests unknown on some rows, so several patterns and the mapping to T degrees of
    freedom) and the shares, with the scaled residuals made per block of rows and at once."""
    rng = np.random.default_rng(7)
    T, n = 6, 5_000
    a = rng.normal(size=(T, T))
    cov = a @ a.T / T + np.eye(T)
    xi = np.eye(T)[:, :3]
    model = CombinedModel(["X", "Y", "Z"], rng.normal(size=T), rng.uniform(0.5, 2, T), cov, xi, 9.0)
    r = rng.normal(size=(n, T))
    r[rng.random((n, T)) < 0.05] = np.nan
    monkeypatch.setattr(unittags, "LAZY_Z_ROWS", 1 << 30)
    t2_whole, sh_whole = model.evaluate(r)
    fresh = CombinedModel(["X", "Y", "Z"], model.center, model.scale, cov, xi, 9.0)
    monkeypatch.setattr(unittags, "LAZY_Z_ROWS", 100)
    t2_blocks, sh_blocks = fresh.evaluate(r)
    assert t2_blocks.tobytes() == t2_whole.tobytes()
    assert sh_blocks.tobytes() == sh_whole.tobytes()
    assert np.isnan(t2_whole).sum() < n  # most rows known
