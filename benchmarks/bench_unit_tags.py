"""The unit-level combined test and isolation to tags (issue 25), beside PCA T² + Q.

On the coupled six-tag process of :mod:`diag_plugin.examples.coupled` (a unit of five wm-avg
models, one per tag but B): models trained and thresholds learned on 14 fault-free days of seed
1 (cross-fitted, budget ``FAR`` per hour, half of it to the combined test); PCA T² + Q (dynamic,
one lag) fitted on the same window with its limits held to the same budget the same way
(``benchmarks/bench_detection_plants.py``'s ``pca_fit``). Then, on seeds never used:

* fault-free fortnights: false alarms per hour of the per-tag tests, the combined test, the
  unit, and PCA;
* faults from day 1 of 3-day runs: single sensor biases (each tag), coordinated small biases of
  several tags, and a process fault (D's gain on C down 2 %): the share of samples after the
  onset (past the filter's settling) in alarm for the tests alone, the combined test, the unit
  and PCA, and how often the faulted tag is first / among the top three of the unit's ranking.

Run: ``python benchmarks/bench_unit_tags.py [--quick]`` (prints markdown tables).
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from diag_plugin.diagnose.unit import Unit
from diag_plugin.diagnose.unitfile import UnitFile
from diag_plugin.diagnose.unittags import COMBINED_SHARE
from diag_plugin.examples.coupled import DAY, build, process
from diag_plugin.learn.thresholds import learn_thresholds
from diag_plugin.status import NE107

FAR = 0.01
SETTLE = 200
FAULTS = [
    ("A bias", {"A": 2.0}, 0.0, "A"),
    ("B bias", {"B": 2.0}, 0.0, "B"),
    ("C bias", {"C": 3.0}, 0.0, "C"),
    ("D bias", {"D": 3.0}, 0.0, "D"),
    ("E bias", {"E": 3.0}, 0.0, "E"),
    ("F bias", {"F": 4.0}, 0.0, "F"),
    ("D, E +2 (coordinated)", {"D": 2.0, "E": 2.0}, 0.0, None),
    ("C, D, E, F +1.5 (common mode)", {"C": 1.5, "D": 1.5, "E": 1.5, "F": 1.5}, 0.0, None),
    ("process: D's gain on C −2 %", {}, 0.02, None),
]


def _bench_plants():
    path = Path(__file__).with_name("bench_detection_plants.py")
    spec = importlib.util.spec_from_file_location("bench_detection_plants", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _episodes(on: np.ndarray) -> int:
    return int(on[0]) + int(np.count_nonzero(on[1:] & ~on[:-1])) if on.size else 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer seeds")
    args = ap.parse_args(argv)
    bp = _bench_plants()
    ff_seeds = range(101, 104) if args.quick else range(101, 111)
    fault_seeds = range(201, 203) if args.quick else range(201, 206)
    t0 = time.perf_counter()
    window = process(14 * DAY, 1)
    folder = Path(tempfile.mkdtemp(prefix="bench25_"))
    path = build(folder, window, {"combined": True, "isolation": "tags"})
    got = learn_thresholds(Unit.load(path), [window], far=FAR)
    uf = UnitFile.load(path)
    uf.set_learned(got)
    uf.save()
    unit = Unit.load(path)
    on, off = unit.ev["on_delay"], unit.ev["off_delay"]
    pca = bp.pca_fit(window, "60s", FAR, on, off)
    t_build = time.perf_counter() - t0

    hours = 0.0
    count = {"tests": 0, "combined": 0, "unit": 0, "pca": 0}
    for seed in ff_seeds:
        f = process(14 * DAY, seed)
        d = unit.reset().evaluate(f)
        hours += len(f) / 60
        st = d.status.to_numpy()
        count["tests"] += _episodes((d.symptoms.fillna(0).to_numpy() != 0).any(axis=1))
        count["combined"] += _episodes(d.combined["s_T2"].fillna(0).to_numpy() != 0)
        count["unit"] += _episodes((st != NE107.NORMAL) & (st != NE107.CHECK_FUNCTION))
        count["pca"] += _episodes(bp.pca_alarms(pca, f, on, off))
    print(f"## Combined test and isolation to tags (built and learned in {t_build:.1f} s)\n")
    print(
        f"Fault-free: {len(ff_seeds)} fortnights of unseen seeds ({hours:,.0f} h); budget "
        f"{FAR:g}/h, {COMBINED_SHARE:g} of it to the combined test\n"
    )
    print("| detector | false alarms/h | its budget | episodes |")
    print("|---|---|---|---|")
    budgets = {"tests": FAR * (1 - COMBINED_SHARE), "combined": FAR * COMBINED_SHARE}
    budgets |= {"unit": FAR, "pca": FAR}
    names = {"tests": "per-tag tests", "combined": "combined T²", "unit": "unit", "pca": "PCA T²+Q"}
    for k, n in count.items():
        print(f"| {names[k]} | {n / hours:.4f} | {budgets[k]:g} | {n} |")
    print(
        f"\nFaults from day 1 of 3-day runs, {len(fault_seeds)} unseen seeds: share of the "
        f"samples after the onset (+{SETTLE} min) in alarm; ranking: samples in alarm whose "
        "first / top-three tags hold the faulted one\n"
    )
    print("| fault | tests | combined | unit | PCA | top-1 | top-3 |")
    print("|---|---|---|---|---|---|---|")
    for label, bias, loss, tag in FAULTS:
        share = {k: [] for k in ("tests", "combined", "unit", "pca")}
        top1 = top3 = alarms = 0
        named: list[str] = []
        for seed in fault_seeds:
            f = process(3 * DAY, seed, bias, DAY, loss=loss)
            d = unit.reset().evaluate(f)
            cut = slice(DAY + SETTLE, None)
            st = d.status.to_numpy()[cut]
            share["tests"].append((d.symptoms.iloc[cut].fillna(0) != 0).any(axis=1).mean())
            share["combined"].append((d.combined["s_T2"].iloc[cut] == 1).mean())
            share["unit"].append(((st != NE107.NORMAL) & (st != NE107.CHECK_FUNCTION)).mean())
            share["pca"].append(bp.pca_alarms(pca, f, on, off)[cut].mean())
            top = d.top_tags.iloc[cut]
            al = top["top1"] != ""
            alarms += int(al.sum())
            named += list(top["top1"][al])
            if tag is not None:
                top1 += int((top["top1"][al] == tag).sum())
                top3 += int(top[["top1", "top2", "top3"]][al].eq(tag).any(axis=1).sum())
        if tag is not None:
            rank = (f"{top1 / alarms:.0%}", f"{top3 / alarms:.0%}") if alarms else ("—", "—")
        else:  # no single faulted tag: the tags the alarms name first
            firsts = pd.Series(named).value_counts(normalize=True).head(2)
            rank = (", ".join(f"{k} {v:.0%}" for k, v in firsts.items()) or "—", "")
        print(
            f"| {label} | "
            + " | ".join(f"{np.mean(share[k]):.0%}" for k in ("tests", "combined", "unit", "pca"))
            + f" | {rank[0]} | {rank[1]} |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
