"""What a drift allowance would do to SKAB's tuning F1 (issue 34, round 6), read from the
raw statistics ``skab_matched_tuning.py --save FILE`` keeps: no unit is built again.

A short window's tests judge a slow tag's wander by what 400 s showed. The allowance asked
about: each chosen statistic (each test's and the combined T²'s value over its limit) is
divided by ``sqrt(1 + tau / T)`` — a random walk's spread, the level's variance growing by
the window's own in every ``T`` samples since the window ends (``tau``) — or, for T² only,
by ``1 + tau / T`` (T² is a square). The limits are then matched on the calibration runs as
the harness matches them, and SKAB's F1 on the tuning runs printed per target, with the
calibration runs over the limit at 0.1 and the tuning faults detected there.

Exact for what it asks (the statistics are divided before the on/off delays, as a unit
with the allowance would raise them), but it reads one build: a unit whose tests carried
the allowance would have the same tests and limits. Run:
``python benchmarks/skab_drift_allowance.py FILE`` (SKAB's mirror or ``$DIAG_SKAB_DIR``).
"""

from __future__ import annotations

import argparse

import numpy as np

TARGETS = (0.02, 0.05, 0.1, 0.25)
SPANS = (200, 400, 800, 1600)


def main(argv: list[str] | None = None) -> int:
    from diag_plugin.bench.matched import Scored, calibrate, method_score
    from diag_plugin.bench.publicbench import skab_metrics
    from diag_plugin.bench.publicplants import load_skab

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("load", help="a --save of skab_matched_tuning.py")
    args = ap.parse_args(argv)
    raw = dict(np.load(args.load))
    on, off = (int(v) for v in raw["delays"])
    plant = load_skab()
    tuning = {r.name: r for r in plant.tuning}

    def level(name: str) -> bool:  # a short window's level and joint tests on SKAB
        return name in ("Pressure", "Volume_Flow_RateRMS") or name.endswith("_joint")

    def scores(allowance, which) -> dict[str, np.ndarray]:
        out = {}
        for run in plant.calibration:
            u = raw[f"{run.name}|unit"].copy()
            names = [str(n) for n in raw[f"{run.name}|unit_names"]]
            tau = np.maximum(np.arange(len(u)) - run.learn, 0).astype(float)
            for j, name in enumerate(names):
                if which(name):
                    u[:, j] /= allowance(tau)
            out[run.name] = method_score(u, on, off)[run.learn :]
        return out

    def report(label: str, by_run: dict[str, np.ndarray]) -> None:
        f1, tail = [], ""
        for target in TARGETS:
            cal = [
                by_run[r.name] if r.labels is None else by_run[r.name][r.labels[r.learn :] == 0]
                for r in plant.calibration
            ]
            lim = calibrate(cal, target, 1.0).limit
            lab = [r.labels[r.learn :] for r in tuning.values()]
            f1.append(skab_metrics([Scored(by_run[n]) for n in tuning], lab, lim)["F1"])
            if target == 0.1:
                over = {r.name: int(np.sum(np.nan_to_num(c, nan=-1) > lim))
                        for r, c in zip(plant.calibration, cal, strict=True)}  # fmt: skip
                seen = {n: float(np.mean(np.nan_to_num(by_run[n][r.labels[r.learn :] > 0],
                                                       nan=-1) > lim))
                        for n, r in tuning.items()}  # fmt: skip
                tail = (
                    f"\n    at 0.1: limit {lim:.2f}; over it "
                    + ", ".join(f"{k} {v}" for k, v in over.items() if v)
                    + "\n    detected: "
                    + ", ".join(f"{k} {v:.0%}" for k, v in seen.items() if v)
                )
        print(f"{label:44s} " + " / ".join(f"{v:.2f}" for v in f1) + tail, flush=True)

    print("unit F1 on the tuning runs at " + " / ".join(f"{t:g}" for t in TARGETS))
    report("none (the build as saved)", scores(lambda t: np.ones_like(t), lambda n: True))
    for span in SPANS:
        walk = lambda t, s=span: np.sqrt(1.0 + t / s)  # noqa: E731
        report(f"every statistic, sqrt(1 + tau/{span})", scores(walk, lambda n: True))
        report(f"level and joint tests, sqrt(1 + tau/{span})", scores(walk, level))
        report(f"T2 only, 1 + tau/{span}", scores(lambda t, s=span: 1.0 + t / s,
                                                   lambda n: n == "T2"))  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
