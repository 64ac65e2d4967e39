"""Writes into months already rolled to the Parquet cold store, and integrity_check on broken
cold segments and a broken SQLite file (both backends unless said)."""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest
from sqlalchemy import func, select

from historian import Historian, schema

IDX = pd.date_range("2024-01-30", "2024-03-02", freq="1h", inclusive="left", tz="UTC")
HOT = 2 * 24  # hourly rows of 2024-03-01 for tags A and B: never rolled below


def frame():
    return pd.DataFrame({"A": np.arange(len(IDX), dtype=float), "B": 1.0}, index=IDX)


def hot_rows(h: Historian) -> int:
    """Rows in the database's samples table (not the cold files)."""
    with h.engine.connect() as c:
        return c.execute(select(func.count()).select_from(schema.samples)).scalar_one()


@pytest.fixture
def rolled(historian):
    """January and February rolled to the cold store, 2024-03-01 still in the database."""
    assert historian.write_samples(frame()) == 2 * len(IDX)
    assert historian.roll_months(before="2024-03-01") == ["2024-01", "2024-02"]
    assert hot_rows(historian) == HOT
    return historian


def test_rewrite_of_rolled_months_adds_nothing(rolled):
    assert rolled.write_samples(frame()) == 0
    assert rolled.write_samples(frame(), batch_rows=7) == 0
    assert hot_rows(rolled) == HOT
    # a different value for a stored sample is ignored, as in the database: first write wins
    assert rolled.write_samples(frame() + 5.0) == 0
    assert rolled.read_samples("A").tolist() == frame()["A"].tolist()
    assert hot_rows(rolled) == HOT


def test_late_sample_in_rolled_month_is_stored_once(rolled):
    late = pd.Series([7.0], index=[pd.Timestamp("2024-02-10 00:30", tz="UTC")], name="A")
    mixed = pd.concat([frame()["A"], late]).sort_index()  # stored samples plus the late one
    assert rolled.write_samples(mixed) == 1
    assert rolled.write_samples(mixed) == 0
    assert hot_rows(rolled) == HOT + 1
    assert rolled.read_samples("A", "2024-02-10", "2024-02-10 01:00").tolist() == [264.0, 7.0]
    assert rolled.roll_months(before="2024-03-01") == ["2024-02"]  # January untouched
    assert hot_rows(rolled) == HOT
    assert rolled.write_samples(mixed) == 0
    assert len(rolled.read_samples("A")) == len(IDX) + 1


def test_update_of_rolled_month_wins_on_read_and_on_next_roll(rolled):
    assert rolled.write_samples(frame(), policy="update") == 0  # same values: nothing to do
    assert hot_rows(rolled) == HOT
    feb10 = (IDX >= "2024-02-10") & (IDX < "2024-02-11")
    changed = frame()[feb10] + 100.0
    changed["B"] = 1.0  # B unchanged: not counted, not copied back
    assert rolled.write_samples(changed, policy="update") == 24
    assert hot_rows(rolled) == HOT + 24
    expect = frame()["A"].where(~feb10, frame()["A"] + 100.0)
    assert rolled.read_samples("A").tolist() == expect.tolist()
    assert rolled.write_samples(changed) == 0  # the updated value is now the stored one
    q = rolled.read_samples("B", "2024-02-10", "2024-02-11", with_quality=True)["quality"]
    assert (q == 0).all()
    assert rolled.write_samples(changed[["B"]], quality=1, policy="update") == 24  # quality too
    assert rolled.roll_months(before="2024-03-01") == ["2024-02"]
    assert hot_rows(rolled) == HOT
    assert rolled.read_samples("A").tolist() == expect.tolist()
    q = rolled.read_samples("B", "2024-02-10", "2024-02-11", with_quality=True)["quality"]
    assert (q == 1).all()
    assert rolled.integrity_check() == []


# -- integrity_check on broken stores ---------------------------------------------------------


def segment_file(h: Historian, month: str):
    (path,) = h.cold_dir.glob(f"samples-{month}-*.parquet")
    return path


def test_integrity_check_reports_a_cold_file_overwritten_with_garbage(rolled):
    path = segment_file(rolled, "2024-02")
    path.write_bytes(np.random.default_rng(0).bytes(path.stat().st_size))
    problems = rolled.integrity_check()
    assert len(problems) == 1 and problems[0].startswith("cold segment 2024-02: ")


def test_integrity_check_reports_a_truncated_cold_file(rolled):
    path = segment_file(rolled, "2024-01")
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    problems = rolled.integrity_check()
    assert len(problems) == 1 and problems[0].startswith("cold segment 2024-01: ")


def test_integrity_check_reports_a_missing_cold_file(rolled):
    segment_file(rolled, "2024-02").unlink()
    problems = rolled.integrity_check()
    assert len(problems) == 1 and problems[0].startswith("cold segment 2024-02: ")


def test_integrity_check_reports_a_cold_file_with_other_rows(rolled):
    """A readable Parquet file that does not hold the rows recorded for its month."""
    from historian import coldstore

    path = segment_file(rolled, "2024-02")
    tag_id, ts, value, quality = coldstore.read_segment(path)
    coldstore.write_segment(path, tag_id[:-5], ts[:-5], value[:-5], quality[:-5])
    assert rolled.integrity_check() == ["cold segment 2024-02: row count differs"]


def sqlite_with_samples(tmp_path):
    """A closed SQLite historian holding frame(); its page size and the pages of the samples
    B-tree: the root (an interior page) and its right-most child (a leaf)."""
    import sqlite3

    db = tmp_path / "diag.db"
    with Historian(f"sqlite:///{db}") as h:
        h.write_samples(frame())
        assert h.integrity_check() == []
    assert not db.with_name("diag.db-wal").exists()  # checkpointed on close: all in the file
    c = sqlite3.connect(db)
    page_size = c.execute("PRAGMA page_size").fetchone()[0]
    root = c.execute("SELECT rootpage FROM sqlite_master WHERE name = 'samples'").fetchone()[0]
    c.close()
    with open(db, "rb") as fh:
        fh.seek((root - 1) * page_size)
        header = fh.read(12)
    assert header[0] == 2  # interior index B-tree page (the table is WITHOUT ROWID)
    return db, page_size, root, int.from_bytes(header[8:12], "big")


def overwrite(path, offset, data):
    with open(path, "r+b") as fh:
        fh.seek(offset)
        fh.write(data)


def test_integrity_check_reports_a_damaged_sqlite_leaf_page(tmp_path):
    """Garbage over the cell contents of a leaf page of a closed database (header intact)."""
    db, page_size, _, leaf = sqlite_with_samples(tmp_path)
    rng = np.random.default_rng(1)
    overwrite(db, leaf * page_size - page_size // 2, rng.bytes(page_size // 2))
    with Historian(f"sqlite:///{db}") as h:
        problems = h.integrity_check()
    # the damaged page is named: "page N cell K: ..." (4 KiB pages), or "Tree T page N: free
    # space corruption" where the garbage also covers free space between cells (16 KiB)
    assert any(re.search(rf"\bpage {leaf}\b", p) for p in problems), problems


def test_integrity_check_reports_a_sqlite_page_it_cannot_read(tmp_path):
    """Garbage over the whole root page: SQLite cannot even run the check; that is reported,
    not raised."""
    db, page_size, root, _ = sqlite_with_samples(tmp_path)
    overwrite(db, (root - 1) * page_size, np.random.default_rng(1).bytes(page_size))
    with Historian(f"sqlite:///{db}") as h:
        problems = h.integrity_check()
    assert len(problems) == 1 and "malformed" in problems[0], problems


@pytest.mark.postgres
def test_integrity_check_reports_duplicate_keys_on_postgres(pg_url, tmp_path):
    """The primary key dropped and a (tag, ts) stored twice: both are reported."""
    with Historian(pg_url, cold_dir=tmp_path / "cold") as h:
        h.write_samples(frame())
        assert h.integrity_check() == []
        with h.engine.begin() as c:
            c.exec_driver_sql("ALTER TABLE samples DROP CONSTRAINT samples_pkey")
            c.exec_driver_sql(
                "INSERT INTO samples SELECT * FROM samples WHERE ts < 1706576400000000"
            )
        assert h.integrity_check() == [
            "2 duplicated (tag_id, ts) keys in samples",
            "primary-key index of samples missing or invalid",
        ]


@pytest.mark.parametrize("n", [1, HOT, HOT + 1, HOT + 100, 30 * 24, 10 * len(IDX)])
def test_recent_sample_times_reach_into_rolled_months(historian, monkeypatch, n):
    """A tag's last ``n`` sample times (what holds() measures a tag's sampling from) are the
    tail of all its samples, database and rolled months alike, also when the months' files
    hold many row groups and only the last of them are read."""
    from historian import coldstore

    monkeypatch.setattr(coldstore, "ROW_GROUP_ROWS", 50)
    historian.write_samples(frame())
    historian.roll_months(before="2024-03-01")
    tag_id = historian._tag("A")[0]
    every = historian.read_samples("A").index.as_unit("us").asi8
    got = historian._recent_ts(tag_id, n)
    np.testing.assert_array_equal(got, every[-n:])
