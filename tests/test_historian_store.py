"""Historian storage: idempotent writes, reads, tags, experiment log, events (both backends)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from historian import BAD, GOOD, UNCERTAIN, from_opcua_status


def wide(n=360, start="2024-01-01", freq="10s", tags=("U17", "F17")):
    idx = pd.date_range(start, periods=n, freq=freq, tz="UTC")
    return pd.DataFrame({t: np.arange(n, dtype=float) * (i + 1) for i, t in enumerate(tags)}, idx)


def test_write_is_idempotent(historian):
    frame = wide()
    assert historian.write_samples(frame) == 720
    assert historian.write_samples(frame) == 0  # re-sent batch: nothing duplicated
    assert historian.write_samples(frame, batch_rows=7) == 0
    s = historian.read_samples("F17")
    assert len(s) == 360
    assert s.index.tz is not None and str(s.index.tz) == "UTC"
    np.testing.assert_array_equal(s.to_numpy(), frame["F17"].to_numpy())


def test_ignore_keeps_first_update_replaces(historian):
    frame = wide(10)
    historian.write_samples(frame)
    changed = frame * 0 + 99.0
    assert historian.write_samples(changed) == 0
    assert historian.read_samples("U17").iloc[0] == 0.0
    assert historian.write_samples(changed, policy="update") == 20
    assert (historian.read_samples("U17") == 99.0).all()
    assert historian.write_samples(changed, policy="update") == 0  # nothing left to change


def test_small_batches_store_everything(historian):
    frame = wide(1000, tags=("A", "B", "C"))
    assert historian.write_samples(frame, batch_rows=333) == 3000
    for t in "ABC":
        assert len(historian.read_samples(t)) == 1000


def test_long_frame_series_and_quality(historian):
    ts = pd.date_range("2024-03-01", periods=4, freq="1min", tz="UTC")
    long = pd.DataFrame(
        {"tag": ["P04"] * 4, "ts": ts, "value": [1.0, 2.0, np.nan, 4.0], "quality": [0, 1, 2, 0]}
    )
    assert historian.write_samples(long) == 4
    got = historian.read_samples("P04", with_quality=True)
    assert got["quality"].tolist() == [GOOD, UNCERTAIN, BAD, GOOD]
    assert np.isnan(got["value"].iloc[2])
    s = pd.Series([5.0, 6.0], index=ts[:2].tz_localize(None), name="X01")  # naive = UTC
    assert historian.write_samples(s, quality=UNCERTAIN) == 2
    assert historian.read_samples("X01").index[0] == ts[0]


def test_read_range_and_time_range(historian):
    historian.write_samples(wide(360))
    s = historian.read_samples("U17", "2024-01-01 00:10", "2024-01-01 00:20")
    assert len(s) == 60
    assert s.index[0] == pd.Timestamp("2024-01-01 00:10", tz="UTC")
    lo, hi = historian.time_range(["U17"])
    assert lo == pd.Timestamp("2024-01-01", tz="UTC")
    assert hi == pd.Timestamp("2024-01-01 00:59:50", tz="UTC")
    with pytest.raises(KeyError):
        historian.read_samples("nope")


def test_tags_metadata(historian):
    tid = historian.ensure_tag("F17", unit="t/h", lo=0, hi=100, description="feed flow")
    assert historian.ensure_tag("F17") == tid
    historian.ensure_tag("F17", source="dcs")
    t = historian.tags().set_index("name").loc["F17"]
    assert (t["unit"], t["lo"], t["hi"], t["description"], t["source"]) == (
        "t/h",
        0.0,
        100.0,
        "feed flow",
        "dcs",
    )


def test_experiments_and_model_versions(historian):
    v1 = historian.record_model_version("valve3", "1", "rules = []\n")
    assert historian.record_model_version("valve3", "1", "rules = [1]\n") == v1
    historian.record_model_version("valve3", "2", "rules = [2]\n")
    mv = historian.model_versions("valve3")
    assert mv["version"].tolist() == ["1", "2"]
    assert mv["rulebase_text"].iloc[0] == "rules = [1]\n"
    historian.record_experiment(
        "valve3", "1", ["CV[k-1]"], "2024-01-01", "2024-07-01", {"rmse_pct": 2.5}
    )
    historian.record_experiment(
        "valve3", "2", ["CV[k-1]", "P1"], "2024-01-01", "2024-07-01", {"rmse_pct": 1.1}
    )
    ex = historian.experiments("valve3")
    assert ex["inputs"].tolist() == [["CV[k-1]"], ["CV[k-1]", "P1"]]
    assert [m["rmse_pct"] for m in ex["metrics"]] == [2.5, 1.1]
    assert ex["data_from"].iloc[0] == pd.Timestamp("2024-01-01", tz="UTC")
    assert historian.experiments("other").empty


def test_events(historian):
    historian.record_event("2024-01-01 10:00", "valve3", fault="f1", status=1, certainty=0.8)
    historian.record_event("2024-01-01 11:00", "valve3", status=2, quality=UNCERTAIN)
    historian.record_event("2024-01-01 12:00", "pump1", status=0)
    ev = historian.events("valve3")
    assert ev["status"].tolist() == [1, 2]
    assert ev["ts"].iloc[0] == pd.Timestamp("2024-01-01 10:00", tz="UTC")
    assert len(historian.events(start="2024-01-01 10:30")) == 2


def test_integrity_check_clean(historian):
    historian.write_samples(wide(100))
    assert historian.integrity_check() == []


def test_opcua_quality_mapping():
    assert from_opcua_status(0x00000000) == GOOD
    assert from_opcua_status(0x40000000) == UNCERTAIN
    assert from_opcua_status(0x80000000) == BAD
    assert from_opcua_status(0x80340000) == BAD


def test_sqlite_reads_come_in_large_batches_and_equal_small_batch_reads(tmp_path, monkeypatch):
    """A SQLite read fetches its rows in Arrow batches of READ_BATCH_ROWS (the driver's own
    default, 1,024 rows, cost a training read 13 % more CPU: issue 37); the samples read are
    the same whatever the batch size, Bad samples and NaN values included."""
    from historian import Historian, backends

    n = 5000
    frame = wide(n, tags=("A",))
    frame.iloc[7, 0] = np.nan
    quality = pd.DataFrame({"A": np.where(np.arange(n) % 97 == 3, BAD, GOOD)}, frame.index)
    with Historian(f"sqlite:///{tmp_path / 'h.db'}") as h:
        h.write_samples(frame.dropna(), quality=quality.loc[frame.dropna().index])
        bulk, tag_id = h._bulk, h._tag("A")[0]
        table = bulk.fetch(f"SELECT ts, value FROM samples WHERE tag_id = {tag_id} ORDER BY ts")
        assert table.num_rows == n - 1
        assert table.column(0).num_chunks == 1  # one batch: READ_BATCH_ROWS > 5000
        big = [bulk.read(tag_id, 0, 2**62, usable=u) for u in (False, True)]
        monkeypatch.setattr(backends, "READ_BATCH_ROWS", 1000)
        table = bulk.fetch(f"SELECT ts FROM samples WHERE tag_id = {tag_id}")
        assert table.column(0).num_chunks == 5
        small = [bulk.read(tag_id, 0, 2**62, usable=u) for u in (False, True)]
    for a, b in zip(big, small, strict=True):
        for x, y in zip(a, b, strict=True):
            np.testing.assert_array_equal(x, y)
    ts, value, q = big[0]
    assert len(ts) == n - 1 and np.all(np.diff(ts) > 0)
    assert (q == BAD).sum() == (quality["A"].drop(frame.index[7]) == BAD).sum()
    assert np.isnan(big[1][1][q == BAD]).all()  # usable: a Bad sample comes as NaN
