"""Benchmark: six months of 10 s actuator data (1.57 M samples) in at most 60 s.

Run: ``python benchmarks/bench_simulator.py [--days 182.5] [--limit 60]``.
Prints wall time, samples per second and peak memory; exits 1 when over the limit.
The first call compiles the numba kernels (cached on disk afterwards); that time
is reported separately and not counted.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
import tracemalloc

from diag_plugin.simulate import FaultSpec, simulate_valve


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--days", type=float, default=182.5)
    ap.add_argument("--period", type=float, default=10.0)
    ap.add_argument("--limit", type=float, default=60.0, help="seconds allowed")
    args = ap.parse_args()

    t0 = time.perf_counter()
    simulate_valve(0.01, period_s=args.period)  # compile / load the cached kernels
    warm = time.perf_counter() - t0

    faults = [FaultSpec("f17", 0.3, None), FaultSpec("f4", 0.2, None, "incipient", 30 * 86400.0)]
    tracemalloc.start()
    t0 = time.perf_counter()
    df = simulate_valve(args.days, period_s=args.period, seed=1, faults=faults)
    wall = time.perf_counter() - t0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0

    n = len(df)
    print(
        f"simulate_valve: {args.days:g} days at {args.period:g} s"
        f" = {n} samples x {df.shape[1]} tags"
    )
    print(f"  compile/load {warm:.1f} s (not counted)")
    print(f"  wall time    {wall:.1f} s   (limit {args.limit:g} s)")
    print(f"  throughput   {n / wall:,.0f} samples/s")
    print(f"  peak memory  {peak / 2**20:.0f} MiB traced (numpy), {rss_mb:.0f} MiB max RSS")
    if wall > args.limit:
        print("FAIL: over the time limit", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
