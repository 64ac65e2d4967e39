"""What the unit's combined T² threshold rests on in a 400-sample window, and how little it says
of the samples after it (issue 34, H2): SKAB's **tuning** runs and the bench's calibration runs
only (the scoring runs are not read).

Per calibration run a unit is built as the bench builds it (``build_run`` of
``skab_matched_tuning.py``), and the combined test's threshold is taken apart: the build
calibrates it on the held-out blocks' ``√T²`` (each block's T² from parameters learned
without it) by Rice's Gaussian rate at the combined test's share of the budget
(:func:`~diag_plugin.learn.budget.rice_parts`; ``T² = (mean + spread · √(1 + 1/n) · z)²``,
``z`` Student t's at the series' own ``n`` independent values). Printed per unit: its tests in
T², the threshold and its ratio to χ²'s 0.999 quantile, the parts (mean, spread, ``n``,
``z``), the largest held-out T², the largest T² after the window on the run's fault-free
samples before any fault (after the bench's on/off delays, as its score takes it) and, for a
tuning run, T² over its fault's samples (median, and what the off-delay holds after it: the
plateau the bench's calibration counts).

``--save PREFIX`` writes, per threshold below, every calibration run's raw statistics as
``skab_matched_tuning.py --load`` reads them (the unit's T² column over that threshold; PCA's
and DPCA's as built), so the matched check can be run on them:

- ``PREFIX_main.npz``: the build's threshold;
- ``PREFIX_gauss.npz``: Rice's normal ``z`` (``n`` unbounded: no Student widening of ``√T²``'s
  own few values; every test in it is already at its predictive spread);
- ``PREFIX_n40.npz``: ``n`` = 40 for every unit (what a short window's low-pass is set to
  leave, ``short.SHORT_INDEPENDENT``).

These are emulations on saved statistics (the build's own threshold stays as it is): the
window's own episodes (``budget._seen``) never raised a SKAB unit's combined threshold, and the
script says where one would have. Run: ``python benchmarks/skab_t2_threshold.py [--save
/tmp/t2]`` (SKAB's mirror or ``$DIAG_SKAB_DIR``; 21 per-run builds, about 40 s of CPU), then
``python benchmarks/skab_matched_tuning.py --load /tmp/t2_gauss.npz --leave-out --targets
0.001,0.005,0.01,0.02,0.05,0.1,0.25``.
"""

from __future__ import annotations

import argparse
from contextlib import contextmanager

import numpy as np

#: the emulated thresholds: the independent values Rice's z is taken at (None: the series' own)
VARIANTS = {"main": None, "gauss": 1e9, "n40": 40.0}


@contextmanager
def combined_calibrations(out: list):
    """While open, every call of :func:`~diag_plugin.learn.budget.calibrate_side` made by
    :func:`~diag_plugin.learn.thresholds.learn_combined` appends ``(x, hours, rate, on, off,
    side)`` to ``out`` (a look inside the build; nothing it computes changes)."""
    import diag_plugin.learn.budget as budget
    import diag_plugin.learn.thresholds as thresholds

    inner, learn = budget.calibrate_side, thresholds.learn_combined
    inside = [False]

    def side(x, hours, rate, on_delay=1, off_delay=1):
        got = inner(x, hours, rate, on_delay, off_delay)
        if inside[0]:
            out.append((np.array(x, float), hours, rate, on_delay, off_delay, got))
        return got

    def combined(*a, **kw):
        inside[0] = True
        try:
            return learn(*a, **kw)
        finally:
            inside[0] = False

    budget.calibrate_side, thresholds.learn_combined = side, combined
    try:
        yield out
    finally:
        budget.calibrate_side, thresholds.learn_combined = inner, learn


def main(argv: list[str] | None = None) -> int:
    from _common import add_scratch_args, scratch
    from scipy.stats import chi2
    from skab_matched_tuning import build_run, cpu_seconds

    from diag_plugin.bench.matched import delayed_score
    from diag_plugin.bench.publicbench import _sample_grid
    from diag_plugin.bench.publicplants import load_skab
    from diag_plugin.learn.budget import rice_parts

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--save", default=None, metavar="PREFIX", help="write PREFIX_<variant>.npz")
    add_scratch_args(ap, "nothing")
    args = ap.parse_args(argv)

    plant = load_skab()
    cols = list(plant.tags)
    tuning = {r.name for r in plant.tuning}
    saved: dict[str, dict[str, np.ndarray]] = {v: {} for v in VARIANTS}
    cpu0 = cpu_seconds()
    print("run | T² of k tests: threshold (× χ²'s 0.999) | √T² held out: mean, spread, n, z "
          "| largest held-out T² | T² after the window: fault-free largest; fault median, "
          "held after it | threshold at n unbounded / 40")  # fmt: skip
    on = off = 1
    with scratch("skab_t2_", args.dir) as work:
        for k, run in enumerate(plant.calibration):
            seen: list = []
            with combined_calibrations(seen):
                _, unit, raw = build_run(run, work / f"run{k}", cols)
            on, off = int(unit.ev["on_delay"]), int(unit.ev["off_delay"])
            cm = unit.cmodel
            inside = len(cm.scale) - (0 if cm.outside is None else int(np.sum(cm.outside)))
            x, hours, rate, c_on, c_off, side = seen[-1]  # the last: √T² (Gaussian) or T²
            rooted = side.method == "gaussian"
            parts = {v: rice_parts(x, hours, rate, c_on, c_off, n) for v, n in VARIANTS.items()}
            high = {v: p.threshold**2 if rooted else np.nan for v, p in parts.items()}
            raised = rooted and not np.isclose(parts["main"].threshold, side.threshold)
            high["main"] = float(cm.high)
            d = unit.reset().evaluate(_sample_grid(run.frame, "1s")).combined
            t2 = delayed_score(d["T2"].to_numpy(), on, off)
            lab = run.labels if run.labels is not None else np.zeros(len(t2))
            after = np.arange(len(t2)) >= run.learn
            fault = lab > 0
            before = after & ~fault & (np.cumsum(fault) == 0)
            held = after & ~fault & (np.cumsum(fault) > 0)

            def top(mask, q=100.0, t2=t2):
                v = t2[mask]
                v = v[np.isfinite(v)]
                return f"{np.percentile(v, q):8.1f}" if v.size else "       -"

            p = parts["main"]
            tail = (f"{top(fault, 50)} {top(held, 50)}" if run.name in tuning
                    else "       -        -")  # fmt: skip
            print(f"{run.name:16s} k={inside:2d} {cm.high:7.1f} "
                  f"({cm.high / chi2.ppf(0.999, inside):5.2f}) | {p.mean:4.2f} {p.spread:4.2f} "
                  f"{p.n_eff:5.1f} {p.z:5.1f} | {np.nanmax(x) ** (2 if rooted else 1):7.1f} | "
                  f"{top(before)}; {tail} | {high['gauss']:7.1f} {high['n40']:7.1f}"
                  + ("  (raised by the window's own episodes)" if raised else ""))  # fmt: skip
            for v in VARIANTS:
                u = raw["unit"].copy()
                u[:, -1] *= cm.high / high[v]
                saved[v].update({f"{run.name}|unit": u, f"{run.name}|PCA": raw["PCA"],
                                 f"{run.name}|DPCA": raw["DPCA"]})  # fmt: skip
    print(f"delays {on}/{off}; CPU {cpu_seconds() - cpu0:.0f} s")
    if args.save:
        for v, arrays in saved.items():
            np.savez_compressed(f"{args.save}_{v}.npz", delays=np.array([on, off]), **arrays)
            print(f"wrote {args.save}_{v}.npz")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
