"""diag import / diag tags: bad rows with file:line, --strict, idempotent re-import."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from diag_plugin.cli import main
from historian import BAD, GOOD, Historian
from historian.importer import ImportRefused, import_file, pick_time_column

CSV = """ts,U17,F17
2024-01-01 00:00:00,1.5,10
2024-01-01 00:00:10,oops,11

nonsense,3,12
2024-01-01 00:00:30,,13
2024-01-01 00:00:40,5,14
"""


def test_time_column_choice():
    assert pick_time_column(["a", "Timestamp", "b"]) == "Timestamp"
    dates = pd.DataFrame({"when": ["2024-01-01 00:00:10", "2024-01-01T00:00:20Z"], "b": "1"})
    assert pick_time_column(["when", "b"], sample=dates) == "when"  # first column of dates
    with pytest.raises(ValueError, match="--time-column"):  # never a guess
        pick_time_column(["when", "b"], sample=dates.assign(when=["1", "2"]))
    with pytest.raises(ValueError, match="--time-column"):
        pick_time_column(["when", "b"])
    assert pick_time_column(["a", "b"], "b") == "b"
    with pytest.raises(ValueError):
        pick_time_column(["a"], "zz")


def test_bad_rows_skipped_bad_cells_stored_bad_and_the_rest_of_the_row_kept(historian, tmp_path):
    """A row without a usable time is skipped; a cell without a usable number is stored as a
    Bad sample and the row's other values are kept (issue 22: one bad cell lost the row)."""
    f = tmp_path / "data.csv"
    f.write_text(CSV)
    r = import_file(historian, f)
    assert r.bad == [f"{f}:5: unparseable time 'nonsense'"]
    assert r.cells == [f"{f}:3: U17: no number in 'oops'; stored as a Bad sample"]
    assert r.bad_cells == {"U17": 1}
    assert r.rows == 5 and r.written == 7
    assert historian.read_samples("F17").tolist() == [10.0, 11.0, 13.0, 14.0]
    u17 = historian.read_samples("U17", with_quality=True)
    assert u17["quality"].tolist() == [GOOD, BAD, GOOD]
    assert u17["value"].iloc[0] == 1.5 and np.isnan(u17["value"].iloc[1])
    again = import_file(historian, f)  # idempotent, the Bad sample included
    assert again.written == 0 and again.samples == 7 and again.conflicts == 0


def test_strict_refuses_and_leaves_db_untouched(historian, tmp_path):
    good = tmp_path / "good.csv"
    good.write_text("time,U17\n2023-12-31 23:59:50,7\n")
    import_file(historian, good)
    before = historian.read_samples("U17")
    f = tmp_path / "data.csv"
    f.write_text(CSV)
    with pytest.raises(ImportRefused) as exc:
        import_file(historian, f, strict=True)
    assert exc.value.n_bad == 2
    pd.testing.assert_series_equal(historian.read_samples("U17"), before)
    assert "F17" not in set(historian.tags()["name"])


def test_tz_and_tags_csv(historian, tmp_path):
    f = tmp_path / "local.csv"
    f.write_text("Datetime,X\n2024-07-01 12:00,1\n2024-07-01 12:00:10,2\n")
    tags = tmp_path / "tags.csv"
    tags.write_text("name,unit,lo,hi,description\nX,kPa,0,600,inlet pressure P1\n")
    r = import_file(historian, f, tz="Europe/Warsaw", tags_csv=tags)
    s = historian.read_samples("X")
    assert r.n_bad == 0
    assert s.index[0] == pd.Timestamp("2024-07-01 10:00", tz="UTC")  # CEST = UTC+2
    assert s.index[1] == pd.Timestamp("2024-07-01 10:00:10", tz="UTC")
    g = tmp_path / "offsets.csv"
    g.write_text("ts,Y\n2024-07-01T12:00:00+02:00,1\n")
    import_file(historian, g, tz="America/New_York")  # explicit offsets win over --tz
    assert historian.read_samples("Y").index[0] == pd.Timestamp("2024-07-01 10:00", tz="UTC")
    t = historian.tags().set_index("name").loc["X"]
    assert (t["unit"], t["lo"], t["hi"]) == ("kPa", 0.0, 600.0)


def test_a_misspelt_time_zone_is_refused_naming_the_option(tmp_path, capsys):
    """``--tz`` that is no time zone: refused before the file is read (exit 2, nothing
    written), whether the file's times carry offsets or not. On main a file with offsets
    was imported with the misspelt zone accepted without a word, and a file of naive times
    was refused by ``No time zone found with key Europe/Berln`` (the option not named)."""
    db = f"sqlite:///{tmp_path / 'tz.db'}"
    offsets = tmp_path / "offsets.csv"
    offsets.write_text("Time,A\n2026-03-02 01:00:00+01:00,1\n2026-03-02 01:00:05+01:00,2\n")
    naive = tmp_path / "naive.csv"
    naive.write_text("Time,B\n2026-03-02 01:00:00,1\n2026-03-02 01:00:05,2\n")
    for f in (offsets, naive):
        assert main(["--db", db, "import", str(f), "--tz", "Europe/Berln"]) == 2
        err = capsys.readouterr().err
        assert "--tz 'Europe/Berln': not a time zone" in err
    assert main(["--db", db, "import", str(offsets), "--tz", "Europe/Berlin"]) == 0
    assert set(Historian.open(db).tags()["name"]) == {"A"}  # nothing of the refused ones


def test_the_repeated_hour_at_the_clock_change_is_read_in_the_rows_order(historian, tmp_path):
    """Local times through the autumn clock change: the repeated hour is the first pass (CEST)
    then the second (CET), as the rows run; out of order, and a time the spring change skips,
    they are bad rows that say which (main: every repeated time skipped as 'unparseable')."""
    times = pd.date_range("2024-10-27 00:30", "2024-10-27 02:30", freq="10min", tz="UTC")
    local = times.tz_convert("Europe/Berlin").tz_localize(None)  # 02:00-02:59 twice
    f = tmp_path / "autumn.csv"
    f.write_text("time,X\n" + "".join(f"{t},{i}\n" for i, t in enumerate(local)))
    r = import_file(historian, f, tz="Europe/Berlin")
    assert r.n_bad == 0, r.bad
    s = historian.read_samples("X")
    assert list(s.index) == list(times) and list(s.to_numpy()) == list(range(len(times)))
    g = tmp_path / "shuffled.csv"
    rows = [f"2024-10-27 02:{m},{i}" for i, m in enumerate((40, 10, 20, 5))]  # back twice
    g.write_text("time,Y\n" + "\n".join([*rows, "2024-03-31 02:30,9", "2024-10-27 04:00,8"]) + "\n")
    r = import_file(historian, g, tz="Europe/Berlin")
    assert r.n_bad == 5
    assert sum("ambiguous in Europe/Berlin" in b for b in r.bad) == 4, r.bad
    assert f"{g}:6: time '2024-03-31 02:30' does not exist in Europe/Berlin" in r.bad[-1]
    assert list(historian.read_samples("Y").to_numpy()) == [8.0]


def test_parquet_import(historian, tmp_path):
    idx = pd.date_range("2024-01-01", periods=50, freq="10s", tz="UTC")
    df = pd.DataFrame({"time": idx, "A": np.arange(50.0), "B": ["1"] * 49 + ["x"]})
    f = tmp_path / "d.parquet"
    df.to_parquet(f)
    r = import_file(historian, f)
    assert r.bad == [] and r.cells == [f"{f}:50: B: no number in 'x'; stored as a Bad sample"]
    assert len(historian.read_samples("A")) == 50  # the row's good value is kept
    assert historian.read_samples("B", with_quality=True)["quality"].iloc[-1] == BAD
    assert import_file(historian, f).written == 0


def test_cli_import_and_tags(tmp_path, capsys):
    db = f"sqlite:///{tmp_path / 'cli.db'}"
    f = tmp_path / "data.csv"
    f.write_text(CSV)
    assert main(["--db", db, "import", str(f), "--strict"]) == 2
    err = capsys.readouterr().err
    assert f"{f}:3: U17: no number in 'oops'" in err and "nothing imported" in err
    assert err.index(f"{f}:3:") < err.index(f"{f}:5:")  # in file order
    assert main(["--db", db, "import", str(f)]) == 0
    out, err = capsys.readouterr()
    assert "7 new samples" in out and f"{f}:5: unparseable time" in err
    assert "stored as Bad samples: U17 1" in err
    assert main(["--db", db, "import", str(f)]) == 0
    assert "0 new samples, 7 already stored" in capsys.readouterr().out
    assert main(["--db", db, "tags", "--json"]) == 0
    rows = {r["tag"]: r for r in json.loads(capsys.readouterr().out)}
    assert rows["F17"]["samples"] == 4 and rows["U17"]["samples"] == 3
    assert rows["U17"]["bad"] == 1
    assert main(["--db", db, "tags"]) == 0
    assert "F17" in capsys.readouterr().out
    with Historian(db) as h:
        assert h.integrity_check() == []


def test_cli_tags_lists_a_tag_whose_unit_cell_is_empty(tmp_path, capsys):
    """A tags CSV whose mode tag has no unit (``AHU1 Occ Mode,,0,1,…`` beside tags with
    units): ``diag tags`` lists it with an empty unit. On main it crashed, ``diag: internal
    error: NotRenderableError: unable to render float`` (the report's unit column is strings,
    the empty cell NaN; the AHU acceptance pass)."""
    db = f"sqlite:///{tmp_path / 'u.db'}"
    data = tmp_path / "ahu.csv"
    data.write_text(
        "ts,SA_TEMP,AHU1 Occ Mode\n2026-04-13 06:00:00,17.1,1\n2026-04-13 06:05:00,17.0,1\n"
    )
    tags = tmp_path / "tags.csv"
    tags.write_text(
        "name,unit,lo,hi,description\n"
        "SA_TEMP,degC,0,50,supply air temperature\n"
        "AHU1 Occ Mode,,0,1,occupied (1) / unoccupied (0)\n"
    )
    assert main(["--db", db, "import", str(data), "--tags", str(tags)]) == 0
    capsys.readouterr()
    assert main(["--db", db, "tags"]) == 0
    out = capsys.readouterr().out
    assert "AHU1 Occ Mode" in out and "degC" in out
    assert main(["--db", db, "tags", "--json"]) == 0
    rows = {r["tag"]: r for r in json.loads(capsys.readouterr().out)}
    assert rows["AHU1 Occ Mode"]["unit"] is None and rows["SA_TEMP"]["unit"] == "degC"
