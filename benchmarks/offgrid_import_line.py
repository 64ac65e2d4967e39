"""The 7-tag line's flow-meter bias (and the heater's steam-meter bias) imported off the grid
the plain way a user does it (issue 34, "Lessons"; docs/how-to/unit-loops.md, "The line
imported off the grid").

Each run is the plant's own samples (:mod:`tests.line7` at 15 s; the heater of
:mod:`tests.heater` simulated at 15 s) or their means over the rate, stamped at the period's
end (``resample("1min", label="right", closed="right").mean()``: the docs' "At other rates"
figures; ``--label left``: pandas' default, stamped at the start), each row stamped at its
grid time ±20 % of the period, written as local times with an offset (``+02:00``) and one
row repeated
(:func:`tests.offgrid.stamps_off_grid`), then ``diag import --duplicates first``, ``diag unit
build`` from the fault-free training window (``--far 0.01`` and the plant's options: the
line's loop ``--loop``, the heater's ``--manual STEAM_V``; the period left to the data) and
``diag diagnose --csv --json`` of each run. Printed per rate: the period the build chose, the
fault-free run's (an unseen seed) share of samples alarmed, its alarm episodes and its share
CHECK_FUNCTION, and per
fault seed the share of alarm samples from day 1 on whose ``top1`` (the CSV's held top tag)
is the faulted tag and the runner-up (the line: ``FEED_FLOW`` / ``VALVE_A``), and the share
whose isolated ``faults`` (the alarm event's, the HMI's fault tag) hold the faulted tag.

``--api`` also builds the same on-grid frames through the Python API (``build_unit`` +
``Unit.evaluate``, as ``benchmarks/line7_meter_bias.py``) and prints the same figures,
counted by the same function, beside them.

Run: ``python -m benchmarks.offgrid_import_line [--plants line,heater] [--rates 15,60]
[--seeds 101 105 …] [--api] [--label right|left] [--bounds grid|file]`` (the line at 15 s
and 1 min with ``--api``: about 30 s of wall on 2 cores).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from benchmarks.settle_offgrid import diag, fmt
from diag_plugin.status import NE107
from tests.offgrid import stamps_off_grid, write_csv

SEEDS = (101, *range(105, 113))
DAY = pd.Timedelta(days=1)


@dataclass(frozen=True)
class Plant:
    """A plant as the benchmark runs it: ``simulate(days, seed, fault)`` at 15 s, its
    training run, its unseen fault-free seed, the fault and its tag, the runner-up tag
    printed beside it (None: the most frequent other), the ``diag unit build`` options."""

    simulate: Callable[..., pd.DataFrame]
    train_days: float
    free_seed: int
    fault: str
    at_fault: str
    other: str | None
    opts: list[str] = field(default_factory=list)
    #: the plant's tags CSV (units, descriptions), imported with the runs (``diag import
    #: --tags``) and given to the API as ``tag_info``; None: the export's columns alone
    tags: Callable[[], pd.DataFrame] | None = None


def _line(days: float, seed: int, fault: str | None = None) -> pd.DataFrame:
    from tests import line7

    return line7.simulate(days, seed, fault)


def _line_tags() -> pd.DataFrame:
    from tests import line7

    return line7.tags_csv()


def _heater(days: float, seed: int, fault: str | None = None) -> pd.DataFrame:
    """tests/heater.py at 15 s (its physics are written in seconds)."""
    from tests import heater

    p = heater.PERIOD_S
    heater.PERIOD_S = 15.0
    try:
        return heater.simulate(days, seed, fault)
    finally:
        heater.PERIOD_S = p


LINE = Plant(_line, 6.0, 101, "flow_bias", "FEED_FLOW", "VALVE_A",
             ["--loop", "FEED_FLOW=FEED_TARGET:VALVE_A"])  # fmt: skip
PLANTS = {
    "line": LINE,
    # the line with its hand valve declared (an input, never tested)
    "line-manual": replace(LINE, opts=[*LINE.opts, "--manual", "HAND_VALVE"]),
    # the line with its tags CSV imported (what each tag measures: a flow, a level, …)
    "line-tags": replace(LINE, tags=_line_tags),
    "heater": Plant(_heater, 5.0, 101, "steam_bias", "F_STEAM", None, ["--manual", "STEAM_V"]),
}


def at_rate(frame: pd.DataFrame, rate_s: int, label: str = "right") -> pd.DataFrame:
    """The 15 s run itself, or its means over ``rate_s``: each mean stamped at its period's
    end and holding the samples of ``(t − rate, t]`` (``label="right"``, the docs' "At other
    rates" figures), or at its start holding ``[t, t + rate)`` (``"left"``, pandas' default)."""
    if rate_s == 15:
        return frame
    return frame.resample(f"{rate_s}s", label=label, closed=label).mean()


def plant_runs(plant: Plant, rate_s: int, seeds, label: str = "right") -> dict[str, pd.DataFrame]:
    """The training run (seed 1), the fault-free run and each seed's fault run (2 days, the
    fault from day 1), at ``rate_s``."""
    runs = {"train": plant.simulate(plant.train_days, 1),
            "free": plant.simulate(2.0, plant.free_seed)}  # fmt: skip
    runs |= {str(s): plant.simulate(2.0, s, plant.fault) for s in seeds}
    return {k: at_rate(v, rate_s, label) for k, v in runs.items()}


def figures(
    status: np.ndarray,
    detected: np.ndarray,
    top1: np.ndarray,
    after: np.ndarray,
    plant: Plant,
    faults: np.ndarray | None = None,
) -> dict:
    """What is counted of one run: the share of samples alarmed (``detected`` 1), the alarm
    episodes (rising edges) and the share CHECK_FUNCTION over the run, and of the alarm
    samples with ``after`` true the share whose top 1 is the faulted tag and the runner-up;
    and, given the isolated ``faults`` (``a|b``), the share of those samples whose faults
    hold the faulted tag (what the alarm event and the HMI's fault tag say)."""
    alarm, check = detected == 1, status == int(NE107.CHECK_FUNCTION)
    out = {"alarm_pct": round(100 * float(alarm.mean()), 2),
           "episodes": int((alarm & ~np.r_[False, alarm[:-1]]).sum()),
           "check_pct": round(100 * float(check.mean()))}  # fmt: skip
    named = alarm & after & (top1 != "")
    share = pd.Series(top1[named]).value_counts(normalize=True)
    other = plant.other or next((t for t in share.index if t != plant.at_fault), "")
    out |= {"alarm_after": int((alarm & after).sum()),
            "fault_tag_pct": round(100 * float(share.get(plant.at_fault, 0.0))),
            "other": other, "other_pct": round(100 * float(share.get(other, 0.0)))}  # fmt: skip
    if faults is not None:
        held = np.array([plant.at_fault in str(f).split("|") for f in faults[alarm & after]])
        out["faults_pct"] = round(100 * float(held.mean())) if held.size else 0
    return out


def cli_path(
    plant: Plant, runs: dict[str, pd.DataFrame], folder: Path, seed: int = 5, bounds: str = "grid"
) -> dict:
    """Each run off the grid into one historian (each its own ten days), ``diag unit build``
    on the training run, ``diag diagnose --csv --json`` of the others (module doc).
    ``bounds``: ``--from``/``--to`` the run's grid times in UTC (``"grid"``), or the file's
    first and last stamps as written, local with their offset (``"file"``: a user copying
    them from the export; the last row then outside the exclusive end)."""
    folder.mkdir(parents=True, exist_ok=True)
    g = ["--db", f"sqlite:///{folder / 'h.db'}", "--rulebases", str(folder / "rb")]
    spans, typed, out = {}, {}, {}
    tags = []
    if plant.tags is not None:
        plant.tags().to_csv(folder / "tags.csv", index=False)
        tags = ["--tags", str(folder / "tags.csv")]
    for k, (name, run) in enumerate(runs.items()):
        run = run.copy()
        run.index = run.index + k * 10 * DAY
        path = folder / f"{name}.csv"
        write_csv(stamps_off_grid(run, seed + k), path)
        rc, text, _ = diag(g, "import", str(path), "--duplicates", "first", *tags)
        assert rc == 0, text
        step = run.index[1] - run.index[0]
        spans[name] = (run.index[0], run.index[-1] + step)
        if bounds == "file":
            stamps = pd.read_csv(path, usecols=[0]).iloc[:, 0]
            typed[name] = (stamps.iloc[0], stamps.iloc[-1])
        else:
            typed[name] = (fmt(spans[name][0]), fmt(spans[name][1]))
    a, b = spans.pop("train")
    rc, text, cpu = diag(g, "unit", "build", "u", "--from", typed["train"][0], "--to",
                         typed["train"][1], "--far", "0.01", "--force", *plant.opts)  # fmt: skip
    assert rc == 0, text
    out["build"] = {"cpu_s": round(cpu, 1), "said": text.splitlines()[0]}
    for name, (a, _) in spans.items():
        csv = folder / f"{name}.csv.out"
        rc, text, _ = diag(g, "diagnose", "u", "--from", typed[name][0], "--to",
                           typed[name][1], "--csv", str(csv), "--json")  # fmt: skip
        assert rc == 0, text
        d = pd.read_csv(csv, low_memory=False, keep_default_na=False, na_values={"detected": [""]})
        ts = pd.to_datetime(d["ts"], utc=True)
        after = (ts >= a + DAY).to_numpy()
        out[name] = figures(d["status"].to_numpy(int), d["detected"].to_numpy(float),
                            d["top1"].astype(str).to_numpy(), after, plant,
                            d["faults"].astype(str).to_numpy())  # fmt: skip
        out[name]["rows"] = len(d)
        out[name]["json_detected_share"] = json.loads(text).get("detected_share")
    return out


def api_path(plant: Plant, runs: dict[str, pd.DataFrame], rate_s: int, folder: Path) -> dict:
    """The same on-grid runs through ``build_unit`` and ``Unit.evaluate`` (the period the
    rate, the options the CLI's)."""
    from diag_plugin.diagnose.unit import Unit
    from diag_plugin.unitbuild.build import build_unit
    from diag_plugin.unitbuild.loops import parse_loop

    opts = dict(zip(plant.opts[::2], plant.opts[1::2], strict=True))
    loops = [parse_loop(opts["--loop"])] if "--loop" in opts else []
    manual = [opts["--manual"]] if "--manual" in opts else []
    info = None
    if plant.tags is not None:
        info = {r["name"]: {"unit": r["unit"], "description": r["description"]}
                for _, r in plant.tags().iterrows()}  # fmt: skip
    c0 = time.process_time()
    res = build_unit("u", runs["train"], folder=folder, period=f"{rate_s}s", loops=loops,
                     manual=manual, far=0.01, force=True, tag_info=info)  # fmt: skip
    out: dict = {"build": {"cpu_s": round(time.process_time() - c0, 1)}}
    unit = Unit.load(res.path, folder)
    for name, run in runs.items():
        if name == "train":
            continue
        d = unit.reset().evaluate(run)
        after = d.status.index >= run.index[0] + DAY
        top1 = d.top_tags["top1"].to_numpy().astype(str)
        out[name] = figures(d.status.to_numpy(int), d.detected.to_numpy(float), top1,
                            np.asarray(after), plant, d.faults.to_numpy().astype(str))  # fmt: skip
    return out


def table(plant: Plant, cli: dict, api: dict | None) -> list[str]:
    """Per run one line: the CLI off the grid's figures, the API on the grid's beside them."""
    lines = []
    for name in cli:
        if name == "build":
            continue
        c, p = cli[name], (api or {}).get(name)
        if name == "free":
            row = (f"free: alarm {c['alarm_pct']} %, {c['episodes']} episodes, CHECK_FUNCTION "
                   f"{c['check_pct']} %")  # fmt: skip
            if p:
                row += (f"  | on-grid API {p['alarm_pct']} %, {p['episodes']} episodes, "
                        f"{p['check_pct']} %")  # fmt: skip
        else:
            row = (f"seed {name}: {plant.at_fault} {c['fault_tag_pct']} / {c['other']} "
                   f"{c['other_pct']} % of {c['alarm_after']}, in faults "
                   f"{c.get('faults_pct', '-')} %")  # fmt: skip
            if p:
                row += (f"  | on-grid API {p['fault_tag_pct']} / {p['other']} {p['other_pct']} "
                        f"% of {p['alarm_after']}, in faults "
                        f"{p.get('faults_pct', '-')} %")  # fmt: skip
        lines.append(row)
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plants", default="line")
    ap.add_argument("--rates", default="15,60")
    ap.add_argument("--seeds", type=int, nargs="+", default=list(SEEDS))
    ap.add_argument("--api", action="store_true", help="the on-grid Python-API figures beside")
    ap.add_argument(
        "--label",
        default="right",
        choices=["right", "left"],
        help="the slower rates' means stamped at their period's end or start",
    )
    ap.add_argument(
        "--bounds",
        default="grid",
        choices=["grid", "file"],
        help="--from/--to the grid times in UTC, or the file's first/last stamps",
    )
    ap.add_argument("--out", default=None, help="write every figure as JSON")
    args = ap.parse_args()
    rows = []
    for name in args.plants.split(","):
        plant = PLANTS[name]
        for rate in (int(r) for r in args.rates.split(",")):
            runs = plant_runs(plant, rate, args.seeds, args.label)
            with tempfile.TemporaryDirectory() as tmp:
                t0 = time.perf_counter()
                cli = cli_path(plant, runs, Path(tmp) / "cli", bounds=args.bounds)
                api = api_path(plant, runs, rate, Path(tmp) / "api") if args.api else None
            print(f"{name} at {rate} s ({args.label}-labelled means, --from/--to {args.bounds}): "
                  f"{cli['build']['said']} "
                  f"(build CPU {cli['build']['cpu_s']} s"
                  + (f", API {api['build']['cpu_s']} s" if api else "")
                  + f"; wall {time.perf_counter() - t0:.0f} s)")  # fmt: skip
            print("\n".join("  " + ln for ln in table(plant, cli, api)), flush=True)
            rows.append({"plant": name, "rate_s": rate, "label": args.label,
                         "bounds": args.bounds, "cli": cli, "api": api})  # fmt: skip
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=1, default=str))


if __name__ == "__main__":
    main()
