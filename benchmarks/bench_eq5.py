"""Eq. 5 as printed beside the averaged outputs (issue 26, gap 6).

Kościelny et al.'s modified Wang–Mendel method averages, per rule cell, the conclusions
``A^{n+1}`` of the samples' rules (eq. 5): the centres of their outputs' max-membership sets.
The product averages the measured outputs themselves (``conclusion = "mean"``, the limit of
eq. 5 for a fine output partition); ``conclusion = "sets"`` is the printed form. This builds the
example unit both ways on the same 180 days (seed 1), prints how far the two rule bases' conclusions
lie apart (% of span), each model's held-out error, and the DAMADICS benchmark on seeds 11, 23,
37 for each.

    python benchmarks/bench_eq5.py [--quick] [--days 180]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--days", type=float, default=180)
    ap.add_argument("--quick", action="store_true", help="one strength per fault")
    ap.add_argument("--seed", type=int, action="append", dest="seeds")
    args = ap.parse_args()
    from diag_plugin.bench.damadics import run_benchmark
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.examples.build import SIM_SEED, UNIT_TESTS, build_valve_unit
    from diag_plugin.rulebase.document import RuleBase
    from diag_plugin.simulate.valve import simulate_valve

    seeds = tuple(args.seeds or (11, 23, 37))
    t0 = time.perf_counter()
    frame = simulate_valve(args.days, seed=SIM_SEED)
    print(f"simulated {args.days:g} days in {time.perf_counter() - t0:.0f} s")
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for conclusion in ("mean", "sets"):
            folder = Path(tmp) / conclusion
            folder.mkdir()
            t0 = time.perf_counter()
            build_valve_unit(folder, frame, "bench_eq5", conclusion=conclusion)
            unit = Unit.load(folder / "valve_unit.unit.toml")
            built = time.perf_counter() - t0
            t0 = time.perf_counter()
            bench = run_benchmark(unit, quick=args.quick, seeds=seeds)
            out[conclusion] = (folder, bench["summary"], built, time.perf_counter() - t0)
        print("\nper model: conclusions of the same cells, and the held-out RMSE of training")
        print(f"{'model':8} {'cells':>6} {'max |sets-mean|':>16} {'mean |…|':>9} "
              f"{'RMSE mean':>10} {'RMSE sets':>10}  (% of span)")  # fmt: skip
        for test in UNIT_TESTS:
            a = RuleBase.load(out["mean"][0] / f"valve_{test}.toml")
            b = RuleBase.load(out["sets"][0] / f"valve_{test}.toml")
            span = a.output.span[1] - a.output.span[0]
            ra = {r.premise: r.then for r in a.rules}
            rb_ = {r.premise: r.then for r in b.rules}
            common = sorted(set(ra) & set(rb_))
            d = np.abs([ra[p] - rb_[p] for p in common]) / span * 100
            print(
                f"{test:8} {len(common):6d} {d.max():16.3f} {d.mean():9.3f} "
                f"{float(a.training['validation_rmse_pct']):10.3f} "
                f"{float(b.training['validation_rmse_pct']):10.3f}"
            )
        print(f"\nDAMADICS benchmark, seeds {', '.join(map(str, seeds))}"
              + (" (quick)" if args.quick else ""))  # fmt: skip
        keys = (
            ("scenarios_detected", "detected"),
            ("scenarios_isolated", "isolated"),
            ("scenarios_with_isolation", "with a matrix column"),
            ("literature_detectable_detected", "literature-detectable faults found"),
            ("mean_false_detection_rate", "mean false detection rate"),
            ("max_false_detection_rate", "max false detection rate"),
        )
        for k, label in keys:
            row = [out[c][1].get(k) for c in ("mean", "sets")]
            print(f"  {label:38} {row[0]!s:>10} {row[1]!s:>10}")
        for c in ("mean", "sets"):
            print(f"  {c}: unit built in {out[c][2]:.0f} s, benchmark {out[c][3]:.0f} s")


if __name__ == "__main__":
    main()
