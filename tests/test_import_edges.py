"""An importer edge a mutation check found untested (issue 28): when a re-import conflicts
with stored samples in several tags, the message names the earliest conflict over all tags,
not the first tag's. Through ``diag import`` only, so it holds through rewrites of the
importer."""

from __future__ import annotations

from test_import_refuses_to_guess import FIRST  # the stored file of the conflict cases

from diag_plugin.cli import main

# against FIRST: P1 differs at 00:01:00 only; F, the later column, differs earlier, at 00:00:10
SECOND = """ts,P1,F
2026-01-01 00:00:10,500.5,9.0
2026-01-01 00:01:00,499.0,11.0
"""


def test_the_earliest_conflict_over_all_tags_is_named(db_url, tmp_path, capsys):
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    a.write_text(FIRST)
    b.write_text(SECOND)
    assert main(["--db", db_url, "import", str(a)]) == 0
    capsys.readouterr()
    assert main(["--db", db_url, "import", str(b)]) == 0
    err = capsys.readouterr().err
    assert (
        f"2 samples conflict with stored values (first: F at 2026-01-01T00:00:10Z ({b}:2): "
        "stored 10.5, file 9.0)"
    ) in err, err


def test_a_row_with_more_fields_than_the_header_is_named_by_its_line(db_url, tmp_path, capsys):
    """Deep in a file (past the rows read to recognise it), a row with an extra field stops
    the import at that row's file:line."""
    rows = [f"2026-01-01 00:{k // 6:02d}:{k % 6 * 10:02d},{k}" for k in range(300)]
    rows[250] += ",9"  # file line 252 (header = line 1)
    f = tmp_path / "wide.csv"
    f.write_text("ts,P1\n" + "\n".join(rows) + "\n")
    assert main(["--db", db_url, "import", str(f)]) != 0
    err = capsys.readouterr().err
    assert f"{f}:252: 3 fields, but the header has 2" in err, err


def _refusal(tmp_path, capsys, name: str, content: bytes) -> str:
    f = tmp_path / name
    f.write_bytes(content)
    db = f"sqlite:///{tmp_path / 'd.db'}"
    assert main(["--db", db, "import", str(f)]) == 2
    return capsys.readouterr().err


def test_a_nul_or_non_utf8_byte_is_named_at_its_line_even_after_a_blank_first_line(
    tmp_path, capsys
):
    """Issue 38 (mutation survivors): the line of the offending byte is counted from the
    file's first byte, a blank first line included."""
    for name, body in (("nul.csv", b"\x00"), ("latin1.csv", b"\xe9")):
        content = b"\nts,P1\n2026-01-01 00:00:00,1\n2026-01-01 00:00:01," + body + b"\n"
        err = _refusal(tmp_path, capsys, name, content)
        assert f"{name}:4: " in err, err


def test_times_from_1970_01_02_to_a_year_ahead_are_plausible_and_others_named(tmp_path, capsys):
    """Issue 38 (mutation survivors): a row at exactly 1970-01-02 00:00 is kept; a row more
    than a year (366 days) ahead is refused at its line, as is one before 1970-01-02."""
    import pandas as pd

    from historian import Historian

    ahead = (pd.Timestamp.now(tz="UTC") + pd.Timedelta(days=366, hours=2)).strftime(
        "%Y-%m-%d %H:%M:%S"
    )
    f = tmp_path / "times.csv"
    f.write_text(
        "ts,P1\n"
        + "".join(  # rows past the sample the importer looks at first
            f"{t:%Y-%m-%d %H:%M:%S},{i}\n"
            for i, t in enumerate(pd.date_range("2026-01-01", periods=200, freq="s"))
        )
        + "1970-01-02 00:00:00,1\n"
        + f"{ahead},2\n"
        + "1970-01-01 23:59:59,3\n"
    )
    db = f"sqlite:///{tmp_path / 'd.db'}"
    assert main(["--db", db, "import", str(f)]) == 0
    err = capsys.readouterr().err
    assert f"times.csv:203: time {ahead}" in err and "a year ahead" in err, err
    assert "times.csv:204: time 1970-01-01 23:59:59" in err, err
    assert "times.csv:202" not in err
    with Historian(db) as h:
        s = h.read_samples("P1")
    assert s.index[0] == pd.Timestamp("1970-01-02", tz="UTC") and len(s) == 201
