"""What a settle costs (issue 34, item 6; docs/how-to/unit-loops.md, "The settles at 1 s, off
the grid"): a fault that starts inside a settle is CHECK_FUNCTION until the settle ends.

The set-point-step heater (tests/spstep_plant.py, simulated at 1 s) built through the CLI by
:mod:`benchmarks.settle_offgrid` (its folder given), then runs of 8 h with one step of
``HEAT_TGT`` (65 → 70 °C at 4 h) and a flow meter bias from a controlled offset after it,
read off the grid as there and judged with ``diag diagnose`` by the unit and by the same unit
without its guard (``settle_max_s = 0``). Per offset: the share of the first hour after the
onset raised (neither NORMAL nor CHECK_FUNCTION) and the delay to the first raised sample.

Run: ``python -m benchmarks.settle_cost FOLDER PERIOD_S [SIZE]`` (FOLDER: a kept
``settle_offgrid`` spstep folder).
"""

from __future__ import annotations

import json
import re
import shutil
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from benchmarks.settle_offgrid import diag, fmt, off_grid, spstep_run, write_csv

STEP_S = 4 * 3600.0
#: fault onsets after the step, s
OFFSETS = (30, 120, 300, 600, 1200, 2400)


def main() -> None:
    folder, period = Path(sys.argv[1]), float(sys.argv[2])
    size = float(sys.argv[3]) if len(sys.argv) > 3 else None
    g = ["--db", f"sqlite:///{folder / 'h.db'}", "--rulebases", str(folder / "rb")]
    plain = folder / "rb0"
    shutil.rmtree(plain, ignore_errors=True)
    shutil.copytree(folder / "rb", plain)
    unit = plain / "u.unit.toml"
    unit.write_text(re.sub(r"(?m)^settle_max_s = .*$", "settle_max_s = 0.0", unit.read_text()))
    g0 = ["--db", g[1], "--rulebases", str(plain)]
    rows = []
    for k, off in enumerate((None, *OFFSETS)):
        # no step (None): the fault at the step's time + 120 s, the reference
        steps = [] if off is None else [(STEP_S, 70.0)]
        onset = STEP_S + (120 if off is None else off)
        run = spstep_run(8 / 24, 4, "flow_bias", onset, size=size, steps=steps)
        run.index = run.index + pd.Timedelta(days=40 + k)
        x = off_grid(run, period, 40 + k)
        path = folder / f"cost{k}.csv"
        write_csv(x, path)
        rc, text, _ = diag(g, "import", str(path), "--duplicates", "first")
        assert rc == 0, text
        a, b = run.index[0], run.index[-1] + pd.Timedelta(seconds=1)
        row = {"offset_s": off, "period_s": period}
        for name, gg in (("guard", g), ("none", g0)):
            csv = folder / f"cost{k}_{name}.csv"
            rc, text, _ = diag(gg, "diagnose", "u", "--from", fmt(a), "--to", fmt(b), "--csv",
                               str(csv))  # fmt: skip
            assert rc == 0, text
            d = pd.read_csv(csv, low_memory=False)
            ts = pd.to_datetime(d["ts"], utc=True)
            s = (ts - a).dt.total_seconds().to_numpy()
            st = d["status"].to_numpy(int)
            raised = (st != 0) & (st != 2)
            hour = (s >= onset) & (s < onset + 3600)
            row[f"{name}_raised_1h_pct"] = round(100 * float(raised[hour].mean()), 1)
            row[f"{name}_cf_1h_pct"] = round(100 * float((st == 2)[hour].mean()), 1)
            first = np.flatnonzero(raised & (s >= onset))
            row[f"{name}_first_s"] = round(float(s[first[0]] - onset)) if first.size else None
            before = (s >= STEP_S - 3600) & (s < onset)
            row[f"{name}_raised_before_pct"] = round(100 * float(raised[before].mean()), 1)
        rows.append(row)
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
