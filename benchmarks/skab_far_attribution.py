"""Where a SKAB build's false alarms on the scoring runs come from, run by run and test by
test (issue 34 round 14: the false alarms): two saved statistics of
``skab_matched_tuning.py --scoring --save`` (a build ``A`` and a build ``B``, e.g. main and
main with one step switched off), each scored as the bench scores it (each statistic after
its own on/off delays, their maximum, the limit matched on the calibration runs).

Per target: the two limits, then per scoring run with a difference its false-alarm samples
(label 0 after the first 400) under A and B, split into

* ``limit``: B's statistics at A's limit minus at B's (the calibration runs moved it),
* ``kept-out``: A's statistics with and without its kept-out tests (names ``*_pair``),
* ``others``: the rest (the other tests' statistics themselves changed),

and how many of A's false alarms fall in a fault's tail (within ``--tail`` samples after a
fault's last labelled sample), with the largest delayed statistic of each kept-out test on the
run's normal samples (over its threshold; A's limit is on the same scale). ``--per-run``
prints every run's false alarms at each target instead: B, A, and PCA and DPCA (A's file) at
their own limits, with the run's normal samples before and after its fault.

Run: ``python benchmarks/skab_far_attribution.py A.npz B.npz``.
"""

from __future__ import annotations

import argparse

import numpy as np


def _delayed(raw: dict, name: str, on: int, off: int) -> tuple[np.ndarray, np.ndarray]:
    """A run's statistics after the delays (samples × statistics) and their names."""
    from diag_plugin.bench.matched import delayed_score

    return delayed_score(raw[f"{name}|unit"], on, off), raw[f"{name}|unit_names"]


def _score(d: np.ndarray, keep: np.ndarray | None = None) -> np.ndarray:
    """The bench's score: the maximum over the (kept) delayed statistics, NaN where none."""
    if keep is not None:
        d = d[:, keep]
    with np.errstate(all="ignore"):
        known = (~np.isnan(d)).any(axis=1)
        out = np.full(len(d), np.nan)
        out[known] = np.nanmax(d[known], axis=1)
    return out


def _limit(raw: dict, cal, target: float, on: int, off: int) -> float:
    """The bench's limit at ``target`` on the calibration runs' normal samples."""
    from diag_plugin.bench.matched import calibrate

    xs = []
    for run in cal:
        s = _score(_delayed(raw, run.name, on, off)[0])[run.learn :]
        xs.append(s if run.labels is None else s[run.labels[run.learn :] == 0])
    return calibrate(xs, target, 1.0).limit


def _over(s: np.ndarray, lim: float) -> np.ndarray:
    """Samples over ``lim`` (unknown ones never)."""
    return np.nan_to_num(s, nan=-np.inf) > lim


def _method_score(raw: dict, method: str, name: str, on: int, off: int) -> np.ndarray:
    """A run's score by the unit (``unit``) or by PCA / DPCA, as the bench takes it."""
    from diag_plugin.bench.matched import method_score

    if method == "unit":
        return _score(_delayed(raw, name, on, off)[0])
    return method_score(raw[f"{name}|{method}"], on, off)


def per_run(a: dict, b: dict, plant, targets: list[float], on: int, off: int) -> None:
    """Every scoring run's false-alarm samples at each target (``x / y / z``): B, A, PCA, DPCA."""
    from diag_plugin.bench.matched import calibrate

    ways = (("B", b, "unit"), ("A", a, "unit"), ("PCA", a, "PCA"), ("DPCA", a, "DPCA"))
    lims = {}
    for key, raw, m in ways:
        xs = []
        for run in plant.calibration:
            s = _method_score(raw, m, run.name, on, off)[run.learn :]
            xs.append(s if run.labels is None else s[run.labels[run.learn :] == 0])
        lims[key] = [calibrate(xs, t, 1.0).limit for t in targets]
    print("run | normal before + after the fault | " + " | ".join(k for k, _, _ in ways))
    tot = {k: np.zeros(len(targets), int) for k in lims}
    for run in plant.faults:
        lab = run.labels[run.learn :]
        before = int((lab[: np.flatnonzero(lab > 0)[0]] == 0).sum())
        cells = []
        for key, raw, m in ways:
            s = _method_score(raw, m, run.name, on, off)[run.learn :]
            v = [int((_over(s, lim) & (lab == 0)).sum()) for lim in lims[key]]
            tot[key] += v
            cells.append(" / ".join(map(str, v)))
        print(f"{run.name} | {before} + {int((lab == 0).sum()) - before} | " + " | ".join(cells))
    n = sum(int((r.labels[r.learn :] == 0).sum()) for r in plant.faults)
    print(f"all | {n} | " + " | ".join(" / ".join(f"{x / n:.1%}" for x in v) for v in tot.values()))


def main(argv: list[str] | None = None) -> int:
    from diag_plugin.bench.publicplants import load_skab

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("a", help="saved statistics of build A (the one with kept-out tests)")
    ap.add_argument("b", help="saved statistics of build B")
    ap.add_argument("--targets", default="0.05,0.1,0.25")
    ap.add_argument("--tail", type=int, default=240, help="samples after a fault's end")
    ap.add_argument("--per-run", action="store_true", help="every run's false alarms")
    args = ap.parse_args(argv)
    a, b = dict(np.load(args.a)), dict(np.load(args.b))
    on, off = (int(v) for v in a["delays"])
    plant = load_skab()
    if args.per_run:
        per_run(a, b, plant, [float(t) for t in args.targets.split(",")], on, off)
        return 0
    for target in (float(t) for t in args.targets.split(",")):
        la, lb = (_limit(r, plant.calibration, target, on, off) for r in (a, b))
        print(f"\ntarget {target:g}: limit A {la:.4g}, B {lb:.4g}")
        print("run | normal | FA B | FA A | limit | kept-out | others | A in tails | A's kept-out")
        tot = np.zeros(5, int)
        for run in plant.faults:
            lab = run.labels[run.learn :]
            normal = lab == 0
            da, names = _delayed(a, run.name, on, off)
            db = _delayed(b, run.name, on, off)[0]
            pair = np.char.endswith(names.astype(str), "_pair")
            sa, sa0 = _score(da)[run.learn :], _score(da, ~pair)[run.learn :]
            sb = _score(db)[run.learn :]
            fa_b, fa_b_at_a = (int((_over(sb, lim) & normal).sum()) for lim in (lb, la))
            fa_a0, fa_a = (int((_over(s, la) & normal).sum()) for s in (sa0, sa))
            ends = np.flatnonzero((lab[:-1] > 0) & (lab[1:] == 0)) + 1
            tail = np.zeros(len(lab), bool)
            for e in ends:
                tail[e : e + args.tail] = True
            in_tail = int((_over(sa, la) & normal & tail).sum())
            row = [fa_b, fa_a, fa_b_at_a - fa_b, fa_a - fa_a0, fa_a0 - fa_b_at_a]
            tot += np.array(row)
            if fa_a != fa_b or pair.any():
                kept = ", ".join(
                    f"{n} {float(np.nanmax(da[run.learn :, i][normal])):.3g}"
                    for i, n in zip(np.flatnonzero(pair), names[pair], strict=True)
                )
                print(f"{run.name} | {int(normal.sum())} | " + " | ".join(map(str, row))
                      + f" | {in_tail} | {kept}")  # fmt: skip
        n = sum(int((r.labels[r.learn :] == 0).sum()) for r in plant.faults)
        print(f"all | {n} | " + " | ".join(map(str, tot))
              + f" | ({tot[0] / n:.1%} -> {tot[1] / n:.1%})")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
