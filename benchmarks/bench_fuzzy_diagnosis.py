"""Fuzzy diagnosis by rules (10)–(14) beside crisp isolation on the DAMADICS benchmark
(issue 26, gap 1).

For each example unit (``valve_unit``: Table 4 with the positioner loop; ``valve_t4``: Table 4
as printed) the same models and thresholds are run three ways on the same scenarios:

* ``crisp``: crisp symptoms, the nearest signature of the matrix;
* ``fuzzy``: three-valued N/0/P evaluation with each test's learned sets, rules (10)–(14) with
  their ELSE branches and certainty factors normalised over the unit's distinct hypotheses
  (:meth:`diag_plugin.diagnose.matrix.DiagnosticMatrix.rules`);
* ``fuzzy, width``: the same rules on sets of the unit-wide ``fuzzy_width`` (no learned sets).

Printed per unit and variant: scenarios detected, isolated (of those with a matrix column),
mean isolation time after the onset, the mean diagnosis accuracy (the benchmark's ``dacc``: 1
over the size of the last isolated set when it holds the fault, else 0) of the isolated
scenarios and of all scenarios with a matrix column, wrong isolations (the share of samples
isolating a set without the fault), and the mean false detection rate.

Then ``valve_t4`` (the printed Table 4) on the plant Table 4 describes (no positioner), the
five faults of ``tests/test_valve_isolation.py`` on seeds 501, 502, 701, 702: per fault the share
of the samples an hour after the onset that are FAILURE, that isolate the fault alone, and whose
isolated set holds it, crisp beside fuzzy. (``diag benchmark``'s scenarios run on the default
actuator with a positioner, which Table 4 does not describe.)

    python benchmarks/bench_fuzzy_diagnosis.py [--quick] [--seed N ...] [--folder DIR]
"""

from __future__ import annotations

import argparse
import re
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np


def variants(unit_file: Path, tmp: Path) -> dict[str, Path]:
    """Copies of the unit's folder with the unit file changed per variant."""
    text = unit_file.read_text(encoding="utf-8")
    out = {}
    for name, symptoms, keep_sets in (
        ("crisp", "crisp", True),
        ("fuzzy", "fuzzy", True),
        ("fuzzy, width", "fuzzy", False),
    ):
        folder = tmp / re.sub(r"\W+", "_", name)
        if not folder.exists():
            shutil.copytree(unit_file.parent, folder)
        t = re.sub(r'symptoms = "\w+"', f'symptoms = "{symptoms}"', text)
        if not keep_sets:
            t = re.sub(r", fuzzy = \[[^\]]*\]", "", t)
        path = folder / unit_file.name
        path.write_text(t, encoding="utf-8")
        out[name] = path
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="one strength per fault")
    ap.add_argument("--seed", type=int, action="append", dest="seeds")
    ap.add_argument("--folder", default=None, help="folder of the example units")
    ap.add_argument("--unit", action="append", dest="units")
    args = ap.parse_args()
    from diag_plugin.bench.damadics import run_benchmark
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.rulebase.folder import shipped_folder

    seeds = tuple(args.seeds or (11, 23, 37))
    folder = Path(args.folder) if args.folder else shipped_folder()
    print(f"seeds {', '.join(map(str, seeds))}; units from {folder}")
    print(
        "| unit | diagnosis | detected | isolated | isolation time, s | accuracy, isolated "
        "| accuracy, all | wrong isolation | false det. |"
    )
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.units or ("valve_unit", "valve_t4"):
            for variant, path in variants(folder / f"{name}.unit.toml", Path(tmp) / name).items():
                t0 = time.perf_counter()
                out = run_benchmark(Unit.load(path), quick=args.quick, seeds=seeds)
                rows, s = out["scenarios"], out["summary"]
                iso = [r for r in rows if r["unit_fault"] is not None and r["isolated"]]
                t_it = np.mean([r["isolation_time_s"] for r in iso]) if iso else float("nan")
                acc = [r["diagnosis_accuracy"] for r in iso if r["diagnosis_accuracy"] is not None]
                col = [r for r in rows if r["unit_fault"] is not None]
                acc_all = np.mean([r["diagnosis_accuracy"] or 0.0 for r in col])
                wrong = np.mean([r["mismatch_isolation_rate"] or 0.0 for r in col])
                print(
                    f"| {name} | {variant} | {s['scenarios_detected']}/{s['scenarios']} | "
                    f"{s['scenarios_isolated']}/{s['scenarios_with_isolation']} | {t_it:.0f} | "
                    f"{np.mean(acc) if acc else float('nan'):.2f} | {acc_all:.2f} | "
                    f"{wrong:.2%} | "
                    f"{s['mean_false_detection_rate']:.4f} |  ({time.perf_counter() - t0:.0f} s)",
                    flush=True,
                )

    table4(folder)


#: the five faults of Table 4's columns on its plant (tests/test_valve_isolation.py)
T4_CASES = (("f_EP", "f12", 0.2), ("f_P0", "f14", -0.3), ("f_S", "f11", 0.3),
            ("f_X", "f13", -0.3), ("f_V", "f3", 1.0))  # fmt: skip


def table4(folder: Path, seeds: tuple[int, ...] = (501, 502, 701, 702)) -> None:
    import pandas as pd

    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.examples.build import TABLE4_PLANT
    from diag_plugin.simulate import FaultSpec
    from diag_plugin.simulate.valve import ValveParams, simulate_valve

    onset = pd.Timestamp("2026-01-02", tz="UTC")
    print("\nvalve_t4 on its plant, an hour after the onset: FAILURE / the fault alone / held")
    print("| fault | " + " | ".join(f"{v}, seed {k}" for k in seeds for v in ("crisp", "fuzzy")))
    print("|---" * (1 + 2 * len(seeds)) + "|")
    with tempfile.TemporaryDirectory() as tmp:
        paths = variants(folder / "valve_t4.unit.toml", Path(tmp))
        units = {v: Unit.load(paths[v]) for v in ("crisp", "fuzzy")}
        for fault, name, size in T4_CASES:
            cells = []
            for seed in seeds:
                frame = simulate_valve(
                    1.5, seed=seed, params=ValveParams(**TABLE4_PLANT),
                    faults=[FaultSpec(name, size, onset)],
                )  # fmt: skip
                after = frame.index >= onset + pd.Timedelta("1h")
                for unit in units.values():
                    unit.reset()
                    d = unit.evaluate(frame)
                    st = np.asarray(d.status)[after]
                    f = np.asarray(d.faults, dtype=object)[after]
                    alone = np.mean(f == fault)
                    held = np.mean([fault in x.split("|") for x in f])
                    cells.append(f"{np.mean(st == 1):.0%} / {alone:.0%} / {held:.0%}")
            print(f"| {fault} ({name} {size:+g}) | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
