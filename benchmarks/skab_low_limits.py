"""What SKAB's matched limits at low false-alarm rates are set on, and why a single slow tag's
excursion (the Thermocouple's) cannot reach them (issue 34, H1): SKAB's **tuning** runs
and the bench's calibration runs only (the scoring runs are not read).

Per calibration run a unit (``build_unit`` on the run's first 400 samples, as the bench and
``skab_matched_tuning.py`` build it), PCA and DPCA (two lags) on the same rows; every method's
score as the bench takes it (:func:`~diag_plugin.bench.matched.method_score`: each statistic
over its limit, after the on/off delays, their maximum). The calibration samples are the
bench's: a labelled run's samples before its anomaly (``--recovery``: every label-0 sample,
the recovery after the anomaly included, the bench until 2026-12-02; the held plateaus of
item 1 are those). Since then (2026-12-02, load 6–7): the unit's limit at 0.001–0.02 is 2.80,
a 240-sample plateau of anomaly-free[3]'s flow level test (0.05: 2.66, anomaly-free[7]'s
T²); PCA's 11.76 / 10.92 / 6.40 / 6.40 (valve1/12 before its anomaly, anomaly-free[4]).
Printed:

1. per method and target the matched limit and the calibration share over it; then the
   distinct values of the largest 5 % of calibration samples
   (:func:`~diag_plugin.bench.matched.tail_levels`): each with its samples and episodes, the
   run holding it, the unit's statistic that is largest there, and whether all of its samples
   lie within the off-delay after a fault's last labelled sample (``held``: the fault's own
   alarm, held over the run's normal samples);
2. per run the Thermocouple's and the Temperature's test (inputs, method, why) or why the
   build left the tag untested; for each test the share of samples after the window it is
   unknown (an input past its span), its largest value over its threshold on the run's normal
   and fault samples, and ``g``: the combined T² over its limit per squared ratio of that test
   alone (``(threshold / scale)² · (S⁻¹)ᵢᵢ / limit``), so ``√(λ / g)`` is the ratio the test
   must reach for T² to pass a matched limit ``λ``; with the unit's T² threshold (its tests in
   T², the threshold over χ²'s 0.999 quantile of as many degrees of freedom);
3. per tuning fault the median over its samples of the unit's largest delayed statistic (and
   which), of its T², and of PCA's and DPCA's scores, beside the limits.

Run: ``python benchmarks/skab_low_limits.py`` (SKAB's mirror or ``$DIAG_SKAB_DIR``; 21
per-run builds, about 30 s of CPU).
"""

from __future__ import annotations

import argparse

import numpy as np

#: the two temperatures (the brief's question): printed in part 2
SLOW = ("Thermocouple", "Temperature")


def held_mask(labels: np.ndarray | None, n: int, off: int) -> np.ndarray:
    """Samples within ``off`` samples after a fault's last labelled sample (label > 0 then 0)."""
    out = np.zeros(n, bool)
    if labels is None:
        return out
    for e in np.flatnonzero((labels[:-1] > 0) & (labels[1:] == 0)):
        out[e + 1 : e + 1 + off] = True
    return out


def gains(unit) -> dict[str, float]:
    """Per test in the combined T²: T² over its limit per squared ratio of that test alone
    (its scale, centre and the covariance's row are the test's, in the unit's test order)."""
    cm = getattr(unit, "cmodel", None)
    if cm is None or not cm.high:
        return {}
    lo, hi = unit._limits()
    names = list(unit.tests)
    inv = np.linalg.pinv(cm.cov)
    out = {}
    for i, t in enumerate(names):  # centre, scale and covariance are per test
        if cm.outside is not None and cm.outside[i]:
            continue
        thr = (abs(lo[i]) + abs(hi[i])) / 2.0
        out[t] = float((thr / cm.scale[i]) ** 2 * inv[i, i] / cm.high)
    return out


def main(argv: list[str] | None = None) -> int:
    from _common import add_scratch_args, scratch
    from scipy.stats import chi2
    from skab_matched_tuning import build_run, cpu_seconds

    from diag_plugin.bench.matched import calibrate, delayed_score, method_score, tail_levels
    from diag_plugin.bench.publicbench import fault_free_mask
    from diag_plugin.bench.publicplants import load_skab

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--targets", default="0.001,0.005,0.01,0.02,0.05,0.1", help="shares")
    ap.add_argument("--share", type=float, default=0.05, help="the calibration tail listed")
    ap.add_argument(
        "--recovery",
        action="store_true",
        help="calibrate on every label-0 sample, the recovery after an anomaly included (the "
        "bench until 2026-12-02); default: a run's samples before its anomaly, as the bench",
    )
    add_scratch_args(ap, "nothing")
    args = ap.parse_args(argv)
    targets = [float(t) for t in args.targets.split(",")]

    plant = load_skab()
    cols = list(plant.tags)
    tuning = {r.name for r in plant.tuning}
    stats: dict[str, dict[str, np.ndarray]] = {}
    names: dict[str, list[str]] = {}
    rows: dict[str, dict] = {}
    cpu0 = cpu_seconds()
    on = off = 1
    with scratch("skab_low_", args.dir) as work:
        for k, run in enumerate(plant.calibration):
            res, unit, one = build_run(run, work / f"run{k}", cols)
            on, off = int(unit.ev["on_delay"]), int(unit.ev["off_delay"])
            names[run.name] = [str(n) for n in one.pop("unit_names")]
            stats[run.name] = one
            cm = unit.cmodel
            inside = len(cm.scale) - (0 if cm.outside is None else int(np.sum(cm.outside)))
            rows[run.name] = {
                "tests": {t.test: t for t in res.tests},
                "skipped": dict(res.skipped),
                "gain": gains(unit),
                "high": float(cm.high),
                "inside": inside,
            }
    cpu = cpu_seconds() - cpu0

    # ---- 1. the limits and the calibration's largest values
    cal_runs = list(plant.calibration)
    keep = {}
    for r in cal_runs:
        k = np.arange(len(r.frame)) >= r.learn
        if r.labels is not None:  # the bench's: before the anomaly (--recovery: every label 0)
            k &= fault_free_mask(r.labels, args.recovery)
        keep[r.name] = k
    scores = {m: {r.name: method_score(stats[r.name][m], on, off) for r in cal_runs}
              for m in ("unit", "PCA", "DPCA")}  # fmt: skip
    delayed = {r.name: delayed_score(stats[r.name]["unit"], on, off) for r in cal_runs}
    n_cal = sum(int(k.sum()) for k in keep.values())
    print(f"SKAB calibration runs: {len(cal_runs)} ({n_cal} normal samples after the window), "
          f"delays {on}/{off}; CPU {cpu:.0f} s")  # fmt: skip
    limits: dict[str, dict[float, float]] = {}
    for m, by_run in scores.items():
        cal = [by_run[r.name][keep[r.name]] for r in cal_runs]
        limits[m] = {}
        print(f"\n{m}: matched limit (calibration share over it) per target")
        for t in targets:
            lim = calibrate(cal, t, 1.0)
            limits[m][t] = lim.limit
            print(f"  {t:g}: {lim.limit:.4g} ({lim.share:.2%})")
        for share in (0.001, 0.005, 0.01, 0.02, 0.05):
            lv = tail_levels(cal, share)
            print(f"  top {share:.1%} of calibration samples: {len(lv)} distinct values")
        print(
            f"  the largest {args.share:.0%}: value, samples, episodes, run, "
            + ("largest statistic, " if m == "unit" else "")
            + "held"
        )
        for lv in tail_levels(cal, args.share):
            for i in lv.runs:
                r = cal_runs[i]
                x = by_run[r.name][keep[r.name]]
                at = np.flatnonzero(keep[r.name])[x == lv.value]
                held = held_mask(r.labels, len(r.frame), off)[at].all()
                what = ""
                if m == "unit":
                    d = delayed[r.name][at]
                    j = np.nanargmax(np.where(np.isnan(d), -np.inf, d), axis=1)
                    which = {names[r.name][q] for q in j}
                    what = "/".join(sorted(which)) + ", "
                print(f"    {lv.value:10.4g} {len(at):4d} {lv.episodes:2d}  {r.name:16s} "
                      f"{what}{'held' if held else 'NOT held'}")  # fmt: skip

    # ---- 2. the two temperatures in each unit
    print(
        "\nThe temperatures' tests per unit (unknown after the window; largest ratio "
        "normal / fault; g; the ratio T² needs at the unit's limits "
        + " / ".join(f"{t:g}" for t in targets)
        + ")"
    )
    for r in cal_runs:
        row = rows[r.name]
        print(
            f"  {r.name:16s} T² of {row['inside']} tests, threshold {row['high']:.4g} "
            f"({row['high'] / chi2.ppf(0.999, row['inside']):.3g} × χ²'s 0.999 quantile)"
        )
        after = np.arange(len(r.frame)) >= r.learn
        lab = r.labels if r.labels is not None else np.zeros(len(r.frame))
        for tag in SLOW:
            t = row["tests"].get(tag)
            if t is None:
                why = row["skipped"].get(tag, "")
                print(f"  {r.name:16s} {tag:12s} no test: {why[:150]}")
                continue
            x = stats[r.name]["unit"][:, names[r.name].index(tag)]
            unk = float(np.mean(np.isnan(x[after])))

            def peak(mask, x=x):
                v = x[mask]
                v = v[np.isfinite(v)]
                return f"{v.max():.2f}" if v.size else "-"

            g = row["gain"].get(tag, np.nan)
            need = " / ".join(f"{np.sqrt(limits['unit'][q] / g):.1f}" for q in targets)
            print(f"  {r.name:16s} {tag:12s} = f({', '.join(t.inputs) or 'its window mean'}) "
                  f"[{t.method}] unknown {unk:.0%}; largest {peak(after & (lab == 0))} / "
                  f"{peak(after & (lab > 0))}; g {g:.3g}; needs {need}")  # fmt: skip

    # ---- 3. the tuning faults against the limits
    print(
        "\nTuning faults: median over the fault (unit: its largest delayed statistic, which; "
        "its T²; PCA; DPCA), then the limits"
    )
    for r in cal_runs:
        if r.name not in tuning:
            continue
        f = r.labels > 0
        d = delayed[r.name][f]
        dd = np.where(np.isnan(d), -np.inf, d)
        j = np.argmax(dd, axis=1)
        top = names[r.name][int(np.bincount(j).argmax())]
        med = float(np.median(dd.max(axis=1)))
        t2 = float(np.nanmedian(d[:, -1]))
        pm = [float(np.nanmedian(scores[m][r.name][f])) for m in ("PCA", "DPCA")]
        print(f"  {r.name:10s} {r.fault:38s} unit {med:8.3g} ({top}) T² {t2:8.3g}  "
              f"PCA {pm[0]:8.3g}  DPCA {pm[1]:8.3g}")  # fmt: skip
    for m in limits:
        print(f"  limits {m}: " + " / ".join(f"{limits[m][t]:.4g}" for t in targets))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
