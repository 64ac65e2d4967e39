"""Does a matched limit hold out of sample on the TEP? The check on the **calibration and
tuning** runs only (issue 34; ``docs/results/index.md``, "Why the unit's matched limit…").

The built unit (the bench's plain ``diag import`` + ``diag unit build`` on the training
runs), PCA and DPCA T² + Q, each one score per sample (:mod:`diag_plugin.bench.matched`),
then:

1. **The bench's protocol on the tuning runs**: each limit matched on the calibration runs,
   the share of samples in alarm on the fault-free tuning samples, and the mean detection
   over the tuning runs' faulty samples. Classic TEP (``--plant tep``): calibration
   ``d00_te``; fault-free the tuning runs whose fault no method detects (``d03``, ``d09``,
   ``d15`` — 480 samples each); detection over the other ``dXX.dat`` (faulty throughout).
   tep-studio (``--plant tep-studio``): the three calibration runs; fault-free the tuning
   runs' samples before their onset, detection after it (none where the tuning runs have
   not been simulated).
2. **Leave one run out**: the fault-free runs none of the methods learned from (the
   calibration runs and the fault-free tuning samples above), each whole run in turn alone
   setting the limit (classic TEP: ``d00_te`` and the three quiet tuning runs; tep-studio:
   its calibration runs), the share in alarm on all the others — how far one run's limit
   moves on the next, per method.

The scoring runs are not read. Run: ``python benchmarks/tep_matched_tuning.py [--plant
tep-studio]`` (the data in ``~/.cache/diag-plugin``; a minute or a few of CPU).
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
    from diag_plugin.bench.publicplants import load_braatz, load_tep_studio

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plant", choices=("tep", "tep-studio"), default="tep")
    ap.add_argument("--targets", default="0.005,0.01,0.02,0.05", help="shares of samples")
    add_scratch_args(ap, "nothing")
    args = ap.parse_args(argv)
    targets = [float(t) for t in args.targets.split(",")]

    plant = load_braatz() if args.plant == "tep" else load_tep_studio()
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

    if args.plant == "tep":
        quiet = [r.frame for r in plant.tuning if r.name in QUIET]
        faulty = [(r.frame, 0) for r in plant.tuning if r.name not in QUIET]
    else:  # before and after each tuning run's onset (scored from the run's start)
        quiet = [r.frame.iloc[: r.onset] for r in plant.tuning]
        faulty = [(r.frame, int(r.onset or 0)) for r in plant.tuning]
    cal = [r.frame for r in plant.calibration]
    print(f"unit: {len(unit.tests)} tests from {built.get('rows')} rows; delays {on}/{off}")
    print(f"calibration runs: {', '.join(r.name for r in plant.calibration)}; "
          f"fault-free tuning samples: {sum(len(f) for f in quiet)}; "
          f"detection over {len(faulty)} tuning runs")  # fmt: skip
    print()
    period = plant.period_s
    head = "| method | target | fault-free tuning | detection | leave one run out: mean (each) |"
    print(head)
    print("|---" * 5 + "|")

    def pct(x: float, spec: str = ".2f") -> str:
        return f"{100 * x:{spec}} %" if np.isfinite(x) else "—"

    for m in ("unit", "PCA", "DPCA"):
        s_cal = [score(m, f) for f in cal]
        s_quiet = [score(m, f) for f in quiet]
        s_fault = [(score(m, f), k) for f, k in faulty]
        for t in targets:
            lim = calibrate(s_cal, t, period).limit
            free = rates(s_quiet, lim, period)[0] if s_quiet else np.nan
            hits = [np.mean(np.nan_to_num(s[k:], nan=-np.inf) > lim) for s, k in s_fault]
            det = float(np.mean(hits)) if hits else np.nan
            # whole fault-free runs take turns (classic TEP: d00_te and the three quiet
            # tuning runs); tep-studio's 8-hour pieces before an onset only score
            pool = s_cal + s_quiet
            turns = len(pool) if args.plant == "tep" else len(s_cal)
            each = []
            for i in range(turns):
                li = calibrate([pool[i]], t, period).limit
                each.append(rates(pool[:i] + pool[i + 1 :], li, period)[0])
            shown = " ".join(f"{100 * x:.1f}" for x in each)
            print(f"| {m} | {100 * t:g} % | {pct(free)} | {pct(det, '.1f')} | "
                  f"{pct(float(np.mean(each)))} ({shown}) |")  # fmt: skip
    print()
    print("leave one run out: each whole fault-free run in turn sets the limit alone")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
