"""Start-up of the ``diag`` CLI (issue 8): each command starts in under 0.3 s.

Wall-clock time of fresh ``diag`` processes (median of several runs, and its ratio to a bare
interpreter measured in the same run, the figure that holds under load): ``--help``,
``tags --help``, ``tags`` on an empty SQLite database, ``train --help`` and a real
``train`` of a tiny model (one day of 10 s data, so the run is mostly start-up), plus the
modules a ``--help`` imports; each process's CPU time (user + system) beside its wall
time. Exit 1 when a ``--help`` or ``tags`` start is over budget by CPU time: on a machine
other work keeps busy (2 cores, a load of 10 or more) a process waits for a core most of its
wall time, the floor itself taking 0.2 s, so the wall figure measures the queue (issue 37
re-measure: ``--help`` 0.37 s wall at 0.10 s CPU, the floor 0.18 s wall at 0.05 s CPU).
"""

from __future__ import annotations

import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BUDGET_S = 0.3
RUNS = int(os.environ.get("BENCH_RUNS", "7"))

COUNT = """
import contextlib, io, sys
base = set(sys.modules)
from diag_plugin.cli import main
with contextlib.redirect_stdout(io.StringIO()):
    try:
        main(["--help"])
    except SystemExit:
        pass
new = set(sys.modules) - base
top = {m.split(".")[0] for m in new} - set(sys.stdlib_module_names)
third = sorted(m for m in top if not m.startswith("_") and m != "cython_runtime")
print(len(new), " ".join(third))
"""


def diag_cmd() -> list[str]:
    script = Path(sys.executable).with_name("diag")
    return [str(script)] if script.exists() else [sys.executable, "-m", "diag_plugin"]


def timed(cmd: list[str], cwd: Path, runs: int = RUNS) -> tuple[float, float]:
    """Median wall-clock and CPU (user + system) seconds of ``cmd`` in fresh processes (after
    one warm-up run); the CPU time is the steadier figure on a machine other work keeps busy."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("DIAG_")}
    times, cpus = [], []
    for i in range(runs + 1):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        res = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
        dt = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if res.returncode != 0:
            raise SystemExit(f"{' '.join(cmd)} failed:\n{res.stderr}")
        if i:  # the first run fills the OS file cache and numba's cache
            times.append(dt)
            cpus.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    return statistics.median(times), statistics.median(cpus)


def tiny_train_setup(work: Path) -> str:
    """A SQLite historian with one day of a two-tag process and an untrained model."""
    import numpy as np
    import pandas as pd

    from diag_plugin.workbench.model_edit import new_model
    from historian.access import open_data
    from historian.store import Historian

    url = f"sqlite:///{work / 'train.db'}"
    idx = pd.date_range("2026-01-01", periods=8640, freq="10s", tz="UTC")
    cv = 50 + 30 * np.sin(np.arange(len(idx)) / 500)
    frame = pd.DataFrame({"CV": cv, "F": 0.2 * cv + 1}, index=idx)
    with Historian.open(url) as h:
        h.ensure_tag("CV", unit="%", lo=0, hi=100)
        h.ensure_tag("F", unit="t/h", lo=0, hi=25)
        h.write_samples(frame)
    data, info = open_data(url, None, None, None, "10s")
    (work / "rulebases").mkdir()
    new_model(work / "rulebases" / "m.toml", "m", "F[k]", ["CV[k-1]"], frame=data, tag_info=info)
    return url


def main() -> int:
    diag = diag_cmd()
    work = Path(tempfile.mkdtemp(prefix="bench_startup_"))
    try:
        empty = f"sqlite:///{work / 'empty.db'}"
        url = tiny_train_setup(work)
        rb = str(work / "rulebases")
        rows = [
            ("diag --help", [*diag, "--help"], True),
            ("diag tags --help", [*diag, "tags", "--help"], True),
            ("diag tags (empty SQLite db)", [*diag, "--db", empty, "tags"], True),
            ("diag train --help", [*diag, "train", "--help"], True),
            (
                "diag train (1 day, tiny model)",
                [*diag, "--db", url, "--rulebases", rb, "train", "m"],
                False,
            ),
        ]
        bare, bare_cpu = timed([sys.executable, "-c", "pass"], work)
        print(f"start-up of {' '.join(diag)} (median of {RUNS} runs, budget {BUDGET_S} s of CPU)")
        print(f"  {'python -c pass (floor)':34s} {bare:6.3f} s  ({bare_cpu:.3f} s CPU)")
        over = []
        for label, cmd, budgeted in rows:
            t, cpu = timed(cmd, work)
            flag = "" if not budgeted else ("  ok" if cpu <= BUDGET_S else "  OVER BUDGET")
            print(f"  {label:34s} {t:6.3f} s  {t / bare:5.1f}x the floor  ({cpu:.3f} s CPU){flag}")
            if budgeted and cpu > BUDGET_S:
                over.append(label)
        res = subprocess.run(
            [sys.executable, "-c", COUNT], cwd=work, capture_output=True, text=True, check=True
        )
        n, _, third = res.stdout.strip().partition(" ")
        print(f"  modules imported for --help: {n} (third-party: {third or 'none'})")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    if over:
        print(f"over the {BUDGET_S} s CPU budget: {', '.join(over)}")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
