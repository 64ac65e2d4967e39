"""An import's pieces are written wide (issue 37): on SQLite staged one row per time and moved
tag by tag in one transaction (``SqliteBulk.insert_wide``), elsewhere as long rows. Both
store the same samples and count the same rows; a new SQLite database has larger pages, an
older one keeps its own; a killed import leaves whole pieces only."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
import time

import numpy as np
import pandas as pd
import pytest

from historian import Historian
from historian.backends import PAGE_BYTES
from historian.importer import FileRefused, import_file
from historian.quality import BAD, GOOD, UNCERTAIN


def _piece(rng, n=500, tags=("A", "B", "C", "D"), start="2025-01-01"):
    """A wide piece: NaN cells (no sample), Bad cells with and without a number, a tag of
    Uncertain codes throughout, and a tag of no sample at all."""
    idx = pd.date_range(start, periods=n, freq="10s", tz="UTC", name="ts")
    values = pd.DataFrame(rng.normal(50, 5, (n, len(tags))), index=idx, columns=list(tags))
    quality = pd.DataFrame(GOOD, index=idx, columns=list(tags), dtype=np.int8)
    values.iloc[rng.random(n) < 0.2, 0] = np.nan  # A: gaps
    bad = rng.random(n) < 0.1
    quality.iloc[bad, 1] = BAD  # B: Bad cells, half of them without a number
    values.iloc[np.flatnonzero(bad)[::2], 1] = np.nan
    quality.iloc[:, 2] = UNCERTAIN  # C: one code that is not GOOD
    values.iloc[:, 3] = np.nan  # D: nothing
    return values, quality


def _stored(h, tags):
    out = {}
    for t in tags:
        try:
            out[t] = h.read_samples(t, with_quality=True)
        except KeyError:
            out[t] = None
    return out


def _long_reference(h, values, quality, policy="ignore"):
    """The same piece as long rows through the bulk ``insert`` (the path before wide)."""
    ts = values.index.as_unit("us").asi8
    v = values.to_numpy(np.float64).T
    q = quality.to_numpy(np.int64).T
    ids = np.array([h._tag(str(c))[0] for c in values.columns], np.int64)
    c, r = np.nonzero(~np.isnan(v) | (q == BAD))
    return h._bulk.insert(ids[c], ts[r], v[c, r], q[c, r], policy=policy)


def test_wide_rows_store_what_long_rows_store(tmp_path):
    rng = np.random.default_rng(3)
    values, quality = _piece(rng)
    tags = list(values.columns)
    expected = int((values.notna().to_numpy() | (quality.to_numpy() == BAD)).sum())
    with (
        Historian(f"sqlite:///{tmp_path / 'wide.db'}") as wide,
        Historian(f"sqlite:///{tmp_path / 'long.db'}") as long,
    ):
        for h in (wide, long):
            for t in tags:
                h.ensure_tag(t)
        assert wide.write_wide(values, quality) == expected
        assert _long_reference(long, values, quality) == expected
        a, b = _stored(wide, tags), _stored(long, tags)
        for t in tags:
            pd.testing.assert_frame_equal(a[t], b[t])
        assert len(a["D"]) == 0
        assert (a["B"]["quality"] == BAD).sum() == (quality["B"] == BAD).sum()
        assert a["B"]["value"].isna().sum() == values["B"].isna().sum()
        assert set(a["C"]["quality"]) == {UNCERTAIN}

        # sent again: nothing added; changed values: kept (ignore) or counted (update)
        assert wide.write_wide(values, quality) == 0
        changed = values.copy()
        changed.iloc[:10, 2] += 1.0
        assert wide.write_wide(changed, quality) == 0
        assert _long_reference(long, changed, quality, policy="update") == 10
        assert wide.write_wide(changed, quality, policy="update") == 10
        a, b = _stored(wide, tags), _stored(long, tags)
        for t in tags:
            pd.testing.assert_frame_equal(a[t], b[t])


def test_wide_rows_out_of_order_keep_the_first_of_a_time(tmp_path):
    rng = np.random.default_rng(4)
    values, quality = _piece(rng, n=50)
    order = rng.permutation(50)
    shuffled, q = values.iloc[order], quality.iloc[order]
    twice = pd.concat([shuffled, shuffled.iloc[:5] + 100.0])
    with Historian(f"sqlite:///{tmp_path / 'h.db'}") as h:
        for t in values.columns:
            h.ensure_tag(t)
        h.write_wide(twice, pd.concat([q, q.iloc[:5]]))
        got = h.read_samples("C")
        pd.testing.assert_series_equal(
            got,
            values["C"].rename("C"),
            check_freq=False,
            check_index_type=False,
            check_names=False,
        )


def test_a_new_database_has_large_pages_an_old_one_keeps_its_own(tmp_path):
    new = tmp_path / "new.db"
    with Historian(f"sqlite:///{new}") as h:
        h.write_samples(
            pd.Series([1.0], index=pd.DatetimeIndex(["2025-01-01"], tz="UTC"), name="A")
        )
    with sqlite3.connect(new) as c:
        assert c.execute("PRAGMA page_size").fetchone()[0] == PAGE_BYTES > 4096
    # a database made before (SQLite's default 4 KiB pages): opened, imported into, read
    old = tmp_path / "old.db"
    with sqlite3.connect(old) as c:
        c.execute("PRAGMA page_size=4096")
        c.execute("PRAGMA journal_mode=WAL")
        c.execute("CREATE TABLE keep (x)")
    csv = tmp_path / "f.csv"
    idx = pd.date_range("2025-01-01", periods=300, freq="10s")
    pd.DataFrame({"A": np.arange(300.0), "B": 1.0}, index=idx.rename("ts")).to_csv(csv)
    with Historian(f"sqlite:///{old}") as h:
        assert import_file(h, csv, chunk_rows=100).written == 600
        assert import_file(h, csv, chunk_rows=100).written == 0
        np.testing.assert_array_equal(h.read_samples("A").to_numpy(), np.arange(300.0))
        assert h.integrity_check() == []
    with sqlite3.connect(old) as c:
        assert c.execute("PRAGMA page_size").fetchone()[0] == 4096


IMPORTER = textwrap.dedent(
    """
    import sys
    from historian import Historian
    from historian.importer import import_file

    url, csv = sys.argv[1], sys.argv[2]
    with Historian(url) as h:
        print("START", flush=True)
        import_file(h, csv, chunk_rows=2_000, hot=True)  # the samples table's pieces
    print("DONE", flush=True)
    """
)


def test_a_piece_is_one_transaction(tmp_path):
    """A piece of more samples than a ``write_samples`` batch (500,000) fails as a whole: a
    failure in its last tag leaves none of its tags stored (written as long batches, the
    first tags' rows stayed)."""
    n = 200_000
    idx = pd.date_range("2025-01-01", periods=n, freq="10s", tz="UTC", name="ts")
    values = pd.DataFrame({t: np.arange(n, dtype=np.float64) for t in "ABC"}, index=idx)
    quality = pd.DataFrame(GOOD, index=idx, columns=list("ABC"))
    with Historian(f"sqlite:///{tmp_path / 'h.db'}") as h:
        ids = [h.ensure_tag(t) for t in "ABC"]
        late = int(idx[150_000].value // 1000)
        with sqlite3.connect(tmp_path / "h.db") as c:
            c.execute(
                f"CREATE TRIGGER fail BEFORE INSERT ON samples WHEN NEW.tag_id = {ids[2]} "
                f"AND NEW.ts >= {late} BEGIN SELECT RAISE(ABORT, 'disk gone'); END"
            )
        with pytest.raises(Exception, match="disk gone"):
            h.write_wide(values, quality)
        assert all(len(h.read_samples(t)) == 0 for t in "ABC")
        with sqlite3.connect(tmp_path / "h.db") as c:
            c.execute("DROP TRIGGER fail")
        assert h.write_wide(values, quality) == 3 * n


def test_a_killed_import_leaves_whole_pieces(tmp_path):
    """After SIGKILL mid-import every tag holds the same times, a prefix of the file's, the
    database is sound, and importing again completes the file."""
    rows, tags = 100_000, [f"T{i}" for i in range(8)]
    csv = tmp_path / "f.csv"
    idx = pd.date_range("2025-01-01", periods=rows, freq="10s").rename("ts")
    data = np.arange(rows, dtype=np.float64)[:, None] + np.arange(len(tags))
    pd.DataFrame(data, index=idx, columns=tags).to_csv(csv)
    url = f"sqlite:///{tmp_path / 'h.db'}"
    proc = subprocess.Popen(
        [sys.executable, "-c", IMPORTER, url, str(csv)],
        stdout=subprocess.PIPE,
        text=True,
        cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
    )
    try:
        assert proc.stdout.readline().strip() == "START"
        db = tmp_path / "h.db-wal"
        deadline = time.monotonic() + 120
        while (not db.exists() or db.stat().st_size < 2_000_000) and time.monotonic() < deadline:
            time.sleep(0.01)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait(timeout=30)
    with Historian(url) as h:
        assert h.integrity_check() == []
        stored = [h.read_samples(t) for t in tags if t in set(h.tags()["name"])]
        assert stored and 0 < len(stored[0]) < rows
        first = stored[0].index
        assert len(stored) == len(tags)
        for s in stored[1:]:
            assert s.index.equals(first)  # no piece stored for some tags only
        np.testing.assert_array_equal(
            first.as_unit("us").asi8, idx[: len(first)].tz_localize("UTC").as_unit("us").asi8
        )
        report = import_file(h, csv)
        assert report.written == (rows - len(first)) * len(tags)
        assert len(h.read_samples("T7")) == rows


def test_write_wide_counts_alike_on_both_backends(historian):
    """PostgreSQL takes the piece as long rows: the same samples kept and rows counted."""
    values, quality = _piece(np.random.default_rng(5), n=300)
    expected = int((values.notna().to_numpy() | (quality.to_numpy() == BAD)).sum())
    for t in values.columns:
        historian.ensure_tag(t)
    assert historian.write_wide(values, quality) == expected
    assert historian.write_wide(values, quality) == 0
    changed = values.copy()
    changed.iloc[:7, 0] = -1.0  # A: 7 changed (a gap among them becomes a sample)
    new = int(values.iloc[:7, 0].isna().sum())
    assert historian.write_wide(changed, quality) == new
    assert historian.write_wide(changed, quality, policy="update") == 7 - new
    b = historian.read_samples("B", with_quality=True)
    assert (b["quality"] == BAD).sum() == (quality["B"] == BAD).sum()
    assert b["value"].isna().sum() == values["B"].isna().sum() > 0
    assert (historian.read_samples("A").iloc[:7] == -1.0).all()


def test_an_import_into_a_rolled_month_writes_only_what_is_new(historian, tmp_path):
    """A piece reaching a month rolled to the cold store goes as long rows past the cold
    file (``hot``: into the samples table; the default import merges it into the month's
    file, tests/test_import_cold.py): a re-import adds nothing, a changed value is a
    conflict, a new tag is added."""
    idx = pd.date_range("2024-01-31 23:00", periods=120, freq="1min").rename("ts")
    frame = pd.DataFrame({"A": np.arange(120.0), "B": 1.0}, index=idx)
    csv = tmp_path / "f.csv"
    frame.to_csv(csv)
    assert import_file(historian, csv, hot=True).written == 240
    assert historian.roll_months(before="2024-02-01") == ["2024-01"]
    assert import_file(historian, csv, hot=True).written == 0
    frame.iloc[3, 0] = -5.0  # in the rolled January
    frame["C"] = 2.0
    frame.to_csv(csv)
    r = import_file(historian, csv, hot=True)
    assert (r.written, r.conflicts) == (120, 1)
    assert r.first_conflict.tag == "A" and r.first_conflict.stored == 3.0
    assert historian.read_samples("A").iloc[3] == 3.0


def _sizes(monkeypatch) -> list[int]:
    """The rows of each ``write_wide`` an import makes, recorded as they go."""
    sizes: list[int] = []
    write = Historian.write_wide

    def recorded(self, values, quality, **kw):
        sizes.append(len(values))
        return write(self, values, quality, **kw)

    monkeypatch.setattr(Historian, "write_wide", recorded)
    return sizes


def _csv(path, tags, start, rows=450):
    idx = pd.date_range(start, periods=rows, freq="10s").rename("ts")
    data = np.arange(rows, dtype=np.float64)[:, None] + np.arange(len(tags))
    pd.DataFrame(data, index=idx, columns=tags).to_csv(path)
    return idx


def test_the_first_pieces_are_one_write_where_they_append(tmp_path, monkeypatch):
    """Where an import's samples land at the end of the (tag_id, ts) key (a new database,
    or tags newer than every stored sample's) its first FIRST_PIECE_FACTOR pieces are one
    write; into the middle of the key (tags holding samples) each piece is one write. The
    same samples are stored either way."""
    from historian.importer import FIRST_PIECE_FACTOR

    sizes = _sizes(monkeypatch)
    writes = {}
    with Historian(f"sqlite:///{tmp_path / 'h.db'}") as h:
        for name, tags, start in [
            ("new", ["A", "B"], "2025-01-01"),
            ("inside", ["A", "B"], "2025-02-01"),  # later times of the same tags
            ("new tags", ["C", "D"], "2025-01-01"),  # their ids end the key
        ]:
            sizes.clear()
            idx = _csv(tmp_path / "f.csv", tags, start)
            r = import_file(h, tmp_path / "f.csv", chunk_rows=100, hot=True)  # the table's
            assert r.written == 900
            assert sum(sizes) == 450
            writes[name] = list(sizes)
        pieces = len(writes["inside"])  # 450 rows in chunks of 100: 5 pieces or more
        assert pieces >= 5
        assert len(writes["new"]) == len(writes["new tags"]) == pieces - FIRST_PIECE_FACTOR + 1
        assert writes["new"][0] > max(writes["inside"])
        got = h.read_samples("D")
        np.testing.assert_array_equal(got.to_numpy(), np.arange(450.0) + 1)
        assert got.index.equals(
            idx.tz_localize("UTC").as_unit(got.index.unit)
        )  # pandas 2.x: us != ns
        assert len(h.read_samples("A")) == 900


def test_a_held_first_piece_is_written_before_an_unreadable_line_refuses_the_file(tmp_path):
    """The first piece waits for the second to be written with it; a line that cannot be
    read in the second chunk still leaves the rows before it stored, as the message says."""
    f = tmp_path / "f.csv"
    _csv(f, ["A"], "2025-01-01", rows=300)
    lines = f.read_text().splitlines()
    lines[159] += ",7"  # line 160: one field too many, in the second chunk of 100
    f.write_text("\n".join(lines) + "\n")
    with Historian(f"sqlite:///{tmp_path / 'h.db'}") as h:
        with pytest.raises(FileRefused, match=r"f.csv:160: .*the rows before it were imported"):
            import_file(h, f, chunk_rows=100)
        got = h.read_samples("A")
        assert 0 < len(got) < 158
        np.testing.assert_array_equal(got.to_numpy(), np.arange(len(got), dtype=np.float64))
