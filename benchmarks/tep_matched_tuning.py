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

3. **More fault-free runs** (tep-studio, ``--more DIR``: the ``tunefree`` runs of
   ``benchmarks/tep_studio_runs.py --roles tunefree --out DIR``, seeds 31–34, 3 days each,
   which no method learns from and nothing scores): they join the fault-free samples of 1
   and take turns with the calibration runs in 2; per fault-free run, each method's largest
   score (over the 1 % limit matched on the calibration runs) and the share of samples where
   some test of the unit reads an input outside the range its model learned
   (:func:`~diag_plugin.diagnose.operating.learned_ranges`, at lag 0): there a rule grid
   answers with its edge rule, flat, whatever the input does beyond it (then along its trend
   for up to a quarter span past its span). And per method where the fault-free alarms fall:
   in the first 8 hours of the calibration and ``--more`` runs (each run starts from the
   simulator's base state) or after them; and each of those runs scored again from hour 8,
   every method cold there (the unit's lags, filters, delays and episodes start empty): if
   its first hour then alarms, the early alarms are the method's cold start, if not the
   plant's settling.

The scoring runs are not read. Run: ``python benchmarks/tep_matched_tuning.py [--plant
tep-studio] [--more DIR]`` (the data in ``~/.cache/diag-plugin``; a minute or a few of CPU).
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np

#: tuning runs whose fault no method detects (IDV3, IDV9, IDV15): fault-free to every method
QUIET = ("d03", "d09", "d15")
#: tep-studio: the roles a tuning check needs (it runs before the scoring runs are simulated)
TUNING_ONLY = ("train", "calibration", "tuning")


def main(argv: list[str] | None = None) -> int:
    from _common import add_scratch_args, scratch

    from diag_plugin.bench.matched import calibrate, method_score, rates
    from diag_plugin.bench.publicbench import (
        DPCA_LAGS,
        build_unit_as_user,
        pca_fit,
        pca_statistics,
        unit_score,
    )
    from diag_plugin.bench.publicplants import load_braatz, load_tep_studio

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plant", choices=("tep", "tep-studio"), default="tep")
    ap.add_argument("--targets", default="0.005,0.01,0.02,0.05", help="shares of samples")
    ap.add_argument("--more", default=None, help="folder of more fault-free runs (tep-studio)")
    add_scratch_args(ap, "nothing")
    args = ap.parse_args(argv)
    targets = [float(t) for t in args.targets.split(",")]

    plant = load_braatz() if args.plant == "tep" else load_tep_studio(need=TUNING_ONLY)
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
            return unit_score(unit, frame, on, off)[0]
        return method_score(pca_statistics(dets[method], frame)[0], on, off)

    if args.plant == "tep":
        quiet = [r.frame for r in plant.tuning if r.name in QUIET]
        faulty = [(r.frame, 0) for r in plant.tuning if r.name not in QUIET]
    else:  # before and after each tuning run's onset (scored from the run's start)
        quiet = [r.frame.iloc[: r.onset] for r in plant.tuning]
        faulty = [(r.frame, int(r.onset or 0)) for r in plant.tuning]
    more = _more_runs(args.more) if args.plant == "tep-studio" and args.more else {}
    quiet += list(more.values())
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

    early: list[str] = []  # tep-studio: the fault-free alarms in each run's first hours
    s_cal_of: dict[str, list[np.ndarray]] = {}
    for m in ("unit", "PCA", "DPCA"):
        s_cal = [score(m, f) for f in cal]
        s_quiet = [score(m, f) for f in quiet]
        s_fault = [(score(m, f), k) for f, k in faulty]
        s_cal_of[m] = s_cal
        if more:
            early += _early(m, s_cal, s_quiet[len(faulty) :], targets, period)
        for t in targets:
            lim = calibrate(s_cal, t, period).limit
            free = rates(s_quiet, lim, period)[0] if s_quiet else np.nan
            hits = [np.mean(np.nan_to_num(s[k:], nan=-np.inf) > lim) for s, k in s_fault]
            det = float(np.mean(hits)) if hits else np.nan
            # whole fault-free runs take turns (classic TEP: d00_te and the three quiet
            # tuning runs); tep-studio's 8-hour pieces before an onset only score
            # tep-studio: the calibration runs and the --more runs (the last in s_quiet)
            pool = s_cal + s_quiet if args.plant == "tep" else s_cal + s_quiet[len(faulty) :]
            each = []
            for i in range(len(pool)):
                li = calibrate([pool[i]], t, period).limit
                each.append(rates(pool[:i] + pool[i + 1 :], li, period)[0])
            shown = " ".join(f"{100 * x:.1f}" for x in each)
            print(f"| {m} | {100 * t:g} % | {pct(free)} | {pct(det, '.1f')} | "
                  f"{pct(float(np.mean(each)))} ({shown}) |")  # fmt: skip
    print()
    print("leave one run out: each whole fault-free run in turn sets the limit alone")
    if early:
        print()
        print(f"| method | target | calibration: first {EARLY_H:g} h | after | "
              f"--more runs: first {EARLY_H:g} h | after |")  # fmt: skip
        print("|---" * 6 + "|")
        print("\n".join(early))
        print("(share of samples in alarm, the limit matched on the calibration runs; every run "
              "starts from the simulator's base state)")  # fmt: skip
    if more:
        _cold(list(cal) + list(more.values()), s_cal_of, targets, period, score)
        _first_hours(unit, more, calibrate(s_cal_of["unit"], min(targets), period).limit,
                     min(targets), (on, off), period)  # fmt: skip
    if args.plant == "tep-studio":
        _beyond(unit, {r.name: r.frame for r in plant.calibration} | more,
                {m: calibrate([score(m, f) for f in cal], 0.01, period).limit
                 for m in ("unit", "PCA", "DPCA")}, score)  # fmt: skip
    return 0


#: tep-studio: the first hours of a run (the simulator's start from its base state), apart
EARLY_H = 8.0


def _early(method: str, cal: list, more: list, targets: list[float], period: float) -> list[str]:
    """Table rows: per target the share of samples in alarm in the first :data:`EARLY_H`
    hours of each calibration and ``--more`` run and after them (where the fault-free alarms
    of a method fall)."""
    from diag_plugin.bench.matched import calibrate

    cut = int(EARLY_H * 3600 / period)

    def split(runs: list, lim: float) -> str:
        on = [np.nan_to_num(s, nan=-np.inf) > lim for s in runs]
        first = np.concatenate([a[:cut] for a in on])
        rest = np.concatenate([a[cut:] for a in on])
        return f"{100 * first.mean():.2f} % | {100 * rest.mean():.2f} %"

    rows = []
    for t in targets:
        lim = calibrate(cal, t, period).limit
        rows.append(f"| {method} | {100 * t:g} % | {split(cal, lim)} | {split(more, lim)} |")
    return rows


def _cold(runs: list, s_cal: dict, targets: list[float], period: float, score) -> None:
    """Plant or cold start? Each fault-free run scored again from hour :data:`EARLY_H` (the
    unit, its lags, filters, delays and episodes starting cold there): the share in alarm in
    its first hour and the next 7, beside the same hours scored from the run's start and the
    run's own first hour. A cold start would alarm in the first hour of either scoring."""
    from diag_plugin.bench.matched import calibrate

    cut, hour = int(EARLY_H * 3600 / period), int(3600 / period)
    print()
    h = f"{EARLY_H:g}"
    print(f"| method | target | from the start: hour 0 | hours 1-{EARLY_H - 1:g} | hour {h} | "
          f"after | from hour {h} (cold): its first hour | after |")  # fmt: skip
    print("|---" * 8 + "|")
    for m, cal in s_cal.items():
        warm = [np.nan_to_num(score(m, f), nan=-np.inf) for f in runs]
        cold = [np.nan_to_num(score(m, f.iloc[cut:]), nan=-np.inf) for f in runs]
        for t in targets:
            lim = calibrate(cal, t, period).limit

            def share(ss: list, a: int, b: int, lim: float = lim) -> str:
                return f"{100 * np.mean(np.concatenate([x[a:b] > lim for x in ss])):.2f} %"

            print(f"| {m} | {100 * t:g} % | {share(warm, 0, hour)} | {share(warm, hour, cut)} | "
                  f"{share(warm, cut, cut + hour)} | {share(warm, cut + hour, 2 * cut)} | "
                  f"{share(cold, 0, hour)} | {share(cold, hour, cut)} |")  # fmt: skip
    print(f"(calibration and --more runs; 'after' is the next {EARLY_H - 1:g} hours)")


def _first_hours(
    unit, runs: dict, lim: float, target: float, delays: tuple[int, int], period: float
) -> None:
    """Per ``--more`` run, which of the unit's statistics (a test, or the combined T²) are
    over ``lim`` (matched at ``target`` on the calibration runs) in the first
    :data:`EARLY_H` hours / after (samples, after the delays); and per hour of the first 12
    the tags that move most, as |x - its mean after hour 8| over its standard deviation
    after hour 8, averaged over the runs (the plant's own settling), beside the tests whose
    residual (over its limit) rises most then."""
    from diag_plugin.bench.matched import delayed_score
    from diag_plugin.bench.publicbench import unit_statistics

    cut, hour = int(EARLY_H * 3600 / period), int(3600 / period)
    names = [*unit.tests, "T2"]
    print()
    print(f"unit statistics over the limit matched at {100 * target:g} %: first {EARLY_H:g} h "
          "/ after (samples in alarm)")  # fmt: skip
    moved, resid = [], []
    for name, f in runs.items():
        st = unit_statistics(unit, f)[0]
        with warnings.catch_warnings():  # a test unknown for a whole hour: NaN there
            warnings.simplefilter("ignore", RuntimeWarning)
            resid.append(np.nanmean(np.abs(st[: 12 * hour, :-1]).reshape(12, hour, -1), axis=1))
        d = delayed_score(st, *delays)
        over = np.nan_to_num(d, nan=-np.inf) > lim
        fired = [f"{names[j]} {over[:cut, j].sum()}/{over[cut:, j].sum()}"
                 for j in np.flatnonzero(over.any(axis=0))]  # fmt: skip
        print(f"  {name}: {', '.join(fired) or 'none'}")
        late = f.iloc[cut:]
        z = ((f.iloc[: 12 * hour] - late.mean()) / late.std()).abs().to_numpy()
        moved.append(z.reshape(12, hour, -1).mean(axis=1))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        r = np.nanmean(resid, axis=0)  # hours × tests: |residual| over its limit
        rise = np.nan_to_num(np.nanmax(r[1:8], axis=0) / np.nanmean(r[8:], axis=0))
    print("tests whose |residual| / limit rises most in hours 1-7, per hour 0-11 (mean):")
    for j in np.argsort(-rise)[:5]:
        print(f"  {names[j]:8s} " + " ".join(f"{v:5.2f}" for v in r[:, j]))
    z = np.mean(moved, axis=0)  # hours × tags
    cols = list(next(iter(runs.values())).columns)
    print("tags furthest from where they settle (|x - mean after hour 8| / std), hours 0-11:")
    for j in np.argsort(-z[1:8].max(axis=0))[:6]:
        print(f"  {cols[j]:8s} " + " ".join(f"{v:5.1f}" for v in z[:, j]))
    print("  all tags " + " ".join(f"{v:5.1f}" for v in z.mean(axis=1)))


def _more_runs(folder: str) -> dict:
    """The fault-free runs in ``folder`` (any depth), by name, with the plant's tags."""
    from pathlib import Path

    import pandas as pd

    from diag_plugin.bench.publicplants import TEP_TAGS

    out = {}
    for f in sorted(Path(folder).expanduser().rglob("tunefree_s*.csv")):
        frame = pd.read_csv(f, index_col="ts", parse_dates=["ts"])
        out[f.stem] = frame[~frame.index.duplicated(keep="first")][list(TEP_TAGS)]
    return out


def _beyond(unit, runs: dict, limits: dict, score) -> None:
    """Per fault-free run: each method's largest score over its 1 % limit, and the share of
    samples where some test's input is outside its model's learned range."""
    from diag_plugin.diagnose.operating import learned_ranges

    ranges = learned_ranges(unit.models, unit.tests)
    tags = unit.file.tags
    print()
    print("| fault-free run | unit max | PCA max | DPCA max | unit: an input beyond its range |")
    print("|---" * 5 + "|")
    for name, f in runs.items():
        out = np.zeros(len(f), bool)
        for r in ranges:
            v = f[tags.get(r.tag, r.tag)].to_numpy(float)
            out |= (v < r.lo) | (v > r.hi)
        mx = {m: np.nanmax(score(m, f)) / lim for m, lim in limits.items()}
        print(f"| {name} | {mx['unit']:.2f} | {mx['PCA']:.2f} | {mx['DPCA']:.2f} | "
              f"{100 * out.mean():.1f} % |")  # fmt: skip
    print("(largest score over the 1 % limit matched on the calibration runs)")


if __name__ == "__main__":
    raise SystemExit(main())
