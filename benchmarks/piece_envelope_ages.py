"""A piece of equipment's start envelope, learned at the ages its own settle judges (issue 34,
items 5-6; docs/how-to/unit-loops.md, "A piece's envelope at its guard's ages").

Two tuning plants with pieces (``[equipment]``), built in this process with the code on the
path (run it once with the branch's code and once with main's to compare):

- the twin chillers (:mod:`tests.twinplant`, 10 days seed 1 at 1 min, chiller B a piece):
  B's leaving-water sensor +1 K from 06:00 with B stopped, B starting at 07:00 (seeds 10-15):
  the minutes to the first FAILURE after the start; fault-free seeds 7-12 (2 days each):
  FAILURE and CHECK_FUNCTION shares;
- the compressed-air station (``benchmarks/acceptance/compressors_sim.py``, 14 days from 1
  June seed 2 at 3 min, its three compressors pieces, as
  tests/test_unit_equipment_first_sample.py builds it): fault-free 4-day runs (seeds 101-104
  from 29 June) and ``C2_TD`` +8 K from 30 June 08:00 (seeds 131-132): FAILURE and
  CHECK_FUNCTION shares, the share raised after the onset and the hours to the first.

Per plant each piece's envelope (starts, bins' first ages, per test per bin) is printed.

Run: ``python -m benchmarks.piece_envelope_ages [--plants twin,air]``.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

SIM = Path(__file__).parent / "acceptance" / "compressors_sim.py"
PIECES = [f"C{n}:C{n}_RUN:C{n}_AMPS,C{n}_KW,C{n}_TD,C{n}_TAC" for n in (1, 2, 3)]


def envelopes(unit) -> dict:
    return {k: {"starts": e.starts, "age_s": list(e.age_s), "quiet_s": getattr(e, "quiet_s", None),
                "tests": {t: list(v) for t, v in e.tests.items()}}
            for k, e in (unit.file.envelope or {}).items()}  # fmt: skip


def shares(d) -> tuple[float, float]:
    st = d.status.to_numpy()
    return round(100 * float((st == 1).mean()), 3), round(100 * float((st == 2).mean()), 2)


def twin(folder: Path) -> dict:
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.unitbuild.build import build_unit
    from diag_plugin.unitbuild.loops import parse_running
    from tests import twinplant
    from tests.test_unit_equipment import DAY, LOOPS, B

    res = build_unit("chw", twinplant.simulate(10, 1), folder=folder, period="1min", far=0.01,
                     loops=LOOPS, disturbances=["LOAD"], equipment=[parse_running(B)])  # fmt: skip
    unit = Unit.load(res.path, folder)
    out: dict = {"plant": "twin", "envelopes": envelopes(unit), "hold": unit.equipment_holds}
    start = DAY + 7 * 60
    first = {}
    for seed in range(10, 16):
        f = twinplant.simulate(2, seed, "b_bias", onset_days=(DAY + 6 * 60) / DAY)
        st = unit.reset().evaluate(f).status.to_numpy()[start:]
        hit = np.flatnonzero(st == 1)
        first[seed] = int(hit[0]) if hit.size else None
    out["b_bias_first_min"] = first
    free = {}
    for seed in range(7, 13):
        free[seed] = shares(unit.reset().evaluate(twinplant.simulate(2, seed)))
    out["free_failure_check_pct"] = free
    return out


def air(folder: Path) -> dict:
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.unitbuild.build import build_unit
    from diag_plugin.unitbuild.loops import parse_running

    spec = importlib.util.spec_from_file_location("compressors_sim", SIM)
    sim = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(sim)

    def run(start: str, days: float, seed: int, **kw) -> pd.DataFrame:
        f = sim.simulate(start, days, seed, period=180.0, jitter=0.0, dt=2.0, **kw)
        f.index = f.index.round("3min")
        return f[~f.index.duplicated()]

    info = {n: {"unit": u, "lo": lo, "hi": hi} for n, u, lo, hi, _, _ in sim.TAG_ROWS}
    res = build_unit("air", run("2026-06-01", 14, 2), folder=folder, period="3min", far=0.01,
                     tag_info=info, disturbances=["FT_PLANT", "T_AMB"],
                     equipment=[parse_running(p) for p in PIECES])  # fmt: skip
    unit = Unit.load(res.path, folder)
    out: dict = {"plant": "air", "envelopes": envelopes(unit), "hold": unit.equipment_holds}
    free = {}
    for seed in (101, 102, 103, 104):
        free[seed] = shares(unit.reset().evaluate(run("2026-06-29", 4, seed)))
    out["free_failure_check_pct"] = free
    onset = pd.Timestamp("2026-06-30T08:00", tz="UTC")
    faults = {}
    for seed in (131, 132):
        f = run("2026-06-29", 4, seed, fault="td_bias", onset="2026-06-30T08:00")
        d = unit.reset().evaluate(f)
        st = d.status.to_numpy()
        after = d.status.index >= onset
        hit = np.flatnonzero((st == 1) & after)
        first = (d.status.index[hit[0]] - onset).total_seconds() / 3600 if hit.size else None
        faults[seed] = {"before_failure_pct": round(100 * float((st[~after] == 1).mean()), 3),
                        "detected_pct": round(100 * float((st[after] == 1).mean()), 1),
                        "first_h": None if first is None else round(first, 2)}  # fmt: skip
    out["td_bias"] = faults
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--plants", default="twin,air")
    a = ap.parse_args()
    for name in a.plants.split(","):
        with tempfile.TemporaryDirectory() as tmp:
            print(json.dumps({"twin": twin, "air": air}[name](Path(tmp))), flush=True)


if __name__ == "__main__":
    main()
