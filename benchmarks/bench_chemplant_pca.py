"""PCA and dynamic PCA T² + Q on the chemical plant with recycle, per fault, at 3 min and 1 s.

The baseline a unit built from the plant's history (issue 25) must beat, on
:mod:`diag_plugin.simulate.chemplant`:

1. **Training**: fault-free runs of seeds 1–5, 10 days each, averaged to 3 min (the first
   ``--train-days-1s`` days of each at 1 s, so the 1 s fit stays in memory);
   :class:`~diag_plugin.bench.plant.PCABaseline` on the 35 measurements and controller
   outputs (set-points left out: a set-point held constant through a training run gets a
   near-zero spread, and any later change becomes an enormous standardised deviation), limits
   at ``--far`` (share of samples, T² or Q) from leave-one-run-out statistics. PCA: no lags;
   DPCA: two lags.
2. **False alarms**: fault-free runs of scoring seeds (never used while building or tuning),
   3 days each: share of samples in alarm and alarm episodes per hour.
3. **Faults**: one 3-day run per fault and scoring seed, the fault from day 1 at its default
   size: detection rate (share of samples in alarm after the onset), delay of the first alarm
   after the onset (median over seeds), and how many runs have the faulted tag among PCA's
   three largest contributions (mean over the samples in alarm after the onset).

Fault sizes were chosen on seeds 100–199 (``--tune``); the default scoring seeds start at 9000.
Run: ``python benchmarks/bench_chemplant_pca.py [--quick] [--tune]`` (prints markdown tables).
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
import pandas as pd

from diag_plugin.bench.plant import (
    PCABaseline,
    detection_delay,
    detection_rate,
    false_alarm_rate,
    in_top,
)
from diag_plugin.simulate.chemplant import CHEMPLANT_TAGS, FAULTS, sample, simulate_chemplant

TRAIN_SEEDS = (1, 2, 3, 4, 5)
METHODS = {"PCA": 0, "DPCA": 2}
RATES = {"3 min": 180, "1 s": 1}


def _delay(s: float) -> str:
    if not np.isfinite(s):
        return "—"
    return f"{s / 3600:.1f} h" if s >= 3600 else f"{s / 60:.0f} min" if s >= 60 else f"{s:.0f} s"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="one fault seed, one fault-free seed")
    p.add_argument("--tune", action="store_true", help="score on the tuning seeds 100–199")
    p.add_argument("--far", type=float, default=0.01, help="false-alarm share (default 0.01)")
    p.add_argument("--train-days-1s", type=float, default=2.0)
    p.add_argument("--fault", action="append", choices=sorted(FAULTS))
    p.add_argument("--rate", action="append", choices=sorted(RATES))
    args = p.parse_args(argv)
    base = 100 if args.tune else 9000
    n_fault, n_free = (1, 1) if args.quick else (3, 3)
    fault_seeds = [base + i for i in range(n_fault)]
    free_seeds = [base + 50 + i for i in range(n_free)]
    rates = {k: RATES[k] for k in (args.rate or list(RATES))}
    faults = args.fault or list(FAULTS)
    t0 = time.perf_counter()

    train = {k: [] for k in rates}
    sim_s = 0.0
    for s in TRAIN_SEEDS:
        t1 = time.perf_counter()
        run = simulate_chemplant(10, s)
        sim_s += time.perf_counter() - t1
        for k, period in rates.items():
            if period == 1:
                train[k].append(run.iloc[: int(args.train_days_1s * 86400)])
            else:
                train[k].append(sample(run, period))
    cols = [c for c, v in CHEMPLANT_TAGS.items() if v[4] != "set-point"]
    models = {
        (k, m): PCABaseline(far=args.far, lags=lags, columns=cols).fit(train[k])
        for k in rates
        for m, lags in METHODS.items()
    }
    fit_s = time.perf_counter() - t0
    del train

    far = {key: [] for key in models}
    for s in free_seeds:
        run = simulate_chemplant(3, s)
        for (k, m), model in models.items():
            far[k, m].append(false_alarm_rate(model.alarms(sample(run, rates[k])), rates[k]))

    res = {}  # (rate, method, fault) -> list of (rate, delay, top3)
    for name in faults:
        f = FAULTS[name]
        for s in fault_seeds:
            run = simulate_chemplant(3, s, fault=name, onset_s=86400.0)
            onset = pd.Timestamp(run.attrs["fault"]["onset"])
            for (k, m), model in models.items():
                x = sample(run, rates[k])
                a = model.alarms(x)
                top = model.rank_tags(x, onset, a)
                res.setdefault((k, m, name), []).append(
                    (detection_rate(a, onset), detection_delay(a, onset), in_top(top, f.tags))
                )
    total_s = time.perf_counter() - t0

    print(
        f"Training: seeds {TRAIN_SEEDS[0]}–{TRAIN_SEEDS[-1]}, 10 days each (1 s: first "
        f"{args.train_days_1s:g} days); limits at {args.far:g} of samples. Fault-free seeds "
        f"{free_seeds}, fault seeds {fault_seeds}, 3-day runs, faults from day 1.\n"
    )
    for k in rates:
        print(f"### {k} data\n")
        head = "| fault | kind | tag | size |"
        rule = "|---|---|---|---|"
        for m in METHODS:
            head += f" {m} detected | {m} delay | {m} tag in top 3 |"
            rule += "---|---|---|"
        print(head + "\n" + rule)
        for name in faults:
            f = FAULTS[name]
            row = f"| {name} | {f.kind} | {', '.join(f.tags)} | {f.size:g} {f.unit} |"
            for m in METHODS:
                r = res[k, m, name]
                rate = np.mean([x[0] for x in r])
                delay = np.median([x[1] for x in r]) if all(np.isfinite(x[1]) for x in r) else (
                    np.nan if not any(np.isfinite(x[1]) for x in r) else
                    np.median([x[1] for x in r if np.isfinite(x[1])]))  # fmt: skip
                top = sum(x[2] for x in r)
                row += f" {rate:.0%} | {_delay(delay)} | {top}/{len(r)} |"
            print(row)
        row = "| **fault-free: share of samples / episodes per h** | | | |"
        for m in METHODS:
            sh = np.mean([x[0] for x in far[k, m]])
            eph = np.mean([x[1] for x in far[k, m]])
            row += f" {sh:.2%} | {eph:.2g} /h | |"
        print(row + "\n")
        means = {
            m: np.mean([np.mean([x[0] for x in res[k, m, n]]) for n in faults]) for m in METHODS
        }
        print(
            "mean detection rate over the faults: "
            + ", ".join(f"{m} {v:.0%}" for m, v in means.items())
            + "\n"
        )
    print(
        f"(simulation {sim_s / (10 * len(TRAIN_SEEDS)):.2f} s per simulated day at 1 s, "
        f"first run's numba compilation included; fit {fit_s:.0f} s, total {total_s:.0f} s)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
