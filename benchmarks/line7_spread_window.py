"""The spread test's window against the 7-tag line's sticking valve and the jacketed vessel
(issue 34 items 4 and 6; docs/how-to/unit-loops.md, "The 7-tag line's sticking valve").

Each variant sets the spread tests' window (``spread_window_s``; the oscillation hold's is
four of it, the settle's quiet time includes it), builds both units as the tests build them
(``build_unit`` on 6 fault-free days, seed 1, the loop declared, ``far = 0.01``; thresholds
learned for that window) and replays:

* the line (``tests/line7.py``): each seed's sticking-valve run (2 days, the valve sticks
  from day 1): unit alarm episodes and share of samples in alarm in the day after the
  onset, the share of those whose first tag is ``VALVE_A``, and ``FEED_FLOW_spread``'s share
  of samples on in the fault-free day before the onset; each seed's fault-free run (2 days):
  episodes, share in alarm, the most episodes in 10 minutes;
* the vessel (``tests/jacket4.py``): the sticking valve on seeds 101–103 (episodes, share
  after the onset) and fault-free days of seeds 105–108 (episodes, share), as
  ``tests/test_unit_stiction.py`` replays them.

Variants: main's 600 s; fixed windows (``--windows``); and ``acf``, the window read off each
unit's own fault-free build data (``unitbuild.build.release_window``: enough independent samples of
the loop's control error, its autocorrelation summed to its first zero, for its MAD to be
known to 20 %). Run: ``python benchmarks/line7_spread_window.py [--windows 600 3600 acf]
[--seeds 101 102 …]`` (about a minute and a half of CPU a variant); ``--statistics``: the
off-line table of :func:`statistics` instead.
"""

from __future__ import annotations

import argparse
import tempfile
from collections.abc import Sequence

import numpy as np
import pandas as pd

from tests import jacket4, line7


def episodes(alarm: np.ndarray) -> int:
    """Alarm episodes (runs of True) in ``alarm``."""
    a = np.asarray(alarm, bool)
    return int(np.count_nonzero(a & ~np.r_[False, a[:-1]]))


def worst_10min(alarm: np.ndarray, period_s: float) -> int:
    """The most episodes starting within any 10 minutes."""
    a = np.asarray(alarm, bool)
    e = np.flatnonzero(a & ~np.r_[False, a[:-1]])
    w = int(600 / period_s)
    return max(int(((e >= x) & (e < x + w)).sum()) for x in e) if e.size else 0


def build(name: str, frame: pd.DataFrame, loop: str, window: str):
    """The unit built on ``frame`` with the spread window of ``window``, and the window."""
    import diag_plugin.unitbuild.build as b
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.unitbuild.loops import parse_loop

    saved = b.SPREAD_WINDOW_S
    pv, rest = loop.split("=")
    how = ""
    if window == "acf":
        b.SPREAD_WINDOW_S, how = b.release_window(frame, [(pv, rest.split(":")[0])], 15.0)
    else:
        b.SPREAD_WINDOW_S = float(window)
    try:
        folder = tempfile.mkdtemp(prefix=f"{name}_")
        b.build_unit(name, frame, folder=folder, period="15s", loops=[parse_loop(loop)],
                     far=0.01, force=True)  # fmt: skip
    finally:
        b.SPREAD_WINDOW_S = saved
    return Unit.load(name, folder), how


def rolling_statistic(x: np.ndarray, window: int, kind: str) -> np.ndarray:
    """A running spread of ``x`` over ``window`` samples (known once a quarter is): ``mad``
    (``RunningSpread``'s), ``std``, or ``q1090`` (the 10–90 % range / 2.563)."""
    s, k = pd.Series(x), max(3, window // 4)
    if kind == "mad":
        med = s.rolling(window, min_periods=k).median()
        return 1.4826 * (s - med).abs().rolling(window, min_periods=k).median().to_numpy()
    if kind == "std":
        return s.rolling(window, min_periods=k).std().to_numpy()
    r = s.rolling(window, min_periods=k)
    return ((r.quantile(0.9) - r.quantile(0.1)) / 2.563).to_numpy()


def statistics(seeds: Sequence[int]) -> None:
    """Off-line, on main's line unit (600 s): each statistic of the filtered ``FEED_FLOW``
    residual over each window, its threshold the training run's largest value (no budget,
    no extrapolation), and nothing else of the unit: episodes above it (share) in the day
    after the onset of each seed's sticking valve, and on each fault-free run (2 days)."""
    unit, _ = build("line", line7.simulate(6.0, 1), line7.LOOP, "600")
    onset = int(86400 / line7.PERIOD_S)

    def residual(frame: pd.DataFrame) -> np.ndarray:
        return unit.reset().evaluate(frame).residuals["FEED_FLOW"].to_numpy()

    train = residual(line7.simulate(6.0, 1))
    fault = {s: residual(line7.simulate(2.0, s, "stiction")) for s in seeds}
    free = {s: residual(line7.simulate(2.0, s)) for s in seeds}
    print("| statistic | window | sticking valve: episodes (share) | fault-free: episodes |")
    print("|---|---|---|---|")
    for kind in ("mad", "q1090", "std"):
        for w in (40, 80, 160, 240, 320, 480):
            hi = np.nanmax(rolling_statistic(train, w, kind))
            st = [rolling_statistic(fault[s], w, kind)[onset:] > hi for s in seeds]
            fr = [episodes(rolling_statistic(free[s], w, kind) > hi) for s in seeds]
            row = " / ".join(f"{episodes(a)} ({a.mean():.0%})" for a in st)
            print(f"| {kind} | {w} | {row} | {' / '.join(map(str, fr))} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--windows", nargs="+", default=["600", "3600", "4800", "7200", "acf"])
    ap.add_argument("--seeds", type=int, nargs="+", default=[101, 102, 103, 104, 105, 106])
    ap.add_argument("--statistics", action="store_true", help="the off-line table only")
    args = ap.parse_args()
    if args.statistics:
        statistics(args.seeds)
        return
    onset = int(86400 / line7.PERIOD_S)
    train_line, train_jacket = line7.simulate(6.0, 1), jacket4.simulate(6.0, 1)
    for window in args.windows:
        unit, how = build("line", train_line, line7.LOOP, window)
        ev = unit.ev
        print(f"\n## window {window}: line spread_window_s {ev['spread_window_s']:.0f}"
              f" {how}, settle_max_s {ev['settle_max_s']:.0f}")  # fmt: skip
        st, fr = [], []
        for seed in args.seeds:
            d = unit.reset().evaluate(line7.simulate(2.0, seed, "stiction"))
            a = d.detected.to_numpy()[onset:] == 1
            top = d.top_tags["top1"].iloc[onset:]
            top = top[top != ""]
            sp = d.symptoms["FEED_FLOW_spread"].iloc[:onset]
            st.append(f"{episodes(a)} ({a.mean():.0%}, VALVE_A {(top == 'VALVE_A').mean():.0%},"
                      f" spread before {(sp != 0).mean():.1%})")  # fmt: skip
            f = unit.reset().evaluate(line7.simulate(2.0, seed)).detected.to_numpy() == 1
            fr.append(f"{episodes(f)} ({f.mean():.1%}, {worst_10min(f, line7.PERIOD_S)})")
        print(f"line sticking valve, seeds {args.seeds}: " + " / ".join(st))
        print("line fault-free (episodes, share, most in 10 min): " + " / ".join(fr))
        vessel, how = build("vessel", train_jacket, "TEMP=TEMP_TARGET:COOL_OUT", window)
        ev = vessel.ev
        st = []
        for seed in (101, 102, 103):
            a = vessel.reset().evaluate(jacket4.simulate(2.0, seed, "stiction"))
            a = a.detected.to_numpy()[onset:] == 1
            st.append(f"{episodes(a)} ({a.mean():.0%})")
        fr = []
        for seed in (105, 106, 107, 108):
            f = vessel.reset().evaluate(jacket4.simulate(1.0, seed)).detected.to_numpy() == 1
            fr.append(f"{episodes(f)} ({f.mean():.1%})")
        print(f"vessel spread_window_s {ev['spread_window_s']:.0f} {how}, settle_max_s "
              f"{ev['settle_max_s']:.0f}: sticking valve 101-103 {' / '.join(st)}; "
              f"fault-free 105-108 {' / '.join(fr)}")  # fmt: skip


if __name__ == "__main__":
    main()
