"""The free run (output-error simulation) of ts-fcm and narmax2 compiled, against the
row-by-row reference (issue 33 item 6: it was most of the engine FDI's cost).

    python benchmarks/bench_free_run.py [--rev 7000] [--seed 5]

Identifies the five models of eqs. 7–11 (:func:`diag_plugin.engine.fdi.identify`) per
method on a simulated run, then per model prints the CPU seconds of ``simulate`` (a numba
kernel) and of :func:`diag_plugin.models.estimation.free_run` over the model's one-row
prediction (the Python loop it replaces, kept as the reference) on a second run, and their
largest relative difference. Not a test.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from diag_plugin.engine import fdi
from diag_plugin.models.estimation import free_run
from diag_plugin.simulate.engine import simulate_engine


def cpu(fn):
    t0 = time.process_time()
    out = fn()
    return time.process_time() - t0, out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rev", type=int, default=fdi.N_REV, help="revolutions per run")
    ap.add_argument("--seed", type=int, default=5)
    args = ap.parse_args(argv)
    train = simulate_engine(args.rev, seed=args.seed)
    run = simulate_engine(args.rev, seed=args.seed + 2000)
    print(f"{'method':8} {'model':6} {'compiled s':>10} {'reference s':>11} {'max rel diff':>12}")
    total = np.zeros(2)
    for method in ("ts-fcm", "narmax2"):
        em = fdi.identify(train, method)
        for name, m in em.models.items():
            X, _, _ = fdi.regressors(run, name)
            m.simulate(X[:10])  # compiled (or loaded from numba's cache) before timing
            fast, a = cpu(lambda m=m, X=X: m.simulate(X))
            slow, b = cpu(lambda m=m, X=X: free_run(X, m.output_lags, m.spans_, m._predict_rows))
            ok = np.isfinite(b)
            rel = float(np.max(np.abs(a[ok] - b[ok])) / np.max(np.abs(b[ok])))
            total += (fast, slow)
            print(f"{method:8} {name:6} {fast:10.4f} {slow:11.3f} {rel:12.1e}", flush=True)
    print(f"{'total':15} {total[0]:10.4f} {total[1]:11.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
