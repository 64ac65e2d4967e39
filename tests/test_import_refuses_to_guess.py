"""diag import refuses to guess (issue 8): no recognisable time column, plain-number times
without a unit, conflicting values at a stored (tag, ts), empty or unreadable files.

Every case runs through the CLI (``diag_plugin.cli.main``), the conflict cases on both
backends (``db_url``), the cold-store case with months rolled to Parquet."""

from __future__ import annotations

import pandas as pd
import pytest

from diag_plugin.cli import main
from historian import Historian
from historian.importer import KEPT
from historian.quality import BAD

FIRST = """ts,P1,F
2026-01-01 00:00:00,500.0,10.0
2026-01-01 00:00:10,500.5,10.5
2026-01-01 00:01:00,501.2,11.0
2026-01-01 00:01:10,502.0,11.5
"""

# the same times; P1 differs at 00:01:00 and 00:01:10, F is identical, one row is new
SECOND = """ts,P1,F
2026-01-01 00:00:10,500.5,10.5
2026-01-01 00:01:00,499.0,11.0
2026-01-01 00:01:10,498.0,11.5
2026-01-01 00:01:20,497.0,12.0
"""


def _diag(capsys, *args):
    rc = main(list(args))
    out, err = capsys.readouterr()
    return rc, out, err


def _nothing_stored(db):
    with Historian(db) as h:
        assert h.tags().empty
        assert h.time_range() == (None, None)


def _refused(capsys, db, f, text: str | bytes | None, *more) -> str:
    """``text`` written to ``f`` (None: no file), ``diag import f *more`` refused with exit 2
    and nothing stored; what it said on stderr."""
    if isinstance(text, bytes):
        f.write_bytes(text)
    elif text is not None:
        f.write_text(text)
    rc, out, err = _diag(capsys, "--db", db, "import", str(f), *more)
    assert rc == 2, err
    _nothing_stored(db)
    return err


# -- 1. the time column -----------------------------------------------------------------


def test_no_time_column_is_refused(tmp_path, capsys):
    db = f"sqlite:///{tmp_path / 'h.db'}"
    f = tmp_path / "notime.csv"
    err = _refused(capsys, db, f, "a,b\n1,2\n3,4\n")
    assert str(f) in err and "a, b" in err and "--time-column" in err
    # a first column of date-times needs no name; a named one wins over the first
    g = tmp_path / "when.csv"
    g.write_text("when,P1\n2026-01-01 00:00:10,1\n2026-01-01T00:00:20Z,2\n")
    assert _diag(capsys, "--db", db, "import", str(g))[0] == 0
    with Historian(db) as h:
        assert h.read_samples("P1").index[0] == pd.Timestamp("2026-01-01 00:00:10", tz="UTC")


def test_plain_number_times_need_a_unit_and_an_origin(tmp_path, capsys):
    """A DAMADICS-style CSV: 'time' in seconds from 0 of the recording."""
    db = f"sqlite:///{tmp_path / 'h.db'}"
    f = tmp_path / "damadics.csv"
    err = _refused(capsys, db, f, "time,P1,F\n0,500,10\n1,501,11\n2,502,12\n")
    assert str(f) in err and "'time'" in err and "plain numbers" in err
    assert "--time-unit s" in err and "--start" in err
    rc, out, err = _diag(
        capsys,
        "--db",
        db,
        "import",
        str(f),
        "--time-column",
        "time",
        "--time-unit",
        "s",
        "--start",
        "2001-11-17T00:00:00Z",
    )
    assert rc == 0, err
    with Historian(db) as h:
        s = h.read_samples("F")
    assert list(s.index) == list(
        pd.date_range("2001-11-17", periods=3, freq="1s", tz="UTC", name="ts")
    )
    assert "time" not in set(Historian(db).tags()["name"])
    # --time-unit alone: Unix time (seconds since 1970-01-01 UTC)
    g = tmp_path / "unix.csv"
    g.write_text("t,X\n1767225600,1\n")
    rc, out, err = _diag(capsys, "--db", db, "import", str(g), "--time-column", "t")
    assert rc == 2 and "--time-unit" in err
    assert (
        _diag(capsys, "--db", db, "import", str(g), "--time-column", "t", "--time-unit", "s")[0]
        == 0
    )
    with Historian(db) as h:
        assert h.read_samples("X").index[0] == pd.Timestamp("2026-01-01", tz="UTC")
    # a unit for a column of date-times is a contradiction, not something to guess around
    h2 = tmp_path / "dates.csv"
    h2.write_text(FIRST)
    rc, out, err = _diag(capsys, "--db", db, "import", str(h2), "--time-unit", "s")
    assert rc == 2 and "--time-unit" in err and str(h2) in err


# -- 2. conflicts with stored values ----------------------------------------------------


def test_conflicts_are_reported_and_stored_values_kept(db_url, tmp_path, capsys):
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    a.write_text(FIRST)
    b.write_text(SECOND)
    assert _diag(capsys, "--db", db_url, "import", str(a))[0] == 0
    rc, out, err = _diag(capsys, "--db", db_url, "import", str(a))  # identical: silent
    assert rc == 0 and "conflict" not in err and "conflicting" not in out
    assert "0 new samples, 8 already stored" in out
    rc, out, err = _diag(capsys, "--db", db_url, "import", str(b))
    assert rc == 0, err
    assert (
        "2 samples conflict with stored values (first: P1 at 2026-01-01T00:01:00Z "
        f"({b}:3): stored 501.2, file 499.0); kept the stored ones — use --replace to overwrite"
    ) in err
    assert "2 new samples, 4 already stored, 2 conflicting" in out
    with Historian(db_url) as h:
        assert h.read_samples("P1").tolist() == [500.0, 500.5, 501.2, 502.0, 497.0]
        assert h.read_samples("F").tolist() == [10.0, 10.5, 11.0, 11.5, 12.0]
    rc, out, err = _diag(capsys, "--db", db_url, "import", str(b), "--replace")
    assert rc == 0
    assert "2 samples conflicted with stored values" in err and "replaced" in err
    assert "0 new samples, 6 already stored, 2 replaced" in out
    with Historian(db_url) as h:
        assert h.read_samples("P1").tolist() == [500.0, 500.5, 499.0, 498.0, 497.0]
    rc, out, err = _diag(capsys, "--db", db_url, "import", str(a), "--update")  # the alias
    assert rc == 0 and "2 replaced" in out
    with Historian(db_url) as h:
        assert h.read_samples("P1").tolist() == [500.0, 500.5, 501.2, 502.0, 497.0]


def test_a_different_quality_is_a_conflict(db_url, tmp_path, capsys):
    with Historian(db_url) as h:
        s = pd.Series([501.2], pd.DatetimeIndex(["2026-01-01 00:01:00"], tz="UTC"), name="P1")
        h.write_samples(s, quality=BAD)
    a = tmp_path / "a.csv"
    a.write_text(FIRST)
    rc, out, err = _diag(capsys, "--db", db_url, "import", str(a))
    assert rc == 0
    assert (
        "1 sample conflicts with stored values (first: P1 at 2026-01-01T00:01:00Z "
        f"({a}:4): stored 501.2 (bad), file 501.2 (good))"
    ) in err


TWICE = (
    "ts,P1,P2\n"
    "2026-01-01 00:00:00,1,10\n"
    "2026-01-01 00:00:10,2,\n"
    "2026-01-01 00:00:00,3,30\n"  # repeats line 2
    "2026-01-01 00:00:20,4,40\n"
    "2026-01-01 00:00:20,,44\n"  # repeats line 5; P1 has no sample here
    "2026-01-01 00:00:20,6,\n"
)


def test_a_repeated_time_is_refused_by_default_naming_the_rows_and_the_count(
    db_url, tmp_path, capsys
):
    """Issue 37: a time repeated in the file was stored as 'already stored' with the first
    value kept silently, exit 0. Now import does not choose: exit 2, nothing stored."""
    f = tmp_path / "twice.csv"
    err = _refused(capsys, db_url, f, TWICE)
    assert (
        f"{f}: 3 rows repeat the time of an earlier row (first: {f}:4 repeats {f}:2, "
        "2026-01-01T00:00:00Z); import does not choose between them: say which sample each "
        "tag keeps with --duplicates first, last or mean; nothing imported"
    ) in err
    err = _refused(capsys, db_url, f, None, "--strict")
    assert "3 rows repeat" in err and "nothing imported" in err


@pytest.mark.parametrize(
    "policy, p1, p2",
    [
        ("first", [1.0, 2.0, 4.0], [10.0, 40.0]),
        ("last", [3.0, 2.0, 6.0], [30.0, 44.0]),
        ("mean", [2.0, 2.0, 5.0], [20.0, 42.0]),
    ],
)
def test_the_user_names_what_a_repeated_time_keeps(db_url, tmp_path, capsys, policy, p1, p2):
    f = tmp_path / "twice.csv"
    f.write_text(TWICE)
    rc, out, err = _diag(capsys, "--db", db_url, "import", str(f), "--duplicates", policy)
    assert rc == 0
    assert (
        f"3 rows repeat a time of an earlier row of the file (first: {f}:4 repeats {f}:2, "
        f"2026-01-01T00:00:00Z); kept {KEPT[policy]} at each repeated time "
        f"(--duplicates {policy})"
    ) in err
    assert "conflict" not in err  # a repeat within the file is not a stored conflict
    assert f"3 rows at a repeated time merged ({policy}); 5 new samples, 0 already stored" in out
    with Historian(db_url) as h:
        assert h.read_samples("P1").tolist() == p1
        assert h.read_samples("P2").tolist() == p2
    # importing again: the same samples, already stored, no conflict
    rc, out, err = _diag(capsys, "--db", db_url, "import", str(f), "--duplicates", policy)
    assert rc == 0 and "0 new samples, 5 already stored" in out and "conflict" not in err


def test_repeats_across_chunks_and_out_of_order(tmp_path):
    """Repeats that follow each other across a chunk boundary meet in one piece; a repeat
    far from its first row (a file out of time order) is found too: ``first`` drops it,
    ``mean`` refuses it, saying why."""
    from historian.importer import FileRefused, import_file

    t = pd.date_range("2026-01-01", periods=10, freq="10s").strftime("%Y-%m-%d %H:%M:%S")
    rows = [f"{t[i]},{i}" for i in range(10)]
    rows.insert(5, f"{t[4]},40")  # a repeat right after line 6 (t[4]), across chunks of 5
    rows.append(f"{t[1]},99")  # far from t[1], in the last chunk
    f = tmp_path / "f.csv"
    f.write_text("ts,A\n" + "\n".join(rows) + "\n")
    with Historian(f"sqlite:///{tmp_path / 'a.db'}") as h:
        r = import_file(h, f, duplicates="first", chunk_rows=5)
        assert r.repeats == 2 and r.repeat_example == f"{f}:7 repeats {f}:6, 2026-01-01T00:00:40Z"
        assert h.read_samples("A").tolist() == [float(i) for i in range(10)]
    with Historian(f"sqlite:///{tmp_path / 'b.db'}") as h:
        with pytest.raises(FileRefused, match=r"f.csv:13: the time 2026-01-01T00:00:10Z repeats"):
            import_file(h, f, duplicates="mean", chunk_rows=5)
    with Historian(f"sqlite:///{tmp_path / 'c.db'}") as h:
        import_file(h, f, duplicates="mean", chunk_rows=50)  # all in one chunk
        assert h.read_samples("A").tolist()[1] == (1 + 99) / 2
        assert h.read_samples("A").tolist()[4] == (4 + 40) / 2
    with Historian(f"sqlite:///{tmp_path / 'd.db'}") as h:
        with pytest.raises(FileRefused, match="2 rows repeat.*the rows before line 7 were"):
            import_file(h, f, chunk_rows=5)
        assert h.read_samples("A").tolist() == [0.0, 1.0, 2.0, 3.0]


def test_conflicts_in_months_rolled_to_the_cold_store(tmp_path, capsys):
    db = f"sqlite:///{tmp_path / 'h.db'}"
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    a.write_text(FIRST)
    b.write_text(SECOND)
    assert _diag(capsys, "--db", db, "import", "--hot", str(a))[0] == 0  # into the table
    with Historian(db) as h:
        assert h.roll_months(before="2026-02-01") == ["2026-01"]
    rc, out, err = _diag(capsys, "--db", db, "import", str(a))
    assert rc == 0 and "conflict" not in err and "conflicting" not in out
    assert "0 new samples, 8 already stored" in out
    rc, out, err = _diag(capsys, "--db", db, "import", str(b))
    assert rc == 0
    assert "2 samples conflict with stored values (first: P1 at 2026-01-01T00:01:00Z" in err
    with Historian(db) as h:
        assert h.read_samples("P1").tolist() == [500.0, 500.5, 501.2, 502.0, 497.0]
    rc, out, err = _diag(capsys, "--db", db, "import", str(b), "--replace")
    assert rc == 0 and "2 replaced" in out
    with Historian(db) as h:
        assert h.read_samples("P1").tolist() == [500.0, 500.5, 499.0, 498.0, 497.0]


# -- 3. empty, header-only, unreadable, missing files -----------------------------------


@pytest.mark.parametrize(
    "kind, content, says",
    [
        ("empty", b"", "empty file"),
        ("blank", b"\n\n  \n", "no header"),
        ("header", b"ts,P1,F\n", "no data rows"),
        ("header-blank", b"ts,P1,F\n\n\n", "no data rows"),
        ("binary", b"ts,P1\n2026-01-01 00:00:00,1\n\x00\x01\x02\xff\xfe", ":3: "),
        ("latin1", "ts,Druck\n2026-01-01 00:00:00,1\n\xfc,2\n".encode("latin-1"), ":3: "),
        ("parquet", b"PAR1 this is not parquet", "Parquet"),
        ("missing", None, "no such file"),
    ],
)
def test_unusable_files_are_refused_by_name(tmp_path, capsys, kind, content, says):
    db = f"sqlite:///{tmp_path / 'h.db'}"
    f = tmp_path / f"{kind}.csv"
    err = _refused(capsys, db, f, content)
    assert f"diag: error: {f}" in err and says in err
