"""Why the unit misses SKAB's inlet-valve faults (valve1) at the low matched targets (issue 34
item 1): the six **tuning** valve1 runs only (the scoring runs are not read).

Per tuning valve1 run a unit built as the bench builds it (``build_run`` of
``skab_matched_tuning.py``: the first 400 samples at 1 s) is replayed over the whole run and,
over the run's fault samples (label 1 after the first 400), printed:

1. the samples after the onset and, at the unit's own threshold (1) and at each matched
   limit, the share in alarm (the bench's score: each statistic after its own on/off delays,
   their maximum, :func:`~diag_plugin.bench.matched.method_score`), unknown (no statistic
   known: CHECK_FUNCTION, counted as not in alarm) and quiet (known, under the limit); with
   the share the score *before* the delays is over the limit (what the on-delay costs);
2. per test (and the combined T²): the share of fault samples it is unknown, its median and
   largest delayed statistic over its threshold, the share over the limit; for the unknown
   samples the unit's own reason (``Diagnosis.why``: the input outside what the window
   learned), most frequent first;
3. the calibration's score (``--load``: a ``skab_matched_tuning.py --save`` of the same code;
   the bench's calibration samples, before each run's anomaly): its share exactly 0, under 1,
   and the largest distinct values with their samples (what keeps the calibration share at 0 %
   up to 0.02: a plateau of ≥ 0.02 of the samples at the top).

The matched limits are each run's leave-out limits (the calibration without the run's own
samples, as ``skab_matched_tuning.py --leave-out``), taken from the ``--load`` file.
Run: ``python benchmarks/skab_valve1_tuning.py --load /tmp/main.npz`` (SKAB's mirror or
``$DIAG_SKAB_DIR``; six builds, about 20 s of CPU).
"""

from __future__ import annotations

import argparse
from collections import Counter

import numpy as np


def main(argv: list[str] | None = None) -> int:
    from _common import add_scratch_args, scratch
    from skab_matched_tuning import build_run

    from diag_plugin.bench.matched import calibrate_leaving_out, delayed_score, method_score
    from diag_plugin.bench.publicbench import _sample_grid, fault_free_mask
    from diag_plugin.bench.publicplants import load_skab

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--load", default=None, help="a skab_matched_tuning.py --save (calibration)")
    ap.add_argument("--targets", default="0.001,0.01,0.05", help="shares of samples")
    ap.add_argument("--folder", default="valve1", help="the fault folder to read")
    add_scratch_args(ap, "nothing")
    args = ap.parse_args(argv)
    targets = [float(t) for t in args.targets.split(",")]

    plant = load_skab()
    cols = list(plant.tags)
    runs = [r for r in plant.tuning if r.name.startswith(args.folder)]
    cal_raw = dict(np.load(args.load)) if args.load else {}
    on = off = None
    if cal_raw:
        on, off = (int(v) for v in cal_raw["delays"])
        cal = {}
        for r in plant.calibration:
            x = method_score(cal_raw[f"{r.name}|unit"], on, off)[r.learn :]
            if r.labels is not None:
                x = x[fault_free_mask(r.labels[r.learn :])]
            cal[r.name] = x
        lims = {t: calibrate_leaving_out(cal, [r.name for r in runs], t, 1.0) for t in targets}
        allc = np.concatenate(list(cal.values()))
        print(f"calibration: {allc.size} samples; unknown {np.isnan(allc).mean():.2%}, "
              f"exactly 0 {np.mean(allc == 0):.2%}, under 1 {np.mean(allc < 1):.2%}, "
              f"over 1 {np.mean(allc > 1):.2%}")  # fmt: skip
        v, c = np.unique(np.round(allc[np.isfinite(allc)], 3), return_counts=True)
        top = []
        for val, cnt in zip(v[::-1], c[::-1], strict=True):
            top.append(f"{val:.2f}×{cnt}")
            if len(top) == 8:
                break
        print("  largest values (value × samples): " + ", ".join(top))
        for t in targets:
            one = next(iter(lims[t].values()))
            print(f"  target {t:g}: limits {sorted({round(x.limit, 3) for x in lims[t].values()})}"
                  f", share over {one.share:.2%}")  # fmt: skip

    with scratch("skab_valve1_", args.dir) as work:
        for k, run in enumerate(runs):
            _, unit, raw = build_run(run, work / f"run{k}", cols)
            on, off = int(unit.ev["on_delay"]), int(unit.ev["off_delay"])
            names = list(raw["unit_names"])
            grid = _sample_grid(run.frame, "1s")
            d = unit.reset().evaluate(grid)
            lab = run.labels
            act = lab > 0
            act[: run.learn] = False
            x = raw["unit"]
            score = method_score(x, on, off)[act]
            undelayed = np.nanmax(np.where(np.isnan(x), -np.inf, x), axis=1)[act]
            print(f"\n{run.name} ({run.fault}): {act.sum()} fault samples, onset "
                  f"{np.flatnonzero(act)[0] - run.learn} s after the window; delays {on}/{off};"
                  f" {len(unit.tests)} tests")  # fmt: skip
            levels = [("own 1", 1.0)] + [
                (f"{t:g}", lims[t][run.name].limit) for t in targets if cal_raw
            ]
            for what, lim in levels:
                print(f"  at {what:6s} (limit {lim:5.2f}): alarm {np.mean(score > lim):4.0%}, "
                      f"unknown {np.mean(np.isnan(score)):4.0%}, quiet "
                      f"{np.mean(score <= lim):4.0%}; before the delays over "
                      f"{np.mean(undelayed > lim):4.0%}")  # fmt: skip
            dd = delayed_score(x, on, off)[act]
            why = d.why.to_numpy()[act] if d.why is not None else None
            for j, name in enumerate(names):
                col = dd[:, j]
                unk = np.isnan(x[act, j])
                med = np.nanmedian(col) if (~np.isnan(col)).any() else np.nan
                mx = np.nanmax(col) if (~np.isnan(col)).any() else np.nan
                over = [np.mean(np.nan_to_num(col, nan=-1) > lim) for _, lim in levels]
                print(f"    {name:40s} unknown {unk.mean():4.0%}  median {med:6.2f}  max "
                      f"{mx:6.2f}  over " + " / ".join(f"{o:.0%}" for o in over))  # fmt: skip
                t = unit.models.get(name)
                if t is not None and unk.any():
                    outside = []
                    for spec in [*t.inputs, t.output]:
                        tag = str(spec).split("[")[0].strip('"')
                        if tag not in grid:
                            continue
                        col_in = grid[tag].to_numpy(float)
                        lo, hi = np.nanmin(col_in[: run.learn]), np.nanmax(col_in[: run.learn])
                        v = col_in[act]
                        outside.append(f"{tag} {np.mean((v < lo) | (v > hi)):.0%}")
                    ins = ", ".join(map(str, t.inputs)) or "its window mean"
                    print(f"      {t.output} = f({ins});"
                          f" fault samples outside the window's min-max: "
                          f"{', '.join(outside) or '-'}")  # fmt: skip
            if why is not None:
                reasons = Counter(w for w in why if isinstance(w, str) and w)
                for w, n in reasons.most_common(3):
                    print(f"    why ({n} samples): {w[:200]}")
            status = d.status.to_numpy()[act]
            print("    status: " + ", ".join(f"{s}×{n}" for s, n in Counter(status).most_common()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
