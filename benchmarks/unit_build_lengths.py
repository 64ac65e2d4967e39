"""``diag unit build`` across the short-window boundary (issue 34, item 3).

Per plant a fault-free window is cut to its first ``N`` samples (600, 900, 990, 1,010, 1,200,
2,000, 5,000 by default), a unit built from each exactly as ``diag unit build`` does
(:func:`~diag_plugin.unitbuild.build.build_unit`, budget 0.01 false alarms per hour), and
each unit run on fault-free data the build did not see:

* held-out residual error: per test the RMS of its raw residual (% of span, eq. 6) over the
  :data:`AFTER` samples that follow the window (the same operating period, never seen by the
  build); the median over the unit's tests, and the median over the tags tested by every
  build of that run (so that a unit that drops a hard tag does not look better);
* false alarms: alarm onsets per hour of those samples (the unit in alarm, not
  CHECK_FUNCTION) and the share of them in alarm; the share CHECK_FUNCTION (a sample in
  alarm is not CHECK_FUNCTION even where a test is unknown, so fewer alarms can raise it),
  and the share where any test is unknown, in alarm or not;
* the unit's tests: how many, and how many linear / rule grids / joint.

Each figure is the mean over the plant's runs. Plants: ``chemplant`` (the chemical plant at
1 min, seeds 1, 2, 3), ``skab`` (SKAB's anomaly-free.csv at 1 s: its first and its last
5,600 rows), ``blend`` (the blending line at 15 s, seeds 7, 8, 9).

Run: ``python benchmarks/unit_build_lengths.py [--plants chemplant skab blend]
[--lengths 600 900 ...]``.
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))

LENGTHS = (600, 900, 990, 1010, 1200, 2000, 5000)


def cpu_s() -> float:
    me = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


#: samples of each window's continuation the unit is run on
AFTER = 600


def chemplant() -> tuple[list[pd.DataFrame], str, dict]:
    from diag_plugin.simulate.chemplant import CHEMPLANT_TAGS, sample, simulate_chemplant
    from historian.taginfo import TagInfo

    days = (max(LENGTHS) + AFTER) / 1440 + 0.05
    runs = [sample(simulate_chemplant(days, s), 60) for s in (1, 2, 3)]
    info = {
        t: TagInfo(t, unit=u, lo=lo, hi=hi, description=d)
        for t, (u, lo, hi, d, _) in CHEMPLANT_TAGS.items()
    }
    return runs, "60s", info


def skab() -> tuple[list[pd.DataFrame], str, dict]:
    from diag_plugin.bench.publicplants import SKAB_TAGS, skab_source

    free = skab_source().read("anomaly-free/anomaly-free.csv")[list(SKAB_TAGS)]
    free.index = pd.DatetimeIndex(free.index).tz_localize("UTC")
    grid = free.resample("1s").mean()
    info = {t: {"unit": u, "description": d} for t, (u, d) in SKAB_TAGS.items()}
    span = max(LENGTHS) + AFTER
    return [grid.iloc[:span], grid.iloc[-span:]], "1s", info


def blend() -> tuple[list[pd.DataFrame], str, dict]:
    from diag_plugin.simulate.blendline import on_grid, simulate_blendline

    days = (max(LENGTHS) + AFTER) * 15 / 86400 + 0.05
    return [on_grid(simulate_blendline(days, seed=s)) for s in (7, 8, 9)], "15s", {}


PLANTS = {"chemplant": chemplant, "skab": skab, "blend": blend}


def run_one(plant: str, run: pd.DataFrame, n: int, period: str, info, folder: Path) -> dict:
    """A unit built from ``run``'s first ``n`` samples, run on the next :data:`AFTER`."""
    from bench_detection_plants import episodes_per_hour, unit_alarms

    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.unitbuild.build import build_unit

    part, after = run.iloc[:n], run.iloc[n : n + AFTER]
    c0 = cpu_s()
    res = build_unit(plant, part, folder=folder, period=period, tag_info=info or None,
                     far=0.01, force=True)  # fmt: skip
    cpu = cpu_s() - c0
    unit = Unit.load(res.path, folder)
    raw = unit.reset().raw_residuals(after)
    by_tag = {}
    for ch in res.tests:
        if ch.test in raw.columns and ch.method != "joint":
            r = raw[ch.test].to_numpy(float)
            r = r[np.isfinite(r)]
            by_tag[ch.tag] = float(np.sqrt(np.mean(r * r))) if r.size else np.nan
    al, unk = unit_alarms(unit, after)
    data = after.notna().any(axis=1).to_numpy()
    tests = [ch.test for ch in res.tests]
    sym = unit.reset().evaluate(after).symptoms
    any_unknown = sym[[t for t in tests if t in sym.columns]].isna().any(axis=1).to_numpy()
    methods = [ch.method for ch in res.tests]
    return dict(
        short=any("short window" in r for r in res.notes),
        tests=len(res.tests),
        linear=methods.count("linear"),
        grid=methods.count("wm-avg"),
        joint=methods.count("joint"),
        inputs=float(np.mean([len(ch.inputs) for ch in res.tests])),
        by_tag=by_tag,
        far=episodes_per_hour(al, data, period),
        in_alarm=float(al[data].mean()),
        unknown=float(unk[data].mean()),
        any_unknown=float(any_unknown[data].mean()),
        cpu=cpu,
    )


def measure(plant: str, lengths, folder: Path) -> list[dict]:
    """Per length the mean over the plant's runs (:func:`run_one`); the residual error as the
    median over the tags tested by every build of the run, then the mean over runs."""
    runs, period, info = PLANTS[plant]()
    per = {n: [] for n in lengths}
    for k, run in enumerate(runs):
        got = {n: run_one(plant, run, n, period, info, folder / f"{plant}{k}_{n}")
               for n in lengths}  # fmt: skip
        common = set.intersection(
            *({t for t, v in g["by_tag"].items() if np.isfinite(v)} for g in got.values())
        )
        for n, g in got.items():
            g["median_err"] = float(np.nanmedian(list(g["by_tag"].values())))
            g["common_err"] = (
                float(np.median([g["by_tag"][t] for t in common])) if common else np.nan
            )
            g["common_tags"] = len(common)
            per[n].append(g)
            print(f"  {plant} run {k} N={n}: {g['tests']} tests ({g['linear']} linear, "
                  f"{g['grid']} grid, {g['joint']} joint), error {g['median_err']:.2f} % "
                  f"(common {g['common_err']:.2f}), FAR {g['far']:.3f}/h, in alarm "
                  f"{g['in_alarm']:.1%}, CPU {g['cpu']:.1f} s", flush=True)  # fmt: skip
    rows = []
    for n, gs in per.items():
        row = {"plant": plant, "n": n, "runs": len(gs), "short": all(g["short"] for g in gs)}
        for key in ("tests", "linear", "grid", "joint", "inputs", "median_err", "common_err",
                    "common_tags", "far", "in_alarm", "unknown", "any_unknown",
                    "cpu"):  # fmt: skip
            row[key] = float(np.mean([g[key] for g in gs]))
        rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    from _common import scratch

    ap = argparse.ArgumentParser()
    ap.add_argument("--plants", nargs="+", default=list(PLANTS), choices=list(PLANTS))
    ap.add_argument("--lengths", nargs="+", type=int, default=list(LENGTHS))
    a = ap.parse_args(argv)
    print(f"load average {os.getloadavg()[0]:.1f}")
    out = []
    with scratch("lengths_") as folder:
        for p in a.plants:
            out += measure(p, a.lengths, folder)
    print("\n| plant | N | plan | tests (lin/grid/joint) | inputs | median err % | "
          "err on common tags % | FAR /h | in alarm | unknown | a test unknown | "
          "CPU s |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in out:
        print(f"| {r['plant']} | {r['n']} | {'short' if r['short'] else 'long'} | {r['tests']:.1f} "
              f"({r['linear']:.1f}/{r['grid']:.1f}/{r['joint']:.1f}) | {r['inputs']:.1f} | "
              f"{r['median_err']:.2f} | {r['common_err']:.2f} ({r['common_tags']:.0f}) | "
              f"{r['far']:.3f} | {r['in_alarm']:.2%} | {r['unknown']:.2%} | "
              f"{r['any_unknown']:.2%} | {r['cpu']:.1f} |")  # fmt: skip
    print(f"load average {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
