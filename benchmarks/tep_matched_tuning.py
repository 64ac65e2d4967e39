"""Does a matched limit hold out of sample on the classic TEP? The check on the **tuning** runs
only (issue 34; ``docs/results/index.md``, "Why the unit's matched limit…").

The built unit (the bench's plain ``diag import`` + ``diag unit build`` on ``d00.dat``), PCA
and DPCA T² + Q, each one score per sample (:mod:`diag_plugin.bench.matched`), then:

1. **The bench's protocol on the tuning runs**: each limit matched on ``d00_te`` (the
   calibration run), the share of samples in alarm on the tuning runs the faults leave
   fault-free to every method (``d03``, ``d09``, ``d15`` — 480 samples each), and the mean
   detection over the other tuning runs (``d01.dat`` … ``d21.dat``, faulty throughout).
2. **Leave one run out**: the four fault-free runs none of the methods learned from
   (``d00_te`` and the three above), each in turn the calibration run, the share in alarm on
   the other three at its limit — how far one run's limit moves on the next, per method.

The scoring runs (``dXX_te``) are not read. Run: ``python benchmarks/tep_matched_tuning.py``
(the classic data in ``~/.cache/diag-plugin/tep-braatz``; about a minute of CPU).
"""

from __future__ import annotations

import argparse

import numpy as np

#: tuning runs whose fault no method detects (IDV3, IDV9, IDV15): fault-free to every method
QUIET = ("d03", "d09", "d15")


def main(argv: list[str] | None = None) -> int:
    from _common import add_scratch_args, scratch

    from diag_plugin.bench.matched import calibrate, method_score, rates
    from diag_plugin.bench.publicbench import (
        DPCA_LAGS,
        build_unit_as_user,
        pca_fit,
        pca_statistics,
        unit_statistics,
    )
    from diag_plugin.bench.publicplants import load_braatz

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--targets", default="0.005,0.01,0.02,0.05", help="shares of samples")
    add_scratch_args(ap, "nothing")
    args = ap.parse_args(argv)
    targets = [float(t) for t in args.targets.split(",")]

    plant = load_braatz()
    with scratch("tep_tuning_", args.dir) as work:
        built = build_unit_as_user(plant, plant.train, work)
    unit = built["unit"]
    if unit is None:
        print(f"the unit was not built: {built['note']}")
        return 1
    on, off = int(unit.ev["on_delay"]), int(unit.ev["off_delay"])
    cols = list(plant.tags)
    frames = [r.frame for r in plant.train]
    dets = {"PCA": pca_fit(frames, cols, 0, 0.9), "DPCA": pca_fit(frames, cols, DPCA_LAGS, 0.9)}

    def score(method: str, frame) -> np.ndarray:
        if method == "unit":
            stats = unit_statistics(unit, frame)[0]
        else:
            stats = pca_statistics(dets[method], frame)[0]
        return method_score(stats, on, off)

    quiet = [r for r in plant.tuning if r.name in QUIET]
    faulty = [r for r in plant.tuning if r.name not in QUIET]
    pool = plant.calibration + quiet
    print(f"unit: {len(unit.tests)} tests from {built.get('rows')} rows; delays {on}/{off}")
    print(f"fault-free tuning runs: {', '.join(r.name for r in quiet)}; "
          f"detection over {len(faulty)} tuning runs")  # fmt: skip
    print()
    period = plant.period_s
    head = "| method | target | on d03/d09/d15 | detection | leave one run out: mean (each) |"
    print(head)
    print("|---" * 5 + "|")
    for m in ("unit", "PCA", "DPCA"):
        s_pool = [score(m, r.frame) for r in pool]
        s_fault = [score(m, r.frame) for r in faulty]
        for t in targets:
            lim = calibrate(s_pool[:1], t, period).limit
            free = rates(s_pool[1:], lim, period)[0]
            det = np.mean([np.mean(np.nan_to_num(s, nan=-np.inf) > lim) for s in s_fault])
            each = []
            for i in range(len(s_pool)):
                li = calibrate([s_pool[i]], t, period).limit
                each.append(rates(s_pool[:i] + s_pool[i + 1 :], li, period)[0])
            shown = " ".join(f"{100 * x:.1f}" for x in each)
            print(f"| {m} | {100 * t:g} % | {100 * free:.2f} % | {100 * det:.1f} % | "
                  f"{100 * np.mean(each):.2f} % ({shown}) |")  # fmt: skip
    print()
    print("leave one run out: calibration run in turn " + ", ".join(r.name for r in pool))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
