"""What raises the unit's fault-free score past its calibration maximum on the classic TEP?
(issue 34 item 1, branch i37-teptail; looked for on the **tuning** data, nothing tuned here.)

The page (``diag benchmark --plant tep --match-far``) at a 0.1 % target sets every method's
limit at the largest score of ``d00_te`` (960 samples: 0.1 % is under one sample), and the
unit then alarms on 1.50 % of the held-out fault-free pieces, PCA on 0.00 %, DPCA on 0.34 %.
This script looks for the cause on the tuning data only — ``d00_te`` cut in six 8-hour
pieces and the tuning runs no method detects (``d03``, ``d09``, ``d15``, three 8-hour
pieces each), every piece scored from rest — and prints:

1. per tuning piece, each method's largest score over the calibration maximum (``d00_te``
   whole), the unit's statistic at its top (a test, or the combined ``T²``), the sample and
   whether some input of that test is outside its model's learned range there
   (:func:`~diag_plugin.diagnose.operating.learned_ranges`, lag 0);
2. the unit's statistics whose tuning maximum comes nearest or past the calibration
   maximum, with their inputs and the independent values their thresholds rest on;
3. per method over the pooled tuning pieces: the shape of the score's top (largest over
   the 99 % quantile, 99 % over 90 %), the effective samples of the score per run
   (:func:`~diag_plugin.models.series.effective_samples`), and random splits (6 pieces set
   the limit, the other 9 are scored; :func:`~diag_plugin.bench.matched.split_spread`): the
   held-out share at 0.1 / 0.5 / 1 % and the held-out maximum over the calibration maximum;
4. the tags whose spread in the later fault-free runs (``d00_te`` and the three quiet runs)
   differs most from the training window ``d00.dat``: the standard deviation and that of the
   first differences (the sample-to-sample noise), later over training;
5. tried, not the bench's: a limit past the calibration's top (:func:`tail_limit`: an
   exponential tail over the calibration's 90 % quantile where the target expects under 5
   calibration samples, the bench's † rule), against the bench's on the same random splits
   (the mean held-out share per target), and the detection over the other tuning runs
   (``d01.dat`` … ``d21.dat`` but the quiet three, faulty throughout) at each.

Found (2026-12-02, ``docs/results/index.md``, "At 0.1 % every limit is the calibration's
largest score"): at 0.1 % every method's limit is ``d00_te``'s largest score and every method
then alarms about one episode per 48 h held out (unit 0.40 %, PCA 0.33 %, DPCA 0.30 % of the
tuning splits' held-out samples); the unit's score goes least far past the calibration's
largest (1.009 on average, PCA 1.037, DPCA 1.017) with the flattest top, its pieces' tops set
by one statistic or another (XMEAS3_joint most often: the D feed is 1.2 times as spread in
every later run as in ``d00.dat``); no input past its span, no start from rest. The
extrapolated limit brings the 0.1 % shares to 0.00 / 0.09 / 0.07 % for 1.7 / 2.3 / 1.2
points of tuning detection; not built (a bench protocol change for every method).

``--more DIR`` (tep-studio; the ``tunefree`` runs of ``benchmarks/tep_studio_runs.py --roles
tunefree --out DIR``) prints instead (7.): its seven fault-free runs no method learns from and
nothing scores (the three calibration runs, seeds 11–13, and seeds 31–34, 3 days each), every
three of them setting the limit and the other four scored: per method the held-out share at
0.1 and 1 % (mean and largest over the 35 splits), episodes per hour at 0.1 %, the held-out
largest over the calibration's, and at the extrapolated limit; per run the unit's top (which
statistic, at which hour) and ``T²``'s largest in the first 4 hours from the simulator's
start against the 4 hours from hour 8 with the unit cold there. Found: every run's top is
``T²``; in seeds 31–34 it falls in hours 0.3–2.1 (1.18–1.73 times the 1 % limit), where
the same runs scored cold from hour 8 stay at 0.79–1.02 — the plant settling from the
simulator's base state (XMV1 and XMV2 5.1 and 4.5 training sd below their training means over
hours 0–2 of every run, printed per run with the tags carrying ``T²``'s early top), not the
unit's cold start; the held-out largest over the
calibration's is 1.123 on average for the unit (PCA 1.026, DPCA 1.032), the held-out share at
0.1 % the same as PCA's (0.19 %, PCA 0.20 %, DPCA 0.12 %).

``--confirm`` adds (6.), after everything above is printed, the **scoring** pieces (the 8 hours
before each ``dXX_te`` onset, a repeated piece once): per piece each method's largest score
over the calibration maximum and the unit's statistics over it (samples, first sample,
largest), with the share of those samples where an input is outside its learned range — to
confirm a mechanism found above, never to choose one — and the page's split at the
extrapolated limit. Run: ``python benchmarks/tep_tail_causes.py [--unit DIR] [--confirm]``
(``--unit`` keeps the built unit and reuses it; about a minute of CPU, the build another).
"""

from __future__ import annotations

import argparse
import tomllib
from pathlib import Path

import numpy as np


def _unit_of(plant, folder: Path):
    """The unit built the way a user builds it from ``plant``'s training runs into ``folder``
    (built when ``folder`` holds none; None, said, when the build refuses)."""
    from diag_plugin.bench.publicbench import build_unit_as_user
    from diag_plugin.diagnose.unit import Unit

    if not (folder / "units").exists():
        built = build_unit_as_user(plant, plant.train, folder)
        if built["unit"] is None:
            print(f"the unit was not built: {built['note']}")
            return None
    return Unit.load(plant.name, folder / "units")


def main(argv: list[str] | None = None) -> int:
    from tep_far_spread import _distinct
    from tep_matched_tuning import QUIET

    from diag_plugin.bench.matched import (
        calibrate,
        delayed_score,
        method_score,
        rates,
        split_spread,
    )
    from diag_plugin.bench.publicbench import (
        DPCA_LAGS,
        pca_fit,
        pca_statistics,
        unit_score,
        unit_statistics,
    )
    from diag_plugin.bench.publicplants import load_braatz
    from diag_plugin.diagnose.operating import learned_ranges
    from diag_plugin.models.series import effective_samples

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--unit", default=None, help="the built unit's folder (built when empty)")
    ap.add_argument("--draws", type=int, default=2000, help="random splits")
    ap.add_argument("--confirm", action="store_true", help="also read the scoring pieces")
    ap.add_argument("--more", default=None, help="tep-studio: the tunefree runs' folder")
    args = ap.parse_args(argv)
    if args.more:
        return _studio(args)

    plant = load_braatz()
    folder = Path(args.unit or "/tmp/tep_tail_causes_unit")
    unit = _unit_of(plant, folder)
    if unit is None:
        return 1
    on, off = int(unit.ev["on_delay"]), int(unit.ev["off_delay"])
    period = plant.period_s
    piece = int(8 * 3600 / period)
    names = [*unit.tests, "T2"]
    with open(folder / "units" / f"{plant.name}.unit.toml", "rb") as fh:
        learned = tomllib.load(fh).get("learned", {})
    cols = list(plant.tags)
    frames = [r.frame for r in plant.train]
    dets = {"PCA": pca_fit(frames, cols, 0, 0.9), "DPCA": pca_fit(frames, cols, DPCA_LAGS, 0.9)}
    methods = ("unit", "PCA", "DPCA")
    ranges = [r for r in learned_ranges(unit.models, unit.tests) if not r.gap]
    tags = unit.file.tags

    def score(m: str, frame) -> np.ndarray:
        if m == "unit":
            return unit_score(unit, frame, on, off)[0]
        return method_score(pca_statistics(dets[m], frame)[0], on, off)

    def outside(frame, test: int | None = None) -> np.ndarray:
        """Samples where some input (of ``test``, or of any test) is outside its range."""
        out = np.zeros(len(frame), bool)
        for r in ranges:
            if test is None or r.test == test:
                v = frame[tags.get(r.tag, r.tag)].to_numpy(float)
                out |= (v < r.lo) | (v > r.hi)
        return out

    cal = plant.calibration[0].frame
    quiet = {r.name: r.frame for r in plant.tuning if r.name in QUIET}
    pieces = {
        f"{k}[{i // piece}]": f.iloc[i : i + piece]
        for k, f in {"d00_te": cal, **quiet}.items()
        for i in range(0, len(f) - piece + 1, piece)
    }
    top = {m: float(np.nanmax(score(m, cal))) for m in methods}
    sc = {m: {k: score(m, f) for k, f in pieces.items()} for m in methods}
    stats = {k: delayed_score(unit_statistics(unit, f)[0], on, off) for k, f in pieces.items()}

    print("1. tuning pieces (8 h, from rest): largest score over d00_te's largest (unit "
          f"{top['unit']:.3f}; the 0.1 % limit), the unit's statistic at its top")  # fmt: skip
    print("| piece | unit | PCA | DPCA | unit's top: statistic, sample | an input outside "
          "its range there |")  # fmt: skip
    print("|---" * 6 + "|")
    for k, f in pieces.items():
        d = np.nan_to_num(stats[k], nan=-np.inf)
        i = int(np.argmax(d.max(axis=1)))
        j = int(np.argmax(d[i]))
        past = "—" if j == len(unit.tests) else ("yes" if outside(f, j)[i] else "no")
        cells = " | ".join(f"{np.nanmax(sc[m][k]) / top[m]:.2f}" for m in methods)
        print(f"| {k} | {cells} | {names[j]}, {i} | {past} |")
    print()
    print("2. the unit's statistics nearest the calibration maximum on the quiet tuning runs")
    print("| statistic | d00_te | quiet pieces | inputs | independent values (thresholds) |")
    print("|---" * 5 + "|")
    rows = []
    for j, n in enumerate(names):
        c = max(np.nanmax(np.nan_to_num(stats[k][:, j], nan=-np.inf)) for k in pieces
                if k.startswith("d00_te"))  # fmt: skip
        q = max(np.nanmax(np.nan_to_num(stats[k][:, j], nan=-np.inf)) for k in pieces
                if not k.startswith("d00_te"))  # fmt: skip
        rows.append((max(c, q), n, c, q))
    for _, n, c, q in sorted(rows, reverse=True)[:10]:
        inp = ", ".join(unit.models[n].inputs) if n in unit.models else "—"
        ind = learned.get(n, {}).get("independent", "—")
        print(f"| {n} | {c / top['unit']:.2f} | {q / top['unit']:.2f} | {inp or 'none'} | {ind} |")
    print()
    print("3. the score's top over the pooled tuning pieces, and random splits (6 set the limit)")
    whole = [cal, *quiet.values()]
    print("| method | max / q99 | q99 / q90 | effective samples: d00_te, d03, d09, d15 | "
          "held-out share at 0.1 / 0.5 / 1 % (mean) | episodes/h at 0.1 % (mean) | held-out "
          "max / calibration max: mean, 95 % |")  # fmt: skip
    print("|---" * 7 + "|")
    split = {m: list(sc[m].values()) for m in methods}
    got = {t: split_spread(split, 6, t, period, draws=args.draws, seed=1)
           for t in (0.001, 0.005, 0.01)}  # fmt: skip
    rng = np.random.default_rng(3)
    ratio = {m: [] for m in methods}
    hourly = {m: [] for m in methods}  # held-out episodes per hour at the 0.1 % limit
    for _ in range(args.draws):
        idx = rng.permutation(len(pieces))
        for m in methods:
            mx = [np.nanmax(split[m][i]) for i in idx]
            ratio[m].append(max(mx[6:]) / max(mx[:6]))
            lim = calibrate([split[m][i] for i in idx[:6]], 0.001, period).limit
            hourly[m].append(rates([split[m][i] for i in idx[6:]], lim, period)[1])
    for m in methods:
        x = np.concatenate(split[m])
        q = np.quantile(x[np.isfinite(x)], [0.9, 0.99, 1.0])
        eff = ", ".join(f"{effective_samples(score(m, f)):.0f}" for f in whole)
        held = " / ".join(f"{100 * got[t][m].mean():.2f}" for t in got)
        print(f"| {m} | {q[2] / q[1]:.3f} | {q[1] / q[0]:.3f} | {eff} | {held} % | "
              f"{np.mean(hourly[m]):.4f} | {np.mean(ratio[m]):.3f}, "
              f"{np.quantile(ratio[m], 0.95):.3f} |")  # fmt: skip
    lim = {t: calibrate([score("unit", cal)], t, period).limit for t in (0.001, 0.01)}
    print(f"(the unit's limits on d00_te: 0.1 % {lim[0.001]:.3f}, 1 % {lim[0.01]:.3f})")
    print()
    print("4. the tags' spread in the later fault-free runs over the training window's "
          "(sd; sd of first differences), the largest")  # fmt: skip
    tr = plant.train[0].frame
    out = []
    for t in cols:
        s = [f[t].std() / tr[t].std() for f in whole]
        d = [f[t].diff().std() / tr[t].diff().std() for f in whole]
        out.append((float(np.mean(s)), t, s, d))
    for m, t, s, d in sorted(out, reverse=True)[:8]:
        print(f"  {t}: sd {m:.2f} ({' '.join(f'{x:.2f}' for x in s)}); first differences "
              f"{' '.join(f'{x:.2f}' for x in d)}")  # fmt: skip
    _tail_limits(split, period, args.draws)
    faulty = [r.frame for r in plant.tuning if r.name not in QUIET]
    print("  detection over the other tuning runs' samples (faulty throughout), limits from "
          "d00_te's six pieces, the bench's → extrapolated:")  # fmt: skip
    for m in methods:
        s_f = np.concatenate([score(m, f) for f in faulty])
        got = []
        for t in (0.001, 0.005):
            a = calibrate(split[m][:6], t, period).limit
            b = tail_limit(split[m][:6], t, period)
            got.append(f"{100 * t:g} % {100 * np.mean(np.nan_to_num(s_f, nan=-np.inf) > a):.1f}"
                       f" → {100 * np.mean(np.nan_to_num(s_f, nan=-np.inf) > b):.1f} % (limit "
                       f"{a:.3f} → {b:.3f})")  # fmt: skip
        print(f"    {m}: " + "; ".join(got))
    if args.confirm:
        _confirm(plant, unit, names, top, score, outside, on, off, _distinct)
        free, _ = _distinct(list(plant.free))
        cal_p = [split[m][:6] for m in methods]
        for m, c in zip(methods, cal_p, strict=True):
            held = [score(m, r.frame) for r in free]
            got = [rates(held, tail_limit(c, t, period), period)[0] for t in (0.001, 0.005, 0.01)]
            print(f"  {m}, the page's split (limit from d00_te's six pieces), extrapolated "
                  "tail: " + " / ".join(f"{100 * g:.2f}" for g in got) + " %")  # fmt: skip
    return 0


#: the extrapolated tail (tried, not the bench's): its base, a quantile of the calibration
BASE = 0.9
#: targets whose expected calibration samples in alarm are under this are extrapolated
RESOLVED = 5


def tail_limit(cal: list, target: float, period: float) -> float:
    """A limit that does not stop at the calibration's largest score (tried here, not the
    bench's): where the target expects under :data:`RESOLVED` calibration samples in alarm,
    an exponential tail fitted to the calibration's scores over their :data:`BASE` quantile
    ``u`` (Pickands–Balkema–de Haan with shape 0: ``P(s > x) = (1 − BASE) exp(−(x − u)/σ)``,
    ``σ`` the mean excess over ``u``), solved for the target; else the bench's
    :func:`~diag_plugin.bench.matched.calibrate`."""
    from diag_plugin.bench.matched import calibrate

    x = np.concatenate([np.asarray(c, float) for c in cal])
    x = x[np.isfinite(x)]
    if target * x.size >= RESOLVED:
        return calibrate(cal, target, period).limit
    u = float(np.quantile(x, BASE))
    sigma = float(np.mean(x[x > u] - u))
    return max(u + sigma * np.log((1.0 - BASE) / target), float(x.max()))


def _tail_limits(split: dict, period: float, draws: int) -> None:
    """5. The extrapolated limit (:func:`tail_limit`) against the bench's on random splits of the
    tuning pieces: the mean held-out share per method and target."""
    from diag_plugin.bench.matched import calibrate, rates

    print()
    print(f"5. a limit past the calibration's top (tried, not the bench's): an exponential "
          f"tail over the calibration's {100 * BASE:g} % quantile where the target expects "
          f"under {RESOLVED} calibration samples; mean held-out share over {draws} random "
          "splits of the tuning pieces, the bench's → extrapolated")  # fmt: skip
    rng = np.random.default_rng(4)
    targets = (0.001, 0.005, 0.01)
    plain = {(m, t): [] for m in split for t in targets}
    tail = {(m, t): [] for m in split for t in targets}
    n = len(next(iter(split.values())))
    for _ in range(draws):
        idx = rng.permutation(n)
        for m, p in split.items():
            cal, held = [p[i] for i in idx[:6]], [p[i] for i in idx[6:]]
            for t in targets:
                plain[m, t].append(rates(held, calibrate(cal, t, period).limit, period)[0])
                tail[m, t].append(rates(held, tail_limit(cal, t, period), period)[0])
    for m in split:
        print(f"  {m}: " + "; ".join(
            f"{100 * t:g} % {100 * np.mean(plain[m, t]):.2f} → {100 * np.mean(tail[m, t]):.2f}"
            for t in targets) + " %")  # fmt: skip


def _studio(args) -> int:
    """7. tep-studio (``--more DIR``): its seven fault-free runs no method learns from and
    nothing scores — the three calibration runs and the ``tunefree`` runs, 3 days each — in
    every split of three setting the limit (as the bench's three) and four scored."""
    from itertools import combinations

    from tep_matched_tuning import _more_runs

    from diag_plugin.bench.matched import calibrate, delayed_score, method_score, rates
    from diag_plugin.bench.publicbench import (
        DPCA_LAGS,
        pca_fit,
        pca_statistics,
        unit_score,
        unit_statistics,
    )
    from diag_plugin.bench.publicplants import load_tep_studio

    plant = load_tep_studio(need=("train", "calibration"))
    folder = Path(args.unit or "/tmp/tep_tail_causes_studio_unit")
    unit = _unit_of(plant, folder)
    if unit is None:
        return 1
    on, off = int(unit.ev["on_delay"]), int(unit.ev["off_delay"])
    period = plant.period_s
    names = [*unit.tests, "T2"]
    cols = list(plant.tags)
    frames = [r.frame for r in plant.train]
    dets = {"PCA": pca_fit(frames, cols, 0, 0.9), "DPCA": pca_fit(frames, cols, DPCA_LAGS, 0.9)}
    runs = {r.name: r.frame for r in plant.calibration} | _more_runs(args.more)
    sc = {"unit": {k: unit_score(unit, f, on, off)[0] for k, f in runs.items()}}
    for m, det in dets.items():
        sc[m] = {k: method_score(pca_statistics(det, f)[0], on, off) for k, f in runs.items()}
    print(f"7. tep-studio: {len(runs)} fault-free runs ({', '.join(runs)}), every 3 set the "
          "limit, the other 4 scored")  # fmt: skip
    print("| method | held-out share at 0.1 / 1 % (mean, max) | episodes/h at 0.1 % | held-out "
          "max / calibration max: mean, max | max / q99 | extrapolated at 0.1 % |")  # fmt: skip
    print("|---" * 6 + "|")
    splits = list(combinations(list(runs), 3))
    for m in sc:
        share = {t: [] for t in (0.001, 0.01)}
        hourly, ratio, tail = [], [], []
        for cal in splits:
            c = [sc[m][k] for k in cal]
            h = [sc[m][k] for k in runs if k not in cal]
            for t in share:
                share[t].append(rates(h, calibrate(c, t, period).limit, period)[0])
            hourly.append(rates(h, calibrate(c, 0.001, period).limit, period)[1])
            ratio.append(max(np.nanmax(x) for x in h) / max(np.nanmax(x) for x in c))
            tail.append(rates(h, tail_limit(c, 0.001, period), period)[0])
        x = np.concatenate(list(sc[m].values()))
        q = np.quantile(x[np.isfinite(x)], [0.99, 1.0])
        cells = " | ".join(f"{100 * np.mean(v):.2f}, {100 * np.max(v):.2f} %"
                           for v in share.values())  # fmt: skip
        print(f"| {m} | {cells} | {np.mean(hourly):.4f} | {np.mean(ratio):.3f}, "
              f"{np.max(ratio):.3f} | {q[1] / q[0]:.3f} | "
              f"{100 * np.mean(tail):.2f} % |")  # fmt: skip
    print("the unit's top per run: statistic, hour, over the 1 % limit of the three "
          "calibration runs; T²'s largest in the first 4 hours from the simulator's start and "
          "in the 4 hours from hour 8, the unit cold there (all empty)")  # fmt: skip
    lim = calibrate([sc["unit"][r.name] for r in plant.calibration], 0.01, period).limit
    train = np.concatenate([f.to_numpy(float) for f in frames])
    mu, sd = train.mean(axis=0), train.std(axis=0)
    sd[sd == 0] = np.inf  # a tag the training holds fixed counts as not moved
    for k, f in runs.items():
        d = np.nan_to_num(delayed_score(unit_statistics(unit, f)[0], on, off), nan=-np.inf)
        i = int(np.argmax(d.max(axis=1)))
        j = int(np.argmax(d[i]))
        top3 = np.argsort(d.max(axis=0))[::-1][:3]
        others = ", ".join(f"{names[a]} {d[:, a].max() / lim:.2f}" for a in top3)
        four = int(4 * 3600 / period)
        cold = unit_statistics(unit, f.iloc[2 * four :])[0][:, -1]  # from hour 8, cold there
        early = [np.nanmax(delayed_score(x, on, off)[:four]) / lim for x in (d[:, -1], cold)]
        print(f"  {k}: {names[j]} at hour {i * period / 3600:.1f}; largest per statistic: "
              f"{others}; T² in the first 4 h from rest {early[0]:.2f}, from hour 8 cold "
              f"{early[1]:.2f}")  # fmt: skip
        contrib = unit_statistics(unit, f)[1]
        at = int(np.nanargmax(d[:four, -1]))
        c = contrib.iloc[at].sort_values(ascending=False).iloc[:3]
        z = (f.iloc[: four // 2].mean().to_numpy(float) - mu) / sd
        big = np.argsort(-np.abs(z))[:3]
        print(f"    T²'s top in the first 4 h (hour {at * period / 3600:.1f}) carried by "
              + ", ".join(f"{t} {v:.2f}" for t, v in c.items())
              + "; the tags' mean over hours 0–2 against training's, in its sd: "
              + ", ".join(f"{cols[b]} {z[b]:+.1f}" for b in big))  # fmt: skip
    return 0


def _confirm(plant, unit, names, top, score, outside, on, off, distinct) -> None:
    """6. The scoring pieces (confirmation only): each method's largest score over the
    calibration maximum, the unit's statistics over it."""
    from diag_plugin.bench.matched import delayed_score
    from diag_plugin.bench.publicbench import unit_statistics

    free, _ = distinct(list(plant.free))
    print()
    print("6. CONFIRMATION on the scoring pieces (not used to choose anything)")
    n = {m: 0 for m in top}
    for r in free:
        s = {m: score(m, r.frame) for m in top}
        for m in top:
            n[m] += int(np.sum(np.nan_to_num(s[m], nan=-np.inf) > top[m]))
        d = np.nan_to_num(delayed_score(unit_statistics(unit, r.frame)[0], on, off), nan=-np.inf)
        over = d > top["unit"]
        got = [f"{names[j]} {int(over[:, j].sum())} (from {np.flatnonzero(over[:, j])[0]}, "
               f"{d[:, j].max() / top['unit']:.2f})"
               for j in np.flatnonzero(over.any(axis=0))]  # fmt: skip
        a = over.any(axis=1)
        past = (
            f"; an input outside its range at {100 * outside(r.frame)[a].mean():.0f} % of them"
            if got
            else ""
        )
        print(f"  {r.name}: " + " ".join(f"{m} {np.nanmax(s[m]) / top[m]:.2f}" for m in top)
              + (f"; {', '.join(got)}{past}" if got else ""))  # fmt: skip
    held = sum(len(r.frame) for r in free)
    print("  samples over the calibration maximum: "
          + ", ".join(f"{m} {n[m]}" for m in top) + f" of {held}")  # fmt: skip


if __name__ == "__main__":
    raise SystemExit(main())
