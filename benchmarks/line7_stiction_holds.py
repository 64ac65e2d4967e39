"""The 7-tag line's sticking valve: its alarm episodes and the holds measured off-line
(issue 34 item 6; docs/how-to/unit-loops.md, "The 7-tag line's sticking valve").

The unit is built as ``tests.line7.how_to_table`` builds it (``build_unit`` on
``line7.simulate(6, 1)``, the loop declared, ``far = 0.01``). Each seed's sticking-valve run
and fault-free run (2 days, the fault from day 1) are replayed once, with the oscillation hold
and without it. Then rules that are not in the unit are applied to what the replay gives:

* ``off-delay + W``: the unit's alarm (``detected``) kept on for ``W`` after each sample.
* ``repeat per test, W``: each side of each test, and T², armed once its symptom has come on
  3 times within ``2W`` and then held on until it has been off for ``W``. The held columns are
  joined and the unit's own off-delay is applied to the result.
* ``repeat on the unit, W``: the same rule on the unit's alarm.

``W`` is the unit's ``oscillation_window_s`` (2400 s, 160 samples at 15 s) times 1, 2 or 3.
Episodes are counted in the day after the onset. Fault-free runs are counted over both days.

Beside them, in the same run, PCA and dynamic PCA (2 lags), T² + Q fitted on the unit's
training run, each statistic over its 1 % limit, with the unit's on/off delays, their limit
matched to the unit's own share of samples in alarm on two fault-free calibration runs none
of them learned from (seeds 150 and 151, 2 days each): the baselines' episodes and detection
at the unit's false-alarm rate (``bench.matched``'s ``calibrate``).
Run: ``python benchmarks/line7_stiction_holds.py [--seeds 101 102 …]`` (under a minute of CPU
for the build and five seeds).
"""

from __future__ import annotations

import argparse
import tempfile

import numpy as np

from tests import line7


def episodes(alarm: np.ndarray) -> int:
    """Alarm episodes (runs of True) in ``alarm``."""
    a = np.asarray(alarm, bool)
    return int(np.count_nonzero(a & ~np.r_[False, a[:-1]]))


def off_delay(alarm: np.ndarray, off: int) -> np.ndarray:
    """``alarm`` kept on for ``off`` samples after each alarm sample."""
    a = np.asarray(alarm, bool)
    idx = np.where(a, np.arange(a.size), -(10**9))
    last = np.maximum.accumulate(idx)
    return (np.arange(a.size) - last) < max(off, 1)


def repeat_hold(alarm: np.ndarray, window: int, runs: int = 3) -> np.ndarray:
    """``alarm`` held on once it has come on ``runs`` times within ``2 × window``, until it
    has been off for ``window`` (then the count starts again)."""
    a = np.asarray(alarm, bool)
    out = a.copy()
    starts: list[int] = []
    armed, last, prev = False, -(10**9), False
    for i in range(a.size):
        if a[i]:
            if not prev:
                starts = [s for s in starts if i - s < 2 * window] + [i]
                armed = armed or len(starts) >= runs
            last = i
        elif armed and i - last < window:
            out[i] = True
        elif armed:
            armed, starts = False, []
        prev = bool(a[i])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[101, 102, 103, 104, 105])
    args = ap.parse_args()

    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.unitbuild.build import build_unit
    from diag_plugin.unitbuild.loops import parse_loop

    folder = tempfile.mkdtemp(prefix="line7_")
    res = build_unit("line", line7.simulate(6.0, 1), folder=folder, period="15s",
                     loops=[parse_loop(line7.LOOP)], far=0.01, force=True)  # fmt: skip
    unit = Unit.load(res.path, folder)
    period = line7.PERIOD_S
    w = int(round(unit.ev["oscillation_window_s"] / period))
    off = int(np.ceil(unit.ev["off_delay_s"] / period))
    onset = int(86400 / period)
    rules = ["main", "the oscillation hold off", f"off-delay + {w * period:.0f} s"]
    rules += [f"repeat per test, W = {k * w * period:.0f} s" for k in (1, 2)]
    rules += [f"repeat on the unit, W = {k * w * period:.0f} s" for k in (1, 3)]
    got: dict[str, dict[str, list[str]]] = {r: {"stiction": [], "free": []} for r in rules}
    base = baselines(unit, line7.simulate(6.0, 1), period, onset, args.seeds)
    for seed in args.seeds:
        for fault in ("stiction", None):
            frame = line7.simulate(2.0, seed, fault)
            d = unit.reset().evaluate(frame)
            saved = unit.ev["oscillation_window_s"]
            unit.ev["oscillation_window_s"] = 0.0
            try:
                plain = unit.reset().evaluate(frame).detected.to_numpy() == 1
            finally:
                unit.ev["oscillation_window_s"] = saved
                unit.reset()
            alarm = d.detected.to_numpy() == 1
            s = np.nan_to_num(d.symptoms.to_numpy())
            sides = [s[:, j] > 0 for j in range(s.shape[1])]
            sides += [s[:, j] < 0 for j in range(s.shape[1])]
            if d.combined is not None:
                sides.append(d.combined["s_T2"].to_numpy() == 1)
            outs = [alarm, plain, off_delay(alarm, w)]
            outs += [off_delay(np.any([repeat_hold(c, k * w) for c in sides], axis=0), off)
                     for k in (1, 2)]  # fmt: skip
            outs += [repeat_hold(alarm, k * w) for k in (1, 3)]
            for rule, out in zip(rules, outs, strict=True):
                if fault:
                    after = out[onset:]
                    got[rule]["stiction"].append(f"{episodes(after)} ({after.mean():.0%})")
                else:
                    got[rule]["free"].append(f"{episodes(out)} ({out.mean():.1%})")
            if fault and seed == args.seeds[0]:
                on = (s[onset:] != 0).mean(axis=0)
                shares = ", ".join(f"{t} {v:.0%}" for t, v in zip(unit.tests, on, strict=True))
                if d.combined is not None:
                    shares += f", T² {(d.combined['s_T2'].to_numpy()[onset:] == 1).mean():.0%}"
                print(f"seed {seed}, samples on after the onset: {shares}")
    print(f"\nseeds {' / '.join(map(str, args.seeds))}: episodes (share of samples in alarm)\n")
    print("| rule | sticking valve, the day after the onset | fault-free runs, 2 days |")
    print("|---|---|---|")
    for rule in rules:
        print(f"| {rule} | {' / '.join(got[rule]['stiction'])} | {' / '.join(got[rule]['free'])} |")
    for rule, row in base.items():
        print(f"| {rule} | {' / '.join(row['stiction'])} | {' / '.join(row['free'])} |")


def baselines(unit, train, period: float, onset: int, seeds) -> dict[str, dict[str, list[str]]]:
    """PCA and DPCA beside the unit at its false-alarm rate (module doc): per method its
    episodes (share of samples in alarm) on each seed's sticking-valve run after the onset
    and on its fault-free run."""
    from diag_plugin.bench.matched import calibrate, method_score
    from diag_plugin.bench.pca import PCADetector

    on = max(1, int(np.ceil(unit.ev["on_delay_s"] / period)))
    off = max(1, int(np.ceil(unit.ev["off_delay_s"] / period)))
    cal = [line7.simulate(2.0, s) for s in (150, 151)]
    unit_share = np.mean(np.concatenate(
        [unit.reset().evaluate(f).detected.to_numpy() == 1 for f in cal]))  # fmt: skip
    out: dict[str, dict[str, list[str]]] = {}
    for name, lags in (("PCA", 0), ("DPCA", 2)):
        det = PCADetector(lags=lags).fit(train)
        lt, lq = det.limits(0.01)

        def score(frame, det=det, lt=lt, lq=lq):
            sc = det.score(frame).reindex(frame.index)
            return method_score(np.c_[sc["T2"] / lt, sc["Q"] / lq], on, off)

        lim = calibrate([score(f) for f in cal], max(unit_share, 1e-6), period).limit
        rule = f"{name} T² + Q at the unit's {unit_share:.1%} of calibration samples"
        row: dict[str, list[str]] = {"stiction": [], "free": []}
        for seed in seeds:
            a = np.nan_to_num(score(line7.simulate(2.0, seed, "stiction")), nan=-np.inf) > lim
            row["stiction"].append(f"{episodes(a[onset:])} ({a[onset:].mean():.0%})")
            b = np.nan_to_num(score(line7.simulate(2.0, seed)), nan=-np.inf) > lim
            row["free"].append(f"{episodes(b)} ({b.mean():.1%})")
        out[rule] = row
    unit.reset()
    return out


if __name__ == "__main__":
    main()
