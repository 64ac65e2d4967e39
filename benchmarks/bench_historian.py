"""Historian speed: ingest into SQLite, one tag-month read, a 3-tag window, rolling to the
Parquet cold store, vacuum, and the same reads from Parquet.

Default scale is the product target: 6 months × 20 tags at 10 s (31 M samples), which needs
about 1.5 GB of temporary disk. ``--months 1`` for a quick look. Prints figures; exits 1 if a
target is missed with ``--check``.

    python benchmarks/bench_historian.py [--months 6] [--tags 20] [--dir /tmp] [--check]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import add_scratch_args, exit_status, fastest, scratch  # noqa: E402

from historian import Historian  # noqa: E402

TARGET_INGEST = 300_000  # samples/s
TARGET_TAG_MONTH = 0.2  # s
TARGET_WINDOW3 = 1.5  # s


def month_frame(start: pd.Timestamp, tags: list[str], rng: np.random.Generator) -> pd.DataFrame:
    end = start + pd.offsets.MonthBegin(1)
    idx = pd.date_range(start, end, freq="10s", inclusive="left", tz="UTC")
    t = np.arange(len(idx), dtype=np.float64)
    data = {
        name: 50 + 20 * np.sin(t / (500 + 37 * i)) + rng.normal(0, 1, len(idx))
        for i, name in enumerate(tags)
    }
    return pd.DataFrame(data, index=idx)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--months", type=int, default=6)
    ap.add_argument("--tags", type=int, default=20)
    add_scratch_args(ap)
    args = ap.parse_args(argv)
    ok = True
    with scratch("bench_historian_", args.dir) as tmp:
        url = f"sqlite:///{tmp / 'bench.db'}"
        tags = [f"T{i:02d}" for i in range(args.tags)]
        months = pd.date_range("2024-01-01", periods=args.months, freq="MS", tz="UTC")
        rng = np.random.default_rng(1)
        with Historian.open(url) as h:
            written, busy = 0, 0.0
            for m in months:
                frame = month_frame(m, tags, rng)  # generation not timed
                t = time.perf_counter()
                written += h.write_samples(frame)
                busy += time.perf_counter() - t
            rate = written / busy
            print(
                f"ingest: {written:,} samples in {busy:.1f} s = {rate:,.0f} samples/s "
                f"(target {TARGET_INGEST:,})"
            )
            ok &= rate >= TARGET_INGEST
            m0, m1 = months[1] if len(months) > 1 else months[0], None
            m1 = m0 + pd.offsets.MonthBegin(1)
            dt, s = fastest(lambda: h.read_samples(tags[0], m0, m1))
            print(
                f"read one tag-month (SQLite): {len(s):,} rows in {dt:.3f} s "
                f"(target {TARGET_TAG_MONTH})"
            )
            ok &= dt < TARGET_TAG_MONTH
            start, end = months[0], months[-1] + pd.offsets.MonthBegin(1)
            three = tags[:3]
            dt, w = fastest(lambda: h.window(three, start, end, "10s"), runs=2)
            print(
                f"window 3 tags × {args.months} months (SQLite): {w.shape[0]:,} rows "
                f"in {dt:.3f} s (target {TARGET_WINDOW3})"
            )
            ok &= dt < TARGET_WINDOW3
            t = time.perf_counter()
            n = sum(len(c) for c in h.iter_windows(three, start, end, "10s", chunk="30D"))
            print(
                f"iter_windows 3 tags, 30-day chunks: {n:,} rows in {time.perf_counter() - t:.3f} s"
            )
            t = time.perf_counter()
            rolled = h.roll_months(before=end)
            store = h.storage()
            print(
                f"roll {len(rolled)} months to Parquet: {time.perf_counter() - t:.1f} s; "
                f"{store['cold_bytes'] / 1e6:.0f} MB of files; the database "
                f"{store['db_bytes'] / 1e6:.0f} MB, {store['free_bytes'] / 1e6:.0f} MB of it free"
            )
            t = time.perf_counter()
            v = h.vacuum()
            print(
                f"vacuum: {v['before_bytes'] / 1e6:.0f} -> {v['after_bytes'] / 1e6:.1f} MB in "
                f"{time.perf_counter() - t:.1f} s"
            )
            dt, rng = fastest(lambda: h.time_range(three))
            print(f"time_range of 3 rolled tags (row-group statistics): {dt * 1e3:.1f} ms")
            dt, s2 = fastest(lambda: h.read_samples(tags[0], m0, m1))
            print(f"read one tag-month (Parquet cold store): {len(s2):,} rows in {dt:.3f} s")
            assert s2.equals(s), "cold read differs from hot read"
            dt, w2 = fastest(lambda: h.window(three, start, end, "10s"), runs=2)
            print(f"window 3 tags × {args.months} months (Parquet): {dt:.3f} s")
            assert w2.equals(w), "cold window differs from hot window"
            t = time.perf_counter()
            n = sum(
                len(c) for c in h.iter_windows(three, start, end, "10s", chunk="7D", summary=False)
            )
            print(
                f"iter_windows 3 tags, 7-day chunks, no summary (Parquet): {n:,} rows in "
                f"{time.perf_counter() - t:.3f} s"
            )
    print("all targets met" if ok else "TARGET MISSED")
    return exit_status(ok, args.check)


if __name__ == "__main__":
    sys.exit(main())
