"""Aligned windows, chunked iteration, quality summary and the Parquet cold store."""

from __future__ import annotations

import numpy as np
import pandas as pd

from historian import BAD, UNCERTAIN, quality_table

T0 = pd.Timestamp("2024-01-01", tz="UTC")


def test_window_mean_and_last(historian):
    idx = T0 + pd.to_timedelta(np.arange(12) * 10, unit="s")
    historian.write_samples(pd.DataFrame({"A": np.arange(12.0)}, index=idx))
    w = historian.window(["A"], T0, T0 + pd.Timedelta("2min"), period="1min")
    assert w.index.name == "ts" and str(w.index.tz) == "UTC"
    assert w.index.tolist() == [T0, T0 + pd.Timedelta("1min")]
    # each grid point takes the samples within half a period of it: [-30 s, 30 s), [30 s, 90 s)
    assert w["A"].tolist() == [1.0, 5.5]
    w = historian.window(["A"], T0, T0 + pd.Timedelta("2min"), period="1min", how="last")
    assert w["A"].tolist() == [2.0, 8.0]


def test_bad_quality_is_nan_and_uncertain_kept(historian):
    idx = T0 + pd.to_timedelta(np.arange(6) * 10, unit="s")
    q = pd.DataFrame({"A": [0, BAD, BAD, 0, UNCERTAIN, 0]}, index=idx)
    historian.write_samples(pd.DataFrame({"A": np.arange(6.0)}, index=idx), quality=q)
    w = historian.window(["A"], T0, T0 + pd.Timedelta("60s"), period="20s")
    assert w["A"].iloc[0] == 0.0
    assert np.isnan(w["A"].iloc[1])  # only bad samples within 10 s of it
    assert w["A"].iloc[2] == 3.5
    last = historian.window(["A"], T0, T0 + pd.Timedelta("60s"), period="20s", how="last")
    assert np.isnan(last["A"].iloc[1])
    summary = quality_table(w).loc["A"]
    # the sample at 50 s belongs to the grid point at 60 s, outside the window
    assert (summary["bad"], summary["uncertain"], summary["good"]) == (2, 1, 2)
    assert summary["coverage"] == 2 / 3


def test_unaligned_start_and_missing_tag_data(historian):
    idx = T0 + pd.to_timedelta(np.arange(30) * 10, unit="s")
    historian.write_samples(pd.DataFrame({"A": np.ones(30), "B": np.ones(30)}, index=idx))
    historian.ensure_tag("EMPTY")
    w = historian.window(["A", "EMPTY"], T0 + pd.Timedelta("25s"), T0 + pd.Timedelta("100s"), 10)
    assert w.index[0] == T0 + pd.Timedelta("30s")  # the first grid point after the start
    assert list(w.columns) == ["A", "EMPTY"]
    assert w["EMPTY"].isna().all()
    assert w.attrs["quality"]["EMPTY"]["stale"] is True
    assert w.attrs["quality"]["EMPTY"]["first"] is None


def test_quality_summary_gaps_flat_out_of_range(historian):
    historian.ensure_tag("F", lo=0, hi=100)
    n = 720  # 2 h at 10 s
    v = np.sin(np.arange(n) / 10.0) * 10 + 50
    v[100:400] = 42.0  # 50 min flat-lined
    v[500:505] = 150.0  # 5 out of range
    idx = T0 + pd.to_timedelta(np.arange(n) * 10, unit="s")
    keep = np.ones(n, bool)
    keep[600:660] = False  # a 10-min gap
    historian.write_samples(pd.DataFrame({"F": v[keep]}, index=idx[keep]))
    w = historian.window(["F"], T0, T0 + pd.Timedelta("2h"), period="10s")
    s = quality_table(w).loc["F"]
    assert s["first"] == T0
    assert s["gaps"] == 1
    assert s["gap_s"] == 610.0
    assert s["flat"] == 1 and s["flat_s"] == 299 * 10
    assert s["out_of_range"] == 5
    assert not s["stale"]
    assert s["coverage"] == (n - 60) / n


def test_iter_windows_concat_equals_window(historian):
    rng = np.random.default_rng(3)
    n = 5000
    ts = T0 + pd.to_timedelta(np.sort(rng.choice(n * 7, n, replace=False)), unit="s")
    frame = pd.DataFrame({"A": rng.normal(size=n), "B": rng.normal(size=n)}, index=ts)
    historian.write_samples(frame)
    start, end = T0 + pd.Timedelta("13s"), T0 + pd.Timedelta(seconds=n * 7)
    for how in ("mean", "last"):
        whole = historian.window(["A", "B"], start, end, "30s", how)
        parts = list(historian.iter_windows(["A", "B"], start, end, "30s", how, chunk="1h"))
        assert len(parts) > 5
        pd.testing.assert_frame_equal(pd.concat(parts), whole, check_freq=False)


def test_roll_months_to_parquet_reads_the_same(historian, tmp_path):
    idx = pd.date_range("2024-01-30", "2024-03-02", freq="1h", inclusive="left", tz="UTC")
    frame = pd.DataFrame({"A": np.arange(len(idx), dtype=float), "B": 1.0}, index=idx)
    q = pd.DataFrame({"A": 0, "B": 0}, index=idx)
    q.iloc[5, 0] = BAD
    historian.write_samples(frame, quality=q)
    before = historian.read_samples("A", with_quality=True)
    w_before = historian.window(["A", "B"], idx[0], idx[-1], "1h")
    rolled = historian.roll_months(before="2024-03-01")
    assert rolled == ["2024-01", "2024-02"]
    assert historian.cold_months() == ["2024-01", "2024-02"]
    assert list((tmp_path / "cold").glob("*.parquet"))
    after = historian.read_samples("A", with_quality=True)
    pd.testing.assert_frame_equal(after, before)
    pd.testing.assert_frame_equal(historian.window(["A", "B"], idx[0], idx[-1], "1h"), w_before)
    assert historian.time_range(["A"]) == (idx[0], idx[-1])
    # idempotent writes still hold for rolled months, and a late sample is merged
    assert historian.write_samples(frame) == 0
    late = pd.Series([7.0], index=[pd.Timestamp("2024-02-10 00:30", tz="UTC")], name="A")
    assert historian.write_samples(late) == 1
    got = historian.read_samples("A", "2024-01-30", "2024-03-01")
    assert got.index.is_unique and len(got) == len(before) - 24 + 1
    assert historian.roll_months(before="2024-03-01") == ["2024-02"]  # the month with news
    pd.testing.assert_series_equal(historian.read_samples("A", "2024-01-30", "2024-03-01"), got)
    assert historian.integrity_check() == []


def test_a_tag_slower_than_the_grid_holds_its_last_value_and_a_bad_sample_ends_it(historian):
    """One rule for tags sampled differently (historian/sampling.py): on a 10 s grid a 60 s
    tag's last value stands for 1.5 x its 95th-percentile spacing (90 s), a Bad sample ends
    the hold at once, and the 10 s tag is never held (a missing sample stays a gap)."""
    fast = T0 + pd.to_timedelta(np.arange(0, 600, 10), unit="s")
    slow = T0 + pd.to_timedelta(np.arange(0, 600, 60), unit="s")
    historian.write_samples(pd.DataFrame({"FAST": np.arange(60.0)}, index=fast).drop(fast[7]))
    q = pd.DataFrame({"SLOW": [0] * 10}, index=slow)
    q.iloc[5, 0] = BAD
    historian.write_samples(pd.DataFrame({"SLOW": np.arange(10.0)}, index=slow), quality=q)
    assert historian.holds(["FAST", "SLOW"], "10s") == {"FAST": 0, "SLOW": 90_000_000}
    w = historian.window(["FAST", "SLOW"], T0, T0 + pd.Timedelta("10min"), "10s")
    assert np.isnan(w["FAST"].iloc[7]) and w["FAST"].iloc[8] == 8.0
    assert w["SLOW"].iloc[:6].tolist() == [0.0] * 6 and w["SLOW"].iloc[6] == 1.0
    assert np.isnan(w["SLOW"].iloc[30:36]).all()  # the Bad sample at 300 s
    assert w["SLOW"].iloc[36] == 6.0
    parts = historian.iter_windows(
        ["FAST", "SLOW"], T0, T0 + pd.Timedelta("10min"), "10s", chunk="70s"
    )
    pd.testing.assert_frame_equal(pd.concat(list(parts)), w, check_freq=False)


def test_jittered_and_offset_timestamps_land_on_the_nearest_grid_point(historian):
    rng = np.random.default_rng(4)
    k = np.arange(500)
    t = T0 + pd.to_timedelta(k * 15 + 4.9 + rng.uniform(-0.45, 0.45, k.size), unit="s")
    historian.write_samples(pd.DataFrame({"A": k.astype(float)}, index=t))
    w = historian.window(["A"], T0, T0 + pd.Timedelta(seconds=15 * 500), "15s")
    assert w["A"].tolist() == k.astype(float).tolist()  # one sample per grid point, in order


def test_a_training_read_without_summary_aligns_exactly_like_the_full_window(historian):
    """``summary=False`` (training jobs) reads only the usable values from the database (a
    Bad sample as NaN); the aligned frame must be the same as the full window's: Bad,
    Uncertain and NaN samples, a held slow tag whose hold a Bad sample ends, and rows both
    rolled to the cold store and still in the database."""
    rng = np.random.default_rng(11)
    t0 = pd.Timestamp("2024-01-30", tz="UTC")  # two days in January, one in February
    fast = t0 + pd.to_timedelta(np.arange(0, 3 * 86400, 10) + rng.uniform(-2, 2, 25920), "s")
    v = rng.normal(50, 5, len(fast))
    v[rng.choice(len(v), 200, replace=False)] = np.nan
    q = rng.choice([0, 0, 0, UNCERTAIN, BAD], len(v))
    historian.write_samples(
        pd.DataFrame({"A": v}, index=fast), quality=pd.DataFrame({"A": q}, index=fast)
    )
    slow = t0 + pd.to_timedelta(np.arange(0, 3 * 86400, 60), "s")
    qs = rng.choice([0, 0, 0, 0, BAD], len(slow))
    historian.write_samples(
        pd.DataFrame({"S": np.arange(len(slow), dtype=float)}, index=slow),
        quality=pd.DataFrame({"S": qs}, index=slow),
    )
    args = (["A", "S"], t0 - pd.Timedelta("1h"), t0 + pd.Timedelta("3D"), "10s")
    full = historian.window(*args)
    train = historian.window(*args, summary=False)
    full.attrs = {}
    pd.testing.assert_frame_equal(train, full, check_freq=False)
    assert train["S"].notna().sum() > 3 * len(slow)  # the slow tag was held
    assert np.isnan(train["A"]).sum() > 200
    # January rolled to the cold store, February still in the database: the same frame
    assert historian.roll_months(before="2024-02-01") == ["2024-01"]
    pd.testing.assert_frame_equal(historian.window(*args, summary=False), train, check_freq=False)


def test_tags_judges_coverage_and_gaps_on_the_tags_own_period_with_jitter(historian):
    """Issue 37: `diag tags` showed 74.9 % coverage and 405 gaps on jittered 15 s data with
    0.2 % of the rows missing (bins of the raw median spacing from the first sample, and
    gaps between raw times). Judged on the tag's own 15 s grid, a sample at its nearest grid
    point: the coverage is the share of rows present and each missed row is one gap. The
    same at 1 s and at 5 min, and for a regular tag nothing changes."""
    rng = np.random.default_rng(3)
    for name, period_s, n in (("FI15", 15, 23_040), ("FI1", 1, 20_000), ("TI5M", 300, 2_000)):
        k = np.arange(n)
        t = T0 + pd.to_timedelta(
            k * period_s + rng.uniform(-0.4, 0.4, n) * period_s + 0.1 * period_s, unit="s"
        )
        keep = np.ones(n, bool)
        keep[rng.choice(np.arange(1, n - 1), max(2, n // 500), replace=False)] = False
        historian.write_samples(pd.DataFrame({name: rng.normal(10, 1, n)}, index=t)[keep])
        row = historian.tag_report().set_index("tag").loc[name]
        missed_runs = int(np.count_nonzero(np.diff(np.r_[0, (~keep).astype(int)]) == 1))
        assert abs(row["coverage"] - keep.mean()) < 1e-3, (name, row["coverage"])
        assert row["gaps"] == missed_runs, (name, row["gaps"], missed_runs)
    historian.write_samples(
        pd.DataFrame({"REG": np.arange(100.0)}, index=T0 + pd.to_timedelta(np.arange(100), "min"))
    )
    row = historian.tag_report().set_index("tag").loc["REG"]
    assert (row["coverage"], row["gaps"], row["interval_s"]) == (1.0, 0, 60.0)


def _bits(frame: pd.DataFrame) -> np.ndarray:
    """The frame's float64 cells as their bytes (NaN payloads and signed zeros included)."""
    return np.ascontiguousarray(frame.to_numpy(np.float64)).view(np.int64)


def test_tags_read_in_parallel_give_the_frame_of_one_tag_at_a_time(historian):
    """A window of several tags reads them on the historian's reader threads, each with its
    own connection (min(tags, cores, READ_THREADS) of them); a window of one tag reads in
    the calling thread. The frames must agree bit for bit, hot, after a month is rolled to
    the cold store (cold and hot rows in one window), with and without the quality summary
    and in chunks; closing the historian closes every reader connection."""
    from historian.store import READ_THREADS, read_threads

    rng = np.random.default_rng(29)  # not the data of the other tests
    t0 = pd.Timestamp("2024-03-30", tz="UTC")  # two days in March, two in April
    span = 4 * 86400
    tags = ["F1", "F2", "S", "J"]
    for name, step in (("F1", 5), ("F2", 10), ("S", 90), ("J", 7)):
        grid = np.arange(0, span, step)
        t = t0 + pd.to_timedelta(grid + rng.uniform(-1, 1, len(grid)), "s")
        v = rng.normal(20, 4, len(t))
        v[rng.choice(len(v), len(v) // 50, replace=False)] = np.nan
        q = rng.choice([0, 0, 0, 0, UNCERTAIN, BAD], len(t))
        historian.write_samples(
            pd.DataFrame({name: v}, index=t), quality=pd.DataFrame({name: q}, index=t)
        )
    args = (t0 - pd.Timedelta("2h"), t0 + pd.Timedelta("4D"), "10s")

    def compare() -> None:
        for summary in (True, False):
            together = historian.window(tags, *args, summary=summary)
            alone = [historian.window([t], *args, summary=summary) for t in tags]
            assert list(together.columns) == tags
            assert all(a.index.equals(together.index) for a in alone)
            assert np.array_equal(_bits(together), _bits(pd.concat(alone, axis=1)))
            if summary:
                for a, t in zip(alone, tags, strict=True):
                    assert together.attrs["quality"][t] == a.attrs["quality"][t]
        chunks = historian.iter_windows(tags, *args, chunk="9h", summary=False)
        assert np.array_equal(_bits(pd.concat(list(chunks))), _bits(together))

    compare()
    assert historian.roll_months(before="2024-04-01") == ["2024-03"]
    compare()
    threads = read_threads(len(tags))
    assert 1 <= threads <= min(len(tags), READ_THREADS)
    if threads > 1:
        assert historian._pool is not None and len(historian._pool._threads) <= threads
    if historian.backend == "sqlite":
        bulk = historian._bulk
        assert 1 <= len(bulk._all) <= threads + 1  # the readers' and the calling thread's
        historian.close()
        assert bulk._all == [] and historian._pool is None


def test_aligned_pieces_equal_the_aligned_joined_samples_to_the_bit():
    """align_pieces (the rolled months' row groups put on the grid one by one, issue 37)
    gives align's values of the joined samples, bit for bit: regular series on the grid
    (the index fast path) with Bad, Uncertain, NaN and infinite samples, pieces before and
    past the grid, gaps between pieces; and the cases it must leave to align: off-grid
    times, a missing sample, a repeated time, overlapping pieces, a hold, how="last"."""
    from historian.window import align, align_pieces

    rng = np.random.default_rng(7)
    p, t0, n = 10_000_000, 1_700_000_000_000_000, 400

    def pieces_of(ts):
        v = rng.normal(50, 5, len(ts))
        v[rng.choice(len(ts), 20, replace=False)] = np.nan
        v[rng.choice(len(ts), 3, replace=False)] = np.inf
        q = rng.choice([0, 0, 0, UNCERTAIN, BAD], len(ts)).astype(np.int64)
        cuts = np.sort(rng.choice(np.arange(1, len(ts)), 4, replace=False))
        return [
            (ts[a:b], v[a:b], q[a:b])
            for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(ts)], strict=True)
        ]

    k = np.arange(-30, 450)
    regular = t0 + k * p
    cases = {
        "on the grid": regular,
        "a gap": np.r_[regular[:100], regular[130:]],
        "off the grid": regular + 3_000_000,
        "jitter": regular + rng.integers(-4_000_000, 4_000_000, len(k)),
        "a repeated time": np.sort(np.r_[regular, regular[50]]),
    }
    for name, ts in cases.items():
        pieces = pieces_of(ts)
        joined = tuple(np.concatenate(col) for col in zip(*pieces, strict=True))
        for how, hold in (("mean", 0), ("last", 0), ("mean", 25_000_000)):
            got = align_pieces(pieces, t0, p, n, how, hold)
            want = align(*joined, t0, p, n, how, hold)
            assert got.view(np.int64).tolist() == want.view(np.int64).tolist(), (name, how)
    # pieces sharing a time (the next piece starts where the last one ended): two samples
    # at one grid point, so not the fast path
    (ts, v, q) = pieces_of(regular)[0]
    shared = [(ts[:10], v[:10], q[:10]), (ts[9:], v[9:] + 1.0, q[9:])]
    joined = tuple(np.concatenate(col) for col in zip(*shared, strict=True))
    for how in ("mean", "last"):
        got = align_pieces(shared, t0, p, n, how)
        want = align(*joined, t0, p, n, how)
        assert got.view(np.int64).tolist() == want.view(np.int64).tolist(), how
    assert np.isnan(align_pieces([], t0, p, n)).all()


def test_a_training_read_of_rolled_regular_months_equals_the_full_window(historian):
    """A regular 10 s series rolled to the cold store (several row groups a month, read in
    chunks through the row-group cache, the fast path of align_pieces) aligns as the full
    window does, Bad, Uncertain and NaN samples included, on its grid and on another."""
    from historian import coldstore

    idx = pd.date_range("2024-01-29", "2024-02-03", freq="10s", inclusive="left", tz="UTC")
    rng = np.random.default_rng(5)
    v = rng.normal(50, 5, len(idx))
    v[rng.choice(len(v), 300, replace=False)] = np.nan
    q = rng.choice([0, 0, 0, 0, UNCERTAIN, BAD], len(v))
    historian.write_samples(
        pd.DataFrame({"A": v, "B": -v}, index=idx),
        quality=pd.DataFrame({"A": q, "B": 0}, index=idx),
    )
    assert historian.roll_months(before="2024-03-01") == ["2024-01", "2024-02"]
    old_rows = coldstore.ROW_GROUP_ROWS
    for period in ("10s", "20s", "7s"):
        args = (["A", "B"], idx[3] - pd.Timedelta("1s"), idx[-5], period)
        full = historian.window(*args)
        full.attrs = {}
        chunks = historian.iter_windows(*args, chunk="9h", summary=False)
        pd.testing.assert_frame_equal(pd.concat(list(chunks)), full, check_freq=False)
        pd.testing.assert_frame_equal(historian.window(*args, summary=False), full)
    assert old_rows == coldstore.ROW_GROUP_ROWS
