"""Diagnostics speed (issue 9): prints figures, exit 1 if a target is missed.

1. One plant cycle of 1,000 units × 4 models (target < 50 ms), twice: a fleet of identical
   valves sharing one set of model files, and 1,000 units with a model object each (4,000
   distinct rule bases, the worst case); Wang–Mendel models run in one stacked kernel call.
2. ``diag diagnose`` of the example unit over 6 months at 10 s (1.58 M samples, 4 models) from a
   SQLite historian, end to end including the read (target < 10 s).
3. ``diag benchmark --quick`` (target < 2 min).
"""

from __future__ import annotations

import copy
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RB = ROOT / "rulebases"
DIAG = [sys.executable, "-m", "diag_plugin"]


def fleet(folder: Path, n: int) -> list[Path]:
    """``n`` unit files reading V0001.F, … through their [tags] tables, one model set."""
    for f in RB.glob("valve_r?.toml"):
        shutil.copy(f, folder / f.name)
    shutil.copy(RB / "valve_unit.matrix.toml", folder)
    text = (RB / "valve_unit.unit.toml").read_text()
    paths = []
    for i in range(n):
        name = f"v{i:04d}"
        tags = "\n".join(f'{t} = "V{i:04d}.{t}"' for t in ("CV", "P1", "P2", "F", "P0", "X"))
        body = text.replace('name = "valve_unit"', f'name = "{name}"')
        p = folder / f"{name}.unit.toml"
        p.write_text(body + "\n[tags]\n" + tags + "\n")
        paths.append(p)
    return paths


def bench_cycle(paths: list[Path], distinct: bool) -> float:
    from diag_plugin.diagnose.plant import Plant
    from diag_plugin.simulate.valve import simulate_valve

    plant = Plant.load(paths, paths[0].parent)
    if distinct:  # one model object per unit and test, as with individually trained units
        for u in plant.units.values():
            for m in u.models.values():
                m.model = copy.deepcopy(m.model)
        plant = Plant(plant.units, plant.broken)
    frame = simulate_valve(0.05, seed=5)
    rng = np.random.default_rng(0)
    times = []
    rows = list(frame.iterrows())
    for k, (ts, row) in enumerate(rows):
        values = {}
        for i in range(len(paths)):
            for t in ("CV", "P1", "P2", "F", "P0", "X"):
                values[f"V{i:04d}.{t}"] = row[t] * (1 + 0.001 * rng.standard_normal())
        if k == len(rows) - 20:  # memory over the last cycles only: tracemalloc slows Python
            tracemalloc.start()
        t0 = time.perf_counter()
        out = plant.cycle(ts, values)
        if 5 <= k < len(rows) - 20:
            times.append(time.perf_counter() - t0)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert len(out) == len(paths)
    ms = statistics.median(times) * 1e3
    kind = "own model objects (4,000 rule bases)" if distinct else "shared models (fleet)"
    print(
        f"cycle of {len(paths):,} units × 4 models, {kind}: median {ms:.1f} ms, "
        f"p95 {np.percentile(times, 95) * 1e3:.1f} ms over {len(times)} cycles; "
        f"peak traced memory {peak / 1e6:.1f} MB"
    )
    return ms


def bench_diagnose(folder: Path) -> float:
    from diag_plugin.simulate.valve import TAGS, simulate_valve
    from historian.store import Historian

    frame = simulate_valve(182.5, seed=4)[["CV", "P1", "P2", "X", "F", "P0"]]
    url = f"sqlite:///{folder}/h.db"
    with Historian.open(url) as h:
        for name in frame.columns:
            m = TAGS[name]
            h.ensure_tag(name, unit=m.unit, lo=m.lo, hi=m.hi)
        h.write_samples(frame)
    t0 = time.perf_counter()
    r = subprocess.run(
        [*DIAG, "--db", url, "--rulebases", str(RB), "diagnose", "valve_unit", "--json"],
        capture_output=True,
        text=True,
        check=True,
    )
    dt = time.perf_counter() - t0
    out = json.loads(r.stdout)
    print(
        f"diag diagnose, 6 months ({out['samples']:,} samples, 4 models) from SQLite: {dt:.2f} s "
        f"({out['samples'] / dt / 1e6:.2f} M samples/s), {len(out['intervals'])} intervals"
    )
    return dt


def bench_benchmark() -> float:
    t0 = time.perf_counter()
    r = subprocess.run(
        [*DIAG, "--rulebases", str(RB), "benchmark", "--quick", "--json"],
        capture_output=True,
        text=True,
        check=True,
    )
    dt = time.perf_counter() - t0
    s = json.loads(r.stdout)["summary"]
    print(f"diag benchmark --quick ({s['scenarios']} scenarios): {dt:.1f} s")
    return dt


def main() -> int:
    ok = True
    with tempfile.TemporaryDirectory() as d:
        paths = fleet(Path(d), 1000)
        for distinct in (False, True):
            ms = bench_cycle(paths, distinct)
            ok &= ms < 50
    with tempfile.TemporaryDirectory() as d:
        ok &= bench_diagnose(Path(d)) < 10
    ok &= bench_benchmark() < 120
    print(f"targets (cycle < 50 ms, 6 months < 10 s, quick < 2 min): {'met' if ok else 'MISSED'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
