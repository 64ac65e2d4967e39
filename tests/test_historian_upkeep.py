"""diag historian roll | check | vacuum on SQLite and PostgreSQL, the cold folder the database
remembers, the cold files' row groups and statistics, and a write racing a roll."""

from __future__ import annotations

import json
import time

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from helpers import run_diag
from sqlalchemy import insert

from diag_plugin.cli import main
from historian import Historian, coldstore, schema

# three months of two tags at 1 min (about 260,000 rows): enough for the room to show
IDX = pd.date_range("2024-01-01", "2024-04-01", freq="1min", inclusive="left", tz="UTC")


def frame() -> pd.DataFrame:
    rng = np.random.default_rng(3)
    return pd.DataFrame(
        {"A": np.cumsum(rng.normal(0, 1, len(IDX))), "B": rng.uniform(0, 10, len(IDX))},
        index=IDX,
    )


def diag(capsys, *args) -> tuple[int, str, str]:
    rc = main(list(args))
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.fixture
def filled(db_url, tmp_path):
    """(url, cold dir, frame) of a database holding frame(); SQLite's cold folder is its
    default beside the file, PostgreSQL's is given to the first roll."""
    with Historian(db_url) as h:
        h.write_samples(frame())
    cold = tmp_path / "diag.db.cold" if db_url.startswith("sqlite") else tmp_path / "cold"
    return db_url, cold, frame()


def test_roll_check_vacuum_from_the_cli(filled, capsys):
    url, cold, f = filled
    extra = [] if url.startswith("sqlite") else ["--cold-dir", str(cold)]
    rc, out, _ = diag(capsys, "--db", url, "historian", "roll", "--before", "2024-03", "--json",
                      *extra)  # fmt: skip
    doc = json.loads(out)
    assert rc == 0 and doc["rolled"] == ["2024-01", "2024-02"]
    assert doc["cold_months"] == ["2024-01", "2024-02"]
    n_rolled = int((f.index < "2024-03-01").sum()) * 2
    assert doc["cold_rows"] == n_rolled
    assert len(list(cold.glob("samples-*.parquet"))) == 2
    # the database remembers its cold folder: opened without it, reads see every row
    with Historian(url) as h:
        pd.testing.assert_series_equal(
            h.read_samples("A"), f["A"].rename_axis("ts"), check_freq=False
        )
        assert h.time_range(["B"]) == (IDX[0], IDX[-1])
    rc, out, _ = diag(capsys, "--db", url, "historian", "check")
    assert rc == 0 and out.startswith("sound:") and "2 rolled months" in out
    rc, out, _ = diag(capsys, "--db", url, "historian", "roll")  # March is closed too
    assert rc == 0 and "rolled 1 month(s) (2024-03)" in out
    rc, out, _ = diag(capsys, "--db", url, "historian", "roll")
    assert rc == 0 and out.startswith("no month before") and "2024-01 .. 2024-03" in out
    rc, out, _ = diag(capsys, "--db", url, "historian", "vacuum", "--json")
    v = json.loads(out)
    assert rc == 0 and v["backend"] in url
    if url.startswith("sqlite"):  # every row moved out: the file gives its room back
        assert v["statement"] == "VACUUM"
        assert v["after_bytes"] < 0.25 * v["before_bytes"]
    else:
        assert v["statement"] == "VACUUM (ANALYZE)"
    with Historian(url) as h:
        pd.testing.assert_frame_equal(
            h.window(["A", "B"], IDX[0], IDX[-1] + pd.Timedelta("1min"), "1min"),
            f.rename_axis("ts"),
            check_freq=False,
        )


@pytest.mark.postgres
def test_vacuum_full_gives_room_back_on_postgres(pg_url, tmp_path, capsys):
    with Historian(pg_url) as h:
        h.write_samples(frame())
    rc, _, err = diag(capsys, "--db", pg_url, "historian", "roll")
    assert rc == 2 and "--cold-dir" in err  # PostgreSQL has no default folder
    rc, out, _ = diag(capsys, "--db", pg_url, "historian", "roll", "--cold-dir",
                      str(tmp_path / "cold"))  # fmt: skip
    assert rc == 0 and "rolled 3 month(s)" in out
    assert "'diag historian vacuum' makes the room of the moved rows reusable" in out
    freed = 0
    for _ in range(3):  # a snapshot older than the roll (autovacuum's ANALYZE of the samples
        # just written, under a loaded suite) keeps the moved rows until it ends: again
        rc, out, _ = diag(capsys, "--db", pg_url, "historian", "vacuum", "--full", "--json")
        v = json.loads(out)
        assert rc == 0 and v["statement"] == "VACUUM (FULL, ANALYZE)"
        freed += v["before_bytes"] - v["after_bytes"]
        if freed > 10e6:
            break
        time.sleep(2.0)
    assert freed > 10e6  # the samples table was ~20 MB


def test_roll_then_vacuum_in_one_command_shrinks_the_sqlite_file(tmp_path):
    """As a user runs it: a subprocess; the file is measured on disk."""
    db = tmp_path / "diag.db"
    with Historian(f"sqlite:///{db}") as h:
        h.write_samples(frame())
    before = db.stat().st_size
    res = run_diag(tmp_path, "--db", f"sqlite:///{db}", "historian", "roll", "--vacuum")
    assert res.returncode == 0, res.stderr
    assert "rolled 3 month(s) (2024-01 .. 2024-03)" in res.stdout
    assert "VACUUM: " in res.stdout and "given back to the disk" in res.stdout
    assert db.stat().st_size < 0.25 * before
    wal = db.with_name("diag.db-wal")
    assert not wal.exists() or wal.stat().st_size == 0


def test_check_reports_a_broken_file_and_an_orphan(tmp_path, capsys):
    url = f"sqlite:///{tmp_path / 'diag.db'}"
    with Historian(url) as h:
        h.write_samples(frame())
        h.roll_months(before="2024-03-01")
        (feb,) = h.cold_dir.glob("samples-2024-02-*.parquet")
    feb.write_bytes(feb.read_bytes()[:1000])
    orphan = feb.with_name("samples-2024-03-1.parquet")
    orphan.write_bytes(b"left by a roll killed before it recorded the month")
    rc, out, _ = diag(capsys, "--db", url, "historian", "check")
    assert rc == 1
    assert f"{url}: cold segment 2024-02: " in out
    assert f"{orphan}: listed by no rolled month" in out
    assert "problems found" in out
    rc, out, _ = diag(capsys, "--db", url, "historian", "check", "--json")
    doc = json.loads(out)
    assert rc == 1 and not doc["ok"] and len(doc["problems"]) == 1
    assert doc["orphan_files"] == [str(orphan)]


@pytest.mark.parametrize(
    "month, message",
    [("2024-3", "not a month like 2024-03"), ("2024-13", "not a month"), ("2999-01", "after the")],
)
def test_roll_refuses_a_bad_month(tmp_path, capsys, month, message):
    rc, _, err = diag(capsys, "--db", f"sqlite:///{tmp_path / 'd.db'}", "historian", "roll",
                      "--before", month)  # fmt: skip
    assert rc == 2 and message in err


def test_a_database_rolled_into_one_folder_refuses_another(tmp_path):
    url = f"sqlite:///{tmp_path / 'diag.db'}"
    with Historian(url, cold_dir=tmp_path / "elsewhere") as h:
        h.write_samples(frame())
        assert h.roll_months(before="2024-02-01") == ["2024-01"]
    with Historian(url) as h:  # remembered
        assert h.cold_dir == (tmp_path / "elsewhere").resolve()
        assert len(h.read_samples("A")) == len(IDX)
    with Historian(url, cold_dir=tmp_path / "third") as h, pytest.raises(ValueError, match="keeps"):
        h.roll_months(before="2024-03-01")


# -- the cold files ------------------------------------------------------------------------


def test_row_groups_hold_one_tag_and_reads_decode_only_theirs(historian):
    """A month of 1 min data is ~44,600 rows per tag: at 10 s (267,840) a tag spans several
    row groups; a read of two days touches one or two of them and gives exact rows."""
    idx = pd.date_range("2024-01-01", "2024-02-01", freq="10s", inclusive="left", tz="UTC")
    f = pd.DataFrame({"A": np.arange(len(idx), dtype=float), "B": -1.0}, index=idx)
    historian.write_samples(f)
    historian.roll_months(before="2024-02-01")
    (path,) = historian.cold_dir.glob("samples-2024-01-*.parquet")
    index = coldstore.SegmentIndex.open(path)
    assert np.all(index.tag_lo == index.tag_hi)  # one tag per row group
    per_tag = -(-len(idx) // coldstore.ROW_GROUP_ROWS)
    assert index.metadata.num_row_groups == 2 * per_tag
    tag_a = historian._tag("A")[0]
    a, b = (pd.Timestamp(t, tz="UTC").value // 1000 for t in ("2024-01-10", "2024-01-12"))
    assert 1 <= len(index.groups(tag_a, a, b)) <= 2
    ts, v, _ = index.read(tag_a, a, b)
    assert len(ts) == 2 * 8640 and ts[0] == a and ts[-1] == b - 10_000_000
    np.testing.assert_array_equal(v, np.arange(9 * 8640, 11 * 8640, dtype=float))
    assert index.bounds(tag_a) == (int(idx[0].value // 1000), int(idx[-1].value // 1000))
    a, b = pd.Timestamp("2024-01-10 23:59:50", tz="UTC"), pd.Timestamp("2024-01-30", tz="UTC")
    expect = f["A"][(f.index >= a) & (f.index < b)].rename_axis("ts")
    pd.testing.assert_series_equal(historian.read_samples("A", a, b), expect, check_freq=False)


def test_a_file_of_the_earlier_layout_reads_the_same(historian):
    """Months rolled before row groups were split per tag and size: one row group mixing
    every tag, default encodings. Reads, time ranges and late writes still work."""
    f = frame()[frame().index < "2024-02-01"]
    historian.write_samples(f)
    ids = {name: historian._tag(name)[0] for name in ("A", "B")}
    # move January by hand into a file of the old layout
    tid, ts, v, q = [], [], [], []
    for name in sorted(ids, key=ids.get):
        s = historian.read_samples(name, with_quality=True)
        tid.append(np.full(len(s), ids[name]))
        ts.append(s.index.as_unit("us").asi8)
        v.append(s["value"].to_numpy())
        q.append(s["quality"].to_numpy())
    table = pa.table(
        {"tag_id": pa.array(np.concatenate(tid), pa.int32()), "ts": np.concatenate(ts),
         "value": np.concatenate(v), "quality": pa.array(np.concatenate(q), pa.int8())}
    )  # fmt: skip
    historian.cold_dir.mkdir(parents=True)
    pq.write_table(table, historian.cold_dir / "samples-2024-01-1.parquet", compression="zstd")
    with historian.engine.begin() as c:
        c.execute(schema.samples.delete())
        c.execute(
            insert(schema.cold_segments).values(
                month="2024-01", path="samples-2024-01-1.parquet", rows=table.num_rows,
                ts_min=int(table["ts"][0].as_py()), ts_max=int(table["ts"][-1].as_py()),
                created_at=0,
            )
        )  # fmt: skip
    pd.testing.assert_series_equal(
        historian.read_samples("A"), f["A"].rename_axis("ts"), check_freq=False
    )
    assert historian.time_range(["B"]) == (f.index[0], f.index[-1])
    assert historian.write_samples(f) == 0
    assert historian.integrity_check() == []


def test_a_write_during_a_roll_is_not_lost(historian, tmp_path):
    """Another connection writes a late sample into the month after the roll read it and
    before it deleted the month's rows: the roll notices (it would delete more rows than it
    read), undoes that try and rolls the month again with the sample."""
    historian.write_samples(frame())
    other = Historian(historian.url, cold_dir=historian.cold_dir)
    late = pd.Series([99.0], index=[pd.Timestamp("2024-01-15 00:00:30", tz="UTC")], name="B")
    read = historian._bulk.read
    b_id = historian._tag("B")[0]
    sent = []

    def read_then_write(tag_id, start, end):
        out = read(tag_id, start, end)
        if tag_id == b_id and not sent:  # the last tag of January has been read
            sent.append(other.write_samples(late))
        return out

    historian._bulk.read = read_then_write
    try:
        assert historian.roll_months(before="2024-02-01") == ["2024-01"]
    finally:
        historian._bulk.read = read
        other.close()
    assert sent == [1]
    got = historian.read_samples("B", "2024-01-15", "2024-01-15 00:02")
    assert got.tolist() == [frame()["B"].iloc[20160], 99.0, frame()["B"].iloc[20161]]
    assert len(list(historian.cold_dir.glob("*.parquet*"))) == 1  # the undone try's file went
    assert historian.integrity_check() == []


def test_training_reads_of_rolled_months_equal_the_full_window(historian):
    """What a training job reads (WindowReader: no summary, the rolled months through the
    row-group cache, chunk after chunk) equals one full window with its summary."""
    from historian.access import WindowReader

    historian.write_samples(frame())
    historian.roll_months(before="2024-03-01")  # March stays in the database
    whole = historian.window(["A", "B"], IDX[0], IDX[-1] + pd.Timedelta("1min"), "1min")
    assert set(whole.attrs["quality"]) == {"A", "B"}
    reader = WindowReader(historian.url, ("A", "B"), "1min")
    reader._h = Historian(historian.url, cold_dir=historian.cold_dir)
    edges = pd.date_range(IDX[0], IDX[-1] + pd.Timedelta("1min"), periods=8)
    try:
        parts = [reader(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True)]
    finally:
        reader.close()
    assert all(not p.attrs for p in parts)
    pd.testing.assert_frame_equal(pd.concat(parts), whole, check_freq=False)


def test_a_reader_given_the_open_historian_reads_through_it_and_leaves_it_open(historian):
    """A training job opens one historian for the data range, the reads and the record:
    the reader it is given reads through it (the same window as a reader of its own),
    closing the reader leaves it open, and a pickled reader (a Dask worker's) opens its own."""
    import pickle

    from historian.access import WindowReader

    historian.write_samples(frame())
    a, b = IDX[0], IDX[0] + pd.Timedelta("2D")
    given = WindowReader(historian.url, ("A", "B"), "1min", historian=historian)
    got = given(a, b)
    assert given._h is historian
    assert historian._pool is not None  # the reads ran on the given historian's threads
    given.close()
    assert historian._pool is not None, "closing the reader closed the given historian"
    copy = pickle.loads(pickle.dumps(given))
    assert copy.historian is None and copy._h is None
    try:
        pd.testing.assert_frame_equal(copy(a, b), got)
        assert copy._h is not historian
    finally:
        copy.close()
    assert copy._h is None
