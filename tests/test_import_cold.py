"""``diag import`` stores the samples of closed months straight into the cold store's month
files (issue 37): the same reads, counts and conflicts as the samples table gives (``hot``,
the old path), on both backends; a month file merged with what the month already held; a
killed import leaves whole months and a re-run ends identical; the current month stays in the
table."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from sqlalchemy import func, select

from historian import Historian, schema
from historian.importer import import_file

MONTH0 = pd.Timestamp.now(tz="UTC").normalize().replace(day=1)  # the current month


def hot_rows(h: Historian) -> int:
    with h.engine.connect() as c:
        return c.execute(select(func.count()).select_from(schema.samples)).scalar_one()


def export(path: Path, start, periods: int, freq="10min", seed=3, bad=True) -> pd.DataFrame:
    """A wide CSV with gaps, a text cell (a Bad sample) and an out-of-float32 number."""
    rng = np.random.default_rng(seed)
    idx = pd.date_range(start, periods=periods, freq=freq, tz="UTC")
    frame = pd.DataFrame(
        {
            "A": np.round(rng.normal(50, 5, periods), 4),
            "B": np.round(np.cumsum(rng.normal(0, 1, periods)), 3),
            "C": np.arange(periods, dtype=float),
        },
        index=pd.Index(idx, name="ts"),
    )
    frame.loc[frame.index[5:40], "B"] = np.nan  # a gap
    out = frame.astype(object)
    if bad:
        out.iloc[7, 0] = "Bad"
        out.iloc[periods // 2, 2] = "1e39"
    out.to_csv(path, date_format="%Y-%m-%dT%H:%M:%S")
    return frame


def state(h: Historian, tags=("A", "B", "C")):
    """Everything a reader sees: raw samples with quality, an aligned window, the range."""
    out = {t: h.read_samples(t, with_quality=True) for t in tags}
    lo, hi = h.time_range(list(tags))
    out["range"] = (lo, hi)
    out["window"] = h.window(list(tags), lo, hi, period="10min", summary=False)
    return out


def assert_same(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for k in a:
        if k == "range":
            assert a[k] == b[k]
            continue
        pd.testing.assert_frame_equal(a[k], b[k], check_exact=True)


def report_figures(r) -> tuple:
    first = r.first_conflict.describe() if r.first_conflict else None
    return (r.rows, r.samples, r.new, r.already, r.conflicts, first, r.repeats, r.tags)


@pytest.fixture
def pair(db_url, tmp_path, request):
    """Two fresh historians of the backend: ``cold`` (the import's default) and ``hot``
    (``hot=True``, the old path: everything in the samples table)."""
    urls = [db_url]
    if db_url.startswith("sqlite"):
        urls.append(f"sqlite:///{tmp_path / 'hot.db'}")
    else:
        urls.append(request.getfixturevalue("pg_url2"))
    cold = Historian(urls[0], cold_dir=tmp_path / "cold")
    hot = Historian(urls[1], cold_dir=tmp_path / "cold-of-hot")
    try:
        yield cold, hot
    finally:
        cold.close()
        hot.close()


def test_closed_months_cold_current_month_hot_reads_identical(pair, tmp_path):
    cold, hot = pair
    start = MONTH0 - pd.Timedelta(days=40)
    periods = int(pd.Timedelta(days=41) / pd.Timedelta("10min"))  # into the current month
    export(tmp_path / "f.csv", start, periods)
    rc = import_file(cold, tmp_path / "f.csv")
    rh = import_file(hot, tmp_path / "f.csv", hot=True)
    assert report_figures(rc) == report_figures(hot_report := rh)
    assert hot_report.cold_months == []
    first, last = start.tz_localize(None), MONTH0.tz_localize(None) - pd.Timedelta(seconds=1)
    closed = [str(p) for p in pd.period_range(first, last, freq="M")]
    assert rc.cold_months == closed
    assert cold.cold_months() == closed
    current = int(pd.Timedelta(days=1) / pd.Timedelta("10min"))
    assert hot_rows(cold) == 3 * current  # only the current month's samples in the table
    assert hot_rows(hot) == rh.written
    assert_same(state(cold), state(hot))
    assert cold.integrity_check() == []
    # tags' coverage report alike
    pd.testing.assert_frame_equal(cold.tag_report(), hot.tag_report(), check_exact=True)
    # again: nothing new, nothing rewritten
    files = sorted(p.name for p in (tmp_path / "cold").glob("*.parquet"))
    again = import_file(cold, tmp_path / "f.csv")
    assert (again.new, again.already, again.conflicts, again.cold_months) == (0, rc.samples, 0, [])
    assert sorted(p.name for p in (tmp_path / "cold").glob("*.parquet")) == files


@pytest.mark.parametrize("policy", ["ignore", "update"])
def test_conflicts_against_rolled_month_and_hot_rows(pair, tmp_path, policy):
    """A month already rolled plus a late row of it in the table; a second file overlapping
    it with other values: the same counts, first conflict and reads as the table path."""
    cold, hot = pair
    start = MONTH0 - pd.Timedelta(days=70)
    export(tmp_path / "a.csv", start, 3000)
    export(tmp_path / "b.csv", start + pd.Timedelta(days=10), 6000, seed=9)
    late = pd.Series(
        [123.0], index=[start + pd.Timedelta(days=12, minutes=5)], name="A"
    )  # between the 10 min samples: new in both
    clash = pd.Series([-1.0], index=[start + pd.Timedelta(days=12, minutes=10)], name="C")
    for h, flag in ((cold, False), (hot, True)):
        import_file(h, tmp_path / "a.csv", hot=flag)
        if not flag:
            assert cold.cold_months()  # the first file's months are files
            assert hot_rows(cold) == 0
        h.write_samples(late)  # a late sample: into the table, beside the rolled month
        h.write_samples(clash, policy="update")  # a stored one changed in the table
    assert hot_rows(cold) == 2
    rc = import_file(cold, tmp_path / "b.csv", policy=policy)
    rh = import_file(hot, tmp_path / "b.csv", policy=policy, hot=True)
    assert rc.conflicts > 0
    assert report_figures(rc) == report_figures(rh)
    assert rc.written == rh.written
    assert_same(state(cold), state(hot))
    assert hot_rows(cold) == 0  # the month's table rows went into its file with it
    assert cold.integrity_check() == [] and cold.cold_orphans() == []


@pytest.mark.parametrize("duplicates", ["first", "last", "mean"])
def test_repeated_times_in_a_closed_month(pair, tmp_path, duplicates):
    cold, hot = pair
    idx = pd.date_range(MONTH0 - pd.Timedelta(days=50), periods=500, freq="1h", tz="UTC")
    idx = idx.repeat(2)  # every time twice, the values differ
    frame = pd.DataFrame({"A": np.arange(len(idx), dtype=float), "B": 1.0}, index=idx)
    frame.index.name = "ts"
    frame.to_csv(tmp_path / "d.csv", date_format="%Y-%m-%dT%H:%M:%S")
    rc = import_file(cold, tmp_path / "d.csv", duplicates=duplicates)
    rh = import_file(hot, tmp_path / "d.csv", duplicates=duplicates, hot=True)
    assert rc.cold_months and report_figures(rc) == report_figures(rh)
    assert_same(state(cold, ("A", "B")), state(hot, ("A", "B")))


def test_hot_flag_and_postgres_without_cold_folder(tmp_path, request):
    """--hot keeps everything in the table; PostgreSQL without a cold folder does too, and
    says so in the report's notes."""
    export(tmp_path / "f.csv", MONTH0 - pd.Timedelta(days=40), 1000, bad=False)
    with Historian(f"sqlite:///{tmp_path / 'h.db'}") as h:  # SQLite: <db>.cold by default
        r = import_file(h, tmp_path / "f.csv", hot=True)
        assert r.cold_months == [] and hot_rows(h) == r.written == 2965  # 35 B cells empty
    with Historian(f"sqlite:///{tmp_path / 'c.db'}") as h:
        r = import_file(h, tmp_path / "f.csv")
        assert r.cold_months and hot_rows(h) == 0
        assert Path(r.cold_dir) == tmp_path / "c.db.cold"
    if not request.getfixturevalue("pg_available"):
        pytest.skip("PostgreSQL not reachable")
    with Historian(request.getfixturevalue("pg_url")) as h:
        r = import_file(h, tmp_path / "f.csv")
        assert r.cold_months == [] and hot_rows(h) == 2965
        assert r.no_cold_folder and "no cold folder" in r.stored_where()


def _months_whole(h: Historian, full: dict[str, pd.DataFrame]) -> list[str]:
    """The months of the reference that ``h`` holds, each checked whole or absent."""
    held = []
    for month in sorted({str(p) for p in full["A"].index.tz_localize(None).to_period("M")}):
        m0 = pd.Timestamp(month + "-01", tz="UTC")
        m1 = m0 + pd.offsets.MonthBegin(1)
        parts = {t: h.read_samples(t, m0, m1, with_quality=True) for t in full}
        sizes = {len(p) for p in parts.values()}
        if sizes == {0}:
            continue
        for t, p in parts.items():  # no half month
            ref = full[t][(full[t].index >= m0) & (full[t].index < m1)]
            pd.testing.assert_frame_equal(p, ref, check_exact=True)
        held.append(month)
    return held


@pytest.mark.slow
def test_killed_import_leaves_whole_months_and_rerun_ends_identical(db_url, tmp_path):
    start = MONTH0 - pd.offsets.MonthBegin(4)
    periods = int((MONTH0 - start) / pd.Timedelta("20s"))
    export(tmp_path / "big.csv", start, periods, freq="20s", bad=False)
    ref_url = f"sqlite:///{tmp_path / 'ref.db'}"
    with Historian(ref_url) as ref:
        import_file(ref, tmp_path / "big.csv", hot=True)
        full = {t: ref.read_samples(t, with_quality=True) for t in ("A", "B", "C")}
    cold_dir = tmp_path / "cold"
    with Historian(db_url, cold_dir=cold_dir) as h:  # the folder recorded in the database
        h._record_cold_dir()
    env = {k: v for k, v in os.environ.items() if not k.startswith("DIAG_")}
    cmd = [sys.executable, "-m", "diag_plugin", "--db", db_url, "import", "--no-progress"]
    proc = subprocess.Popen(
        [*cmd, "--cold-dir", str(cold_dir), str(tmp_path / "big.csv")],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    with Historian(db_url, cold_dir=cold_dir) as h:
        deadline = time.monotonic() + 300
        while not h.cold_months() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert proc.poll() is None, "the import ended before a month was written"
        os.kill(proc.pid, signal.SIGKILL)  # mid-import: the next months being read
        proc.wait()
        assert proc.returncode == -signal.SIGKILL
    with Historian(db_url) as h:  # the recorded folder found again
        assert h.integrity_check() == []
        held = _months_whole(h, full)
        assert 1 <= len(held) < 4 and h.cold_months() == held
        assert hot_rows(h) == 0
        r = import_file(h, tmp_path / "big.csv")
        end = pd.Timestamp(held[-1] + "-01", tz="UTC") + pd.offsets.MonthBegin(1)
        assert r.already == sum(int((full[t].index < end).sum()) for t in full)
        assert _months_whole(h, full) == sorted(set(held) | set(r.cold_months))
        assert len(_months_whole(h, full)) == 4
        for t, ref in full.items():
            pd.testing.assert_frame_equal(
                h.read_samples(t, with_quality=True), ref, check_exact=True
            )
        assert h.integrity_check() == []
        for orphan in h.cold_orphans():  # a file written but not recorded at the kill
            orphan.unlink()


def test_the_cli_says_where_closed_months_went(tmp_path, capsys):
    from diag_plugin.cli import main

    export(tmp_path / "f.csv", MONTH0 - pd.Timedelta(days=40), 1000, bad=False)
    db = f"sqlite:///{tmp_path / 'h.db'}"
    assert main(["--db", db, "import", "--hot", str(tmp_path / "f.csv")]) == 0
    out = capsys.readouterr().out
    assert "2965 new samples" in out and "Parquet" not in out
    assert main(["--db", db, "import", "--json", str(tmp_path / "g.csv")]) == 2  # no file
    capsys.readouterr()
    export(tmp_path / "g.csv", MONTH0 - pd.Timedelta(days=40), 1000, bad=False, seed=4)
    assert main(["--db", db, "import", "--replace", str(tmp_path / "g.csv")]) == 0
    out = capsys.readouterr().out
    month = (MONTH0 - pd.Timedelta(days=40)).strftime("%Y-%m")
    assert f"closed months {month} stored as Parquet month files in {tmp_path}" in out
    assert "0 new samples, 1000 already stored, 1965 replaced" in out  # A, B differ; C not
    with Historian(db) as h:
        assert hot_rows(h) == 0 and h.cold_months()
