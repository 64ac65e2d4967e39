"""SKAB's matched false-alarm check on the **tuning** runs only (issue 34): the bench's
protocol (``diag benchmark --plant skab``) with the tuning runs in the scoring runs' place.

Per run a unit (``build_unit`` on the run's first 400 samples, as the bench builds every
run's), PCA and DPCA (two lags) T² + Q on the same rows; every method one score per sample
(:mod:`diag_plugin.bench.matched`, the unit's on/off delays); each limit matched on the
bench's calibration runs (the anomaly-free chunks and the tuning runs' samples after their
first 400 and before their anomaly; ``--recovery``: every label-0 sample after the first
400, the recovery after the anomaly included, the bench's protocol until 2026-12-02) and
SKAB's F1 / FAR / MAR on the tuning runs' samples after their first 400, with the per-fault
detection of the unit, PCA and DPCA. The scoring runs are not read.

``--leave-out`` scores each tuning run at limits matched without its own normal samples
(:func:`~diag_plugin.bench.matched.calibrate_leaving_out`), as the scoring runs are scored at
limits they did not set: with the common limits every target up to 0.01 sits on the largest
tuning fault's tail (its alarm held into the run's normal samples by the off-delay), which
leaves every method at F1 0 there and cannot tell two builds apart (with ``--recovery``).
``--drop-held`` (with ``--recovery``) leaves the off-delay's samples after each tuning fault
(the fault's alarm, held) out of the calibration: near what the bench does since 2026-12-02
(every sample after the anomaly out), as the tuning runs end within the off-delay after it.

``--dpca-t2 W`` scores the unit with ``W`` times DPCA's ``T²`` over its limit beside its own
statistics (a DPCA-like test among the unit's, emulated on the saved statistics; issue 34
round 12); ``--dpca-t2 budget`` takes each run's ``W`` from the unit's own budget
(:func:`dpca_weight`).

``--off-delay N`` scores every method with an off-delay of ``N`` samples in place of the
unit's (SKAB's tuning runs end 36–173 samples after their fault, under the 240 of a 1 s unit,
so a fault seen to its end is one plateau over all of its run's normal samples after it).

``--save FILE`` keeps every run's raw statistics (the unit's per test and T², over their
limits, before the delays) in a ``.npz`` for a look at what holds an alarm or misses a
fault; ``--load FILE`` (repeatable) reuses them. ``--scoring`` reports the 21 scoring runs
instead, with the same calibration — once, after a choice was made on the tuning runs
(``--build-only scoring --save FILE`` builds those alone, beside a tuning run). Run:
``python benchmarks/skab_matched_tuning.py`` (SKAB's mirror or ``$DIAG_SKAB_DIR``; 21
per-run builds, CPU time printed: the process's and its forked workers').
"""

from __future__ import annotations

import argparse
import resource

import numpy as np

#: the combined test's share of a SKAB unit's budget, alarms an hour (its ``[combined]`` notes)
COMBINED_FAR = 0.0005


def dpca_weight(run, cols: list[str], on: int, off: int, blocks: int = 5) -> float:
    """The weight a DPCA ``T²`` test would get among a unit's tests from the unit's own budget:
    DPCA's F limit over the threshold that :func:`~diag_plugin.learn.budget.calibrate_side`
    sets on the held-out ``T²`` of the run's first rows (DPCA fitted without each of
    ``blocks`` time blocks, as ``learn_combined`` takes the combined test's), at the combined
    test's share, Rice's Gaussian rate on ``√T²`` where the window is too short for a tail."""
    from diag_plugin.bench.publicbench import DPCA_LAGS, pca_fit
    from diag_plugin.learn.budget import calibrate_side

    head = run.frame.iloc[: run.learn].reset_index(drop=True)
    block = np.arange(len(head)) * blocks // len(head)
    t2 = np.full(len(head), np.nan)
    for b in range(blocks):
        det = pca_fit([head[block != b]], cols, DPCA_LAGS, 0.85)
        t2[block == b] = det.score(head)["T2"].to_numpy()[block == b]
    hours = float(np.isfinite(t2).sum()) / 3600.0
    side = calibrate_side(t2, hours, COMBINED_FAR, on, off)
    thr = side.threshold
    if side.method == "gaussian":
        thr = calibrate_side(np.sqrt(t2), hours, COMBINED_FAR, on, off).threshold ** 2
    return float(pca_fit([head], cols, DPCA_LAGS, 0.85).t2_limit_ / thr)


def cpu_seconds() -> float:
    """CPU seconds so far, the process's and its finished forked workers' (user + system)."""
    return sum(
        u.ru_utime + u.ru_stime
        for u in (resource.getrusage(resource.RUSAGE_SELF),
                  resource.getrusage(resource.RUSAGE_CHILDREN))
    )  # fmt: skip


def build_on_grid(run, folder):
    """The unit as the bench builds it: on the first ``run.learn`` samples of the run's 1 s
    grid (in ``folder``). Returns the build's result, the unit and the grid."""
    from diag_plugin.bench.publicbench import _sample_grid
    from diag_plugin.bench.publicplants import SKAB_TAGS
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.unitbuild.build import build_unit

    info = {t: {"unit": u, "description": d} for t, (u, d) in SKAB_TAGS.items()}
    grid = _sample_grid(run.frame, "1s")
    res = build_unit("skab", grid.iloc[: run.learn], folder=folder, period="1s", tag_info=info,
                     force=True)  # fmt: skip
    return res, Unit.load(res.path, folder), grid


def baselines(run, cols: list[str]) -> dict[str, np.ndarray]:
    """PCA's and DPCA's (two lags) raw statistics over the whole run, fitted on the same
    first ``run.learn`` rows as the unit."""
    from diag_plugin.bench.publicbench import DPCA_LAGS, pca_fit, pca_statistics

    head = run.frame.iloc[: run.learn]
    return {m: pca_statistics(pca_fit([head], cols, lags, 0.85), run.frame)[0]
            for m, lags in (("PCA", 0), ("DPCA", DPCA_LAGS))}  # fmt: skip


def build_run(run, folder, cols: list[str]):
    """One SKAB run as the bench builds and scores it: the unit built on the run's first
    ``run.learn`` samples (in ``folder``), PCA and DPCA (two lags) on the same rows. Returns
    the build's result, the unit and the raw statistics (``unit`` with ``unit_names``, ``PCA``,
    ``DPCA``: each statistic over its limit, per sample of the whole run)."""
    from diag_plugin.bench.publicbench import unit_statistics

    res, unit, grid = build_on_grid(run, folder)
    raw = {"unit": unit_statistics(unit, grid)[0],
           "unit_names": np.array(list(unit.tests) + ["T2"])}  # fmt: skip
    return res, unit, raw | baselines(run, cols)


def main(argv: list[str] | None = None) -> int:
    from _common import add_scratch_args, scratch

    from diag_plugin.bench.matched import (
        Scored,
        calibrate,
        calibrate_leaving_out,
        method_score,
        rates,
    )
    from diag_plugin.bench.publicbench import fault_free_mask, skab_metrics
    from diag_plugin.bench.publicplants import load_skab

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--targets", default="0.02,0.05,0.1,0.25", help="shares of samples")
    ap.add_argument("--save", default=None, help="keep the raw statistics in this .npz")
    ap.add_argument(
        "--load",
        action="append",
        default=[],
        help="raw statistics of runs already built (a --save of the same code)",
    )
    ap.add_argument(
        "--build-only",
        choices=("scoring",),
        default=None,
        help="build and --save the scoring runs' statistics only, no report",
    )
    ap.add_argument(
        "--scoring",
        action="store_true",
        help="score the 21 scoring runs instead (once, after a choice is made)",
    )
    ap.add_argument(
        "--leave-out",
        action="store_true",
        help="score each tuning run at limits matched without its own normal samples",
    )
    ap.add_argument(
        "--drop-held",
        action="store_true",
        help="with --recovery: leave the off-delay's samples after each tuning fault out of "
        "the calibration",
    )
    ap.add_argument(
        "--recovery",
        action="store_true",
        help="calibrate on every label-0 sample of the tuning runs, the recovery after the "
        "fault included (the bench's protocol until 2026-12-02)",
    )
    ap.add_argument(
        "--dpca-t2",
        default=None,
        metavar="W",
        help="add W times DPCA's T² (over its limit) to the unit's statistics: an emulation "
        "of a DPCA-like test among the unit's own (issue 34 round 12), not a build; "
        "'budget': each run's W from the unit's budget (dpca_weight)",
    )
    ap.add_argument(
        "--off-delay",
        type=int,
        default=None,
        metavar="N",
        help="score every method with an off-delay of N samples instead of the unit's (all "
        "alike; a look at what the held tails after the tuning faults do to the low targets, "
        "issue 34 H2: not the bench's protocol, which takes the unit's)",
    )
    add_scratch_args(ap, "nothing")
    args = ap.parse_args(argv)
    targets = [float(t) for t in args.targets.split(",")]

    plant = load_skab()
    cols = list(plant.tags)
    raw: dict[str, np.ndarray] = {}
    for f in args.load:
        raw.update(np.load(f))
    runs = list(plant.calibration) + (list(plant.faults) if args.scoring else [])
    if args.build_only:
        runs = list(plant.faults)
    scores: dict[str, dict[str, np.ndarray]] = {"unit": {}, "PCA": {}, "DPCA": {}}
    on = off = None

    cpu = cpu_seconds()
    with scratch("skab_tuning_", args.dir) as work:
        for k, run in enumerate(runs):  # the tuning runs are among the calibration runs
            if f"{run.name}|unit" not in raw:
                _, unit, one = build_run(run, work / f"run{k}", cols)
                on, off = int(unit.ev["on_delay"]), int(unit.ev["off_delay"])
                raw.update({f"{run.name}|{key}": v for key, v in one.items()})
                print(f"{run.name}: built and scored ({len(unit.tests)} tests)", flush=True)
                raw["delays"] = np.array([on, off])
            on, off = (int(v) for v in raw["delays"])
            off = args.off_delay or off
            for m in scores:
                x = raw[f"{run.name}|{m}"]
                if m == "unit" and args.dpca_t2 is not None:
                    w = args.dpca_t2
                    w = dpca_weight(run, cols, on, off) if w == "budget" else float(w)
                    x = np.c_[x, w * raw[f"{run.name}|DPCA"][:, :1]]
                scores[m][run.name] = method_score(x, on, off)[run.learn :]
    cpu = cpu_seconds() - cpu
    if args.save:
        np.savez_compressed(args.save, **raw)
    if args.build_only:
        return 0

    tuning = {r.name: r for r in (plant.faults if args.scoring else plant.tuning)}
    what = "scoring" if args.scoring else "tuning"
    print(f"\nSKAB {what} runs ({len(tuning)}), limits matched on {len(plant.calibration)} "
          f"calibration runs; delays {on}/{off}; CPU {cpu:.0f} s")  # fmt: skip
    print("target | " + " | ".join(f"{m} F1 / FAR / MAR (cal)" for m in scores))
    det_rows = []
    for target in targets:
        cells, det = [], {}
        for m, by_run in scores.items():
            cal = {}
            for run in plant.calibration:
                x = by_run[run.name]
                if run.labels is not None:
                    lab = run.labels[run.learn :]
                    keep = fault_free_mask(lab, args.recovery)
                    if args.drop_held:  # the off-delay's hold after a fault: its alarm
                        for e in np.flatnonzero((lab[:-1] > 0) & (lab[1:] == 0)):
                            keep[e + 1 : e + 1 + off] = False
                    x = x[keep]
                cal[run.name] = x
            lim = calibrate(list(cal.values()), target, 1.0).limit
            share = rates(list(cal.values()), lim, 1.0)[0]
            # per scored run its limit: the common one, or (--leave-out) one matched without
            # that run's own normal samples, as a scoring run is scored at limits it never set
            lab = [r.labels[r.learn :] for r in tuning.values()]
            lims = {n: lim for n in tuning}
            if args.leave_out:
                lims = {
                    n: v.limit for n, v in calibrate_leaving_out(cal, tuning, target, 1.0).items()
                }
            sk = skab_metrics([Scored(by_run[n]) for n in tuning], lab, [lims[n] for n in tuning])
            cells.append(f"{sk['F1']:.2f} / {sk['FAR']:.1%} / {sk['MAR']:.1%} ({share:.2%})")
            for n, r in tuning.items():
                s = by_run[n]
                act = r.labels[r.learn :] > 0
                det.setdefault(n, {})[m] = float(np.mean(np.nan_to_num(s[act], nan=-1) > lims[n]))
        print(f"{target:g} | " + " | ".join(cells))
        det_rows.append((target, det))
    for target, det in det_rows:
        print(f"\nfault samples in alarm at {target:g} (unit / PCA / DPCA):")
        for n, d in det.items():
            print(f"  {n:10s} {tuning[n].fault:40s} "
                  + " / ".join(f"{d[m]:.0%}" for m in scores))  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
