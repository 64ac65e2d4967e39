"""Where a sample lands in the ``(tag_id, ts)`` key decides what SQLite's insert costs
(issue 37): the same wide pieces moved into ``samples`` as an import moves them
(``SqliteBulk.insert_wide``'s statements: one staged row per time, one ``INSERT … SELECT …
ON CONFLICT`` per tag), into a database where each tag's rows go

- ``append``: at the end of the whole key (a new table, the pieces staged together and moved
  tag after tag: each tag's rows follow the last stored row), or
- ``middle``: before another tag's rows (any piece after an import's first: tag k's new rows
  go between its earlier rows and tag k+1's; here a piece of a later tag, stored first,
  makes every insert land inside the key).

It prints the thread CPU per sample of staging, moving and committing, fastest of ``--runs``
in turns. SQLite finds an insert's place from the root of the key's tree unless it lands on
the key's last page, so inserts inside the key cost about twice the appends (0.62 against
0.31 µs a sample moved, load 6-9). An import appends in its first write on a new key (two
pieces joined: ``importer.FIRST_PIECE_FACTOR``); appending throughout would need a tag's
rows of the whole file moved at once: one transaction for the file (the write lock held
for all of it) or one per tag (tags of unequal length after a kill).

    python benchmarks/bench_insert_order.py [--rows 200000] [--tags 20] [--pieces 3]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow as pa

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import add_scratch_args, scratch  # noqa: E402

from historian.backends import SqliteBulk  # noqa: E402
from historian.store import Historian  # noqa: E402

T0 = 1_735_689_600_000_000  # 2025-01-01, µs


def run(db: Path, rows: int, tags: int, pieces: int, where: str) -> dict[str, float]:
    """Stage ``pieces`` wide pieces and move them tag by tag, one transaction per tag;
    returns thread CPU seconds per stage."""
    with Historian.open(f"sqlite:///{db}") as h:
        ids = [h.ensure_tag(f"T{j:02d}") for j in range(tags)]
        if where == "middle":  # a later tag's piece: the moves land before its rows
            h.write_samples(later_tag(f"T{tags:02d}", rows))
    bulk = SqliteBulk(db)
    cur = bulk.conn.cursor()
    rng = np.random.default_rng(7)
    cpu = {"stage": 0.0, "move": 0.0, "commit": 0.0}
    try:
        for k in range(pieces):
            ts = T0 + (np.arange(rows) + k * rows) * 10_000_000
            v = np.round(50 + rng.normal(0, 1, (tags, rows)), 4)
            cols = {"ts": pa.array(ts)} | {f"v{j}": pa.array(v[j]) for j in range(tags)}
            c = time.thread_time()
            cur.adbc_ingest("_wide", pa.table(cols), mode="create_append", temporary=True)
            cpu["stage"] += time.thread_time() - c
        for j in range(tags):
            cur.execute("BEGIN IMMEDIATE")
            c = time.thread_time()
            cur.execute(
                "INSERT INTO samples (tag_id, ts, value, quality) "
                f"SELECT {ids[j]}, ts, v{j}, 0 FROM temp._wide WHERE v{j} IS NOT NULL "
                "ON CONFLICT (tag_id, ts) DO NOTHING"
            )
            cpu["move"] += time.thread_time() - c
            c = time.thread_time()
            cur.execute("COMMIT")
            cpu["commit"] += time.thread_time() - c
    finally:
        cur.close()
        bulk.close()
    for p in db.parent.glob(db.name + "*"):
        p.unlink()
    return cpu


def later_tag(name: str, rows: int):
    """A piece of a tag whose id is above the moved tags' (as tag k+1's rows are for tag k's
    in an import's later pieces)."""
    import pandas as pd

    idx = pd.date_range("2025-01-01", periods=rows, freq="10s", tz="UTC")
    return pd.Series(np.ones(rows), index=idx, name=name)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=200_000, help="rows per piece")
    ap.add_argument("--tags", type=int, default=20)
    ap.add_argument("--pieces", type=int, default=3)
    ap.add_argument("--runs", type=int, default=3)
    add_scratch_args(ap)
    args = ap.parse_args(argv)
    n = args.rows * args.tags * args.pieces
    best: dict[str, dict[str, float]] = {}
    with scratch("bench_insert_order_", args.dir) as work:
        for i in range(args.runs):
            for where in ("append", "middle"):
                cpu = run(work / f"{where}{i}.db", args.rows, args.tags, args.pieces, where)
                old = best.get(where)
                if old is None or sum(cpu.values()) < sum(old.values()):
                    best[where] = cpu
    print(
        f"{n:,} samples ({args.pieces} pieces × {args.rows:,} rows × {args.tags} tags), "
        f"fastest of {args.runs} in turns, thread CPU µs a sample"
    )
    for where, cpu in best.items():
        parts = "  ".join(f"{k} {v / n * 1e6:.3f}" for k, v in cpu.items())
        print(f"  {where:7s} {parts}  total {sum(cpu.values()) / n * 1e6:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
