"""A stranger's bad input on the newest user paths of issue 34 (`diag import` with a tags CSV,
`diag unit build` with its loops, a hand-edited unit file): each case exits 2 with one
message naming what and where, and leaves the historian and the rule-base folder as they
were (docs/reference/cli.md, "Bad input"). Each test failed before its mend (branch
``i34-badinput``)."""

from __future__ import annotations

import hashlib
import re
import sqlite3
from pathlib import Path

import pandas as pd
import pytest

from diag_plugin.diagnose.unit import Unit
from diag_plugin.diagnose.unitfile import UnitError
from diag_plugin.unitbuild.build import build_unit
from diag_plugin.unitbuild.loops import parse_loop
from tests import line7
from tests.test_any_plant_tour import diag

#: a window of the historian below: 2026-03-02, 6 h (1,440 rows of 15 s)
WINDOW = ["--from", "2026-03-02T00:00", "--to", "2026-03-02T06:00"]


def _state(tmp: Path) -> str:
    """The historian's rows and every file under ``tmp`` but the inputs: what must not
    change when a command refuses its input."""
    h = hashlib.sha256()
    con = sqlite3.connect(f"file:{tmp / 'h.db'}?mode=ro", uri=True)
    for line in con.iterdump():
        h.update(line.encode())
    con.close()
    for p in sorted(tmp.rglob("*")):
        if p.is_file() and p.suffix not in (".db", ".csv") and "-wal" not in p.name:
            h.update(str(p).encode() + p.read_bytes())
    return h.hexdigest()


@pytest.fixture
def hist(tmp_path):
    """A historian holding 6 h of the 7-tag line, imported with its tags CSV."""
    f = line7.simulate(0.25, seed=1)
    out = f.copy()
    out.index = out.index.strftime("%Y-%m-%dT%H:%M:%S")
    out.index.name = "time"
    out.to_csv(tmp_path / "line.csv")
    line7.tags_csv().to_csv(tmp_path / "tags.csv", index=False)
    (tmp_path / "rb").mkdir()
    g = ["--db", f"sqlite:///{tmp_path / 'h.db'}", "--rulebases", str(tmp_path / "rb")]
    rc, text = diag(g, "import", str(tmp_path / "line.csv"), "--tags", str(tmp_path / "tags.csv"))
    assert rc == 0, text
    return g, tmp_path, f


def _refused(g, tmp, *argv) -> str:
    before = _state(tmp)
    rc, text = diag(g, *argv)
    assert rc == 2, text
    assert "Traceback" not in text and "internal error" not in text, text
    assert _state(tmp) == before, "a refused command changed the historian or the rule bases"
    return text


def test_a_header_naming_a_column_twice_is_refused_not_imported_as_name_1(hist):
    """Before: the second ``FEED_FLOW`` became a tag ``FEED_FLOW.1`` nobody wrote."""
    g, tmp, f = hist
    later = f.iloc[:300].copy()
    later.index = (later.index + pd.Timedelta(days=1)).strftime("%Y-%m-%dT%H:%M:%S")
    later.index.name = "time"
    later.insert(3, "AGAIN", later["FEED_FLOW"] + 1.0)
    text = later.to_csv().replace("AGAIN", "FEED_FLOW", 1)
    (tmp / "dup.csv").write_text(text)
    msg = _refused(g, tmp, "import", str(tmp / "dup.csv"))
    assert "dup.csv:1: the header names column 'FEED_FLOW' 2 times (columns 4, 5)" in msg


def _later_csv(f, rows: int = 300) -> str:
    """``rows`` of the line a day after the historian's, as CSV text (time first)."""
    later = f.iloc[:rows].copy()
    later.index = (later.index + pd.Timedelta(days=1)).strftime("%Y-%m-%dT%H:%M:%S")
    later.index.name = "time"
    return later.to_csv()


def test_a_row_short_of_fields_is_refused_at_its_line_an_empty_cell_is_not(hist):
    """Before: the missing cells of a row with fewer fields than the header were imported
    as no sample, without a word (a row with more was refused)."""
    g, tmp, f = hist
    lines = _later_csv(f).splitlines()
    n = len(lines[0].split(","))
    lines[50] = ",".join(lines[50].split(",")[:-1]) + ","  # its last cell empty: a missing value
    lines[60] = ",".join(lines[60].split(",")[:3] + [""] + lines[60].split(",")[4:])  # a,,c
    lines[100] = ",".join(lines[100].split(",")[:-2])  # two fields short
    (tmp / "short.csv").write_text("\n".join(lines) + "\n")
    msg = _refused(g, tmp, "import", str(tmp / "short.csv"))
    assert f"short.csv:101: {n - 2} fields, but the header has {n} (a row short of" in msg, msg
    assert "short.csv:51" not in msg and "short.csv:61" not in msg
    del lines[100]
    (tmp / "empty.csv").write_text("\n".join(lines) + "\n")
    rc, text = diag(g, "import", str(tmp / "empty.csv"))
    assert rc == 0, text
    assert f"{299 * (n - 1) - 2} new samples" in text, text


@pytest.mark.parametrize("strict", [False, True])
def test_a_short_row_in_a_later_chunk_is_found_past_chunks_without_suspects(tmp_path, strict):
    """Chunks of 100 rows, the last column blank in 2 rows of 3, a blank line before the
    short row: its line found (the lines of the chunks before skipped or counted); without
    ``--strict`` the chunks before it stored and said, with it nothing."""
    import numpy as np

    from historian.importer import FileRefused, import_file
    from historian.store import Historian

    idx = pd.date_range("2026-03-02", periods=1000, freq="15s").strftime("%Y-%m-%dT%H:%M:%S")
    n = np.arange(1000.0)
    frame = pd.DataFrame({"a": n, "b": np.where(n % 3, np.nan, 1.0)}, index=idx)
    lines = frame.rename_axis("time").to_csv().splitlines()
    lines[700] = lines[700].rsplit(",", 1)[0]
    lines.insert(400, "")
    (tmp_path / "x.csv").write_text("\n".join(lines) + "\n")
    with Historian.open(f"sqlite:///{tmp_path / 'h.db'}") as h:
        with pytest.raises(FileRefused) as exc:
            import_file(h, tmp_path / "x.csv", chunk_rows=100, strict=strict)
        stored = len(h.tags())
    msg = str(exc.value)
    assert msg.startswith(f"{tmp_path / 'x.csv'}:702: 2 fields, but the header has 3 (a row"), msg
    assert ("the rows before it were imported" in msg) is not strict
    assert stored == (0 if strict else 2)


@pytest.mark.parametrize(
    "text,said",
    [
        ("", "tags.csv: empty file; a tags CSV needs a header line"),
        ("name,unit,unit\nFEED_FLOW,m3/h,x\n", "tags.csv:1: the header names column 'unit' 2"),
        (
            "name;unit\nFEED_FLOW;m3/h\n",
            "tags.csv:1: a tags CSV needs a 'name' (or 'tag') "
            "column; the header reads 'name;unit' (separated by ';'?",
        ),
    ],
    ids=["empty", "unit-twice", "semicolons"],
)
def test_a_tags_csv_empty_or_naming_a_column_twice_is_refused_naming_the_file(hist, text, said):
    """Before: ``No columns to parse from file`` (which file?), and a second ``unit`` column
    silently unread."""
    g, tmp, _ = hist
    (tmp / "bad").mkdir()
    (tmp / "bad" / "tags.csv").write_text(text)
    msg = _refused(g, tmp, "import", str(tmp / "line.csv"), "--tags", str(tmp / "bad/tags.csv"))
    assert said in msg


@pytest.mark.parametrize(
    "edit,said",
    [
        (("feed,out", "feed,valve"), "tags.csv:5: role 'valve' of VALVE_A (loop feed) is not one"),
        (("feed,sp", "feed,pv"), "tags.csv:4: loop feed has two pv tags (FEED_TARGET on line 3"),
        (("feed,sp", "feed2,sp"), "tags.csv:3: loop feed2 has no pv tag"),
        (("drain valve,,", "drain valve,feed,manual"), "tags.csv:7: HAND_VALVE is a hand valve"),
    ],
    ids=["role-valve", "two-pv", "no-sp", "manual-in-a-loop"],
)
def test_a_tags_csv_at_import_is_checked_as_unit_build_loops_from_checks_it(hist, edit, said):
    """The same checks (historian.tagroles), before anything is written. Before: imported,
    the mistake said only at a later ``unit build --loops-from`` of the same file."""
    g, tmp, _ = hist
    text = (tmp / "tags.csv").read_text()
    assert edit[0] in text
    (tmp / "bad").mkdir()
    (tmp / "bad" / "tags.csv").write_text(text.replace(edit[0], edit[1], 1))
    msg = _refused(g, tmp, "import", str(tmp / "line.csv"), "--tags", str(tmp / "bad/tags.csv"))
    assert said in msg, msg
    msg = _refused(g, tmp, "unit", "build", "u", *WINDOW, "--loops-from", str(tmp / "bad/tags.csv"))
    assert said in msg, msg


def test_a_time_without_offset_among_times_with_one_says_so(hist):
    """Before: ``unparseable time '2026-03-03T00:25:00'`` for a time that parses."""
    g, tmp, f = hist
    later = f.iloc[:200].copy()
    stamps = list((later.index + pd.Timedelta(days=1)).strftime("%Y-%m-%dT%H:%M:%S+00:00"))
    stamps[100] = stamps[100].removesuffix("+00:00")
    later.index = pd.Index(stamps, name="time")
    later.to_csv(tmp / "mixed.csv")
    rc, text = diag(g, "import", str(tmp / "mixed.csv"))
    assert rc == 0, text  # a bad row is skipped and said (docs/reference/historian.md)
    assert "mixed.csv:102: time '2026-03-03T00:25:00' has no UTC offset, among times" in text


@pytest.mark.parametrize("far", ["inf", "1000"])
def test_a_far_budget_that_is_no_budget_is_refused_before_anything_is_read(hist, far):
    """Before: ``inf`` an internal error (OverflowError), ``1000`` a unit whose limits were
    ±0.0001 % of span (every sample an alarm)."""
    g, tmp, _ = hist
    msg = _refused(g, tmp, "unit", "build", "u", *WINDOW, "--loop", line7.LOOP, "--far", far)
    assert f"--far {far}: the budget must be a positive rate per hour, at most 6" in msg


@pytest.mark.parametrize(
    "text,said",
    [
        (line7.tags_csv().to_csv(index=False, sep=";"), "(separated by ';'? write it comma-"),
        ("name,loop,role\n", "tags.csv: no rows, only a header: it declares no loop"),
        ("name,loop,role,role\nFEED_FLOW,feed,pv,sp\n", "tags.csv:1: the header names column"),
    ],
    ids=["semicolons", "header-only", "role-twice"],
)
def test_a_loops_from_file_that_declares_nothing_is_refused(hist, text, said):
    """Before: each built a unit without the loop, saying nothing of the file."""
    g, tmp, _ = hist
    (tmp / "bad").mkdir()
    (tmp / "bad" / "tags.csv").write_text(text)
    msg = _refused(g, tmp, "unit", "build", "u", *WINDOW, "--loops-from", str(tmp / "bad/tags.csv"))
    assert said in msg


def test_a_declared_loops_measurement_without_a_value_in_the_window_is_refused(hist):
    """As a hand valve without a value is. Before: the unit was built without the loop's
    test (``not tested: FEED_FLOW: good samples in 0%``)."""
    g, tmp, f = hist
    later = f.iloc[:400].copy()
    later.index = (later.index + pd.Timedelta(days=1)).strftime("%Y-%m-%dT%H:%M:%S")
    later.index.name = "time"
    later["FEED_FLOW"] = float("nan")
    later.to_csv(tmp / "later.csv")
    assert diag(g, "import", str(tmp / "later.csv"))[0] == 0
    msg = _refused(g, tmp, "unit", "build", "u", "--from", "2026-03-03", "--to",
                   "2026-03-03T01:40", "--loop", line7.LOOP)  # fmt: skip
    assert (
        f"--loop '{line7.LOOP}': loop {line7.LOOP}: its measurement FEED_FLOW has no value in "
        "the window" in msg
    )


@pytest.fixture(scope="module")
def unit5(tmp_path_factory):
    """The line's units on 5-min means, the loop declared: ``narrow`` (the hand valve not
    declared: its span in ``[narrow]``) and ``manual`` (declared: in ``[manual]``)."""
    folder = tmp_path_factory.mktemp("bad34")
    f = line7.simulate(6.0, 1).resample("5min", label="right", closed="right").mean()
    for name, manual in (("narrow", []), ("manual", ["HAND_VALVE"])):
        build_unit(name, f, folder=folder, period="300s", loops=[parse_loop(line7.LOOP)],
                   manual=manual, far=0.01, force=True)  # fmt: skip
    return folder


@pytest.mark.parametrize("table", ["narrow", "manual"])
def test_a_hand_edited_row_naming_no_tag_of_the_unit_is_a_file_line_problem(unit5, table):
    """A typo in a ``[narrow]`` or ``[manual]`` row's tag. Before: ``unit check`` said ok
    and the row did nothing."""
    folder = unit5
    Unit.load(folder / f"{table}.unit.toml", folder)  # the unit as built reads
    lines = (folder / f"{table}.unit.toml").read_text().splitlines()
    at = lines.index(f"[{table}]")
    k = next(i for i in range(at + 1, len(lines)) if " = {min" in lines[i])
    tag = lines[k].split(" = ")[0]
    lines[k] = lines[k].replace(tag, tag + "X", 1)
    p = folder / "typo.unit.toml"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(UnitError) as exc:
        Unit.load(p, folder)
    assert f"typo.unit.toml:{k + 1}: [{table}] {tag}X: " in str(exc.value)
    rc, out = diag(["--rulebases", str(folder)], "unit", "check", str(p))
    assert rc == 2 and f"typo.unit.toml:{k + 1}: [{table}] {tag}X" in out, out


def _accepted(unit5, tmp_path, drop: str | None = None):
    """A copy of unit ``manual`` that accepted 2 days of seed 4 a week on (``drop``: a tag
    without a value there); its folder and the accept's result."""
    import shutil

    from diag_plugin.unitbuild.accept import accept

    folder = tmp_path / "rb"
    shutil.copytree(unit5, folder)
    five = {"rule": "5min", "label": "right", "closed": "right"}
    old = line7.simulate(6.0, 1).resample(**five).mean()
    new = line7.simulate(2.0, 4)
    new.index = new.index + pd.Timedelta(days=7)
    new = new.resample(**five).mean()
    if drop:
        new[drop] = float("nan")
    every = pd.concat([old, new])
    unit = Unit.load(folder / "manual.unit.toml", folder)
    a, b = new.index[0], new.index[-1]
    res = accept(unit, lambda t0, t1: [every[(every.index >= t0) & (every.index < t1)]], a, b)
    return folder, res


def test_accept_of_a_period_without_a_tests_tag_says_the_tag_has_no_value(unit5, tmp_path):
    """The unit has no equipment. Before: ``FEED_FLOW: its equipment did not run in the
    window``."""
    _, res = _accepted(unit5, tmp_path, drop="FEED_FLOW")
    said = [w for w in res.warnings if "its model keeps what it learned" in w]
    assert said == [
        f"{t}: FEED_FLOW has no value in the period: its model keeps what it learned"
        for t in ("FEED_FLOW", "FEED_FLOW_spread")
    ], said


@pytest.mark.parametrize(
    "edit,said",
    [
        (lambda r: re.sub(r", max = [^,]+", "", r), "(max missing)"),
        (lambda r: re.sub(r"min = [^,]+", 'min = "low"', r), "(min 'low' is not a finite number)"),
        (lambda r: re.sub(r"margin = [^}]+", "margin = -1.0 ", r), "got min 40, max 47, margin -1"),
    ],
    ids=["missing-max", "min-text", "negative-margin"],
)
def test_a_broken_narrow_row_says_what_is_wrong_at_its_line(unit5, tmp_path, edit, said):
    """Before: ``must be { min = …, max = …, margin = … }`` whatever was wrong, and
    ``needs min ≤ max and margin ≥ 0`` without the values."""
    from diag_plugin.diagnose.unitfile import UnitFile

    lines = (unit5 / "narrow.unit.toml").read_text().splitlines()
    k = lines.index("[narrow]") + 2  # its comment, then the hand valve's row
    assert lines[k].startswith("HAND_VALVE = {min = 40.0, max = 47.0"), lines[k]
    lines[k] = edit(lines[k])
    with pytest.raises(UnitError) as exc:
        UnitFile("\n".join(lines) + "\n", tmp_path / "n.unit.toml")
    assert f"n.unit.toml:{k + 1}: [narrow] HAND_VALVE: " in str(exc.value)
    assert said in str(exc.value)


def _day_imported(unit5, tmp_path, f: pd.DataFrame, every: str, first: int = 0) -> list[str]:
    """A day of the line as ``every``'s means (from row ``first``), a week on, imported into a
    SQLite historian through ``diag import``: the global options to diagnose it with."""
    f = f.resample(every, label="right", closed="right").mean().iloc[first:]
    f.index = f.index + pd.Timedelta(days=7)
    f.index = f.index.strftime("%Y-%m-%dT%H:%M:%S")
    f.index.name = "time"
    f.to_csv(tmp_path / "day.csv")
    g = ["--db", f"sqlite:///{tmp_path / 'h.db'}", "--rulebases", str(unit5)]
    assert diag(g, "import", str(tmp_path / "day.csv"))[0] == 0
    return g


@pytest.mark.parametrize("where", ["no/such/folder/out.csv", "."])
def test_diagnose_csv_into_no_folder_is_refused_before_the_replay(unit5, tmp_path, where):
    """Before: the whole replay ran, then ``[Errno 2] No such file or directory`` (its result
    lost), or ``[Errno 21] Is a directory``."""
    g = _day_imported(unit5, tmp_path, line7.simulate(1.0, 4), "5min")
    target = tmp_path / where
    rc, text = diag(g, "diagnose", "narrow", "--from", "2026-03-09", "--to", "2026-03-10",
                    "--csv", str(target))  # fmt: skip
    assert rc == 2, text
    assert text.startswith(f"diag: error: --csv {target}: "), text
    assert "timeline" not in text and not (tmp_path / "no").exists()


def test_rollback_keeps_the_version_it_replaces(unit5, tmp_path):
    """A hand edit made after an accept. Before: ``diag unit rollback`` overwrote it, kept
    nowhere."""
    folder, _ = _accepted(unit5, tmp_path)
    unit_file = folder / "manual.unit.toml"
    edited = unit_file.read_text() + "# my note after the accept\n"
    unit_file.write_text(edited)
    rc, text = diag(["--rulebases", str(folder)], "unit", "rollback", "manual")
    assert rc == 0, text
    assert "# my note" not in unit_file.read_text()
    kept = folder / ".unit-backups" / "manual" / "replaced" / "1"
    assert f"the files it replaced are kept in {kept}" in text, text
    assert [p.read_text() for p in kept.glob("*_manual.unit.toml")] == [edited]


@pytest.mark.parametrize("every", ["15min", "1min"])
def test_diagnose_of_data_coarser_than_the_unit_says_both_periods(unit5, tmp_path, every):
    """Data every 15 min for a unit of 5 min: each sample held over 3 of its periods. Before:
    replayed without a word. Data every minute (finer) are averaged onto its grid, as at the
    build: nothing said."""
    g = _day_imported(unit5, tmp_path, line7.simulate(1.0, 4), every, first=1)
    rc, text = diag(g, "diagnose", "narrow", "--from", "2026-03-09", "--to", "2026-03-10")
    assert rc == 0, text
    if every == "1min":
        assert "the data come every" not in text, text
        return
    assert re.search(
        r"⚠ the data come every 15min \(FEED_TARGET, .*\), the unit narrow every (300s|5min): "
        r"each sample is held over ~3 of the unit's periods.* build a unit at the data's rate "
        r"\(diag unit build NAME --period 15min …\) or give the data every (300s|5min)",
        text,
    ), text


def test_a_tags_csv_row_for_a_tag_neither_imported_nor_stored_is_said_not_dropped(hist):
    """A misspelt name in the tags CSV (``FEED_FLOWW``): its row matches no column of the file
    and no stored tag. Before: dropped without a word (the tag the user meant kept no
    metadata); now the import says which rows at ``file:line`` and stores no such tag. A row
    for a tag already stored, not in this file, still updates its metadata."""
    g, tmp, f = hist
    later = f.iloc[:100, :3].copy()  # three of the line's tags, a day later
    later.index = (later.index + pd.Timedelta(days=1)).strftime("%Y-%m-%dT%H:%M:%S")
    later.index.name = "time"
    later.to_csv(tmp / "later.csv")
    tags = line7.tags_csv()
    tags.loc[len(tags)] = tags.iloc[0]
    tags.loc[len(tags) - 1, "name"] = "FEED_FLOWW"
    tags.to_csv(tmp / "typo.csv", index=False)
    rc, text = diag(g, "import", str(tmp / "later.csv"), "--tags", str(tmp / "typo.csv"))
    assert rc == 0, text
    line = len(tags) + 1  # the header is line 1
    said = "tags CSV: 1 row names a tag neither in this file nor in the historian, not stored"
    assert said in text, text
    assert f"FEED_FLOWW ({tmp / 'typo.csv'}:{line})" in text, text
    names = {r[0] for r in sqlite3.connect(tmp / "h.db").execute("SELECT name FROM tags")}
    assert "FEED_FLOWW" not in names and set(f.columns) <= names
    rc, text = diag(g, "import", str(tmp / "later.csv"), "--tags", str(tmp / "tags.csv"))
    assert rc == 0 and "neither in this file" not in text, text  # the others are all stored
