"""Readers of the SQLite historian's samples, side by side (issue 37): the four tags a
``diag train`` of bench_train reads (CV, P1, P2, F over six months at 10 s, 1.58 M rows a
tag), each read whole into numpy (int64 µs times, float64 values with NaN, int64 quality)
by

- ``adbc``: today's path (:class:`historian.backends.SqliteBulk`, the ADBC SQLite driver);
- ``connectorx``: ``cx.read_sql("sqlite://…", query, return_type="arrow")`` (Rust, rusqlite);
- ``duckdb``: DuckDB's SQLite scanner (``ATTACH … (TYPE sqlite)``), where installed;
- ``sqlite3``: the standard library's module, for scale.

connectorx and DuckDB are not dependencies of the project (neither earned its place, see
docs/reference/historian.md, "Speed"): ``pip install connectorx duckdb
duckdb-extension-sqlite-scanner`` into the venv to compare them; a reader not installed is
reported as failed.

Each reader runs in its own process (its peak memory is its own), reads the four tags
``--runs`` times and reports the least CPU time of a pass (``time.process_time``: all its
threads) and the process's peak resident memory; the arrays of each are compared with
adbc's bit for bit (NaN where NULL, quality codes, dtypes). ``--usable`` reads as a
training does (a Bad sample as NaN, no quality column).

    python benchmarks/bench_sqlite_read.py [--runs 3] [--db PATH] [--usable]
"""

from __future__ import annotations

import argparse
import json
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import add_scratch_args, scratch  # noqa: E402

TAGS4 = ("CV", "P1", "P2", "F")
READERS = ("adbc", "connectorx", "duckdb", "sqlite3")
LO, HI = -(2**62), 2**62  # the window: all of it


def build(db: Path) -> None:
    """bench_train's SQLite historian (its ``build``, the hot part only)."""
    from diag_plugin.simulate.valve import TAGS, simulate_valve
    from historian.store import Historian

    frame = simulate_valve(182.5, seed=4)[["CV", "P1", "P2", "T1", "X", "F"]]
    with Historian.open(f"sqlite:///{db}") as h:
        for name in frame.columns:
            h.ensure_tag(name, unit=TAGS[name].unit, lo=TAGS[name].lo, hi=TAGS[name].hi)
        n = h.write_samples(frame)
    print(f"built {db}: {n:,} samples")


def _query(tag_id: int, usable: bool) -> str:
    from historian.quality import BAD

    cols = f"ts, CASE WHEN quality < {BAD} THEN value END" if usable else "ts, value, quality"
    return (
        f"SELECT {cols} FROM samples WHERE tag_id = {tag_id} AND ts >= {LO} AND ts < {HI} "
        "ORDER BY ts"
    )


def _from_arrow(tb, usable: bool):
    import pyarrow as pa

    ts = tb.column(0).to_numpy().astype(np.int64, copy=False)
    value = tb.column(1).cast(pa.float64()).to_numpy(zero_copy_only=False)
    if usable:
        return ts, value, np.zeros(len(ts), np.int64)
    return ts, value, tb.column(2).to_numpy().astype(np.int64, copy=False)


def reader(name: str, db: Path, usable: bool):
    """A function of a tag id returning (ts, value, quality) read by ``name``."""
    if name == "adbc":
        from historian.backends import SqliteBulk

        bulk = SqliteBulk(db)
        return lambda t: bulk.read(t, LO, HI, usable=usable)
    if name == "connectorx":
        import connectorx as cx

        url = f"sqlite://{db.resolve()}"
        return lambda t: _from_arrow(
            cx.read_sql(url, _query(t, usable), return_type="arrow"), usable
        )
    if name == "duckdb":
        import duckdb

        con = duckdb.connect()
        try:  # the extension from PyPI (duckdb-extension-sqlite-scanner), else DuckDB's own
            import duckdb_extension_sqlite_scanner as ext

            found = Path(ext.__file__).parent.glob("extensions/*/sqlite_scanner.duckdb_extension")
            con.execute(f"LOAD '{next(found)}'")
        except ImportError:
            con.execute("LOAD sqlite")
        con.execute(f"ATTACH '{db}' AS h (TYPE sqlite, READ_ONLY)")
        return lambda t: _from_arrow(
            con.execute(
                _query(t, usable).replace("FROM samples", "FROM h.samples")
            ).fetch_arrow_table(),
            usable,
        )
    if name == "sqlite3":
        con = sqlite3.connect(db)

        def read(t):
            rows = con.execute(_query(t, usable)).fetchall()
            ts = np.fromiter((r[0] for r in rows), np.int64, len(rows))
            v = np.array([np.nan if r[1] is None else r[1] for r in rows], np.float64)
            q = np.zeros(len(rows), np.int64) if usable else np.fromiter(
                (r[2] for r in rows), np.int64, len(rows))  # fmt: skip
            return ts, v, q

        return read
    raise ValueError(name)


def _hwm_mb() -> float:
    """Peak resident memory of this process, MB (``VmHWM``: its own since exec, unlike
    ``ru_maxrss``, which keeps the forking parent's)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def child(name: str, db: Path, usable: bool, runs: int, out: Path) -> None:
    """One reader's process: its least CPU of a pass, peak RSS, arrays saved to ``out``."""
    con = sqlite3.connect(db)
    ids = [con.execute("SELECT id FROM tags WHERE name = ?", (t,)).fetchone()[0] for t in TAGS4]
    con.close()
    base = _hwm_mb()
    t = time.process_time()
    read = reader(name, db, usable)
    setup = time.process_time() - t
    best, arrays = float("inf"), None
    for _ in range(runs):
        arrays = None
        t = time.process_time()
        arrays = [read(i) for i in ids]
        best = min(best, time.process_time() - t)
    peak = _hwm_mb()
    np.savez(
        out,
        **{f"{k}{j}": a for j, arr in enumerate(arrays) for k, a in zip("tvq", arr, strict=True)},
    )
    print(json.dumps({"cpu": best, "setup": setup, "peak_mb": peak, "base_mb": base}))


def same(a: Path, b: Path) -> str:
    """'identical' or what differs between two readers' saved arrays."""
    x, y = np.load(a), np.load(b)
    for k in x.files:
        u, v = x[k], y[k]
        if u.dtype != v.dtype:
            return f"{k}: dtype {u.dtype} vs {v.dtype}"
        if u.shape != v.shape:
            return f"{k}: shape {u.shape} vs {v.shape}"
        if u.tobytes() != v.tobytes():  # bit for bit: NaN payloads and -0.0 too
            return f"{k}: {int((u.view(np.uint8) != v.view(np.uint8)).sum())} bytes differ"
    return "identical"


def floor(db: Path, cols: str) -> float:
    """Least CPU of three passes of SQLite visiting the four tags' rows and evaluating
    ``cols`` over them in C: what any reader through SQLite's row API pays before its own
    per-value work."""
    con = sqlite3.connect(db)
    con.execute("PRAGMA mmap_size=2147483648")
    q = "SELECT id FROM tags WHERE name = ?"
    ids = [con.execute(q, (t,)).fetchone()[0] for t in TAGS4]
    best = float("inf")
    for _ in range(3):
        t = time.process_time()
        for i in ids:
            con.execute(f"SELECT {cols} FROM samples WHERE tag_id = {i}").fetchall()
        best = min(best, time.process_time() - t)
    con.close()
    return best


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--db", default=None, help="the historian's file (built when missing; "
                    "default: one built in a scratch folder)")  # fmt: skip
    add_scratch_args(ap)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--usable", action="store_true")
    ap.add_argument("--readers", default=",".join(READERS))
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--out", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        child(args.child, Path(args.db), args.usable, args.runs, Path(args.out))
        return 0
    if args.db:
        return compare(Path(args.db), args)
    with scratch("bench_sqlite_read_", args.dir) as work:
        return compare(work / "h.db", args)


def compare(db: Path, args) -> int:
    """Each reader in its own process, then the table."""
    if not db.exists():
        build(db)
    rows = {}
    for name in args.readers.split(","):
        out = db.with_name(f"{db.stem}_{name}{'_u' if args.usable else ''}.npz")
        cmd = [sys.executable, __file__, "--db", str(db), "--runs", str(args.runs)]
        cmd += ["--child", name, "--out", str(out)] + (["--usable"] if args.usable else [])
        res = subprocess.run(cmd, capture_output=True, text=True)
        if res.returncode:
            print(f"  {name:11s} failed: {res.stderr.strip().splitlines()[-1]}")
            continue
        rows[name] = json.loads(res.stdout.strip().splitlines()[-1]) | {"out": out}
    ref = rows.get("adbc")
    print(f"four tags' {'usable (ts, value)' if args.usable else '(ts, value, quality)'} reads,"
          f" least CPU of {args.runs} passes; peak RSS of the process")  # fmt: skip
    for name, r in rows.items():
        vs = f"{ref['cpu'] / r['cpu']:5.2f} x faster" if ref else ""
        eq = same(ref["out"], r["out"]) if ref else ""
        print(
            f"  {name:11s} {r['cpu']:6.3f} s CPU (setup {r['setup']:.3f} s)  "
            f"peak {r['peak_mb']:4.0f} MB (before the reader {r['base_mb']:.0f})  {vs}  "
            f"vs adbc: {eq}"
        )
    print("SQLite's own visit of the same rows, no fetch (stdlib sqlite3, least of 3 passes):")
    for cols in ("count(*)", "total(ts), total(value)", "total(ts), total(value), total(quality)"):
        print(f"  {floor(db, cols):6.3f} s CPU  SELECT {cols}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
