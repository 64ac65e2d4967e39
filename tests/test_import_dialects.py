"""Real plant exports (issue 22): European dialects, time formats and units, bad values kept
as Bad samples per cell, absurd times refused, tag names a model can use, nothing left
behind by an import that stores nothing."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from diag_plugin.cli import main
from historian import BAD, GOOD, Historian
from historian.importer import FileRefused, import_file

EU = """Zeitstempel;Füllstand LT101 (%);Zulauf FI101;Ablauf.FI102
01.03.2026 00:00:00;51,2;38,5;37,9
01.03.2026 00:00:01;51,3;38,7;38,0
13.03.2026 00:00:02;51,3;38,6;38,1
"""


def _read(h: Historian, tag: str) -> pd.DataFrame:
    return h.read_samples(tag, with_quality=True)


def test_european_export_is_detected_and_says_what_it_detected(historian, tmp_path):
    f = tmp_path / "export.csv"
    f.write_text(EU, encoding="utf-8")
    r = import_file(historian, f, time_column="Zeitstempel")
    assert r.notes == [
        "separator ';' (detected; --sep to choose)",
        "decimal comma (detected; --decimal to choose)",
        "times read as day.month.year ('%d.%m.%Y %H:%M:%S', detected; --time-format to choose)",
    ]
    level = _read(historian, "Füllstand LT101 (%)")
    assert level["value"].tolist() == [51.2, 51.3, 51.3]
    assert level.index[2] == pd.Timestamp("2026-03-13T00:00:02Z")
    assert historian.read_samples("Ablauf.FI102").tolist() == [37.9, 38.0, 38.1]


def test_day_month_order_not_shown_in_the_file_is_asked_for_not_guessed(historian, tmp_path):
    f = tmp_path / "export.csv"
    f.write_text(EU.replace("13.03.2026", "02.03.2026"), encoding="utf-8")
    with pytest.raises(FileRefused, match="day first or month first.*--time-format"):
        import_file(historian, f)
    assert historian.tags().empty  # nothing written
    r = import_file(historian, f, time_format="%d.%m.%Y %H:%M:%S")
    assert r.notes[-1] == "decimal comma (detected; --decimal to choose)"
    assert _read(historian, "Zulauf FI101").index[2] == pd.Timestamp("2026-03-02T00:00:02Z")


def test_tab_and_pipe_separators_and_a_bom(historian, tmp_path):
    f = tmp_path / "tab.csv"
    f.write_text("\ufefftime\tA\tB\n2026-01-01 00:00:00\t1.5\t2\n2026-01-01 00:00:10\t1.6\t3\n")
    r = import_file(historian, f)
    assert r.notes == ["separator tab (detected; --sep to choose)"]
    assert historian.read_samples("A").tolist() == [1.5, 1.6]
    g = tmp_path / "pipe.csv"
    g.write_text("time|C\n2026-01-01 00:00:00|4,5\n", encoding="utf-8")
    import_file(historian, g)
    assert historian.read_samples("C").tolist() == [4.5]


def test_an_ambiguous_decimal_mark_is_refused(historian, tmp_path):
    f = tmp_path / "mixed.csv"
    f.write_text("time;A;B\n2026-01-01 00:00:00;1,5;2.5\n")
    with pytest.raises(FileRefused, match="--decimal"):
        import_file(historian, f)
    import_file(historian, f, decimal=",")  # B's 2.5 is then a bad cell, A is read
    assert historian.read_samples("A").tolist() == [1.5]
    assert _read(historian, "B")["quality"].tolist() == [BAD]


BAD_VALUES = """time,F,P,T
2026-01-01 00:00:00,10.0,500,20
2026-01-01 00:00:10,inf,501,21
2026-01-01 00:00:20,1e400,-inf,22
2026-01-01 00:00:30,1e300,502,#N/A
2026-01-01 00:00:40,11.0,Bad,NaN
2026-01-01 00:00:50,12.0,503,-1.0
2026-01-01 00:01:00,13.0,504,107.0
2026-01-01 00:01:10,14.0,505,105.0
"""


def test_non_finite_absurd_and_text_cells_are_bad_samples_counted_per_tag(historian, tmp_path):
    """inf, 1e400, 1e300 (beyond float32), text, NaN and readings outside the declared range
    by NAMUR NE 43's failure margins become Bad samples at their time, each reported as
    file:line with its tag; the row's other values stay Good."""
    f = tmp_path / "bad.csv"
    f.write_text(BAD_VALUES)
    tags = tmp_path / "tags.csv"
    tags.write_text("name,unit,lo,hi\nT,degC,0,100\n")
    r = import_file(historian, f, tags_csv=tags)
    assert r.bad == [] and r.rows == 8
    assert r.bad_cells == {"F": 3, "P": 2, "T": 3}
    assert f"{f}:3: F: not finite (inf); stored as a Bad sample" in r.cells
    assert f"{f}:5: F: 1e+300 is beyond the float range a historian stores; stored as a " \
        "Bad sample" in r.cells  # fmt: skip
    assert f"{f}:6: P: no number in 'Bad'; stored as a Bad sample" in r.cells
    assert any(c.startswith(f"{f}:8: T: 107 is outside the tag's range 0..100") for c in r.cells)
    f_ = _read(historian, "F")
    assert f_["quality"].tolist() == [GOOD, BAD, BAD, BAD, GOOD, GOOD, GOOD, GOOD]
    assert f_["value"].iloc[3] == 1e300  # the number is kept beside its Bad quality
    t = _read(historian, "T")
    # -1.0 and 105.0 are within NE 43's margins (-2.5 %, +6.25 % of the span): Good
    assert t["quality"].tolist() == [GOOD, GOOD, GOOD, BAD, BAD, GOOD, BAD, GOOD]
    w = historian.window(["F", "P", "T"], "2026-01-01", "2026-01-01 00:01:20", "10s")
    assert np.isnan(w["F"].iloc[1:4]).all() and w["P"].iloc[0] == 500
    assert np.isfinite(w.to_numpy()[~np.isnan(w.to_numpy())]).all()


def test_epoch_milliseconds_read_as_seconds_are_refused_with_the_unit_that_fits(
    historian, tmp_path
):
    t0 = pd.Timestamp("2026-02-01", tz="UTC")
    ms = (t0 + pd.to_timedelta(np.arange(5) * 1000, unit="ms")).as_unit("ms").asi8
    f = tmp_path / "epoch.csv"
    f.write_text("t,A\n" + "".join(f"{m},{i}\n" for i, m in enumerate(ms)))
    with pytest.raises(FileRefused, match="with --time-unit ms it reads as 2026-02-01"):
        import_file(historian, f, time_column="t", time_unit="s")
    assert historian.tags().empty
    import_file(historian, f, time_column="t", time_unit="ms")
    assert historian.read_samples("A").index[0] == t0
    g = tmp_path / "epoch_ns.csv"
    ns = (t0 + pd.to_timedelta(np.arange(3), unit="s")).as_unit("ns").asi8
    g.write_text("t,B\n" + "".join(f"{n},{i}\n" for i, n in enumerate(ns)))
    import_file(historian, g, time_column="t", time_unit="ns")
    assert historian.read_samples("B").index.tolist() == list(
        t0 + pd.to_timedelta(np.arange(3), unit="s")
    )


def test_cli_takes_sep_decimal_time_format_and_micro_sign(tmp_path, capsys):
    db = f"sqlite:///{tmp_path / 'd.db'}"
    f = tmp_path / "e.csv"
    f.write_text("ts;A\n2026/01/02 03:04:05;1,25\n")
    argv = ["--db", db, "import", str(f), "--sep", ";", "--decimal", ","]
    assert main([*argv, "--time-format", "%Y/%m/%d %H:%M:%S", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["new"] == 1 and rep["first"].startswith("2026-01-02T03:04:05")
    g = tmp_path / "u.csv"
    t0 = pd.Timestamp("2026-02-01", tz="UTC").value // 1000
    g.write_text(f"t,B\n{t0},1\n{t0 + 1_000_000},2\n")
    assert main(["--db", db, "import", str(g), "--time-column", "t", "--time-unit", "µs"]) == 0
    with Historian(db) as h:
        assert h.read_samples("B").index[1] == pd.Timestamp("2026-02-01T00:00:01Z")


def test_an_import_that_stores_nothing_fails_and_leaves_nothing_behind(tmp_path, capsys):
    db = f"sqlite:///{tmp_path / 'd.db'}"
    f = tmp_path / "nothing.csv"
    f.write_text("time,A,B\nyesterday,1,2\nlater,3,4\n")
    assert main(["--db", db, "import", str(f)]) == 2
    err = capsys.readouterr().err
    assert "nothing imported" in err and f"{f}:2: unparseable time 'yesterday'" in err
    with Historian(db) as h:
        assert h.tags().empty


def test_tag_names_a_spec_cannot_name_are_refused_with_the_rename_that_fixes_them(
    historian, tmp_path
):
    f = tmp_path / "names.csv"
    f.write_text('time,"Flow ""A""",P[1]\n2026-01-01 00:00:00,1,2\n')
    with pytest.raises(FileRefused, match=r"--rename 'Flow \"A\"=Flow _A_'"):
        import_file(historian, f)
    assert historian.tags().empty
    import_file(historian, f, rename={'Flow "A"': "Flow A", "P[1]": "P1"})
    assert sorted(historian.tags()["name"]) == ["Flow A", "P1"]


def test_tag_names_with_spaces_parentheses_and_umlauts_work_through_the_tour(tmp_path, capsys):
    """Imported as the export names them, used in specs in double quotes."""
    db = f"sqlite:///{tmp_path / 'd.db'}"
    rb = tmp_path / "rb"
    idx = pd.date_range("2026-03-01", periods=600, freq="1s", tz="UTC")
    rng = np.random.default_rng(5)
    u = np.clip(50 + np.cumsum(rng.normal(0, 1, len(idx))), 0, 100)
    frame = pd.DataFrame(
        {"Ventil Y (%)": u, "Durchfluß F (t/h)": 0.4 * u + rng.normal(0, 0.1, len(u))},
        index=idx.strftime("%d.%m.%Y %H:%M:%S"),
    )
    frame.index.name = "Zeit"
    f = tmp_path / "export.csv"
    frame.to_csv(f, sep=";", decimal=",")
    g = ["--db", db, "--rulebases", str(rb)]
    assert main([*g, "import", str(f), "--time-format", "%d.%m.%Y %H:%M:%S"]) == 0
    capsys.readouterr()
    spec = '"Ventil Y (%)"[k-1]'
    assert main([*g, "model", "new", "m", "--output", '"Durchfluß F (t/h)"', "--input", spec]) == 0
    out = capsys.readouterr().out
    assert "period 1s from the data" in out
    assert main([*g, "train", "m", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["validation"]["rmse_pct"] < 5 and res["validation"]["samples"] > 100


def test_a_row_with_too_many_fields_in_the_first_lines_is_named_by_file_and_line(
    historian, tmp_path
):
    """The same message whether the bad row is among the lines read to recognise the file or
    further on (found by the mutation check of issue 28)."""
    f = tmp_path / "short.csv"
    f.write_text("time,A\n2026-01-01 00:00:00,1\n2026-01-01 00:00:01,2,3\n")
    with pytest.raises(FileRefused, match=rf"^{f}:3: 3 fields, but the header has 2$"):
        import_file(historian, f)
    assert historian.tags().empty
