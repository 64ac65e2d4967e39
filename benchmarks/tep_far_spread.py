"""Is the unit's held-out false-alarm rate on the classic TEP worse, or one draw of chance?
(issue 34, branch i34-tepfar; the page's figures explained, nothing tuned here.)

The page (``diag benchmark --plant tep --match-far``) matches every method's limit on
``d00_te`` (48 h) and counts false alarms on the 8-hour fault-free pieces before each
scoring run's onset. This script reads those pieces — to put an interval on the page's
figures, not to choose anything — and prints:

1. per method and target, on the page's split: the calibration's samples and episodes in
   alarm, the held-out ones, samples per episode, and the exact 95 % interval of the
   held-out episode rate (:func:`~diag_plugin.bench.matched.episode_interval`);
2. which of the unit's statistics (a test, or the combined ``T²``) are over the 1 % limit in
   each held-out piece, after the on/off delays;
3. **random splits** (:func:`~diag_plugin.bench.matched.split_spread`): the fault-free
   8-hour pieces taken as exchangeable, ``d00_te`` cut in six (each scored from rest, as the
   scoring pieces are) and the scoring pieces together; six set the limit (48 h, as
   ``d00_te`` does), the rest are scored. Per method the mean and 90 % range of the held-out
   share, where the page's split falls among the draws, and the unit's excess over PCA and
   DPCA on the same draws. Then the same on the tuning runs only (``d00_te``'s six pieces
   and the tuning runs no method detects, ``d03``, ``d09``, ``d15``, in 8-hour pieces);
4. a limit cross-fitted over the calibration pieces (tried, not the bench's): each piece
   scored at the limit the others set, the target lowered until their mean holds it.

A scoring piece identical to another (``d05_te``'s first 160 samples are ``d04_te``'s) is
counted once. Run: ``python benchmarks/tep_far_spread.py [--unit DIR] [--draws N]`` (``--unit``
keeps the built unit and reuses it; a few minutes of CPU).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def _distinct(runs: list) -> tuple[list, list[str]]:
    """The runs without one whose samples repeat an earlier run's, and the names left out."""
    kept, dropped = [], []
    for r in runs:
        x = r.frame.to_numpy()
        if any(k.frame.shape == x.shape and np.array_equal(k.frame.to_numpy(), x) for k in kept):
            dropped.append(r.name)
        else:
            kept.append(r)
    return kept, dropped


def main(argv: list[str] | None = None) -> int:
    from tep_matched_tuning import QUIET

    from diag_plugin.bench.matched import (
        calibrate,
        delayed_score,
        episode_count,
        episode_interval,
        method_score,
        split_spread,
    )
    from diag_plugin.bench.publicbench import (
        DPCA_LAGS,
        build_unit_as_user,
        pca_fit,
        pca_statistics,
        unit_statistics,
    )
    from diag_plugin.bench.publicplants import load_braatz
    from diag_plugin.diagnose.unit import Unit

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--unit", default=None, help="the built unit's folder (built when empty)")
    ap.add_argument("--targets", default="0.005,0.01,0.02,0.05", help="shares of samples")
    ap.add_argument("--draws", type=int, default=2000, help="random splits")
    args = ap.parse_args(argv)
    targets = [float(t) for t in args.targets.split(",")]

    plant = load_braatz()
    folder = Path(args.unit or "/tmp/tep_far_spread_unit")
    if not (folder / "units").exists():
        built = build_unit_as_user(plant, plant.train, folder)
        if built["unit"] is None:
            print(f"the unit was not built: {built['note']}")
            return 1
    unit = Unit.load(plant.name, folder / "units")
    on, off = int(unit.ev["on_delay"]), int(unit.ev["off_delay"])
    cols = list(plant.tags)
    frames = [r.frame for r in plant.train]
    dets = {"PCA": pca_fit(frames, cols, 0, 0.9), "DPCA": pca_fit(frames, cols, DPCA_LAGS, 0.9)}
    methods = ("unit", "PCA", "DPCA")
    period = plant.period_s
    piece = int(8 * 3600 / period)

    def stats(m: str, frame) -> np.ndarray:
        if m == "unit":
            return unit_statistics(unit, frame)[0]
        return pca_statistics(dets[m], frame)[0]

    free, dropped = _distinct(list(plant.free))
    cal = plant.calibration[0].frame
    cal_pieces = [cal.iloc[i : i + piece] for i in range(0, len(cal) - piece + 1, piece)]
    quiet = [r.frame for r in plant.tuning if r.name in QUIET]
    quiet_pieces = [f.iloc[i : i + piece] for f in quiet for i in range(0, len(f), piece)]
    st_free = {m: [stats(m, r.frame) for r in free] for m in methods}
    sc = {
        m: {
            "cal": [method_score(stats(m, cal), on, off)],
            "free": [method_score(x, on, off) for x in st_free[m]],
            "cal_pieces": [method_score(stats(m, f), on, off) for f in cal_pieces],
            "quiet": [method_score(stats(m, f), on, off) for f in quiet_pieces],
        }
        for m in methods
    }
    hours = sum(map(len, sc["unit"]["free"])) * period / 3600
    same = f" ({', '.join(dropped)} left out: the same samples as another)" if dropped else ""
    print(f"held-out: {len(free)} distinct fault-free pieces, {hours:g} h{same}")
    print()
    print("1. the page's split (limit on d00_te, 48 h)")
    print("| method | target | calibration: samples, episodes | held-out: samples, episodes | "
          "per episode | share | episodes/h (95 % interval) |")  # fmt: skip
    print("|---" * 7 + "|")
    for m in methods:
        for t in targets:
            lim = calibrate(sc[m]["cal"], t, period).limit

            def count(runs: list, lim: float = lim) -> tuple[int, int]:
                over = [np.nan_to_num(s, nan=-np.inf) > lim for s in runs]
                return sum(int(a.sum()) for a in over), sum(episode_count(a) for a in over)

            (cn, ce), (n, e) = count(sc[m]["cal"]), count(sc[m]["free"])
            lo, hi = episode_interval(e, hours)
            share = n / sum(map(len, sc[m]["free"]))
            print(f"| {m} | {100 * t:g} % | {cn}, {ce} | {n}, {e} | {n / max(e, 1):.1f} | "
                  f"{100 * share:.2f} % | {e / hours:.4f} ({lo:.4f}–{hi:.4f}) |")  # fmt: skip
    print()
    lim = calibrate(sc["unit"]["cal"], 0.01, period).limit
    names = [*unit.tests, "T2"]
    print(f"2. the unit's statistics over its 1 % limit ({lim:.3f}) in the held-out pieces "
          "(samples, after the delays)")  # fmt: skip
    for r, x in zip(free, st_free["unit"], strict=True):
        over = np.nan_to_num(delayed_score(x, on, off), nan=-np.inf) > lim
        got = [f"{names[j]} {int(over[:, j].sum())}" for j in np.flatnonzero(over.any(axis=0))]
        if got:
            print(f"  {r.name}: {', '.join(got)}")
    print()
    print(f"3. random splits ({args.draws}): 6 pieces of 8 h set the limit, the others scored")
    print("| pieces | target | " + " | ".join(f"{m}: mean (90 % range)" for m in methods)
          + " | the page's split: quantile | unit − PCA | unit − DPCA |")  # fmt: skip
    print("|---" * (2 + len(methods) + 3) + "|")
    for label, key in (("d00_te + scoring", "free"), ("d00_te + tuning (quiet)", "quiet")):
        for t in targets:
            pieces = {m: sc[m]["cal_pieces"] + sc[m][key] for m in methods}
            got = split_spread(pieces, len(cal_pieces), t, period, draws=args.draws, seed=1)
            cells = [f"{100 * got[m].mean():.2f} % ({100 * np.quantile(got[m], 0.05):.2f}–"
                     f"{100 * np.quantile(got[m], 0.95):.2f})" for m in methods]  # fmt: skip
            if key == "free":
                page = [np.mean(got[m] <= _held(sc[m], t, period)) for m in methods]
                where = ", ".join(f"{q:.2f}" for q in page)
            else:
                where = "—"
            diff = []
            for other in ("PCA", "DPCA"):
                d = got["unit"] - got[other]
                diff.append(f"{100 * d.mean():+.2f} pts, P(>0) {np.mean(d > 0):.2f}")
            print(f"| {label} | {100 * t:g} % | {' | '.join(cells)} | {where} | "
                  f"{' | '.join(diff)} |")  # fmt: skip
    _crossfit(sc, methods, targets, period, max(args.draws // 7, 50))
    return 0


def _crossfit_limit(cal: list, target: float, period: float) -> float:
    """A limit that is not optimistic (tried here, not the bench's): the largest adjusted
    target ``t' ≤ target`` (in tenths of ``target``) at which each calibration piece, scored
    at the limit the other pieces set at ``t'``, is in alarm on at most ``target`` of its
    samples on average; the limit at ``t'`` from all the pieces."""
    from diag_plugin.bench.matched import calibrate, rates

    for tp in np.linspace(target, 0.1 * target, 19):
        held = [
            rates([cal[i]], calibrate(cal[:i] + cal[i + 1 :], tp, period).limit, period)[0]
            for i in range(len(cal))
        ]
        if np.mean(held) <= target:
            break
    return calibrate(cal, tp, period).limit


def _crossfit(sc: dict, methods: tuple, targets: list[float], period: float, draws: int) -> None:
    """4. Every method's limit cross-fitted over its calibration pieces
    (:func:`_crossfit_limit`) against the plain one: the mean held-out share over random
    splits of the tuning pieces, and on the page's split."""
    from diag_plugin.bench.matched import calibrate, rates

    print()
    print(f"4. cross-fitted limits (tried, not the bench's): mean held-out share over {draws} "
          "random splits of d00_te + tuning pieces, plain → cross-fitted")  # fmt: skip
    rng = np.random.default_rng(2)
    for t in targets:
        plain = {m: [] for m in methods}
        fitted = {m: [] for m in methods}
        for _ in range(draws):
            idx = rng.permutation(len(sc["unit"]["cal_pieces"]) + len(sc["unit"]["quiet"]))
            for m in methods:
                p = sc[m]["cal_pieces"] + sc[m]["quiet"]
                cal, held = [p[i] for i in idx[:6]], [p[i] for i in idx[6:]]
                plain[m].append(rates(held, calibrate(cal, t, period).limit, period)[0])
                fitted[m].append(rates(held, _crossfit_limit(cal, t, period), period)[0])
        page = {
            m: rates(sc[m]["free"], _crossfit_limit(sc[m]["cal_pieces"], t, period), period)[0]
            for m in methods
        }
        print(f"  {100 * t:g} %: " + "; ".join(
            f"{m} {100 * np.mean(plain[m]):.2f} → {100 * np.mean(fitted[m]):.2f} % "
            f"(page's split {100 * page[m]:.2f} %)" for m in methods))  # fmt: skip


def _held(s: dict, target: float, period: float) -> float:
    """The held-out share on the page's split: the limit from ``d00_te``'s six pieces."""
    from diag_plugin.bench.matched import calibrate, rates

    return rates(s["free"], calibrate(s["cal_pieces"], target, period).limit, period)[0]


if __name__ == "__main__":
    raise SystemExit(main())
