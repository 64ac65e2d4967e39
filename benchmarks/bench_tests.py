"""CPU seconds of test files (issue 33, item 6): what `make test` and `make check` cost.

The suite is CPU-bound (three xdist workers on two cores, ``--dist loadfile``: one file runs
on one worker), so the figures that matter are each file's CPU time (user + system, its
``diag`` subprocesses included) and the longest files, which set the critical path. Wall time
is printed beside it with the load average, since other jobs on the machine stretch it.

Each file runs alone in a fresh ``pytest -p no:xdist`` process (as CI would run it, without
the other files' fixtures), one after another; ``-m "not slow"`` measures the `make check`
tier of the files instead. Run the files you change, niced, never the whole suite on a
shared machine::

    nice -n 10 .venv/bin/python benchmarks/bench_tests.py tests/test_plant_built.py ...
    nice -n 10 .venv/bin/python benchmarks/bench_tests.py --tier check tests/test_engine_fdi.py

Prints one row per file (CPU s, wall s, load, pytest's closing line; with ``--durations N``
its N slowest phases in wall seconds, to see which tests of a file cost) and the total; exit
1 when a file fails.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def cpu_of_children() -> float:
    """User + system CPU seconds of the children waited for so far (their own children
    included)."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run_file(
    path: str, tier: str, durations: int = 0
) -> tuple[float, float, float, str, int, list[str]]:
    """One test file in its own pytest process: (CPU s, wall s, load average at the end,
    pytest's closing line, exit status, its ``durations`` slowest phases as pytest prints
    them)."""
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:xdist", "-p", "no:cacheprovider"]
    if tier == "check":
        cmd += ["-m", "not slow"]
    if durations:
        cmd += [f"--durations={durations}"]
    c0, t0 = cpu_of_children(), time.perf_counter()
    p = subprocess.run([*cmd, path], cwd=REPO, capture_output=True, text=True, check=False)
    cpu, wall = cpu_of_children() - c0, time.perf_counter() - t0
    lines = [ln for ln in p.stdout.splitlines() if ln.strip()]
    last = lines[-1].strip("= ") if lines else p.stderr.strip()[-200:]
    # exit 5: every test of the file is in the slow tier (none selected)
    status = 0 if p.returncode in (0, 5) else p.returncode
    slowest = [ln for ln in lines if re.match(r"\d+\.\d+s (setup|call|teardown) ", ln)]
    return cpu, wall, os.getloadavg()[0], last, status, slowest


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("files", nargs="+", help="test files (tests/test_x.py)")
    ap.add_argument(
        "--tier", choices=("all", "check"), default="all", help="check: -m 'not slow' only"
    )
    ap.add_argument(
        "--durations", type=int, default=0, help="also print each file's N slowest phases"
    )
    args = ap.parse_args(argv)
    total, failed = 0.0, 0
    print(f"{'file':38} {'CPU s':>7} {'wall s':>7} {'load':>5}  result ({args.tier})")
    for f in args.files:
        cpu, wall, load, last, status, slowest = run_file(f, args.tier, args.durations)
        total += cpu
        failed += status != 0
        print(f"{Path(f).name:38} {cpu:7.1f} {wall:7.1f} {load:5.1f}  {last}", flush=True)
        for ln in slowest:
            print(f"    {ln}")
    print(f"{'total':38} {total:7.1f}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
