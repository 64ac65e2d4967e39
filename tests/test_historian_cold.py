"""Writes into months already rolled to the Parquet cold store, and integrity_check on broken
cold segments and a broken SQLite file (both backends unless said)."""

from __future__ import annotations

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
