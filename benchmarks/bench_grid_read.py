"""The grid read of ``diag diagnose`` alone (issue 34, "Speed"): every tag of the historian
``bench_diagnose_cli.py`` writes (``--dir``, made there first), its window from its first
sample on, read as :meth:`historian.backends.SqliteBulk.read_grid` reads a regular series
(its values alone, one per grid point) — by this checkout's query and by the query before
round twelve (the grid's test first, ``(ts − t0) % P``), pass by pass alternately in one
process, on one ADBC connection each. Prints each query's CPU seconds of a pass over all
tags (``time.thread_time``: the driver runs in the calling thread), least and median of
``--runs``, ns a value, and checks that both give the same arrays bit for bit (NaN where
Bad or NULL).

Round twelve (branch ``i34-speed``), 48 tags × 200,000 rows, 7 passes each at a load of
~15 on the 2 cores: see docs/how-to/unit-short-windows.md, "round twelve".

    python benchmarks/bench_grid_read.py --dir /tmp/diagcli [--runs 7]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def old_query(tag_id: int, t0: int, period: int, n: int) -> str:
    """The query of ``read_grid`` before round twelve (kept here to compare with)."""
    from historian.quality import BAD

    half = period // 2
    lo, hi = t0 - half, t0 + n * period - half
    return (
        f"SELECT CASE WHEN (ts - {int(t0)}) % {int(period)} THEN 9e999 "
        f"WHEN quality < {BAD} THEN value END FROM samples "
        f"WHERE tag_id = {int(tag_id)} AND ts >= {int(lo)} AND ts < {int(hi)} ORDER BY ts"
    )


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--dir", required=True, help="bench_diagnose_cli.py's folder (kept)")
    ap.add_argument("--runs", type=int, default=7)
    a = ap.parse_args()
    import pyarrow as pa

    from historian.backends import SqliteBulk
    from historian.store import Historian
    from historian.times import period_us, to_us

    db = Path(a.dir).resolve() / "h.db"
    if not db.exists():
        raise SystemExit(f"{db} missing: run bench_diagnose_cli.py --dir {a.dir} first")
    with Historian.open(f"sqlite:///{db}") as h:
        names = list(h.tags()["name"])
        first, last = h.time_range(names)
        ids = [h._tag(t)[0] for t in names]
    p = period_us("180s")
    t0, n = to_us(first), (to_us(last) - to_us(first)) // p + 1
    new, old = SqliteBulk(db), SqliteBulk(db)

    def now(i: int) -> np.ndarray | None:
        return new.read_grid(i, t0, p, n)

    def before(i: int) -> np.ndarray | None:
        tb = old.fetch(old_query(i, t0, p, n))
        if tb.num_rows != n:
            return None
        v = tb.column(0).cast(pa.float64()).to_numpy(zero_copy_only=False)
        return None if np.isinf(v).any() else v

    for i in ids:  # the same arrays, bit for bit (and the pages mapped once)
        x, y = now(i), before(i)
        assert x is not None and y is not None, f"tag {i}: not a regular series"
        np.testing.assert_array_equal(x.view(np.int64), y.view(np.int64))
    took: dict[str, list[float]] = {"before": [], "now": []}
    for _ in range(a.runs):
        for key, f in (("before", before), ("now", now)):
            t = time.thread_time()
            for i in ids:
                f(i)
            took[key].append(time.thread_time() - t)
    values = len(ids) * n
    print(f"{len(ids)} tags × {n:,} rows ({values:,} values), {a.runs} passes each")
    for key, ts in took.items():
        med = statistics.median(ts)
        print(
            f"{key:>6}: least {min(ts):.3f} CPU s, median {med:.3f} "
            f"({med / values * 1e9:.0f} ns a value)"
        )
    ratio = statistics.median(x / y for x, y in zip(took["now"], took["before"], strict=True))
    print(f"  pairs' median ratio now / before {ratio:.3f}")
    new.close()
    old.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
