"""``diag unit build`` speed and quality on the synthetic coupled process.

Speed (issue 25's target: 50 tags over 10 days of 3-min data, 4,800 rows, in under 2 minutes on
this machine): the process (:mod:`diag_plugin.simulate.coupled`) is imported into a temporary
SQLite historian, then built with :func:`~diag_plugin.unitbuild.build.build_from_historian`
exactly as ``diag unit build`` does; the time of each stage and the process's peak resident
memory are printed.

Quality (with ``--quality``): the built unit and PCA T² + Q (dynamic, one lag) fitted on the
same window with limits held to the same budget and the same on/off delays
(``benchmarks/bench_detection_plants.py``'s ``pca_fit``), on fault-free runs of seeds never
used to build (false alarms per hour) and on runs with a sensor bias on one tag from the
middle (share of the samples after the onset in alarm).

With ``--rig hx``: the heat exchanger of :mod:`diag_plugin.examples.rigs` (60 s, six tags), a
unit built from its 60-day training window beside PCA on exactly the runs, faults and budget of
``benchmarks/bench_detection_plants.py`` (which prints its hand-built unit's figures;
docs/explanation/other-plants.md explains them).

Issue 34's speed target: 200 tags × 10 days at 1 min (``--tags 200 --period 60``) in under
60 s on two cores. On a shared machine the wall time follows the load, so the CPU time is
printed beside it: the parent's (the serial parts), each worker process's (the per-test work
handed to :func:`~diag_plugin.unitbuild.parallel.map_tests`, timed inside the worker), and
the wall two idle cores would take — the parent's CPU plus, for each pool, its busiest
worker's — with the same run's PCA fit time. Measured (branch i34-build8, interleaved with
main d39e220 on this session's faster machine, load 5–10): the busiest choice worker 29.7 →
21.8 s CPU (medians of three), parent 6.9 → 5.7 s, two idle cores ≈ 45.6 → 37.2 s, under the
60 s goal by that estimate (docs/how-to/unit-from-history.md; the wall on idle cores was not
measured: the machine was shared). Measured wall (2026-12-01, main 88e2349 with i36-disturb,
three runs at load 1.5–2.6 with other work beside them, cache warm): 27.2, 26.2, 26.5 s for 200
tags (183 tests), CPU 44.9–46.4 s in all, parent 2.9 s, busiest choice worker 13.4 s — under
the 60 s goal on that machine. The first run after a fresh checkout or install compiles
numba's kernels into their cache (the parent's ``warm_kernels``): main 07c9aaa's parent took
18.8 s CPU in that run against 7.2 s with the cache warm (load 7–12), so run it once before
measuring. Since branch i34-build (H2) the historian's two reads (the tags' sampling, then the
window) run by shares of the tags in the local pool (:mod:`diag_plugin.unitbuild.read`): they
are the first two pools printed, the choice the fourth.

With ``--dask``: the local pool and a Dask LocalCluster (bound to 127.0.0.1 only: two worker
processes of one thread each, started by this script and closed at its end) build the same
historian window ``--repeat`` times each, interleaved (the order alternating), each build
from ``build_from_historian`` as ``diag unit build [--dask ADDRESS]`` runs it. Printed per
build and as medians: the wall, the CPU of this process (the client; with Dask also the
scheduler, which a LocalCluster runs in this process), the CPU of the workers (the local
pool's ended children; each Dask worker's own ``getrusage``, before and after), the load
average, and whether the unit's files are the first local build's (but the times written).

Run: ``python benchmarks/bench_unit_build.py [--tags 50] [--days 10] [--period 60]
[--workers N] [--quality] [--rig hx] [--dask [--repeat 3]]``.
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))

from diag_plugin.diagnose.unit import Unit  # noqa: E402
from diag_plugin.simulate import coupled  # noqa: E402
from diag_plugin.unitbuild.build import build_from_historian  # noqa: E402
from historian.store import Historian  # noqa: E402


def rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def cpu_s() -> float:
    """CPU seconds of this process and of its children that have ended (the workers)."""
    me = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def cpu_self() -> float:
    me = resource.getrusage(resource.RUSAGE_SELF)
    return me.ru_utime + me.ru_stime


#: per call of map_tests in the build: {worker pid: CPU seconds of its items}
POOLS: list[dict[int, float]] = []


def _timed(item, fn, *args):
    """``fn(item, *args)`` in a worker, with the worker's pid and the CPU seconds it took."""
    import os

    t = time.process_time()
    out = fn(item, *args)
    return out, os.getpid(), time.process_time() - t


def time_workers() -> None:
    """Time every item the build hands to its workers (``build.map_tests`` wrapped)."""
    from diag_plugin.unitbuild import build

    inner = build.map_tests

    def timed(fn, items, args=(), **kw):
        got = inner(_timed, items, (fn, *args), **kw)
        per: dict[int, float] = {}
        for _, pid, s in got:
            per[pid] = per.get(pid, 0.0) + s
        POOLS.append(per)
        return [g[0] for g in got]

    build.map_tests = timed


def store(url: str, frame: pd.DataFrame) -> None:
    with Historian.open(url) as h:
        h.write_samples(frame)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--tags", type=int, default=50)
    ap.add_argument("--days", type=float, default=10.0)
    ap.add_argument("--far", type=float, default=0.01)
    ap.add_argument("--period", type=float, default=180.0, help="grid in s (issue 34: 60)")
    ap.add_argument("--workers", type=int, default=None, help="processes (default: cores)")
    ap.add_argument("--quality", action="store_true")
    ap.add_argument("--rig", choices=["hx"], help="build on the rig instead, beside PCA")
    ap.add_argument("--dask", action="store_true", help="local pool vs a Dask LocalCluster")
    ap.add_argument("--repeat", type=int, default=3, help="builds of each (with --dask)")
    a = ap.parse_args()
    if a.rig:
        return rig(a.rig)
    if a.dask:
        return local_vs_dask(a)
    import os

    from diag_plugin.bench.pca import PCADetector
    from diag_plugin.unitbuild.parallel import default_workers

    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    frame, st = coupled.simulate(a.days, period_s=a.period, n_tags=a.tags, seed=1)
    tmp = Path(tempfile.mkdtemp())
    url = f"sqlite:///{tmp / 'h.db'}"
    t = time.perf_counter()
    store(url, frame)
    step = pd.Timedelta(seconds=a.period)
    print(f"{a.tags} tags × {len(frame):,} rows of {a.period:g} s; stored in "
          f"{time.perf_counter() - t:.1f} s")  # fmt: skip
    before = rss_mb()
    t0, t1 = frame.index[0], frame.index[-1] + step
    workers = a.workers or default_workers()
    if a.workers:
        os.environ["DIAG_WORKERS"] = str(a.workers)
    time_workers()
    t, cpu, own = time.perf_counter(), cpu_s(), cpu_self()
    res = build_from_historian(url, "u", t0, t1, folder=tmp / "rb", far=a.far)
    took, build_cpu, parent = time.perf_counter() - t, cpu_s() - cpu, cpu_self() - own
    print(f"built {len(res.tests)} tests, skipped {len(res.skipped)} on {workers} worker(s): "
          f"{took:.1f} s, {len(frame) * a.tags / took:,.0f} tag-rows/s; CPU {build_cpu:.1f} s "
          f"(the workers' included); load {os.getloadavg()[0]:.1f}; {res.path}")  # fmt: skip
    pools = "; ".join(
        f"pool {i + 1}: " + ", ".join(f"{s:.1f}" for s in sorted(p.values(), reverse=True))
        for i, p in enumerate(POOLS)
    )
    kids = [[s for pid, s in p.items() if pid != os.getpid()] for p in POOLS]
    idle = parent + sum(max(k, default=0.0) for k in kids)
    print(f"  CPU: parent {parent:.1f} s (serial parts; a one-worker pool runs in it), per "
          f"worker {pools} s; on {workers} idle core(s) ≈ {idle:.1f} s wall")  # fmt: skip
    for k, v in res.seconds.items():
        print(f"  {k:18s} {v:7.1f} s")
    print(f"  peak resident memory {rss_mb():.0f} MB (before the build {before:.0f} MB; the "
          "workers' own not counted)")  # fmt: skip
    t, cpu = time.perf_counter(), cpu_s()
    cols = [c for c in frame.columns if frame[c].std() > 0]
    PCADetector(n_components=0.9, columns=cols).fit(frame[cols])
    pca, pca_cpu = time.perf_counter() - t, cpu_s() - cpu
    print(f"PCA T² + Q fitted on the same window in {pca:.2f} s (CPU {pca_cpu:.2f} s): the "
          f"build takes {took / pca:.1f}× its time, {build_cpu / max(pca_cpu, 1e-3):.1f}× its "
          "CPU")  # fmt: skip
    if not a.quality:
        return
    from bench_detection_plants import episodes_per_hour, pca_alarms, pca_fit, unit_alarms

    unit = Unit.load(res.path, tmp / "rb")
    ev = unit.ev
    pca = pca_fit(frame, "3min", a.far, ev["on_delay"], ev["off_delay"])
    rows = []
    start = frame.index[-1] + pd.Timedelta(days=1)
    for seed in (101, 102, 103):
        q, _ = coupled.simulate(3.0, n_tags=a.tags, seed=seed, start=start.strftime("%Y-%m-%d"))
        data = q.notna().any(axis=1).to_numpy()
        u_al, _ = unit_alarms(unit, q)
        p_al = pca_alarms(pca, q, ev["on_delay"], ev["off_delay"])
        rows.append(("fault-free", seed, episodes_per_hour(u_al, data, "3min"),
                     episodes_per_hour(p_al, data, "3min")))  # fmt: skip
    print(f"\nfault-free, false alarms per hour (budget {a.far:g}):")
    for r in rows:
        print(f"  seed {r[1]}: unit {r[2]:.3f}, PCA {r[3]:.3f}")
    tested = [t.tag for t in res.tests if t.tag.startswith("Y")][:8]
    print("\nsensor bias from the middle of a 2-day run: share of samples after onset in alarm")
    print("| bias (% of range) | unit | PCA |\n|---|---|---|")
    for size in (0.02, 0.05, 0.1, 0.2):
        det_u, det_p = [], []
        for i, tag in enumerate(tested):
            q, _ = coupled.simulate(2.0, n_tags=a.tags, seed=200 + i,
                                    start=start.strftime("%Y-%m-%d"))  # fmt: skip
            half = len(q) // 2
            q.iloc[half:, q.columns.get_loc(tag)] += size * np.ptp(frame[tag])
            u_al, _ = unit_alarms(unit, q)
            p_al = pca_alarms(pca, q, ev["on_delay"], ev["off_delay"])
            det_u.append(u_al[half:].mean())
            det_p.append(p_al[half:].mean())
        print(f"| {size:.0%} | {np.mean(det_u):.0%} | {np.mean(det_p):.0%} |")


def _worker_cpu() -> float:
    """CPU seconds of the process this runs in (a Dask worker)."""
    me = resource.getrusage(resource.RUSAGE_SELF)
    return me.ru_utime + me.ru_stime


def _unit_text(folder: Path) -> dict[str, str]:
    import re

    return {
        p.name: re.sub(r"(?m)^.*(_at|learned) = .*$", "", p.read_text(encoding="utf-8"))
        for p in sorted(folder.iterdir())
    }


def local_vs_dask(a) -> None:
    """The local pool and a Dask LocalCluster on 127.0.0.1, interleaved (see the module)."""
    import os
    import statistics

    from distributed import LocalCluster

    from diag_plugin.unitbuild.parallel import DaskPool

    frame, _ = coupled.simulate(a.days, period_s=a.period, n_tags=a.tags, seed=1)
    tmp = Path(tempfile.mkdtemp())
    url = f"sqlite:///{tmp / 'h.db'}"
    store(url, frame)
    t0, t1 = frame.index[0], frame.index[-1] + pd.Timedelta(seconds=a.period)
    print(f"{a.tags} tags × {len(frame):,} rows of {a.period:g} s; {os.cpu_count()} cores; "
          f"local pool: {a.workers or 'every core'}; Dask: LocalCluster 127.0.0.1, "
          "2 worker processes × 1 thread")  # fmt: skip
    if a.workers:
        os.environ["DIAG_WORKERS"] = str(a.workers)
    rows: dict[str, list[tuple[float, float, float, float]]] = {"local": [], "dask": []}
    ref: dict[str, str] | None = None
    with (
        LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                     dashboard_address=None, protocol="tcp") as cluster,
        DaskPool.connect(cluster.scheduler_address) as pool,
    ):  # fmt: skip
        pool.client.run(_worker_cpu)  # the workers up and importing
        for i in range(a.repeat):
            for mode in ("local", "dask") if i % 2 == 0 else ("dask", "local"):
                folder = tmp / f"rb-{mode}-{i}"
                load0 = os.getloadavg()[0]
                before = pool.client.run(_worker_cpu) if mode == "dask" else None
                kids = resource.getrusage(resource.RUSAGE_CHILDREN)
                t, own = time.perf_counter(), cpu_self()
                build_from_historian(url, "u", t0, t1, folder=folder, far=a.far,
                                     workers=pool if mode == "dask" else None)  # fmt: skip
                wall, parent = time.perf_counter() - t, cpu_self() - own
                if mode == "dask":
                    after = pool.client.run(_worker_cpu)
                    workers = sum(after[w] - before.get(w, 0.0) for w in after)
                else:
                    k = resource.getrusage(resource.RUSAGE_CHILDREN)
                    workers = (k.ru_utime + k.ru_stime) - (kids.ru_utime + kids.ru_stime)
                load = (load0 + os.getloadavg()[0]) / 2
                text = _unit_text(folder)
                ref = ref or text
                rows[mode].append((wall, parent, workers, load))
                print(f"  {mode:5s} #{i + 1}: wall {wall:6.1f} s, CPU parent {parent:5.1f} s, "
                      f"workers {workers:5.1f} s, load {load:4.1f}; {len(text)} files, "
                      f"{'the same unit' if text == ref else 'A DIFFERENT UNIT'}")  # fmt: skip
    print("| build | wall | CPU parent | CPU workers | CPU total | load average |")
    print("|---|---|---|---|---|---|")
    for mode, got in rows.items():
        med = [statistics.median(x[k] for x in got) for k in range(4)]
        tot = statistics.median(x[1] + x[2] for x in got)
        print(f"| {mode} (median of {len(got)}) | {med[0]:.1f} s | {med[1]:.1f} s | "
              f"{med[2]:.1f} s | {tot:.1f} s | {med[3]:.1f} |")  # fmt: skip


def rig(plant: str) -> None:
    from bench_detection_plants import (
        PLANTS,
        episodes_per_hour,
        pca_alarms,
        pca_fit,
        unit_alarms,
    )

    from diag_plugin.examples.rigs import HX_TAGS, PERIODS, RigFault, runs, tag_info
    from diag_plugin.unitbuild.build import build_unit

    cfg = PLANTS[plant]
    period = PERIODS[plant]
    step = pd.Timedelta(period)
    train = runs(plant, cfg["train"], length=cfg["length"])
    tmp = Path(tempfile.mkdtemp())
    t = time.perf_counter()
    res = build_unit("hx", train, folder=tmp, period=period, tag_info=tag_info(HX_TAGS),
                     far=cfg["far"])  # fmt: skip
    print(f"built in {time.perf_counter() - t:.1f} s from {len(train):,} rows of {period}:")
    for ch in res.tests:
        errs = " → ".join(
            f"{x:.2f}" for x in [ch.baseline_rmse_pct, *(s.rmse_pct for s in ch.steps)]
        )
        print(f"  {ch.test} = f({', '.join(ch.inputs)}): held-out error {errs} % of span")
    for tag, why in res.skipped.items():
        print(f"  not tested: {tag}: {why}")
    unit = Unit.load(res.path, tmp)
    on, off = unit.ev["on_delay"], unit.ev["off_delay"]
    # PCA with the built unit's on/off delays, and with the 30 samples of the hand-built unit
    pcas = {"pca": (pca_fit(train, period, cfg["far"], on, off), on, off),
            "pca30": (pca_fit(train, period, cfg["far"], 30, 30), 30, 30)}  # fmt: skip
    ff = runs(plant, list(cfg["fault_free"]), length=cfg["run"])
    data = ff.notna().all(axis=1).to_numpy()
    ours, unknown = unit_alarms(unit, ff)
    rates = {k: episodes_per_hour(pca_alarms(p, ff, a, b), data, period)
             for k, (p, a, b) in pcas.items()}  # fmt: skip
    print(
        f"fault-free runs of {len(cfg['fault_free'])} unseen seeds: false alarms per hour unit "
        f"{episodes_per_hour(ours, data, period):.3g}, PCA {rates['pca']:.3g} (delays {on}), "
        f"PCA {rates['pca30']:.3g} (delays 30) (budget {cfg['far']:g}); unit "
        f"CHECK_FUNCTION {unknown[data].mean():.2%}"
    )
    print(f"| fault | strength | unit detected | delay | PCA (delays {on}) | delay | "
          "PCA (delays 30) | delay |\n|---|---|---|---|---|---|---|---|")  # fmt: skip
    onset = cfg["onset"]
    at = int(onset / step.total_seconds())
    for kind, strength in cfg["faults"]:
        got = {"unit": [], "pca": [], "pca30": []}
        for s in cfg["fault_seeds"]:
            f = runs(plant, [s], faults=[RigFault(kind, strength, onset)],
                     length=cfg.get("run_faulty", cfg["run"]))  # fmt: skip
            al_by = {"unit": unit_alarms(unit, f)[0]}
            al_by.update({k: pca_alarms(p, f, a, b) for k, (p, a, b) in pcas.items()})
            for key, al in al_by.items():
                hit = np.flatnonzero(al[at:])
                got[key].append(hit[0] * step.total_seconds() / 3600 if hit.size else None)
        cells = []
        for key in ("unit", "pca", "pca30"):
            d = [x for x in got[key] if x is not None]
            cells += [f"{len(d)}/{len(got[key])}", f"{np.median(d):.1f} h" if d else "—"]
        print(f"| {kind} | {strength:g} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
