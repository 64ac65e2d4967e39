"""Fuzzy c-Means and the Takagi–Sugeno fit on many rows (issue 11's target: 1 M rows × 10
inputs, N = 10, under 30 s on the 2-core machine, memory flat in the rows).

    python benchmarks/bench_fcm.py [--rows 1000000] [--inputs 10] [--clusters 10]

Prints rows/s, seconds, iterations and the peak memory traced beyond the input array
(tracemalloc: numpy's allocations), for the clustering alone and for the whole ``fit``
(clustering + weighted least squares per rule). Not a timed test.
"""

from __future__ import annotations

import argparse
import time
import tracemalloc

import numpy as np

from diag_plugin.fuzzy.ts_fcm import TakagiSugenoRegressor, fuzzy_c_means


def data(rows: int, inputs: int, clusters: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Rows around ``clusters`` random centres in [0, 100]^inputs, a smooth output."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(10, 90, (clusters, inputs))
    X = centres[rng.integers(0, clusters, rows)] + rng.normal(0, 15, (rows, inputs))
    y = np.sin(X[:, 0] / 20) * 10 + X[:, 1 % inputs] * 0.3 + rng.normal(0, 0.1, rows)
    return X, y


def run(label: str, fn):
    tracemalloc.start()
    t0 = time.perf_counter()
    out = fn()
    dt = time.perf_counter() - t0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return out, dt, peak


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=1_000_000)
    ap.add_argument("--inputs", type=int, default=10)
    ap.add_argument("--clusters", type=int, default=10)
    ap.add_argument("--eps", type=float, default=0.01)
    args = ap.parse_args()
    X, y = data(args.rows, args.inputs, args.clusters)
    fuzzy_c_means(X[:1000], args.clusters, 2.0, args.eps, 2, 0)  # compile (numba) before timing
    spans = (np.zeros(args.inputs), np.full(args.inputs, 100.0))
    (V, it), dt, peak = run(
        "fcm", lambda: fuzzy_c_means(X, args.clusters, 2.0, args.eps, 300, 0, scale=spans)
    )
    print(
        f"fuzzy c-means  {args.rows:,} rows × {args.inputs} inputs, N={args.clusters}: "
        f"{dt:.1f} s, {it} iterations, {args.rows * it / dt / 1e6:.1f} M row-iterations/s, "
        f"{args.rows / dt / 1e6:.2f} M rows/s, peak traced {peak / 2**20:.0f} MiB "
        f"(input {X.nbytes / 2**20:.0f} MiB)"
    )
    model = TakagiSugenoRegressor(
        n_clusters=args.clusters, eps=args.eps, input_spans=[(0.0, 100.0)] * args.inputs
    )
    m, dt, peak = run("fit", lambda: model.fit(X, y))
    print(
        f"ts-fcm fit     {args.rows:,} rows: {dt:.1f} s ({m.n_iter_} iterations), "
        f"{args.rows / dt / 1e6:.2f} M rows/s, peak traced {peak / 2**20:.0f} MiB"
    )
    _, dt, peak = run("predict", lambda: m.predict(X))
    print(
        f"ts-fcm predict {args.rows:,} rows: {dt:.1f} s, {args.rows / dt / 1e6:.2f} M rows/s, "
        f"peak traced {peak / 2**20:.0f} MiB"
    )


if __name__ == "__main__":
    main()
