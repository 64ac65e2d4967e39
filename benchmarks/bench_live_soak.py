"""Memory soak of the live plug-in at plant size (issue 35, item 7): 5,000 tags for 30+ minutes.

The plant of ``bench_live.py`` (a Modbus PLC in a child process serving 5,000 float32 tags
that move every second, 100 copies of the example valve unit, a SQLite historian written in
the background every 20 cycles, OPC UA and Modbus outputs) runs for ``--duration`` seconds
inside this process, so that its memory can be watched from the loop's own ``after`` hook:
each minute the resident set size (``/proc/self/statm``), the number of objects the garbage
collector tracks and, with ``--trace``, the bytes traced by ``tracemalloc`` (one frame per
allocation; it slows the loop, so it is off by default) are printed. After the
warm-up (``--warmup``, default 5 minutes: the stale limits, SQLite's page cache and the
units' histories fill up in it) both must stay within 5 % of their warm-up level, else the
benchmark fails; the growth per hour and, at the end, the ten source lines whose traced
memory grew most since the warm-up are printed to name a cause.

    nice -n 10 python benchmarks/bench_live_soak.py [--duration 1860] [--warmup 300]
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import os
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_live import N_TAGS, N_UNITS, PLC, build, free_port, plant_toml  # noqa: E402

TOLERANCE = 0.05


def rss_mb() -> float:
    """Resident set size of this process, MB."""
    with open("/proc/self/statm", encoding="ascii") as f:
        pages = int(f.read().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def sqlite_mb() -> float:
    """Memory the system's libsqlite3 holds (``sqlite3_memory_used``), MB; NaN when it
    cannot be reached. The historian's ADBC driver bundles its own SQLite, not counted here
    (its page cache is measured by ``--sqlite-cache``)."""
    import ctypes

    try:
        lib = ctypes.CDLL("libsqlite3.so.0")
        lib.sqlite3_memory_used.restype = ctypes.c_int64
        return lib.sqlite3_memory_used() / 2**20
    except (OSError, AttributeError):
        return float("nan")


def malloc_trim() -> bool:
    """Hand the C heap's free pages back to the system (glibc ``malloc_trim(0)``)."""
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("c")
    if not name:
        return False
    try:
        return bool(ctypes.CDLL(name).malloc_trim(0))
    except (OSError, AttributeError):
        return False


def soak(
    duration: float, warmup: float, every: float, trim_probe: bool = False, trace: bool = False
) -> int:
    from diag_plugin.live.config import load_config, run_config

    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    samples: list[tuple[float, float, float]] = []  # (s since start, RSS MB, traced MB)
    state: dict = {"next": 0.0, "base": None}
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        rb, csv = build(d)
        plc_port = free_port()
        cfg_path = plant_toml(d, plc_port)
        plc = subprocess.Popen(
            [sys.executable, "-c", PLC, str(plc_port), str(csv), str(d / "rows.parquet")],
            stdout=subprocess.PIPE,
            text=True,
            env=env,
        )
        log = open(d / "events.log", "w", encoding="utf-8")  # noqa: SIM115 - closed below
        try:
            assert plc.stdout is not None and plc.stdout.readline().strip() == "ready"

            async def after(loop, i, statuses) -> None:
                if "t0" not in state:  # from the first cycle: start-up is not measured
                    state["t0"] = time.monotonic()
                    if trace:
                        tracemalloc.start(1)
                t = time.monotonic() - state["t0"]
                if t < state["next"]:
                    return
                state["next"] = t + every
                traced = tracemalloc.get_traced_memory()[0] / 2**20 if trace else 0.0
                gc_objects = len(gc.get_objects())
                samples.append((t, rss_mb(), traced))
                st = loop.stats
                if trim_probe:  # is the growth free heap not given back? trim, measure again
                    malloc_trim()
                    print(f"         after malloc_trim: RSS {rss_mb():7.1f} MB", flush=True)
                print(
                    f"{t / 60:5.1f} min  cycle {st.cycles:5d}  RSS {samples[-1][1]:7.1f} MB  "
                    f"traced {traced:7.1f} MB  libsqlite3 {sqlite_mb():6.1f} MB  "
                    f"{gc_objects} objects  overruns {st.overruns}  "
                    f"backlog {loop.historian.backlog if loop.historian else 0}",
                    flush=True,
                )
                if trace and state["base"] is None and t >= warmup:
                    state["base"] = tracemalloc.take_snapshot()

            os.chdir(d)
            cfg = load_config(cfg_path)
            rc = asyncio.run(run_config(cfg, duration=duration, tty=False, out=log, after=after))
            end_snap = tracemalloc.take_snapshot() if trace else None
        finally:
            log.close()
            plc.kill()
            plc.wait()
            os.chdir("/")
        summary = [
            ln for ln in (d / "events.log").read_text().splitlines() if "stopped after" in ln
        ]
    print(summary[-1] if summary else f"no summary line (exit {rc})")
    after_warm = [s for s in samples if s[0] >= warmup]
    if rc != 0 or len(after_warm) < 3:
        print(f"too short: {len(after_warm)} samples after the {warmup:.0f} s warm-up")
        return 1
    ok = True
    for col, what in ((1, "RSS"), (2, "traced (tracemalloc)"))[: 1 + trace]:
        base = max(after_warm[0][col], 1e-9)
        vals = [s[col] for s in after_warm]
        span_h = (after_warm[-1][0] - after_warm[0][0]) / 3600
        dev = max(abs(v - base) for v in vals) / base
        print(
            f"{what}: {base:.1f} MB after {after_warm[0][0] / 60:.1f} min warm-up, "
            f"{vals[-1]:.1f} MB at {after_warm[-1][0] / 60:.1f} min (min {min(vals):.1f}, "
            f"max {max(vals):.1f}); largest deviation {dev * 100:.1f} %, "
            f"{(vals[-1] - base) / span_h:+.1f} MB/h"
        )
        ok &= dev <= TOLERANCE
    if end_snap is not None and state["base"] is not None:
        print("largest traced growth since the warm-up (file:line, KB):")
        for st in end_snap.compare_to(state["base"], "lineno")[:10]:
            print(f"  {st.size_diff / 1024:+9.1f} KB  {st.count_diff:+7d} blocks  {st.traceback}")
    print(
        f"{N_TAGS} tags, {N_UNITS} units, {duration / 60:.0f} min: memory flat within "
        f"{TOLERANCE * 100:.0f} % after warm-up: {'met' if ok else 'MISSED'}"
    )
    return 0 if ok else 1


def sqlite_cache(blocks: int) -> int:
    """The cause of the growth before the plateau: the historian's SQLite page cache
    (``PRAGMA cache_size=-65536``, 64 MiB per connection) filling as the database grows.
    Blocks of 100,000 samples (20 cycles of 5,000 tags) are written through
    ``Historian.write_samples`` (the writer's path), once with our cache and once with
    SQLite's default of 2 MiB, in a child process each; RSS is printed every 10 blocks."""
    code = r"""
import os, sys, tempfile
import numpy as np, pandas as pd
from historian.store import Historian
def rss():
    return int(open("/proc/self/statm").read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
d = tempfile.mkdtemp()
h = Historian.open(f"sqlite:///{d}/p.db")
tags = [f"t{i:04d}" for i in range(5000)]
rng = np.random.default_rng(0)
t0 = pd.Timestamp("2026-01-01", tz="UTC")
out = [f"{rss():.0f}"]
for b in range(int(sys.argv[2])):
    if b == 0 and sys.argv[1]:
        cur = h._bulk.conn.cursor()
        cur.execute(f"PRAGMA cache_size={sys.argv[1]}")
        cur.fetchall()
        cur.close()
    idx = pd.date_range(t0 + pd.Timedelta(seconds=20 * b), periods=20, freq="1s")
    h.write_samples(pd.DataFrame(rng.normal(50, 5, (20, 5000)), index=idx, columns=tags))
    if b % 10 == 9:
        out.append(f"{rss():.0f}")
print(" ".join(out))
"""
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    for label, pragma in (("ours, 64 MiB", ""), ("SQLite's default, 2 MiB", "-2000")):
        r = subprocess.run(
            [sys.executable, "-c", code, pragma, str(blocks)],
            capture_output=True,
            text=True,
            env=env,
            check=True,
        )
        rss = r.stdout.split()
        steps = ", ".join(f"{(i + 1) * 1_000_000 // 1000:,}k {v} MB" for i, v in enumerate(rss[1:]))
        print(f"page cache {label}: RSS {rss[0]} MB at start; after {steps}")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=1860.0, help="seconds of live run")
    ap.add_argument("--warmup", type=float, default=300.0, help="seconds before the baseline")
    ap.add_argument("--every", type=float, default=60.0, help="seconds between samples")
    ap.add_argument(
        "--trim-probe",
        action="store_true",
        help="after each sample call malloc_trim(0) and print the RSS again (diagnosis)",
    )
    ap.add_argument(
        "--trace",
        action="store_true",
        help="also trace Python allocations (tracemalloc, 1 frame): slower, names the lines",
    )
    ap.add_argument(
        "--sqlite-cache",
        type=int,
        metavar="BLOCKS",
        help="instead: RSS of BLOCKS historian writes of 100,000 samples, our page cache vs 2 MiB",
    )
    args = ap.parse_args()
    if args.sqlite_cache:
        return sqlite_cache(args.sqlite_cache)
    return soak(args.duration, args.warmup, args.every, args.trim_probe, args.trace)


if __name__ == "__main__":
    sys.exit(main())
