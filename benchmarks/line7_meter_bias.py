"""The 7-tag line's flow-meter bias: on which tag it is held first, per seed (issue 34 item 4;
docs/how-to/unit-loops.md, "Why the fan flipped, and a gain in the judged residual's terms").

The unit is built as ``tests.line7.how_to_table`` builds it (``build_unit`` on
``line7.simulate(6, 1)``, the loop declared, ``far = 0.01``). Each seed's flow-bias run (2
days, the fault from day 1) is replayed once; printed per seed: the held top 1's share of the
alarm samples from day 1 on for ``FEED_FLOW`` (the meter) and ``VALVE_A`` (its loop's valve),
and the valve model's gain on the flow set-point the directions use (``combined.gains``)
beside the data's least-squares slope over the build window.
Run: ``python benchmarks/line7_meter_bias.py [--seeds 101 105 …]`` (about a minute of CPU
for the build, a few seconds per seed).
"""

from __future__ import annotations

import argparse
import tempfile

import numpy as np
import pandas as pd

from tests import line7


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[101, *range(105, 113)])
    args = ap.parse_args()

    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.unitbuild.build import build_unit
    from diag_plugin.unitbuild.loops import parse_loop

    folder = tempfile.mkdtemp(prefix="line7_")
    train = line7.simulate(6.0, 1)
    res = build_unit("line", train, folder=folder, period=f"{int(line7.PERIOD_S)}s",
                     loops=[parse_loop(line7.LOOP)], far=0.01, force=True)  # fmt: skip
    unit = Unit.load(res.path, folder)
    x = np.column_stack([train["FEED_TARGET"], train["SUPPLY_P"], np.ones(len(train))])
    slope = np.linalg.lstsq(x, train["VALVE_A"].to_numpy(), rcond=None)[0][0]
    gain = unit.file.combined.gains["VALVE_A"]["FEED_TARGET"]
    print(f"valve gain on FEED_TARGET {gain:.2f} %/(m3/h), data slope {slope:.2f}")
    onset = int(86400 / line7.PERIOD_S)
    for seed in args.seeds:
        d = unit.reset().evaluate(line7.simulate(2.0, seed, "flow_bias"))
        alarm = (d.detected.to_numpy() == 1)[onset:]
        top1 = d.top_tags["top1"].to_numpy()[onset:]
        share = pd.Series(top1[alarm & (top1 != "")]).value_counts(normalize=True)
        print(
            f"seed {seed}: FEED_FLOW {share.get('FEED_FLOW', 0.0):.0%}, "
            f"VALVE_A {share.get('VALVE_A', 0.0):.0%} of {int(alarm.sum())} alarm samples"
        )


if __name__ == "__main__":
    main()
