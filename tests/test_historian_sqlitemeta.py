"""A SQLite historian's small metadata reads go through one ``sqlite3`` connection
(:mod:`historian.sqlitemeta`, issue 34 "Speed": ``diag diagnose`` no longer imports
SQLAlchemy): the answers are SQLAlchemy's, the reads are counted as reads of the file as
SQLAlchemy's were (a checkpoint and ``VACUUM`` wait for them; a forked child may not use
them), and neither ``import historian.store`` nor a replay of a unit imports SQLAlchemy.
Real files, real processes; the valve simulator on a seed used nowhere else (834)."""

from __future__ import annotations

import json
import multiprocessing as mp
import subprocess
import sys
import textwrap
import threading

import numpy as np
import pandas as pd
import pytest

from historian.store import Historian
from historian.times import to_us

#: prints whether SQLAlchemy was imported, after the code given as argv[1] ran
NO_SQLALCHEMY = textwrap.dedent(
    """
    import sys
    exec(sys.argv[1])
    print(json.dumps(sorted(m for m in sys.modules if m.split(".")[0] == "sqlalchemy")))
    """
)


def _sqlalchemy_modules(code: str, *argv: str) -> tuple[list[str], str]:
    res = subprocess.run(
        [sys.executable, "-c", "import json\n" + NO_SQLALCHEMY, code, *argv],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr
    lines = res.stdout.strip().splitlines()
    return json.loads(lines[-1]), "\n".join(lines[:-1])


def _populated(tmp_path) -> str:
    """A historian of three tags (one with a range and unit), two months of samples, the
    first month rolled to a cold folder recorded in the database (not the default one)."""
    url = f"sqlite:///{tmp_path / 'h.db'}"
    idx = pd.date_range("2026-01-20", "2026-02-10", freq="1h", tz="UTC", inclusive="left")
    rng = np.random.default_rng(834)
    frame = pd.DataFrame(
        {"A": rng.random(len(idx)), "B": rng.random(len(idx)), "C": np.arange(len(idx)) * 1.0},
        index=idx,
    )
    frame.loc[idx[:5], "C"] = np.nan  # C starts later
    with Historian(url, cold_dir=tmp_path / "cold") as h:
        h.ensure_tag("A", unit="bar", lo=0.0, hi=10.0, description="pressure", source="opc")
        h.ensure_tag("B", lo=-1.5)
        h.write_samples(frame)
        h.roll_months(pd.Timestamp("2026-02-01", tz="UTC"))
        h.ensure_tag("D")  # a tag without samples
    return url


def _sqlalchemy_reads(url: str) -> Historian:
    """The same historian with its metadata read through SQLAlchemy (as before)."""
    h = Historian(url)
    h._meta.close()
    h._meta = None
    return h


def test_importing_the_historian_does_not_import_sqlalchemy():
    found, _ = _sqlalchemy_modules("import historian.store, historian.coldmonths")
    assert found == []


def test_reading_a_sqlite_historian_does_not_import_sqlalchemy(tmp_path):
    """Open, list the tags, find their time range, read an aligned window (rolled months
    and the database), close: what ``diag diagnose`` does with the historian."""
    url = _populated(tmp_path)
    code = textwrap.dedent(
        """
        from historian.store import Historian
        with Historian(sys.argv[2]) as h:
            names = list(h.tags()["name"])
            lo, hi = h.time_range(["A", "C"])
            w = pd.concat(h.iter_windows(["A", "C"], lo, hi, "1h", chunk="3D", summary=False))
            print(names, lo, hi, w.shape, h.cold_months())
        """
    )
    found, out = _sqlalchemy_modules("import pandas as pd\n" + code, url)
    assert found == []
    assert out == (
        "['A', 'B', 'C', 'D'] 2026-01-20 00:00:00+00:00 2026-02-09 23:00:00+00:00 (503, 2) "
        "['2026-01']"
    )


def test_diagnose_on_sqlite_does_not_import_sqlalchemy(tmp_path, monkeypatch):
    """``diag diagnose`` of the example valve unit, start to end, in a process of its own."""
    from helpers import REPO

    from diag_plugin.simulate import simulate_valve

    monkeypatch.setenv("DIAG_MODEL_CACHE", str(tmp_path / "cache"))
    url = f"sqlite:///{tmp_path / 'h.db'}"
    with Historian(url) as h:
        h.write_samples(simulate_valve(1, seed=834))
    code = textwrap.dedent(
        """
        import contextlib, io
        from diag_plugin.cli import main
        with contextlib.redirect_stdout(io.StringIO()) as out:
            rc = main(sys.argv[2:])
        print(rc, json.loads(out.getvalue())["samples"])
        """
    )
    argv = ["--db", url, "--rulebases", str(REPO / "rulebases"), "diagnose", "valve_unit"]
    found, out = _sqlalchemy_modules(code, *argv, "--json")
    assert out == "0 8640"
    assert found == []


def test_metadata_answers_are_sqlalchemys(tmp_path):
    url = _populated(tmp_path)
    with Historian(url) as h, _sqlalchemy_reads(url) as ref:
        assert h._meta is not None and ref._meta is None
        pd.testing.assert_frame_equal(h.tags(), ref.tags())
        assert h.tags().dtypes.tolist() == ref.tags().dtypes.tolist()
        for name in ("A", "B", "C", "D"):
            assert h._tag(name) == ref._tag(name)
        with pytest.raises(KeyError):
            h._tag("nope")
        for tags in (None, ["A"], ["C"], ["A", "C"], ["D"], ["D", "B"]):
            assert h.time_range(tags) == ref.time_range(tags)
        assert h._segments(None, None) == ref._segments(None, None)
        m = to_us("2026-01-15")
        assert h._segments(m, m + 1) == ref._segments(m, m + 1) != []
        assert h._recorded_cold_dir() == ref._recorded_cold_dir() == (tmp_path / "cold")
        assert h.cold_dir == ref.cold_dir
        assert h.last_sample_tag() == ref.last_sample_tag() == 3
        w, r = (x.window(["A", "B", "C"], period="1h", summary=False) for x in (h, ref))
        pd.testing.assert_frame_equal(w, r)


def test_an_empty_historian_answers_alike(tmp_path):
    url = f"sqlite:///{tmp_path / 'new.db'}"
    with Historian(url) as h, _sqlalchemy_reads(url) as ref:
        pd.testing.assert_frame_equal(h.tags(), ref.tags())
        assert h.time_range() == ref.time_range() == (None, None)
        assert h._segments(None, None) == [] and h.cold_dir == ref.cold_dir
        assert h.last_sample_tag() == 0 and h.integrity_check() == []


@pytest.mark.parametrize(
    "url",
    ["sqlite:///diag.db", "sqlite:////tmp/x/h.db", "sqlite:///a b.db", "sqlite:///a:b@c#d.db"],
)
def test_plain_urls_read_as_sqlalchemy_reads_them(url):
    from sqlalchemy.engine import make_url

    from historian.sqlitemeta import sqlite_path

    assert sqlite_path(url) == make_url(url).database


@pytest.mark.parametrize(
    "url", ["sqlite:////tmp/a%20b.db", "sqlite:///x.db?timeout=5", "sqlite+pysqlite:///x.db"]
)
def test_other_urls_are_left_to_sqlalchemy(url):
    from historian.sqlitemeta import sqlite_path

    assert sqlite_path(url) is None


def test_the_schema_check_knows_every_table_and_index():
    from historian import schema
    from historian.sqlitemeta import INDEXES, TABLES

    assert set(schema.metadata.tables) == TABLES
    assert {i.name for t in schema.metadata.tables.values() for i in t.indexes} == INDEXES


def _paused_read(h: Historian, out: dict) -> tuple[threading.Thread, threading.Event]:
    """``h.tags()`` in a thread, paused inside its statement until the event is set."""
    inside, go = threading.Event(), threading.Event()

    def pause():
        if not inside.is_set():
            inside.set()
            go.wait(60)
        return 0

    h._meta.rows("SELECT 1")  # its connection opened, then paused inside the next read
    h._meta._conn.set_progress_handler(pause, 1)

    def run():
        try:
            out["names"] = list(h.tags()["name"])
        except Exception as exc:  # noqa: BLE001 - reported by the test
            out["error"] = exc

    t = threading.Thread(target=run)
    t.start()
    assert inside.wait(30)
    return t, go


def test_a_metadata_read_is_counted_and_a_checkpoint_waits_for_it(tmp_path):
    from historian.sqlitefile import DatabaseLocked

    url = _populated(tmp_path)
    with Historian(url) as h:
        out: dict = {}
        t, go = _paused_read(h, out)
        try:
            assert h._file._readers == 1
            with pytest.raises(DatabaseLocked):
                h._file.checkpoint(timeout_s=0.5)  # it waits for the read, which is open
        finally:
            go.set()
            t.join(60)
        assert out == {"names": ["A", "B", "C", "D"]} and h._file._readers == 0
        assert h._file.checkpoint(timeout_s=30)


def test_a_metadata_read_waits_while_a_checkpoint_runs(tmp_path):
    """A read starting while the process checkpoints waits for it (as SQLAlchemy's did)."""
    url = _populated(tmp_path)
    with Historian(url) as h:
        f = h._file
        with f._gate:
            f._checkpointing = True
        done = threading.Event()
        t = threading.Thread(target=lambda: (h.tags(), done.set()))
        t.start()
        assert not done.wait(1.0)  # held at the gate
        with f._gate:
            f._checkpointing = False
            f._gate.notify_all()
        t.join(60)
        assert done.is_set() and f._readers == 0


def _child(h: Historian, q) -> None:
    try:
        h.tags()
        q.put("read")
    except Exception as exc:  # noqa: BLE001 - reported to the parent
        q.put(type(exc).__name__)


def test_a_forked_child_may_not_read_its_parents_metadata_connection(tmp_path):
    url = _populated(tmp_path)
    with Historian(url) as h:
        h.tags()  # the connection is open in the parent
        ctx = mp.get_context("fork")
        q = ctx.Queue()
        p = ctx.Process(target=_child, args=(h, q))
        p.start()
        p.join(60)
        assert q.get(timeout=5) == "ForkedHistorian"
        assert list(h.tags()["name"]) == ["A", "B", "C", "D"]  # the parent's is unharmed


def test_closing_closes_the_metadata_connection(tmp_path):
    url = _populated(tmp_path)
    h = Historian(url)
    h.tags()
    conn = h._meta._conn
    h.close()
    assert h._meta._conn is None
    with pytest.raises(Exception, match="closed"):
        conn.execute("SELECT 1")
