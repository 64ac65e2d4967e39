"""``diag import --time-unit U --start T``: each plain number ``x`` of the time column is the
time ``T + x U``, for every unit the importer offers (issue 38, bug 12: an hour read as a
tenth of one). The expected times come from pandas' own unit arithmetic, not our table."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from diag_plugin.cli import main
from historian import Historian
from historian.importer import TIME_UNITS

#: our unit → pandas' name of it
PANDAS_UNIT = {"s": "s", "ms": "ms", "us": "us", "µs": "us", "ns": "ns", "min": "min", "h": "h"}
START = pd.Timestamp("2001-11-17T06:00:00Z")


def test_every_time_unit_offered_is_known_to_this_test():
    assert set(TIME_UNITS) == set(PANDAS_UNIT)


@pytest.mark.parametrize("unit", list(PANDAS_UNIT))
def test_plain_number_times_count_the_unit_given_after_the_start(tmp_path, capsys, unit):
    # whole and fractional counts, off any round grid; times are stored in whole µs, so
    # counts of µs and ns are scaled to whole µs
    scale = {"us": 4, "µs": 4, "ns": 4000}.get(unit, 1)
    x = np.array([0, 1, 2.5, 7, 36.25]) * scale
    f = tmp_path / "rel.csv"
    f.write_text("t,F\n" + "".join(f"{v:g},{i}\n" for i, v in enumerate(x)), encoding="utf-8")
    db = f"sqlite:///{tmp_path / 'd.db'}"
    argv = ["--db", db, "import", str(f), "--time-column", "t", "--time-unit", unit]
    assert main([*argv, "--start", START.isoformat()]) == 0, capsys.readouterr().err
    with Historian(db) as h:
        got = h.read_samples("F")
    want = START + pd.to_timedelta(x, unit=PANDAS_UNIT[unit])
    assert list(got.index) == list(want), unit
    assert got.tolist() == list(range(len(x)))
