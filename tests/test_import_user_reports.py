"""What a user met importing real exports (issue 37): a pandas DtypeWarning on a column with
a text cell deep in a big file, and a spreadsheet workbook answered with a misleading
message. Through ``diag_plugin.cli.main``, as the user ran them."""

from __future__ import annotations

import warnings
import zipfile

import numpy as np
import pandas as pd
import pytest

from diag_plugin.cli import main
from historian import Historian


def _import_without_warnings(tmp_path, f, capsys) -> tuple[str, str]:
    """``diag import`` of ``f`` into a new SQLite historian, any warning an error: the
    database URL and what was printed to stderr."""
    db = f"sqlite:///{tmp_path / 'h.db'}"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any warning fails the import
        rc = main(["--db", db, "import", str(f), "--no-progress"])
    _, err = capsys.readouterr()
    assert rc == 0, err
    return db, err


def test_a_text_cell_deep_in_a_big_file_gives_no_dtype_warning(tmp_path, capsys):
    """pandas read each chunk in pieces and met numbers in one piece and text in another
    (DtypeWarning, printed to the user); the chunk's column types now come from the whole
    chunk, and the text cell is a Bad sample at its line."""
    n = 50_000
    rng = np.random.default_rng(1)
    frame = pd.DataFrame({f"T{i}": np.round(rng.normal(50, 1, n), 4) for i in range(20)})
    frame.insert(0, "ts", pd.date_range("2025-01-01", periods=n, freq="10s"))
    frame["T3"] = frame["T3"].astype(object)
    frame.loc[40_000, "T3"] = "Bad"
    f = tmp_path / "big.csv"
    frame.to_csv(f, index=False, date_format="%Y-%m-%dT%H:%M:%S")
    db, err = _import_without_warnings(tmp_path, f, capsys)
    assert f"{f}:40002: T3: no number in 'Bad'; stored as a Bad sample" in err
    with Historian(db) as h:
        s = h.read_samples("T3", with_quality=True)
        assert len(s) == n and int(s["quality"].sum()) == 2
        assert np.allclose(h.read_samples("T5").to_numpy(), frame["T5"].to_numpy())


def test_times_with_mixed_offsets_give_no_warning(tmp_path, capsys):
    """A summer-time switch in an export's offsets: pandas 2.x warned (FutureWarning,
    printed to the user) when it parsed times with mixed offsets; they are stored in UTC."""
    f = tmp_path / "dst.csv"
    f.write_text(
        "time,A\n2026-03-29T01:00:00+01:00,1\n2026-03-29T03:00:00+02:00,2\n"
        "2026-03-29T04:00:00+02:00,3\n"
    )
    db, err = _import_without_warnings(tmp_path, f, capsys)
    with Historian(db) as h:
        s = h.read_samples("A")
    assert list(s.index.strftime("%H:%M")) == ["00:00", "01:00", "02:00"]


def _xlsx(path):
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("[Content_Types].xml", '<?xml version="1.0"?><Types/>')
        z.writestr("xl/workbook.xml", "<workbook/>")
        z.writestr("xl/worksheets/sheet1.xml", "<worksheet><sheetData/></worksheet>")


def _ods(path):
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("mimetype", "application/vnd.oasis.opendocument.spreadsheet")
        z.writestr("content.xml", "<office:document-content/>")


def _xls(path):
    path.write_bytes(b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1" + bytes(504))


@pytest.mark.parametrize(
    "name, make, kind",
    [
        ("export.xlsx", _xlsx, "an Excel workbook (.xlsx)"),
        ("export.csv", _xlsx, "an Excel workbook (.xlsx)"),  # renamed, still a workbook
        ("export.ods", _ods, "an OpenDocument spreadsheet (.ods)"),
        ("export.xls", _xls, "an Excel 97-2003 workbook (.xls)"),
    ],
)
def test_a_spreadsheet_is_named_with_what_to_do(tmp_path, capsys, name, make, kind):
    f = tmp_path / name
    make(f)
    db = f"sqlite:///{tmp_path / 'h.db'}"
    rc = main(["--db", db, "import", str(f)])
    err = capsys.readouterr().err
    assert rc == 2
    assert f"{f}: {kind}, not a CSV text file" in err
    assert "save the sheet as 'CSV UTF-8 (comma delimited)'" in err
    with Historian(db) as h:
        assert h.tags().empty
