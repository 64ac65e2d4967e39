"""Wang–Mendel training and inference speed (issue 2): rows/s and peak memory.

For 1, 2 and 3 inputs at 1 M and 10 M rows: ``fit`` (averaged method, 31
trapezoidal sets) and ``predict``. Data are generated chunk by chunk so the
figures show the model's own memory, which must stay flat as rows grow.
Targets on the reference machine (2 cores): training ≥ 30 M rows/s and
inference ≥ 10 M rows/s for 2 inputs. Exit status 1 if a target is missed.
"""

from __future__ import annotations

import sys
import time
import tracemalloc

import numpy as np

from diag_plugin.fuzzy.wang_mendel import WangMendelRegressor

CHUNK = 1_000_000


def chunks(n_rows: int, d: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    for s in range(0, n_rows, CHUNK):
        n = min(CHUNK, n_rows - s)
        X = rng.uniform(0, 100, (n, d))
        y = X.mean(axis=1) * 0.4 + rng.normal(0, 0.5, n)
        yield X, y


def run(n_rows: int, d: int) -> tuple[float, float, float]:
    data = list(chunks(min(n_rows, 3 * CHUNK), d))  # reuse chunks: generation is not timed
    model = WangMendelRegressor([(0, 100)] * d, (0, 40))
    model.partial_fit(*data[0]).predict(data[0][0][:10])  # compile once, then start afresh
    model = WangMendelRegressor([(0, 100)] * d, (0, 40))
    tracemalloc.start()
    t_fit = 0.0
    for i in range(n_rows // CHUNK):
        X, y = data[i % len(data)]
        t0 = time.perf_counter()
        model.partial_fit(X, y)
        t_fit += time.perf_counter() - t0
    t_pred = 0.0
    for i in range(n_rows // CHUNK):
        X, _ = data[i % len(data)]
        t0 = time.perf_counter()
        model.predict(X)
        t_pred += time.perf_counter() - t0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return n_rows / t_fit, n_rows / t_pred, peak / 2**20


def main() -> int:
    ok = True
    print(f"{'inputs':>6} {'rows':>6} {'train rows/s':>14} {'predict rows/s':>15} {'peak MiB':>9}")
    for d in (1, 2, 3):
        for n in (1_000_000, 10_000_000):
            fit_rate, pred_rate, peak = run(n, d)
            print(
                f"{d:>6} {n // 1_000_000:>5}M {fit_rate / 1e6:>12.1f} M {pred_rate / 1e6:>13.1f} M "
                f"{peak:>9.1f}"
            )
            if d == 2 and n == 10_000_000:
                ok &= fit_rate >= 30e6 and pred_rate >= 10e6
    print(
        "targets (2 inputs): train >= 30 M rows/s, predict >= 10 M rows/s:",
        "met" if ok else "MISSED",
    )
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
