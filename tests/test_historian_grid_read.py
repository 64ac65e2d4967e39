"""A regular series read without its times (issue 34, round six).

:meth:`historian.backends.SqliteBulk.read_grid` answers a tag's values alone when its samples
are exactly one on each grid point, and None (read the samples) otherwise: a sample off the
grid, a grid point without one, an infinite value. The chunked windows ``diag diagnose``
reads (``summary=False``) must equal the windows aligned from the samples
(:func:`historian.window.align`) in every such case, to the bit.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from historian import BAD, UNCERTAIN, Historian
from historian.times import to_us

T0 = pd.Timestamp("2026-03-02T00:00:00Z")
P = pd.Timedelta("1min")


def _series(seed: int, n: int = 500) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Five tags on the grid (values and quality codes), each with its own defect:
    none, Bad and Uncertain samples, one off the grid, one missing, one infinite value."""
    rng = np.random.default_rng(seed)
    idx = T0 + P * np.arange(n)
    v = pd.DataFrame(rng.normal(size=(n, 5)), index=idx, columns=list("ABCDE"))
    q = pd.DataFrame(0, index=idx, columns=v.columns)
    q.iloc[rng.choice(n, 20, replace=False), 1] = BAD
    q.iloc[rng.choice(n, 20, replace=False), 1] = UNCERTAIN
    v.iloc[rng.integers(n), 3] = np.nan  # D: a grid point without a sample
    v.iloc[rng.integers(n), 4] = np.inf  # E: an infinite value (not usable)
    return v, q


def _write(h: Historian, seed: int) -> pd.DataFrame:
    v, q = _series(seed)
    h.write_samples(v, q)
    # C: one sample moved 7 s off its grid point (its grid point left without one)
    k = 123 + seed
    c = pd.Series([v["C"].iloc[k]], index=[v.index[k] + pd.Timedelta("7s")], name="C")
    h.write_samples(v[["C"]].drop(index=v.index[k]))
    h.write_samples(c)
    return v


@pytest.mark.parametrize("seed", [3, 11])
def test_read_grid_answers_only_a_regular_series(tmp_path, seed):
    with Historian(f"sqlite:///{tmp_path / 'h.db'}") as h:
        v = _write(h, seed)
        _, q = _series(seed)
        t0, p, n = to_us(T0), P.value // 1000, len(v)
        got = {name: h._bulk.read_grid(h._tag(name)[0], t0, p, n) for name in "ABCDE"}
        assert got["C"] is None and got["D"] is None and got["E"] is None
        np.testing.assert_array_equal(got["A"], v["A"].to_numpy())
        # B: Bad samples NaN, Uncertain ones kept
        want = np.where(q["B"].to_numpy() < BAD, v["B"].to_numpy(), np.nan)
        np.testing.assert_array_equal(got["B"], want)
        assert (q["B"] == UNCERTAIN).any() and np.isnan(want).any()
        # a shorter grid (fewer points than rows) and one shifted off the samples: None
        assert h._bulk.read_grid(h._tag("A")[0], t0 + p // 3, p, n - 1) is None
        assert h._bulk.read_grid(h._tag("A")[0], t0, p, 0) is None
        # the window ends inside the series: the rows in it, read alone
        part = h._bulk.read_grid(h._tag("A")[0], t0 + 10 * p, p, 50)
        np.testing.assert_array_equal(part, v["A"].to_numpy()[10:60])


@pytest.mark.parametrize(("seed", "chunk", "period"), [(5, "2h", "1min"), (8, "97min", "1min")])
def test_chunked_windows_equal_the_aligned_window(tmp_path, seed, chunk, period):
    with Historian(f"sqlite:///{tmp_path / 'h.db'}") as h:
        v = _write(h, seed)
        tags = list(v.columns)
        end = v.index[-1] + P
        hold = dict.fromkeys(tags, 0)
        whole = h.window(tags, T0, end, period, hold=hold)  # aligned from the samples
        for how in ("mean", "last"):
            parts = h.iter_windows(
                tags, T0, end, period, how, chunk=chunk, hold=hold, summary=False
            )
            joined = pd.concat(list(parts))
            ref = h.window(tags, T0, end, period, how, hold=hold) if how == "last" else whole
            pd.testing.assert_frame_equal(joined, ref, check_freq=False)
        # an off-grid start: the grid's points are not the samples' times
        late = T0 + pd.Timedelta("20s")
        parts = h.iter_windows(tags, late, end, period, chunk=chunk, hold=hold, summary=False)
        shifted = pd.concat(list(parts))
        ref = h.window(tags, late, end, period, hold=hold)
        pd.testing.assert_frame_equal(shifted, ref, check_freq=False)


def test_read_grid_before_the_epoch(tmp_path):
    """An epoch-anchored grid is tested by ``ts % period`` alone (SQLite's ``%`` takes the
    dividend's sign): across the epoch, a regular series is read and one sample moved off
    its grid point before the epoch is found (issue 34, the grid's test without ``t0``)."""
    start = pd.Timestamp("1969-12-31T23:00:00Z")
    n = 120
    idx = start + P * np.arange(n)
    v = pd.DataFrame({"A": np.arange(n, dtype=float), "B": np.arange(n, dtype=float)}, index=idx)
    with Historian(f"sqlite:///{tmp_path / 'h.db'}") as h:
        h.write_samples(v[["A"]])
        moved = v["B"].drop(index=idx[10])
        h.write_samples(moved.to_frame())
        h.write_samples(pd.Series([10.0], index=[idx[10] + pd.Timedelta("7s")], name="B"))
        t0, p = to_us(start), P.value // 1000
        assert t0 < 0 and t0 % p == 0
        np.testing.assert_array_equal(h._bulk.read_grid(h._tag("A")[0], t0, p, n), v["A"])
        assert h._bulk.read_grid(h._tag("B")[0], t0, p, n) is None
        # past the moved sample: the rest of B on the grid, after the epoch too
        np.testing.assert_array_equal(
            h._bulk.read_grid(h._tag("B")[0], t0 + 20 * p, p, n - 20), v["B"].to_numpy()[20:]
        )
