"""The 7-tag line's sticking valve, episode by episode (issue 34 item 6; docs/how-to/
unit-loops.md, "The spread alarm released on a long window"): for each unit alarm episode in
the day after the onset, the symptoms on at its start and at its last alarm sample (``T2``,
each test by name), its length and the gap to the next episode; per seed the episodes, the
share of samples in alarm after the onset and the share of those whose first tag is
``VALVE_A``; and (``--free``) the line's fault-free runs (2 days): episodes and share.

The unit is built as ``benchmarks/line7_spread_window.py`` builds it (``build_unit`` on
``line7.simulate(6, 1)``, the loop declared, ``far = 0.01``). Run: ``python
benchmarks/line7_stiction_episodes.py [--seeds 101 102 …] [--free] [--quiet]``.
"""

from __future__ import annotations

import argparse
import tempfile

import numpy as np

from tests import line7


def runs_of(a: np.ndarray) -> list[tuple[int, int]]:
    """(start, end exclusive) of each run of True in ``a``."""
    a = np.asarray(a, bool)
    d = np.diff(np.r_[0, a.astype(np.int8), 0])
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[101, 102, 103, 104, 105, 106])
    ap.add_argument("--free", action="store_true", help="the fault-free runs too")
    ap.add_argument("--quiet", action="store_true", help="the per-seed figures only")
    ap.add_argument(
        "--cli",
        action="store_true",
        help="built as tests/test_unit_loops.py builds it (import, --loops-from)",
    )
    args = ap.parse_args()

    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.unitbuild.build import build_unit
    from diag_plugin.unitbuild.loops import parse_loop

    folder = tempfile.mkdtemp(prefix="line7_")
    if args.cli:
        unit = cli_build(folder)
    else:
        res = build_unit("line", line7.simulate(6.0, 1), folder=folder, period="15s",
                         loops=[parse_loop(line7.LOOP)], far=0.01, force=True)  # fmt: skip
        unit = Unit.load(res.path, folder)
    period = line7.PERIOD_S
    onset = int(86400 / period)
    summary = []
    for seed in args.seeds:
        d = unit.reset().evaluate(line7.simulate(2.0, seed, "stiction"))
        alarm = d.detected.to_numpy()[onset:] == 1
        s = np.nan_to_num(d.symptoms.to_numpy()[onset:]) != 0
        names = list(d.symptoms.columns)
        if d.combined is not None:
            s = np.c_[s, d.combined["s_T2"].to_numpy()[onset:] == 1]
            names.append("T2")
        eps = runs_of(alarm)
        top = d.top_tags["top1"].iloc[onset:]
        top = top[top != ""]
        line = (f"seed {seed}: {len(eps)} episodes, {alarm.mean():.1%} in alarm, "
                f"VALVE_A first {(top == 'VALVE_A').mean():.0%}")  # fmt: skip
        if args.free:
            f = unit.reset().evaluate(line7.simulate(2.0, seed)).detected.to_numpy() == 1
            line += f"; fault-free {len(runs_of(f))} episodes ({f.mean():.2%})"
        summary.append(line)
        if args.quiet:
            continue
        print(f"\n## {line}")
        for k, (a, b) in enumerate(eps):
            on = np.flatnonzero(s[a:b].any(axis=1))
            last = a + (on[-1] if on.size else 0)

            def at(i: int, s=s, names=names) -> str:
                return "+".join(n for n, x in zip(names, s[i], strict=True) if x) or "-"

            during = "+".join(n for n, x in zip(names, s[a:b].any(axis=0), strict=True) if x)
            gap = (eps[k + 1][0] - b) * period / 60 if k + 1 < len(eps) else float("nan")
            print(f"{(a * period) / 3600:6.2f} h  len {(b - a) * period / 60:7.1f} min  "
                  f"start {at(a)}  end {at(last)}  during {during}  gap {gap:.1f} min")  # fmt: skip
    print("\n" + "\n".join(summary))


def cli_build(folder: str):
    """The line's unit built as ``tests/test_unit_loops.py``'s fixture builds it
    (:func:`tests.line7.cli_build`)."""
    from pathlib import Path

    from diag_plugin.diagnose.unit import Unit

    line7.cli_build(folder)
    return Unit.load("line", Path(folder) / "rb")


if __name__ == "__main__":
    main()
