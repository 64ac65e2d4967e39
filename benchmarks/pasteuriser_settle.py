"""What a production start's settle costs on the pasteuriser, and what learning its envelope
from the guard's own ages costs the build (issue 34, items 5-6; docs/how-to/unit-loops.md,
"A start's settle ends when its tests are back").

The HTST pasteuriser (:mod:`benchmarks.acceptance.pasteuriser_sim`, a tuning plant) built with
``--running MODE=1`` through the CLI a user runs (``diag import``, ``diag unit build``,
``diag diagnose --csv``), at 10 s on two weeks (seed 1) and at 1 s on one day (seed 3), its
runs as the module docstring of the simulator gives them. Per judged run (10 s: from 2 h in;
1 s: from 30 min in): the share of samples in FAILURE, the share CHECK_FUNCTION split by its
reason (the unit not running; a state change's settle; a combination of states never
learned; another), the settles' count and their median / longest CHECK_FUNCTION stretch
after a start, and for a faulted run the share in FAILURE after the onset, the hours to the
first and the share of its alarm samples whose first tag is the right one.

``--cost N``: the build's CPU seconds (``resource.getrusage`` of a child process) with the
state envelope's replay of the guard (:func:`~diag_plugin.diagnose.settle.settle_replay`) and
without it (the replay answered "no settle open" at once: no envelope learned), ``N`` builds
of each interleaved, their medians, the replay's own CPU seconds inside the first, and the
load (``uptime``) before and after.

Run: ``python -m benchmarks.pasteuriser_settle FOLDER [--rate 10|1] [--runs 101,102]
[--cost N] [--label L]`` (FOLDER: where the simulator's CSVs are, written there when
missing; a database and rulebase folder are made there per rate, ``rb<rate><L>``: a unit
already in it is judged as it is, so a copy edited by hand is judged beside the built one).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd

SIM = Path(__file__).parent / "acceptance" / "pasteuriser_sim.py"
LOOPS = ["--loop", "BT_LEVEL=50:BT_INLET_VLV", "--loop", "FEED_FLOW=FEED_FLOW_SP:FEED_VFD",
         "--loop", "HEAT_OUT_TEMP=HEAT_OUT_SP:HW_TEMP_SP", "--loop",
         "HW_TEMP=HW_TEMP_SP:STEAM_VLV", "--loop", "COOL_OUT_TEMP=4:CHW_VLV"]  # fmt: skip
FAULTS = ("hold_drift", "regen_foul", "hw_stiction", "pump_wear", "chw_step", "pinhole")
#: the tags right first per fault (acceptance-pasteuriser.md)
RIGHT = {
    "hold_drift": ("HOLD_TEMP",),
    "regen_foul": ("REGEN_RAW_OUT", "REGEN_PAST_OUT", "HW_TEMP_SP"),
    "hw_stiction": ("STEAM_VLV", "HW_TEMP"),
    "pump_wear": ("FEED_VFD",),
    "chw_step": ("CHW_VLV",),
    "pinhole": ("P_PAST_REGEN", "P_RAW_REGEN"),
}
RATES = {
    # period s: build (seed, start, days, extra), judged runs' start and days, skipped s,
    # fault onsets after
    10: dict(
        build=(
            1,
            "2026-03-02T00:00:00",
            14,
            ["--jitter", "2", "--gap", "2026-03-09T06:00:00:3", "--repeat", "50000"],
        ),
        run=("2026-03-16T00:00:00", 4, ["--jitter", "2"]),
        skip_s=7200,
        onset_after="2026-03-17T08:00:00",
        to="2026-03-16T00:00Z",
    ),  # fmt: skip
    1: dict(
        build=(3, "2026-03-16T00:00:00", 1, ["--jitter", "0.2"]),
        run=("2026-03-17T00:00:00", 1, ["--jitter", "0.2"]),
        skip_s=1800,
        onset_after="2026-03-17T02:00:00",
        to="2026-03-17T00:00Z",
    ),  # fmt: skip
}


def jittered(extra: list[str], jitter: float | None) -> list[str]:
    """``extra`` (the simulator's options) with its stamp jitter ``jitter`` (None: as it is;
    0: none)."""
    if jitter is None:
        return extra
    out = list(extra)
    if "--jitter" in out:
        k = out.index("--jitter")
        del out[k : k + 2]
    return out + (["--jitter", f"{jitter:g}"] if jitter > 0 else [])


def window(period: int, days: float | None, jitter: float | None, run_jitter: float | None):
    """The build window's days and stamp jitter, the judged runs' jitter (None: as
    :data:`RATES` gives them; a folder holds one choice: its CSVs are kept). The 10 s build
    on 8 days without jitter learns its state envelope from 34 changes (issue 34 H4)."""
    p = RATES[period]
    s, start, d, extra = p["build"]
    p["build"] = (s, start, d if days is None else days, jittered(extra, jitter))
    start_r, days_r, extra_r = p["run"]
    p["run"] = (start_r, days_r, jittered(extra_r, run_jitter))


def fault_of(seed: int) -> str | None:
    """The fault of a judged run's seed (``1ij`` / ``2i1``: FAULTS[i - 1]; 1x0, 2x0: none)."""
    i = (seed // 10) % 10
    return FAULTS[i - 1] if 1 <= i <= 6 else None


def sim(path: Path, seed: int, period: int, build: bool = False) -> str | None:
    """The simulator's CSV at ``path`` (written when missing); the fault's onset (ISO) or None."""
    p = RATES[period]
    if build:
        s, start, days, extra = p["build"]
    else:
        s, (start, days, extra) = seed, p["run"]
    argv = [sys.executable, str(SIM), str(path), "--seed", str(s), "--start", start, "--days",
            str(days), "--period", str(period), *extra]  # fmt: skip
    f = None if build else fault_of(seed)
    if f:
        argv += ["--fault", f, "--onset-after", p["onset_after"]]
    onset_file = path.with_suffix(".onset")
    if not path.exists():
        out = subprocess.run(argv, check=True, capture_output=True, text=True).stdout
        got = re.search(r"onset (\S+)", out)
        onset_file.write_text(got.group(1) if got else "")
    elif f and not onset_file.exists():  # the onset alone: the simulator prints it first
        proc = subprocess.Popen([argv[0], "-u", argv[1], os.devnull, *argv[3:]],
                                stdout=subprocess.PIPE, text=True)  # fmt: skip
        line = proc.stdout.readline()
        proc.kill()
        proc.wait()
        onset_file.write_text(line.split()[1] if line.startswith("onset") else "")
    text = onset_file.read_text().strip() if onset_file.exists() else ""
    return text or None


def diag(g: list[str], *argv: str) -> str:
    """``diag`` in a child process (this interpreter), its output; raises on failure."""
    code = "import sys; from diag_plugin.cli import main; sys.exit(main(sys.argv[1:]))"
    got = subprocess.run([sys.executable, "-c", code, *g, *argv], capture_output=True,
                         text=True)  # fmt: skip
    if got.returncode:
        raise RuntimeError(f"diag {' '.join(argv)}: {got.stdout}{got.stderr}")
    return got.stdout


def build(folder: Path, period: int, tags: Path, label: str = "") -> list[str]:
    """The unit ``p`` built at ``period`` (once: kept in ``folder``, its rulebase folder
    ``rb{period}{label}``); the CLI's global options."""
    db = folder / f"t{period}.db"
    rb = folder / f"rb{period}{label}"
    g = ["--db", f"sqlite:///{db}", "--rulebases", str(rb)]
    train = folder / f"train{period}s.csv"
    sim(train, 0, period, build=True)
    if not (rb / "p.unit.toml").exists():
        rb.mkdir(exist_ok=True)
        if not db.exists():
            diag(g, "import", str(train), "--tags", str(tags), "--duplicates", "first")
        diag(g, *build_argv(period, tags))
    return g


def build_argv(period: int, tags: Path) -> list[str]:
    p = RATES[period]
    start = p["build"][1][:16] + "Z"
    return ["unit", "build", "p", "--from", start, "--to", p["to"], "--far", "0.01",
            "--loops-from", str(tags), *LOOPS, "--running", "MODE=1"]  # fmt: skip


def episodes(a: np.ndarray) -> int:
    return int((a & ~np.r_[False, a[:-1]]).sum())


def stretches(a: np.ndarray) -> list[int]:
    """The lengths of ``a``'s runs of True."""
    d = np.diff(np.r_[0, a.astype(np.int8), 0])
    return list(np.flatnonzero(d == -1) - np.flatnonzero(d == 1))


def reason(why: pd.Series) -> np.ndarray:
    """Per CHECK_FUNCTION sample why: ``stopped`` (the unit not running), ``state`` (a state
    change's settle), ``loop`` (another settle: a set-point's, a hand valve's),
    ``combination`` (states never learned together), ``other``."""
    w = why.fillna("").astype(str)
    out = np.full(len(w), "other", dtype=object)
    out[w.str.contains("settling").to_numpy()] = "loop"
    out[w.str.contains("settling after a state change").to_numpy()] = "state"
    out[w.str.contains("combination of states").to_numpy()] = "combination"
    out[w.str.contains("not running").to_numpy()] = "stopped"
    return out


def judge(folder: Path, g: list[str], period: int, seed: int, tags: Path) -> dict:
    """One judged run (module doc)."""
    p = RATES[period]
    path = folder / f"r{seed}.csv"
    onset = sim(path, seed, period)
    db = folder / f"r{seed}.db"
    gr = ["--db", f"sqlite:///{db}", g[2], g[3]]
    if not db.exists():
        diag(gr, "import", str(path), "--tags", str(tags), "--hot")
    start = pd.Timestamp(p["run"][0], tz="UTC")
    end = start + pd.Timedelta(days=p["run"][1])
    out_csv = folder / f"d{period}_{seed}{Path(g[3]).name[len(f'rb{period}') :]}.csv"
    diag(gr, "diagnose", "p", "--from", start.strftime("%Y-%m-%dT%H:%MZ"), "--to",
         end.strftime("%Y-%m-%dT%H:%MZ"), "--csv", str(out_csv))  # fmt: skip
    d = pd.read_csv(out_csv, low_memory=False)
    ts = pd.to_datetime(d["ts"], utc=True)
    keep = (ts >= start + pd.Timedelta(seconds=p["skip_s"])).to_numpy()
    st = d["status"].to_numpy(int)
    why = reason(d["why"] if "why" in d else pd.Series([""] * len(d)))
    row: dict = {"period_s": period, "seed": seed, "fault": fault_of(seed)}
    pre = keep if onset is None else keep & (ts < pd.Timestamp(onset)).to_numpy()
    fail = st == 1
    cf = st == 2
    row["failure_pct"] = round(100 * float(fail[pre].mean()), 3)
    row["failure_episodes"] = episodes(fail & pre)
    row["check_pct"] = round(100 * float(cf[pre].mean()), 2)
    for k in ("stopped", "state", "loop", "combination", "other"):
        row[f"check_{k}_pct"] = round(100 * float((cf & (why == k))[pre].mean()), 2)
    held = stretches(cf & (why == "state") & pre)
    row["state_settles"] = len(held)
    row["state_settle_median_s"] = float(np.median(held) * period) if held else None
    row["state_settle_max_s"] = float(max(held) * period) if held else None
    if onset is not None:
        after = keep & (ts >= pd.Timestamp(onset)).to_numpy()
        row["onset"] = onset
        row["detected_pct"] = round(100 * float(fail[after].mean()), 1)
        first = np.flatnonzero(fail & after)
        t_on = pd.Timestamp(onset)
        row["first_h"] = round((ts.iloc[first[0]] - t_on).total_seconds() / 3600, 2) \
            if first.size else None  # fmt: skip
        top = d["top1"].fillna("").astype(str).to_numpy() if "top1" in d else None
        if top is not None and (fail & after).any():
            right = np.isin(top[fail & after], RIGHT[row["fault"]])
            row["right_first_pct"] = round(100 * float(right.mean()), 1)
    return row


#: the child that builds without the envelope's replay (settle_replay answering "none")
NO_REPLAY = """
import sys, numpy as np
import diag_plugin.diagnose.settle as s
def none(unit, frame, bounds=None, holds=None):
    n = len(frame)
    eq = None if holds is None else np.full((n, len(holds)), -1, np.int64)
    return np.full(n, -1, np.int64), np.zeros(n, bool), eq
s.settle_replay = none
from diag_plugin.cli import main
sys.exit(main(sys.argv[1:]))
"""
#: the child that builds with it and says the replay's own CPU seconds
TIMED_REPLAY = """
import sys, time
import diag_plugin.diagnose.settle as s
f = s.settle_replay
def timed(*a, **k):
    c = time.process_time()
    try:
        return f(*a, **k)
    finally:
        print("settle_replay_cpu_s", round(time.process_time() - c, 2), file=sys.stderr)
s.settle_replay = timed
from diag_plugin.cli import main
sys.exit(main(sys.argv[1:]))
"""


def build_cpu(g: list[str], argv: list[str], code: str) -> tuple[float, float | None]:
    """CPU seconds (user + system) of one ``diag unit build`` child, and the replay's own."""
    import resource

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    got = subprocess.run([sys.executable, "-c", code, *g, *argv], capture_output=True,
                         text=True)  # fmt: skip
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if got.returncode:
        raise RuntimeError(got.stdout + got.stderr)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    m = re.findall(r"settle_replay_cpu_s (\S+)", got.stderr)
    return cpu, (sum(float(x) for x in m) if m else None)


def cost(folder: Path, g: list[str], period: int, tags: Path, n: int) -> dict:
    """The build's CPU with and without the envelope's replay, interleaved (module doc)."""
    rb = folder / f"cost{period}"
    rb.mkdir(exist_ok=True)
    gg = [g[0], g[1], "--rulebases", str(rb)]
    argv = [*build_argv(period, tags), "--force"]
    argv[2] = "c"
    load = [os.getloadavg()[0]]
    with_s, without_s, replay_s = [], [], []
    for k in range(n):
        cpu, rep = build_cpu(gg, argv, TIMED_REPLAY)
        with_s.append(cpu)
        replay_s.append(rep or 0.0)
        without_s.append(build_cpu(gg, argv, NO_REPLAY)[0])
        load.append(os.getloadavg()[0])
        print(json.dumps({"pair": k + 1, "cpu_with_s": round(cpu, 2), "replay_s": rep,
                          "cpu_without_s": round(without_s[-1], 2),
                          "load_1min": round(load[-1], 1)}), flush=True)  # fmt: skip
    med = statistics.median
    return {"period_s": period, "builds": n, "cpu_with_s": [round(x, 2) for x in with_s],
            "cpu_without_s": [round(x, 2) for x in without_s],
            "median_with_s": round(med(with_s), 2), "median_without_s": round(med(without_s), 2),
            "median_replay_s": round(med(replay_s), 2),
            "load_1min": [round(x, 1) for x in load]}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--rate", type=int, default=10, choices=sorted(RATES))
    ap.add_argument("--runs", default=None, help="seeds, comma-separated (default: all; '': none)")
    ap.add_argument("--cost", type=int, default=0, help="builds of each for the CPU cost")
    ap.add_argument("--label", default="", help="the rulebase folder's suffix (another build)")
    ap.add_argument(
        "--build-days",
        type=float,
        default=None,
        help="the build window's days (default: the rate's, 14 at 10 s)",
    )
    ap.add_argument(
        "--build-jitter",
        type=float,
        default=None,
        help="the build window's stamp jitter, +- s (0: none)",
    )
    ap.add_argument(
        "--run-jitter",
        type=float,
        default=None,
        help="the judged runs' stamp jitter, +- s (0: none)",
    )
    a = ap.parse_args()
    window(a.rate, a.build_days, a.build_jitter, a.run_jitter)
    folder = a.folder
    folder.mkdir(parents=True, exist_ok=True)
    tags = folder / "tags.csv"
    if not tags.exists():
        subprocess.run([sys.executable, str(SIM), "x", "--tags-csv", str(tags)], check=True)
    g = build(folder, a.rate, tags, a.label)
    unit = (Path(g[3]) / "p.unit.toml").read_text()
    for key in ("state_settle_max_s", "settle_max_s"):
        got = re.search(rf"(?m)^{key} = (\S+)", unit)
        print(json.dumps({"period_s": a.rate, key: got and float(got.group(1))}), flush=True)
    default = "101,102,103,141,151,161" if a.rate == 10 else ",".join(
        ["201", "202", "203", *(f"2{i}1" for i in range(1, 7))])  # fmt: skip
    for seed in (int(s) for s in (default if a.runs is None else a.runs).split(",") if s):
        print(json.dumps(judge(folder, g, a.rate, seed, tags)), flush=True)
    if a.cost:
        print(json.dumps(cost(folder, g, a.rate, tags, a.cost)), flush=True)


if __name__ == "__main__":
    main()
