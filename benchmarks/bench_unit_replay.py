"""Replay speed of a built unit (issue 34: ``diag diagnose`` of a 50-tag unit ≥ 100 k rows/s).

A unit is built (``build_unit``, as ``diag unit build`` does) from 10 days of the synthetic
coupled process (:mod:`diag_plugin.simulate.coupled`, ``--tags`` tags at ``--period`` s), then
a fault-free run of ``--rows`` rows is replayed through :meth:`Unit.evaluate` in one pass and
in the chunks ``diag diagnose`` reads (7 days); PCA T² + Q (90 % of the variance) fitted on the
same 10 days scores the same rows beside it. Printed: tags, rows, seconds, rows/s, peak
resident memory, and the machine's load average (the machine is shared: run it niced, once).

With ``--profile N`` the one pass runs once more under :mod:`cProfile`, timed in CPU seconds
of this process (the machine is shared), and the ``N`` functions with most time of their own
are printed (the profile the speed work is chosen by).

With ``--repeat N`` each replay runs N times and the run with the median CPU time is shown,
with every run's CPU seconds (the first run is the unit's first pass over so many rows: it
fits the coarse levels and the combined test's inverses it meets).

Figures (issue 34 round nine, ``--unit`` of the default 50-tag unit, 45 tests, ``--repeat 5``,
four runs of ``main`` and the branch interleaved at a load of 7–14 on 2 shared cores, medians
of the four): one pass 2.22 → 1.88 CPU s (90,100 → 106,700 rows per CPU s; the first run
2.40 → 2.04 s, 83,500 → 98,300), 7-day pieces 3.12 → 2.45 CPU s (64,100 → 81,800); PCA
T² + Q scores the same rows in 0.33–0.61 CPU s. Round ten (``--repeat 3``, four pairs
interleaved at a load of 3.4–6.7, medians): the first run 1.35 → 1.21 CPU s (148,000 →
165,000 rows per CPU s), 7-day pieces 1.52 → 1.46 s (132,000 → 137,000), the warm one pass
1.04 s both; ``main`` was above 100,000 rows per CPU s that day in all three, about 1.5× the
quiet figures of ae03181 (first run 2.13 s, pieces 2.27 s): compare only within one
interleaved run. Three pairs quiet (load 1.3–1.6): first run 1.47 → 1.00 s (136,000 →
200,000), one pass 0.99 → 0.89 s, 7-day pieces 1.46 → 1.34 s (137,000 → 149,000).
Details: docs/how-to/unit-short-windows.md, "Round nine" and "Round ten".

Run: ``nice -n 10 python benchmarks/bench_unit_replay.py [--tags 50] [--rows 200000]
[--profile 15] [--repeat 5]``.
"""

from __future__ import annotations

import argparse
import os
import resource
import tempfile
import time

import pandas as pd


def rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def timed(run, repeat: int) -> tuple[float, float, list[float]]:
    """Wall and CPU seconds of ``run()``: those of the run with the median CPU time of
    ``repeat`` runs, and every run's CPU seconds (the machine is shared: one run's CPU time
    varies with the other jobs' use of the caches and memory)."""
    times = []
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        run()
        times.append((time.process_time() - c, time.perf_counter() - t))
    cpu, wall = sorted(times)[(repeat - 1) // 2]
    return wall, cpu, [x for x, _ in times]


def main() -> None:
    from diag_plugin.bench.pca import PCADetector
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.simulate import coupled
    from diag_plugin.unitbuild.build import build_unit

    ap = argparse.ArgumentParser()
    ap.add_argument("--tags", type=int, default=50)
    ap.add_argument("--period", type=float, default=180.0)
    ap.add_argument("--rows", type=int, default=200_000)
    ap.add_argument("--unit", help="an already built unit file to replay instead")
    ap.add_argument("--profile", type=int, default=0, help="print the N top functions (CPU s)")
    ap.add_argument("--repeat", type=int, default=1, help="runs of each replay (median shown)")
    a = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    train, _ = coupled.simulate(10, period_s=a.period, n_tags=a.tags, seed=1)
    period = f"{a.period:g}s"
    if a.unit:
        unit = Unit.load(a.unit)
    else:
        folder = tempfile.mkdtemp()
        t = time.perf_counter()
        res = build_unit("replay", train, folder=folder, period=period, far=0.01)
        print(f"built {len(res.tests)} tests in {time.perf_counter() - t:.1f} s: {res.path}")
        unit = Unit.load(res.path, folder)
    days = a.rows * a.period / 86400
    frame, _ = coupled.simulate(days, period_s=a.period, n_tags=a.tags, seed=7,
                                start="2026-06-01")  # fmt: skip
    frame = frame.iloc[: a.rows]
    n = len(frame)
    from threadpoolctl import threadpool_limits

    before = rss_mb()
    chunk = pd.Timedelta("7D") // pd.Timedelta(period)

    def one_pass() -> None:
        unit.reset().evaluate(frame)

    def pieces() -> None:
        unit.reset()
        for s in range(0, n, chunk):
            unit.evaluate(frame.iloc[s : s + chunk])

    with threadpool_limits(1):  # as diag diagnose runs it
        unit.reset().evaluate(frame.iloc[:100])  # compiled kernels loaded, as in a service
        one, one_cpu, one_all = timed(one_pass, a.repeat)
        chunked, chunked_cpu, chunked_all = timed(pieces, a.repeat)
    peak = rss_mb()
    cols = [c for c in train.columns if train[c].std() > 0]
    t = time.perf_counter()
    pca = PCADetector(n_components=0.9, columns=cols).fit(train[cols])
    fit = time.perf_counter() - t
    with threadpool_limits(1):
        t, c = time.perf_counter(), time.process_time()
        pca.score(frame[cols])
        pca_s, pca_cpu = time.perf_counter() - t, time.process_time() - c
    # on a shared machine the wall clock counts the other jobs too: the CPU seconds of this
    # process are given beside it (rows per CPU second)
    print(f"unit: {len(unit.tests)} tests over {len(unit.tags)} tags; {n:,} rows of {period}")
    print(f"  one pass        {one:7.2f} s  {n / one:10,.0f} rows/s   "
          f"(CPU {one_cpu:6.2f} s, {n / one_cpu:10,.0f} rows/CPU s)")  # fmt: skip
    print(f"  7-day chunks    {chunked:7.2f} s  {n / chunked:10,.0f} rows/s   "
          f"(CPU {chunked_cpu:6.2f} s, {n / chunked_cpu:10,.0f} rows/CPU s)")  # fmt: skip
    if a.repeat > 1:
        print(f"  CPU s of the {a.repeat} runs (median above): one pass "
              f"{', '.join(f'{x:.2f}' for x in one_all)}; 7-day chunks "
              f"{', '.join(f'{x:.2f}' for x in chunked_all)}")  # fmt: skip
    print(f"  peak resident memory {peak:.0f} MB (before the replay {before:.0f} MB)")
    print(f"PCA T² + Q ({len(cols)} tags): fit {fit:.2f} s; score {pca_s:.2f} s, "
          f"{n / pca_s:,.0f} rows/s (CPU {pca_cpu:.2f} s, {n / pca_cpu:,.0f} rows/CPU s); "
          f"the unit's one pass is {pca_s / one:.1f}× PCA's speed (CPU "
          f"{pca_cpu / one_cpu:.1f}×)")  # fmt: skip
    print(f"load average {os.getloadavg()[0]:.1f} at the end")
    if a.profile:
        import cProfile
        import pstats

        prof = cProfile.Profile(time.process_time)
        with threadpool_limits(1):
            unit.reset().evaluate(frame.iloc[:100])
            prof.runcall(unit.reset().evaluate, frame)
        print(f"profile of the one pass (CPU s of this process, load {os.getloadavg()[0]:.1f}):")
        pstats.Stats(prof).sort_stats("tottime").print_stats(a.profile)


if __name__ == "__main__":
    main()
