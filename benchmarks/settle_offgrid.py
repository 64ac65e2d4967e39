"""The settle guards at 1 s and at a slower rate, with timestamps off the grid, through the
CLI a user runs (issue 34, items 3/5/6; docs/how-to/unit-loops.md, "The settles at 1 s, off
the grid").

Each plant is simulated at 1 s (its physics written in seconds), read every ``period`` with
timestamps jittered ±20 % of the period, written as local times with an offset (``+02:00``)
and one row repeated, then ``diag import`` (``--duplicates first``), ``diag unit build`` and
``diag diagnose --csv --json``, as a user would. Per plant and rate: the learned bounds and
the build's note, the fault-free share of samples raised (neither NORMAL nor
CHECK_FUNCTION) and CHECK_FUNCTION, episodes per day, and a fault's share raised after its
onset.

Run: ``python -m benchmarks.settle_offgrid [--plants spstep,heater,station] [--rates 1,60]``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from tests.offgrid import off_grid, station_1s, write_csv


def spstep_run(
    days: float, seed: int, fault=None, onset_s=None, steps=None, size=None
) -> pd.DataFrame:
    """tests/spstep_plant.py simulated at 1 s (its physics are in seconds)."""
    from tests import spstep_plant as sp

    dt = sp.DT
    sp.DT = 1.0
    try:
        return sp.simulate(days, seed, fault, onset_s, size, steps)
    finally:
        sp.DT = dt


def heater_run(days: float, seed: int, fault=None, onset_days=1.0) -> pd.DataFrame:
    """tests/heater.py simulated at 1 s (its physics are in seconds)."""
    from tests import heater

    p = heater.PERIOD_S
    heater.PERIOD_S = 1.0
    try:
        return heater.simulate(days, seed, fault, onset_days)
    finally:
        heater.PERIOD_S = p


def diag(g, *argv) -> tuple[int, str, float]:
    """``diag`` in this process: return code, output, CPU seconds."""
    from diag_plugin.cli import main

    out = io.StringIO()
    c0 = time.process_time()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        try:
            rc = main([*g, *argv])
        except SystemExit as exc:
            rc = exc.code
    return int(rc or 0), out.getvalue(), time.process_time() - c0


def fmt(t: pd.Timestamp) -> str:
    return t.tz_convert("UTC").strftime("%Y-%m-%dT%H:%M:%SZ")


PLANTS = {
    # name: (build window, judged fault-free, fault run, onset s, unit build options)
    "spstep": dict(
        build=lambda: spstep_run(
            2.0, 1, steps=[(6 * 3600.0, 60.0), (20 * 3600.0, 70.0), (34 * 3600.0, 65.0)]
        ),
        free=lambda: spstep_run(1.0, 2),
        fault=lambda: spstep_run(
            1.0, 4, "flow_bias", 4 * 3600.0 + 120.0, steps=[(4 * 3600.0, 70.0)]
        ),
        onset_s=4 * 3600.0 + 120.0,
        opts=["--loop", "TEMP=HEAT_TGT:FLOW_SP", "--loop", "FLOW=FLOW_SP:VALVE"],
    ),
    "heater": dict(
        build=lambda: heater_run(2.0, 1),
        free=lambda: heater_run(1.0, 2),
        fault=lambda: heater_run(1.0, 3, "steam_bias", onset_days=0.5),
        onset_s=0.5 * 86400,
        opts=["--manual", "STEAM_V"],
    ),
    "station": dict(
        build=lambda: station_1s(2.0, 1),
        free=lambda: station_1s(1.0, 7),
        fault=lambda: station_1s(1.0, 7, bias_at_s=_first_start(station_1s(1.0, 7)) + 120),
        onset_s=None,
        opts=[],
    ),
}


def _first_start(x: pd.DataFrame) -> float:
    k = np.flatnonzero(np.diff(x["RUN2"].to_numpy()) > 0) + 1
    return float(k[0])


def _episodes(a: np.ndarray) -> int:
    return int((a & ~np.r_[False, a[:-1]]).sum())


def one(plant: str, period_s: float, folder: Path, seed: int = 5) -> dict:
    """Build and judge ``plant`` read every ``period_s`` off the grid (module doc)."""
    p = PLANTS[plant]
    g = ["--db", f"sqlite:///{folder / 'h.db'}", "--rulebases", str(folder / "rb")]
    out: dict = {"plant": plant, "period_s": period_s}
    runs = {"build": p["build"](), "free": p["free"](), "fault": p["fault"]()}
    day = pd.Timedelta(days=10)
    onset_s = p["onset_s"] if p["onset_s"] is not None else None
    if plant == "station":
        onset_s = _first_start(runs["free"]) + 120
    spans = {}
    for k, (name, run) in enumerate(runs.items()):
        run = run.copy()
        run.index = run.index + k * day  # each run its own time in one historian
        x = off_grid(run, period_s, seed + k)
        path = folder / f"{name}.csv"
        write_csv(x, path)
        rc, text, _ = diag(g, "import", str(path), "--duplicates", "first")
        assert rc == 0, text
        spans[name] = (run.index[0], run.index[-1] + pd.Timedelta(seconds=1))
    a, b = spans["build"]
    rc, text, cpu = diag(g, "unit", "build", "u", "--from", fmt(a), "--to", fmt(b),
                         "--far", "0.01", "--force", *p["opts"])  # fmt: skip
    assert rc == 0, text
    out["build_cpu_s"] = round(cpu, 1)
    import tomllib

    doc = tomllib.loads((folder / "rb" / "u.unit.toml").read_text())
    ev, build = doc["evaluation"], doc.get("build", {})
    out["period"] = doc.get("unit", {}).get("period", ev.get("period"))
    for key in ("settle_max_s", "manual_settle_max_s", "state_settle_max_s"):
        out[key] = ev.get(key, 0.0)
    for key in ("settle", "manual_settle", "state_settle"):
        if key in build:
            out[key] = build[key]
    out["notes"] = [ln for ln in text.splitlines() if "grid" in ln or "settle" in ln][:6]
    meta = {k: [fmt(a), fmt(b)] for k, (a, b) in spans.items()}
    (folder / "meta.json").write_text(json.dumps({"spans": meta, "onset_s": onset_s}))
    return {**out, **judge(folder)}


def judge(folder: Path, rulebases: str = "rb") -> dict:
    """``diag diagnose --csv --json`` of the fault-free and the faulty run of a built
    ``folder`` (:func:`one`), and what it says: shares raised and CHECK_FUNCTION, episodes
    per day, the fault's share raised after its onset and its first raised sample."""
    meta = json.loads((folder / "meta.json").read_text())
    g = ["--db", f"sqlite:///{folder / 'h.db'}", "--rulebases", str(folder / rulebases)]
    out: dict = {}
    for name in ("free", "fault"):
        a, b = meta["spans"][name]
        csv = folder / f"{name}.{rulebases}.csv"
        rc, text, _ = diag(g, "diagnose", "u", "--from", a, "--to", b, "--csv", str(csv),
                           "--json")  # fmt: skip
        assert rc == 0, text
        d = pd.read_csv(csv, low_memory=False)
        st = d["status"].to_numpy(int)
        cf = st == 2  # CHECK_FUNCTION (NE107), any reason: warming up, an input unknown, ...
        settling = cf & d["why"].fillna("").astype(str).str.contains("settling").to_numpy()
        raised = (st != 0) & ~cf
        ts = pd.to_datetime(d["ts"], utc=True)
        days = (ts.iloc[-1] - ts.iloc[0]).total_seconds() / 86400
        if name == "free":
            out["free_raised_pct"] = round(100 * float(raised.mean()), 2)
            out["free_cf_pct"] = round(100 * float(cf.mean()), 2)
            out["free_settling_pct"] = round(100 * float(settling.mean()), 2)
            out["free_episodes_per_day"] = round(_episodes(raised) / days, 2)
            out["free_rows"] = len(d)
        else:
            on = (ts >= pd.Timestamp(a) + pd.Timedelta(seconds=meta["onset_s"])).to_numpy()
            r = raised[on]
            out["fault_raised_after_onset_pct"] = round(100 * float(r.mean()), 1)
            out["fault_settling_after_onset_pct"] = round(100 * float(settling[on].mean()), 1)
            first = np.flatnonzero(r)
            out["fault_first_raised_s"] = (
                round((ts[on].iloc[first[0]] - ts[on].iloc[0]).total_seconds()) if first.size
                else None)  # fmt: skip
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--plants", default="spstep,heater,station")
    ap.add_argument("--rates", default="1,60")
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    rows = []
    for plant in args.plants.split(","):
        for rate in (float(r) for r in args.rates.split(",")):
            with tempfile.TemporaryDirectory() as tmp:
                t0 = time.perf_counter()
                row = one(plant, rate, Path(tmp))
                row["wall_s"] = round(time.perf_counter() - t0, 1)
                rows.append(row)
                print(json.dumps(row), flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
