"""The isolated faults (``faults``: the alarm event's and the HMI's fault tag) against the
tags at fault, on a public plant's runs, with the derived matrix's compensated columns
(:func:`~diag_plugin.diagnose.unittags.compensating_tests`) and without them, one unit.

Per fault run, over the alarm samples after the onset: the share whose ``faults`` hold a tag
at fault ("right"), and the share naming tags none of which is at fault ("wrong"; ``unit``
and empty are neither). Prints one row per fault and the totals.

    python benchmarks/faults_field_naming.py --plant chemplant|tep|tep-studio [--quick]
        [--tuning]  (chemplant: the tuning seeds 101–103 instead of the scoring ones)
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np


def _score(d, run) -> tuple[int, int, int, int, int]:
    """Alarm samples after the onset; those whose faults hold a tag at fault; those naming
    only other tags; those whose first fault is at fault, as written and in the ranking's
    order (the faults' tags in the top three first, by rank; the rest after, as written)."""
    alarm = d.detected.to_numpy() == 1
    alarm[: run.onset] = False
    f = d.faults.to_numpy()[alarm]
    top = d.top_tags[["top1", "top2", "top3"]].to_numpy()[alarm]
    tags = set(run.tags)
    named = [[x for x in str(v).split("|") if x not in ("", "unit")] for v in f]
    right = sum(1 for s in named if set(s) & tags)
    wrong = sum(1 for s in named if s and not set(s) & tags)
    first = sum(1 for s in named if s and s[0] in tags)
    ranked = 0
    for s, t in zip(named, top, strict=True):
        if s:
            pos = {x: i for i, x in enumerate(t) if x}
            order = sorted(s, key=lambda x: (pos.get(x, len(pos)), s.index(x)))
            ranked += order[0] in tags
    return int(alarm.sum()), right, wrong, first, ranked


def _pct(s) -> str:
    return f"{100 * s[1] / max(s[0], 1):5.1f} / {100 * s[2] / max(s[0], 1):5.1f} %"


def _chemplant_tuning(plant) -> list:
    """The chemical plant's fault runs on its tuning seeds 101–103 (3 days, the fault from
    day 1, 3-min means), as :func:`~diag_plugin.bench.publicbench.chemplant_plant` makes the
    scoring ones."""
    from diag_plugin.bench.publicbench import chemplant_fault_run

    names = dict.fromkeys(r.fault for r in plant.faults)
    return [
        chemplant_fault_run(n, s, 3.0, 1.0, f"seed {s}") for n in names for s in (101, 102, 103)
    ]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--plant", default="chemplant", choices=["chemplant", "tep", "tep-studio"])
    p.add_argument("--quick", action="store_true")
    p.add_argument("--data", default=None)
    p.add_argument("--tuning", action="store_true", help="chemplant: the tuning seeds 101-103")
    a = p.parse_args()

    from diag_plugin.bench import publicbench as pb
    from diag_plugin.bench import publicplants as pp
    from diag_plugin.diagnose import unittags

    t = time.perf_counter()
    if a.plant == "chemplant":
        plant = pb.chemplant_plant(quick=a.quick)
        if a.tuning:
            plant.faults = _chemplant_tuning(plant)
    elif a.plant == "tep":
        plant = pp.load_braatz(a.data)
    else:
        plant = pp.load_tep_studio(a.data)
    with tempfile.TemporaryDirectory() as work:
        built = pb.build_unit_as_user(plant, plant.train, Path(work))
    unit = built["unit"]
    if unit is None:
        raise SystemExit(f"no unit: {built['note']}")
    print(f"{plant.name}: unit of {len(unit.tests)} tests built in {time.perf_counter() - t:.0f} s")
    with_cols = unit.matrix
    keep = unittags.compensating_tests
    unittags.compensating_tests = lambda *_: {}
    without = unittags.derived_matrix(unit)
    unittags.compensating_tests = keep
    changed = int((with_cols.entries != without.entries).sum())
    print(f"matrix entries the compensated columns add: {changed}")
    tot = {"with": np.zeros(5, int), "without": np.zeros(5, int)}
    print(f"{'fault':28s} {'alarm':>6s}  right/wrong with   right/wrong without")
    for run in plant.faults:
        row = {}
        for key, m in (("with", with_cols), ("without", without)):
            unit.matrix = m
            s = _score(unit.reset().evaluate(run.frame), run)
            tot[key] += s
            row[key] = s
        n = row["with"][0]
        name = f"{run.fault} {run.name}"
        print(f"{name:28s} {n:6d}  {_pct(row['with'])}   {_pct(row['without'])}")
    unit.matrix = with_cols
    for key, s in tot.items():
        print(
            f"all runs, {key:7s}: {s[0]} alarm samples, faults right {100 * s[1] / s[0]:.1f} %, "
            f"wrong {100 * s[2] / s[0]:.1f} %; the first fault right as written "
            f"{100 * s[3] / s[0]:.1f} %, in the ranking's order {100 * s[4] / s[0]:.1f} %"
        )


if __name__ == "__main__":
    main()
