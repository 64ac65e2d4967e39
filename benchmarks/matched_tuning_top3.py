"""Detection and naming at matched false alarms on the **tuning** runs only (issue 34): the
bench's matched protocol (:func:`~diag_plugin.bench.publicbench.run_matched_benchmark`) with
each plant's tuning runs in place of its scoring runs, per fault the unit's, PCA's and DPCA's
detection, the runs whose faulted tag is in the top three and the runs whose faulted tag is
named first (the first of a run's ``top``: a run can hold the right tag in its top three and
still lead an operator to the wrong one), and the alarm episodes named right (of the episodes).

* ``--plant chemplant``: the unit built from training seeds 1–3 × 10 days (as the page),
  limits matched on fault-free seeds 150–152, fault-free 153–154, the faults on seeds
  101–103 (3-day runs, the fault from day 1) — the seeds the bench sets aside for tuning.
* ``--plant tep``: classic TEP, limits on ``d00_te``, fault-free the tuning runs no method
  detects (``d03``, ``d09``, ``d15``), the faults on ``d01.dat`` … ``d21.dat`` (faulty from
  their first sample).
* ``--plant tep-studio``: its calibration runs, the faults on its seed-101 tuning runs (the
  fault from hour 8; no fault-free scoring runs read).

The scoring runs are never simulated or read. ``--cache DIR`` keeps the simulated chemical
plant runs (parquet) so a second call does not simulate again. Run: ``python
benchmarks/matched_tuning_top3.py --plant chemplant [--cache DIR] [--json FILE] [--work
DIR]`` (minutes of CPU; ``--work`` keeps the unit it builds).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pandas as pd

#: classic TEP tuning runs whose fault no method detects (IDV3, IDV9, IDV15)
QUIET = ("d03", "d09", "d15")


def _sim(cache: Path | None, name: str, days: float, seed: int, fault: str | None = None,
         start: pd.Timestamp | None = None) -> tuple[pd.DataFrame, int | None]:  # fmt: skip
    """A 3-min sampled chemical plant run (from ``cache`` when there) and its onset row."""
    from diag_plugin.simulate.chemplant import sample, simulate_chemplant

    f = cache / f"{name}.parquet" if cache else None
    if f is not None and f.exists():
        return pd.read_parquet(f), json.loads(f.with_suffix(".json").read_text())["onset"]
    kw = {"fault": fault, "onset_s": 86400.0} if fault else {}
    if start is not None:
        kw["start"] = start
    raw = simulate_chemplant(days, seed, **kw)
    x = sample(raw, 180)
    onset = None
    if fault:
        t = pd.Timestamp(raw.attrs["fault"]["onset"])
        if x.index.tz is not None and t.tz is None:
            t = t.tz_localize(x.index.tz)
        onset = int(np.searchsorted(x.index, t))
    if f is not None:
        f.parent.mkdir(parents=True, exist_ok=True)
        x.to_parquet(f)
        f.with_suffix(".json").write_text(json.dumps({"onset": onset}))
    return x, onset


def chemplant_tuning(cache: Path | None = None):
    """The chemical plant with its tuning seeds as the runs scored (see module doc)."""
    from diag_plugin.bench.publicbench import chemplant_public
    from diag_plugin.bench.publicplants import PlantRun
    from diag_plugin.simulate.chemplant import FAULTS

    start = pd.Timestamp("2026-01-01", tz="UTC")
    train = []
    for s in (1, 2, 3):
        x, _ = _sim(cache, f"train_{s}", 10.0, s, start=start)
        train.append(PlantRun(f"seed {s}", x))
        start = x.index[-1] + pd.Timedelta("1h")
    cal = [PlantRun(f"seed {s}", _sim(cache, f"free_{s}", 3.0, s)[0]) for s in (150, 151, 152)]
    free = [PlantRun(f"seed {s}", _sim(cache, f"free_{s}", 3.0, s)[0]) for s in (153, 154)]
    faults = []
    for name in FAULTS:
        for s in (101, 102, 103):
            x, k = _sim(cache, f"{name}_{s}", 3.0, s, fault=name)
            faults.append(PlantRun(f"{name} seed {s}", x, name, k, tuple(FAULTS[name].tags)))
    return chemplant_public(
        train, cal, free, faults, "the chemical plant simulator, tuning seeds",
        ["train 1-3 x 10 d, calibration 150-152, fault-free 153-154, faults 101-103"],
    )  # fmt: skip


def tep_tuning(studio: bool):
    """Classic TEP or tep-studio with the tuning runs as the runs scored (module doc)."""
    from diag_plugin.bench.publicplants import load_braatz, load_tep_studio

    need = ("train", "calibration", "tuning")  # the scoring runs are not read
    plant = load_tep_studio(need=need) if studio else load_braatz()
    if studio:
        plant.faults, plant.free = list(plant.tuning), []
    else:
        plant.free = [r for r in plant.tuning if r.name in QUIET]
        plant.faults = [r for r in plant.tuning if r.name not in QUIET]
    plant.tuning = []
    return plant


def named_first(out: dict, point: dict, method: str, fault: str) -> int:
    """The runs of ``fault`` whose first named tag (the first of the run's ``top``, ranked by
    :func:`~diag_plugin.bench.matched.ranked_tags`) is one of its faulted tags, at one
    target of :func:`~diag_plugin.bench.matched.curve` for one method."""
    tags = set(out["fault_tags"].get(fault) or [])
    runs = point["methods"][method]["faults"][fault]["per_run"]
    return sum(bool(r["named_counted"] and r["top"] and r["top"][0] in tags) for r in runs)


def main(argv: list[str] | None = None) -> int:
    from diag_plugin.bench.publicbench import run_matched_benchmark

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plant", choices=("chemplant", "tep", "tep-studio"), default="chemplant")
    ap.add_argument("--targets", default="0.001,0.005,0.01,0.02,0.05", help="shares of samples")
    ap.add_argument("--cache", default=None, help="folder for the simulated chemplant runs")
    ap.add_argument("--json", default=None, help="write the whole result to this file")
    ap.add_argument("--work", default=None, help="keep the built unit in this folder")
    args = ap.parse_args(argv)
    targets = [float(t) for t in args.targets.split(",")]
    if args.plant == "chemplant":
        plant = chemplant_tuning(Path(args.cache) if args.cache else None)
    else:
        plant = tep_tuning(args.plant == "tep-studio")
    out = run_matched_benchmark(plant, targets=targets, per="sample", work=args.work)
    if args.json:
        Path(args.json).write_text(json.dumps(out, default=str), encoding="utf-8")
    methods = out["methods"]
    pts = out["curve"]["points"]
    print(f"{plant.name} tuning runs: {len(plant.faults)} fault runs; unit "
          f"{out['unit'].get('tests')} tests")  # fmt: skip
    faults = list(pts[0]["methods"][methods[0]]["faults"])
    print("| target | " + " | ".join(f"{m} det | {m} top 3 | {m} first | {m} episodes right"
                                      for m in methods) + " |")  # fmt: skip
    for p in pts:
        cells = [f"{p['target']:g}"]
        for m in methods:
            x = p["methods"][m]
            first = sum(named_first(out, p, m, f) for f in faults)
            cells += [f"{100 * x['mean_detection']:.1f} %", f"{x['in_top']}/{x['named_runs']}",
                      f"{first}/{x['named_runs']}",
                      f"{x['episodes_right']}/{x['episodes_named']}"]  # fmt: skip
        print("| " + " | ".join(cells) + " |")
    print()
    print("per fault, detection % / top 3 / named first at each target ("
          + ", ".join(f"{t:g}" for t in targets) + ")")  # fmt: skip
    for f in faults:
        cells = []
        for m in methods:
            cells.append(m + " " + " ".join(
                f"{100 * p['methods'][m]['faults'][f]['detection_rate']:.0f}/"
                f"{p['methods'][m]['faults'][f]['in_top']}/{named_first(out, p, m, f)}"
                for p in pts))  # fmt: skip
        print(f"{f:24s} " + " | ".join(cells))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
