"""Simulate the Tennessee Eastman runs of the public-plant benchmark with tep-studio.

tep-studio (PyPI, BSD) is a simulator of Ricker's modified TEP (``temexd_mod.c`` through
CFFI) with Ricker's decentralised multiloop PI control. This script does not import
``diag_plugin``: it runs in its own virtual environment (``make tep-studio-data`` makes one
under ~/.cache/diag-plugin, so the project's own does not carry gymnasium and a C build) and
writes one CSV per run plus ``manifest.json`` into ``--out`` (default
``$DIAG_TEP_STUDIO_DIR`` or ~/.cache/diag-plugin/tep-studio). The benchmark reads them
(``diag benchmark --plant tep-studio``).

The runs and what each is for were fixed before any result was looked at:

* ``train``: fault-free, seeds 1 and 2, 5 days each (10 days) — every method learns here;
* ``calibration``: fault-free, seeds 11, 12, 13, 3 days each — the matched limits are set here;
* ``free``: fault-free, seeds 21, 22, 23, 2 days each — false alarms out of sample;
* ``tuning``: IDV(1)…IDV(20), seed 101, 48 h, the fault from hour 8 — for choosing changes;
* ``fault``: IDV(1)…IDV(20), seeds 201 and 202, 48 h, the fault from hour 8 — scoring only.

Added later (issue 34), for choosing changes to the false-alarm side, never scored:

* ``tunefree``: fault-free, seeds 31, 32, 33, 34, 3 days each (as a calibration run).

Samples every 3 min (as the classic data sets): XMEAS(1)…(41) and XMV(1)…(11) as
``XMEAS1``…, ``XMV1``… (the agitator XMV(12) is fixed). The seed sets the measurement noise.
A run that trips the plant's shutdown ends there; the manifest says when.

Run: ``python benchmarks/tep_studio_runs.py [--roles train,calibration,free,fault]``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

STEP_H = 0.0005  # the controller's interval (1.8 s)
SAMPLE_H = 0.05  # 3 min
START = pd.Timestamp("2020-01-01", tz="UTC")

RUNS = {
    "train": [(s, None, 5 * 24.0) for s in (1, 2)],
    "calibration": [(s, None, 3 * 24.0) for s in (11, 12, 13)],
    "free": [(s, None, 2 * 24.0) for s in (21, 22, 23)],
    "tuning": [(101, k, 48.0) for k in range(1, 21)],
    "fault": [(s, k, 48.0) for s in (201, 202) for k in range(1, 21)],
    "tunefree": [(s, None, 3 * 24.0) for s in (31, 32, 33, 34)],
}
ONSET_H = 8.0
DEFAULT_ROLES = "train,calibration,free,fault,tuning"


def run_name(role: str, seed: int, idv: int | None) -> str:
    """A run's file stem, e.g. ``tuning_s101_idv03``."""
    return f"{role}_s{seed}" + (f"_idv{idv:02d}" if idv else "")


# each run's start, in weeks after START: its place in the default order, whatever roles or
# seeds are asked for and in which order (runs of other roles are numbered as asked)
WEEK = {
    run_name(role, seed, idv): k + 1
    for k, (role, (seed, idv, _)) in enumerate(
        (role, run) for role in DEFAULT_ROLES.split(",") for run in RUNS[role]
    )
}


def simulate(seed: int, idv: int | None, hours: float) -> tuple[pd.DataFrame, float | None]:
    from tep_studio.control import ClosedLoopSimulation

    def schedule(t: float) -> np.ndarray:
        v = np.zeros(28)
        if idv is not None and t >= ONSET_H - 1e-9:
            v[idv - 1] = 1.0
        return v

    every = int(round(SAMPLE_H / STEP_H))
    res = ClosedLoopSimulation(control_interval=STEP_H, horizon=hours).run(
        seed=seed, disturbance_schedule=schedule, record_every=every
    )
    meas = np.array([r.measurements[:41] for r in res.results])
    xmv = np.array([r.implemented_action[:11] for r in res.results])
    t_h = np.array([r.time_end for r in res.results])
    cols = [f"XMEAS{i}" for i in range(1, 42)] + [f"XMV{i}" for i in range(1, 12)]
    frame = pd.DataFrame(np.hstack([meas, xmv]), columns=cols)
    frame.insert(0, "hours", np.round(t_h / SAMPLE_H) * SAMPLE_H)
    frame = frame.drop_duplicates("hours", keep="first")  # a shutdown's last step
    return frame, (res.final_time if res.terminated else None)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    default = os.environ.get("DIAG_TEP_STUDIO_DIR") or "~/.cache/diag-plugin/tep-studio"
    p.add_argument("--out", default=default)
    p.add_argument("--roles", default=DEFAULT_ROLES)
    p.add_argument("--seeds", default="", help="only these seeds (comma-separated)")
    args = p.parse_args(argv)
    only = {int(x) for x in args.seeds.split(",") if x}
    out = Path(args.out).expanduser()
    out.mkdir(parents=True, exist_ok=True)
    mpath = out / "manifest.json"
    manifest = json.loads(mpath.read_text()) if mpath.exists() else {"runs": {}}
    offset = 0
    for role in args.roles.split(","):
        for seed, idv, hours in RUNS[role]:
            if only and seed not in only:
                continue
            name = run_name(role, seed, idv)
            offset += 1
            if name in manifest["runs"] and (out / f"{name}.csv").exists():
                continue
            t0 = time.perf_counter()
            frame, trip = simulate(seed, idv, hours)
            start = START + pd.Timedelta(days=7 * WEEK.get(name, offset))
            frame.insert(0, "ts", start + pd.to_timedelta(frame.pop("hours"), unit="h"))
            frame.to_csv(out / f"{name}.csv", index=False, float_format="%.6g")
            manifest["runs"][name] = {
                "role": role,
                "seed": seed,
                "idv": idv,
                "hours": hours,
                "onset_h": ONSET_H if idv else None,
                "shutdown_h": trip,
                "rows": len(frame),
                "seconds": round(time.perf_counter() - t0, 1),
            }
            mpath.write_text(json.dumps(manifest, indent=1))
            print(f"{name}: {len(frame)} rows, {time.perf_counter() - t0:.0f} s"
                  + (f", shutdown at {trip:.1f} h" if trip else ""), file=sys.stderr)  # fmt: skip
    import tep_studio

    manifest["generator"] = f"tep-studio {getattr(tep_studio, '__version__', '0.2.0')}"
    mpath.write_text(json.dumps(manifest, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
