"""The 7-tag line's faults beside PCA and DPCA at the unit's false-alarm rate (issue 34, items
1/4/6: the baselines computed in the same run on the same data; docs/how-to/unit-loops.md,
"The 7-tag line's sticking valve" and "Named first on the line").

The unit is built as ``benchmarks/line7_meter_bias.py`` builds it (``build_unit`` on
``line7.simulate(6, 1)``, the loop declared, ``far = 0.01``). PCA and DPCA (2 lags): T² + Q
fitted on the same training run, each statistic over its 1 % limit, the unit's on/off delays,
their limit matched to the unit's own share of samples in alarm on two fault-free calibration
runs none of them learned from (seeds 150, 151; ``bench.matched.calibrate``). For each fault
(2 days, from day 1) and seed, per method: the share of samples raised after the onset, the
alarm episodes, and the tag held first on most alarm samples with its share (the unit's held
``top1``; PCA's and DPCA's largest contribution, lagged columns summed per tag) against the
tag at fault (``line7.AT_FAULT``).
Run: ``python benchmarks/line7_pca_beside.py [--seeds 101 102 …]`` (about a minute of CPU).
"""

from __future__ import annotations

import argparse
import tempfile

import numpy as np
import pandas as pd

from tests import line7


def _episodes(a: np.ndarray) -> int:
    return int(np.count_nonzero(a & ~np.r_[False, a[:-1]]))


def _first(names: np.ndarray) -> str:
    """The tag most often first, with its share (``-`` when nothing is raised)."""
    names = names[names != ""]
    if not names.size:
        return "-"
    share = pd.Series(names).value_counts(normalize=True)
    return f"{share.index[0]} {share.iloc[0]:.0%}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[101, 102, 103])
    args = ap.parse_args()

    from diag_plugin.bench.matched import calibrate, method_score
    from diag_plugin.bench.pca import PCADetector
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.unitbuild.build import build_unit
    from diag_plugin.unitbuild.loops import parse_loop

    period, onset = line7.PERIOD_S, int(86400 / line7.PERIOD_S)
    train = line7.simulate(6.0, 1)
    folder = tempfile.mkdtemp(prefix="line7_")
    res = build_unit("line", train, folder=folder, period=f"{int(period)}s",
                     loops=[parse_loop(line7.LOOP)], far=0.01, force=True)  # fmt: skip
    unit = Unit.load(res.path, folder)
    on = max(1, int(np.ceil(unit.ev["on_delay_s"] / period)))
    off = max(1, int(np.ceil(unit.ev["off_delay_s"] / period)))
    cal = [line7.simulate(2.0, s) for s in (150, 151)]
    share = float(np.mean(np.concatenate(
        [unit.reset().evaluate(f).detected.to_numpy() == 1 for f in cal])))  # fmt: skip
    print(f"unit: {share:.2%} of the calibration samples in alarm (seeds 150, 151)")

    def unit_run(frame: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
        d = unit.reset().evaluate(frame)
        return d.detected.to_numpy() == 1, d.top_tags["top1"].fillna("").to_numpy(str)

    methods = {"unit": unit_run}
    for name, lags in (("PCA", 0), ("DPCA", 2)):
        det = PCADetector(lags=lags).fit(train)
        lt, lq = det.limits(0.01)

        def score(frame, det=det, lt=lt, lq=lq) -> np.ndarray:
            sc = det.score(frame).reindex(frame.index)
            s = method_score(np.c_[sc["T2"] / lt, sc["Q"] / lq], on, off)
            return np.nan_to_num(s, nan=-np.inf)

        lim = calibrate([score(f) for f in cal], max(share, 1e-6), period).limit

        def run(frame, det=det, score=score, lim=lim) -> tuple[np.ndarray, np.ndarray]:
            c = det.contributions(frame).reindex(frame.index).fillna(0.0)
            c = c.T.groupby(c.columns.str.replace(r"\[.*", "", regex=True)).sum().T
            return score(frame) > lim, c.idxmax(axis=1).to_numpy(str)

        methods[name] = run
    print("\n| fault (tag at fault) | seed | " + " | ".join(methods) + " |")
    print("|---|---|" + "---|" * len(methods))
    for fault, tag in line7.AT_FAULT.items():
        for seed in args.seeds:
            frame = line7.simulate(2.0, seed, fault)
            cells = []
            for run in methods.values():
                alarm, first = run(frame)
                a = alarm[onset:]
                cells.append(f"{a.mean():.0%}, {_episodes(a)} ep., {_first(first[onset:][a])}")
            print(f"| {fault} ({tag}) | {seed} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
