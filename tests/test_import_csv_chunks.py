"""Issue 37 (i37-csv): the CSV reader infers the time column's type (pandas' fast path for
text) and reads a chunk whose times all look like numbers again with the time column as text.
The chunks must be those of the reader that always kept the time column as text: the times
as written (an error message quotes them), the same rows at the same lines, the same
malformed-line errors; checked chunk by chunk against that reader on files mixing every kind
of time cell, and end to end through ``import_file``."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from historian import Historian
from historian.importer import Dialect, FileRefused, _csv_chunks, import_file


def _text_times_chunks(path, tcol, chunk_rows):
    """The reference: the reader with the time column text from the first chunk, as every
    chunk was read before i37-csv (one reader, nothing read again)."""
    return _csv_chunks(path, tcol, chunk_rows, lambda _done: None, Dialect(), numbers=True)


def _read(chunks):
    """The chunks as a list, and the parse error's text that ended them (None: none)."""
    out = []
    try:
        for chunk in chunks:
            out.append(chunk)
    except pd.errors.ParserError as exc:
        return out, str(exc)
    return out, None


def _time_cell(kind: str, i: int, rng) -> str:
    when = pd.Timestamp("2026-01-01") + pd.Timedelta(seconds=10 * i)
    if kind == "dates":
        return f"{when:%Y-%m-%d %H:%M:%S}"
    if kind == "numbers":  # written as no float or int prints them back
        return str(rng.choice(["007", "1.50", "+5", "1e3", " 20260101", "-0"]))
    if kind == "epoch":
        return str(1_767_225_600 + 10 * i)
    if kind == "bools":
        return str(rng.choice(["True", "false", "TRUE"]))
    if kind == "blank":
        return ""
    # mixed: mostly numbers, a date now and then
    return f"{when:%Y-%m-%dT%H:%M:%S}" if rng.random() < 0.2 else str(rng.integers(0, 99))


@pytest.mark.parametrize("seed", range(6))
def test_chunks_are_those_of_the_text_time_reader(tmp_path, seed):
    """Random files: chunks of dates, of number-looking times, of booleans, of blank times,
    of a mix; blank lines, a quoted cell across two lines, a short last chunk and (odd
    seeds) a malformed row near the end."""
    rng = np.random.default_rng(seed)
    kinds = ["dates"] + list(rng.choice(["dates", "numbers", "bools", "blank", "mixed"], 6))
    rows = []
    for k, kind in enumerate(kinds):
        for j in range(17 if k == len(kinds) - 1 else 20):
            i = 20 * k + j
            rows.append(f"{_time_cell(str(kind), i, rng)},{i * 0.5:.2f},{rng.integers(0, 9)}")
    rows[int(rng.integers(5, 15))] = ""  # a blank line: a row of its own
    q = int(rng.integers(20, 100))
    rows[q] = rows[q].rsplit(",", 1)[0] + ',"4\nbis"'  # one row over two lines
    if seed % 2:
        rows[-3] += ",extra"
    f = tmp_path / "mixed.csv"
    f.write_text("\ufeffts,A,B\n" + "\n".join(rows) + "\n")
    for chunk_rows in (20, 33):
        want, want_err = _read(_text_times_chunks(f, "ts", chunk_rows))
        got, got_err = _read(_csv_chunks(f, "ts", chunk_rows, lambda _done: None, Dialect()))
        assert got_err == want_err
        assert [first for _, first in got] == [first for _, first in want]
        for (a, _), (b, _) in zip(got, want, strict=True):
            pd.testing.assert_frame_equal(a, b)
            assert pd.api.types.is_string_dtype(a["ts"].dtype)


def test_an_epoch_file_read_with_inferred_times_is_read_again_from_its_first_row(tmp_path):
    """Times that are plain numbers in the first chunk (the caller did not say so): that
    chunk and the rest are read again as text, nothing skipped; a later chunk holds a text
    time too."""
    rows = [f"{1_767_225_600 + 10 * i},{i}" for i in range(60)]
    rows[45] = "soon,45"
    f = tmp_path / "epoch.csv"
    f.write_text("t,A\n" + "\n".join(rows) + "\n")
    want, _ = _read(_text_times_chunks(f, "t", 20))
    got, err = _read(_csv_chunks(f, "t", 20, lambda _done: None, Dialect()))
    assert err is None and len(got) == len(want) == 3
    assert want[0][0]["t"].iloc[0] == "1767225600" and want[2][0]["t"].iloc[5] == "soon"
    for (a, first), (b, first_b) in zip(got, want, strict=True):
        assert first == first_b
        pd.testing.assert_frame_equal(a, b)


def test_import_quotes_number_looking_times_as_written_after_a_chunk_of_them(tmp_path):
    """Past the sample, a chunk of times that all look like numbers: each row is refused
    quoting its time as written, at its line; the rows after it (one of them a blank line)
    are stored at their times; a malformed row after that is named at its line."""
    dates = [f"2026-01-01 00:{i // 6:02d}:{i % 6 * 10:02d},{i}" for i in range(120)]
    numbers = ["007", "1.50", "+5", "1e3"] * 5  # lines 122-141
    rows = dates[:100] + [f"{t},1" for t in numbers] + [""] + dates[100:]
    f = tmp_path / "f.csv"
    f.write_text("ts,P1\n" + "\n".join(rows) + "\n")
    with Historian(f"sqlite:///{tmp_path / 'd.db'}") as h:
        r = import_file(h, f, chunk_rows=20)
        assert r.n_bad == 20
        assert r.bad[:4] == [
            f"{f}:102: unparseable time '007'",
            f"{f}:103: unparseable time '1.50'",
            f"{f}:104: unparseable time '+5'",
            f"{f}:105: unparseable time '1e3'",
        ]
        assert r.bad[-1] == f"{f}:121: unparseable time '1e3'"
        assert r.rows == 140 and r.written == 120
        stored = h.read_samples("P1")
        assert stored.tolist() == list(map(float, range(120)))
        assert stored.index[-1] == pd.Timestamp("2026-01-01 00:19:50", tz="UTC")
    rows.insert(135, "2026-01-01 01:00:00,1,2")  # file line 137
    g = tmp_path / "g.csv"
    g.write_text("ts,P1\n" + "\n".join(rows) + "\n")
    with Historian(f"sqlite:///{tmp_path / 'e.db'}") as h, pytest.raises(FileRefused) as exc:
        import_file(h, g, chunk_rows=20)
    assert str(exc.value).startswith(f"{g}:137: 3 fields, but the header has 2"), exc.value
