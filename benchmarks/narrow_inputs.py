"""Which inputs the build's narrow-span note names, and whether later fault-free data leave
what the window showed (issue 34 item 3, ``i34-review``; ``build.narrow_spans``).

Short windows of 400 samples (tuning plants only): the tank and the heat exchanger of
:mod:`diag_plugin.simulate.smallplants` at 15 s and 1 min, their tags' spans 0 … 3 × the
run's largest value (as ``tests/test_unit_short_learned_span.py``), the rest of the run as
the later data; the HTST pasteuriser (``benchmarks/acceptance/pasteuriser_sim.py``, seed 5,
10 s, its tags CSV) over 02:00–03:06:40 of one day, its later production rows (``MODE`` 1)
as the later data. Every tag with a span is taken as an input. Per tag: the window's share
of its span, its independent values (``effective_samples``), the rule before (under 5 % of
the span) and now (``narrow_spans``), and the share of later samples outside the window's
range. Prints a table and, per rule, the mean later-outside share of the named and the
unnamed tags.

    python benchmarks/narrow_inputs.py
"""

from __future__ import annotations

import csv
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from diag_plugin.models.series import effective_samples
from diag_plugin.simulate import smallplants as sp
from diag_plugin.unitbuild.build import Step, TestChoice, narrow_spans
from historian.taginfo import TagInfo

OLD_SHARE = 0.05  # the rule before: under 5 % of the span


def rows(plant: str, window: pd.DataFrame, later: pd.DataFrame, spans: dict) -> list[dict]:
    """One row per tag with a span (module doc)."""
    info = {t: TagInfo(t, lo=lo, hi=hi) for t, (lo, hi) in spans.items()}
    cols = [t for t in window.columns if t in spans]
    kept = [TestChoice("y", "y", 1.0, steps=[Step(f"{t}[k]", 1.0, 1.0) for t in cols])]
    named = {s.split(" ")[0] for s in narrow_spans(window, info, kept, {})}
    out = []
    for t in cols:
        v = window[t].to_numpy(float)
        v = v[np.isfinite(v)]
        lo, hi = float(v.min()), float(v.max())
        x = later[t].to_numpy(float)
        x = x[np.isfinite(x)]
        out.append({
            "plant": plant, "tag": t, "share": (hi - lo) / (spans[t][1] - spans[t][0]),
            "n": effective_samples(v) if hi > lo else 0.0,
            "old": (hi - lo) / (spans[t][1] - spans[t][0]) < OLD_SHARE, "new": t in named,
            "outside": float(np.mean((x < lo) | (x > hi))),
        })  # fmt: skip
    return out


def small_plants() -> list[dict]:
    out = []
    for name, sim in (("tank", sp.simulate_tank), ("heatex", sp.simulate_heat_exchanger)):
        for period, days in ((15.0, 0.5), (60.0, 2.0)):
            frame = sp.export(sim(days, seed=43, start="2026-05-04"), period, timing="grid",
                              seed=43)  # fmt: skip
            spans = {c: (0.0, float(f"{3.0 * frame[c].abs().max():g}")) for c in frame.columns}
            out += rows(f"{name} {period:g}s", frame.iloc[:400], frame.iloc[400:], spans)
    return out


def pasteuriser() -> list[dict]:
    sim = Path(__file__).parent / "acceptance" / "pasteuriser_sim.py"
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        run = ["--seed", "5", "--start", "2026-03-03T00:00:00", "--days", "1", "--period", "10"]
        subprocess.run([sys.executable, str(sim), str(tmp / "p.csv"), *run], check=True)
        subprocess.run([sys.executable, str(sim), "x", "--tags-csv", str(tmp / "tags.csv")],
                       check=True)  # fmt: skip
        frame = pd.read_csv(tmp / "p.csv", index_col=0, parse_dates=True)
        with open(tmp / "tags.csv", newline="") as f:
            spans = {r["name"]: (float(r["lo"]), float(r["hi"])) for r in csv.DictReader(f)
                     if r.get("lo") and r.get("hi")}  # fmt: skip
    window = frame.loc["2026-03-03T02:00":"2026-03-03T03:06:30"]
    later = frame.loc["2026-03-03T03:06:40":]
    return rows("pasteuriser 10s", window, later[later["MODE"] == 1], spans)


def main() -> None:
    table = pd.DataFrame(small_plants() + pasteuriser())
    with pd.option_context("display.width", 140, "display.max_rows", 200):
        print(table.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    for group, part in (("small plants", ~table.plant.str.startswith("pasteuriser")),
                        ("pasteuriser", table.plant.str.startswith("pasteuriser"))):  # fmt: skip
        t = table[part]
        for rule in ("old", "new"):
            on = t[rule]
            print(f"{group}, rule {rule}: {int(on.sum())} of {len(t)} named; later samples "
                  f"outside the window's range: named {t.outside[on].mean():.0%}, not named "
                  f"{t.outside[~on].mean():.0%}")  # fmt: skip


if __name__ == "__main__":
    main()
