"""``diag diagnose`` end to end, as a user runs it (issue 34: a 50-tag unit ≥ 100 k rows/s).

The default 50-tag unit of ``bench_unit_replay.py`` (built once from 10 days of the coupled
process at 180 s, ``build_unit`` as ``diag unit build`` does) and ``--rows`` fault-free rows
(200,000 by default) written once into a SQLite historian under ``--dir`` (kept, so later runs
and other checkouts reuse them). Then ``diag diagnose NAME --json --csv FILE`` runs ``--runs``
times, each a process of its own, and prints per run: wall seconds, CPU seconds of the process
and its threads (user + system, from ``wait4``), rows per second of each, peak resident memory,
the load average, and the CPU seconds per stage: start-up and imports, the unit's load, the
historian read and frame building (the reading thread's own CPU), the replay (``Unit.evaluate``
in the main thread) and the output (the rest: concatenation, JSON, CSV). The stages come from a
small wrapper that times the command's own functions (``load_unit``, ``unit_frames``,
``Unit.evaluate``) from outside: the same for any checkout, the command itself unchanged.

``--tree DIR`` runs the command from another checkout (e.g. ``git archive`` of ``main`` into
DIR), this interpreter; ``--tree`` may be given twice to interleave two checkouts run by run
(medians printed per checkout). The JSON and CSV outputs' md5 are printed per checkout.

Figures (issue 34, branch ``i34-diagcli``; ``main`` and the branch interleaved, 5 runs each,
medians, load 5–11 on 2 shared cores): ``--json --csv`` 28.26 → 12.78 CPU s (7,080 → 15,660 rows
per CPU s; the CSV 19.8 → 6.0 s), ``--json`` 8.27 → 7.03 CPU s (24,200 → 28,500); outputs
identical (md5). Round two (branch ``i34-cli100k``: no scipy.signal nor scipy.stats imported — a
port of the filter design, not landed —, the intervals per distinct why, nothing concatenated
the JSON does not read), the same protocol at a load of 12–17: ``--json`` 10.74 → 8.96 CPU s
(18,630 → 22,330 rows per CPU s; imports 2.28 → 1.32, the rest 1.61 → 0.68), ``--json --csv``
18.62 → 15.43 CPU s (10,740 → 12,960); after merging main, 3 pairs at a load of 9: ``--json``
8.48 → 7.09 CPU s (23,590 → 28,200). As landed, without the port, 5 pairs at a load of 10–12:
``--json`` 9.18 → 7.87 CPU s (21,790 → 25,420). Round three (branch ``i34-cli4``: the unit
read with ``tomllib``, tomlkit only to edit; the JSON's intervals encoded by column; without
``--csv`` each piece cut to what the summary reads as it is replayed), 5 pairs interleaved
against ``main``, each a ``git archive`` snapshot, at a load of 10–13 (this session's machine
ran ``main`` 1.7× faster than the figures above at a like load): ``--json`` 5.42 → 4.74 CPU s
(36,930 → 42,240 rows per CPU s; the unit's load 0.27 → 0.15, the rest 0.54 → 0.16; peak RSS
927 → 786 MB); with ``--rows 1000000`` 16.17 → 13.43 CPU s (61,830 → 74,460; peak RSS 2.9 →
1.9 GB, most of it the database file through SQLite's memory map); 1 row 2.65 → 2.57 s.
100,000 rows per CPU s is not reached at any ``--rows`` at that load: ~2.6 CPU s fixed and
10.9 µs a row (``main`` 13.5–13.9), of which the ADBC read of 46 tags ~5.8 and the replay
~4.4. The branch as it ends, at a load of 3.4–5.6: 1 row 2.32 → 2.12 CPU s, 200,000 rows 5.16
→ 4.54 (38,740 → 44,070), 1,000,000 rows 14.57 → 12.52 (68,630 → 79,890): 10.4 µs a row,
at most ~96,000 rows per CPU s however many rows.

``--rolled`` reads a second historian, ``rolled/h.db`` under ``--dir``, made once: the same
values moved in time to end at 2026-11-08, the months before 2026-11 rolled to the Parquet cold
store (``Historian.roll_months`` and ``vacuum``, as ``diag historian roll --vacuum`` does), the
rest hot, as a user keeps months of history (200,000 rows: 14 months rolled, 3,840 rows hot;
1,000,000 rows: 69 months). Its JSON is the JSON of the same rows unrolled (md5 checked once).
Round four (branch ``i34-cli5``: no garbage collection during the command's start-up, then
``gc.freeze()``; the intervals' times written at once), 5 pairs interleaved against ``main``,
each a ``git archive`` snapshot, medians: 200,000 rows 7.44 → 6.21 CPU s hot (26,870 → 32,190
rows per CPU s, load 12–13), 7.57 → 6.15 rolled (26,420 → 32,520, load 9–10); 1,000,000 rows
18.24 → 18.10 hot (pairs' median ratio 0.95, load 6–13), 15.85 → 14.88 rolled (63,090 →
67,200, load 4–6). The rolled months halve the read (1,000,000 rows: 7.8 → 4.0 CPU s), but
100,000 rows per CPU s is not reached hot or rolled at either size on this machine: at
1,000,000 rows rolled the replay alone took 7.3 CPU s. Round five (branch ``i34-speed``: the
filter's Butterworth design in numpy and the χ² levels from ``scipy.special``, neither
``scipy.signal`` nor ``scipy.stats`` imported), 5 pairs against ``main`` at a load of 8–9.5,
``--rolled --no-csv``: 200,000 rows 4.94 → 4.43 CPU s (40,480 → 45,150 rows per CPU s;
imports 1.64 → 1.03); 1,000,000 rows, 12 pairs at a load of 10–15, 16.52 → 16.47 (60,530 →
60,720; pairs' median ratio 0.97: the 0.7 s saved is inside that load's ±20 % per run); the
same JSON. Round six (branch ``i34-replay``: a regular series read as its values alone,
``SqliteBulk.read_grid``; the CSV written by a compiled ``%.6g``, ``diagnose/csvfast.py``),
``--rows 1000000`` hot, ``--json --csv``, 5 pairs against ``main`` (07c9aaa, a ``git archive``
snapshot) at a load of 6.2–9.8, medians: 71.09 → 35.60 CPU s (14,070 → 28,090 rows per CPU s;
pairs' ratios 0.48–0.61, median 0.51), wall 126 → 62 s; per stage read 12.36 → 9.95 (80,900 →
100,500 rows per CPU s), replay 9.09 → 8.86 (the same code), CSV 42.10 → 11.21 (23,750 →
89,200), imports 1.16 → 1.13, the rest 4.63 → 4.54; peak RSS 2.93 → 3.08 GB; JSON and CSV the
same bytes (md5 ``47b16325…``, ``71b40c4a…``); ``--no-csv``, 5 pairs at a load of 8.7–13.5:
24.87 → 20.00 CPU s (40,200 → 50,000 rows per CPU s; pairs' median ratio 0.83; the read 13.30
→ 9.47). 100,000 rows per CPU s end to end is not reached: the read and the replay ~7–10 CPU s
each at 1,000,000 rows.
The stage "read" now also counts ``read_grid`` in the reading threads. Round seven (branch
``i34-diag100k``: the CSV written piece by piece in a thread of its own while the next pieces
replay, ``CsvPieces``; the kernel reads the piece's columns in place, finds a value's digits
once, writes them two by two and stops at the rare value Python formats; the times by a
compiled date; the first and last pieces an eighth of a piece), 3 pairs against ``main``
(26f0f92, a ``git archive`` snapshot) at a load of 7.3–11.5, medians, ``--rows 1000000``:
23.07 → 15.60 CPU s (43,340 → 64,090 rows per CPU s); per stage read 5.00 → 5.10, replay
5.57 → 4.48, CSV 8.54 → 4.09 (now in its own thread), imports 0.69 → 0.74, the rest 3.17 →
0.90 (nothing joined); peak RSS 3.13 → 2.13 GB; the same JSON and CSV (md5 ``47b16325…``,
``71b40c4a…``). The stage "csv" is the writing thread's CPU, "main thread" the main thread's
own (imports, load, replay, its part of the rest): 17.78 → 6.11 s. With both cores free a run
takes at least the larger of the main thread and half the CPU: ~7.8 s, ~128,000 rows/s,
against main's 16.89 s measured idle (one branch run at a load of 9.9: 16.7 s wall). 200,000
rows ``--json`` alone, 5 pairs at a load of 7.5–9.3: 3.22 → 3.18 CPU s, the main thread 1.92
→ 1.90 (its floor when idle, plus the waits at the ends the ramp shortens; main took 2.05 s);
with ``--csv``, 3 pairs at 9.1–9.4: 5.55 → 4.41 CPU s (CSV 1.67 → 0.81, main thread 4.20 →
2.15), the same md5.
Round eight (branch ``i34-start``: the first piece read from when the unit is loaded,
``diagnose/readahead.py``, while the start-up ends with ``scipy.linalg``, ``scipy.special`` and
numba's registries, loaded under the collector's freeze instead of in the first replay), pairs
against ``main`` (17cdb99, a ``git archive`` snapshot), medians: 200,000 rows ``--json``, 7
pairs at a load of 11.1–14.7, 3.83 → 3.52 CPU s (main thread 2.31 → 2.11, lower in 7 of 7);
with ``--csv``, 3 pairs at 10.3–11.0, 4.65 → 4.39; 1,000,000 rows ``--json``, 3 pairs at
11.4–12.0, 11.90 → 11.53 (main thread 6.21 → 5.85); with ``--csv``, 3 pairs at 8.0–13.4,
16.78 → 16.72 (main thread 6.50 → 6.48); the same md5. On the branch the stage
"other" holds those imports and registries (~0.36 CPU s at that load; "imports" ends at the
unit's load); the idle wall at 200,000 rows (``main`` 2.13 s) is to be measured.
Round nine (branch ``i34-fast``: a piece's per-test residuals — design rows, Wang–Mendel
inference, residual — shared by the main thread and a helper, ``diagnose/pertest.py``, and the
replay's compiled kernels ``nogil``), 3 pairs against ``main`` (8654f41, a ``git archive``
snapshot), medians, the machine at a load of 30–35 (six sessions' test runs): 200,000 rows
``--json`` 4.72 → 4.49 CPU s (42,360 → 44,590 rows per CPU s), main thread 3.08 → 2.55 (3 of
3 lower); ``--json --csv`` 6.05 → 5.92, main thread 3.04 → 2.65; 1,000,000 rows ``--json``
16.98 → 16.44 (58,900 → 60,830; pairs' ratios 0.86 / 0.96 / 0.98), main thread 10.08 → 8.03
(ratios 0.66 / 0.77 / 0.81); ``--json --csv`` at 1,000,000 rows (both cores full with the
read, the CSV and the replay) 24.77 → 23.55, pairs' ratios 1.07 / 1.29 / 0.89: no gain
shown; peak RSS unchanged (720 MB, 1.9 GB; 2.0 → 2.1 GB with the CSV); the same JSON and CSV
(200,000 rows ``804a00c3…``/``31fec695…``; 1,000,000 ``e177ec7b…``/``9ee70412…``). The helper's CPU
is now in "replay" (it was in "other" before this round's wrapper). Wall seconds at that load
say nothing of an idle run (35–45 s for 200,000 rows); not measured idle.
Round ten (branch ``i34-speed``): numba's BLAS check without ``scipy.linalg``, the model
cache's arrays as one member, the pieces read two ahead. The wrapper now also prints the
start-up alone, "start-up" (the main thread's CPU until its first replay: imports, the
unit's load, ``scipy.special``, numba's registries), and "read ahead" (the read's CPU done
by then, beside the start-up on the other core).
Round eleven (branch ``i34-replay``): the read started from the plan the last run of the unit
file read (``diagnose/readplan.py``), before the unit's modules are imported and the unit
loaded, three pieces ahead. "imports" is now the main thread's CPU until the unit's load (a
remembered read may be under way by then, counted in "read"), and the read's timers are set
at the first read. 5 pairs against ``main`` (4948dad, a ``git archive`` snapshot) at a load of
11–15, medians: read ahead 0.22 → 0.63 CPU s, start-up 1.07 → 0.96, CPU 4.58 → 4.49 s; the
same JSON.
Round twelve (branch ``i34-speed``: ``read_grid``'s query asks for the usable sample on the
grid first, without ``t0`` on an epoch-anchored grid; the unit file hashed once; the settle's
per-row ages only where collected), 5 pairs against ``main`` (d51c042, a ``git archive``
snapshot) at a load of 16–20, medians: 200,000 rows 6.58 → 6.38 CPU s (30,380 → 31,370 rows
per CPU s; read 2.49 → 2.39); 1,000,000 rows, 3 pairs at 22–32, 23.68 → 23.09 (42,220 →
43,310; read 11.44 → 10.92, lower in 3 of 3); the same JSON and CSV. The read's query alone:
``bench_grid_read.py``.
Round thirteen (branch ``i36-replay``: on SQLite the historian's metadata — its schema check,
the tags, their time range, the rolled months, the cold folder — read through one ``sqlite3``
connection, ``historian/sqlitemeta.py``, and SQLAlchemy not imported), 5 pairs against
``main`` (88e2349, a ``git archive`` snapshot), medians, on a quiet machine (load 0.9–1.2):
200,000 rows ``--no-csv`` 3.08 → 2.87 CPU s (65,040 → 69,640 rows per CPU s; imports 0.33 →
0.23, start-up 0.75 → 0.59, main thread 1.59 → 1.42; wall 2.06 → 1.86 s, 97,300 → 107,500
rows/s); with ``--csv`` 3.79 → 3.54 (52,710 → 56,440; wall 2.40 → 2.19); ``--rolled
--no-csv`` 2.72 → 2.48 (73,510 → 80,730; the read 0.61 → 0.51, the rolled months' list read
per piece); 1,000,000 rows ``--no-csv``, 3 pairs at a load of 3.1–4.5, 10.09 → 10.13 (99,110
→ 98,690: the ~0.2 CPU s saved is inside the noise there); the same JSON and CSV (md5
``804a00c3…``, ``31fec695…``; rolled ``c21a4eba…``; 1,000,000 rows ``e177ec7b…``).
Round fourteen (branch ``i37-replay``): each run without ``PYTHONDONTWRITEBYTECODE``
(:func:`child_env`): with it, as in the sessions' shells, a ``git archive`` snapshot compiled
every module from source in every timed run (200,000 rows, 3 runs each at a load of 7–8:
9.77 → 9.16 CPU s); the ``--warm`` run now writes the bytecode. Nothing of the command
changed: ``main`` (0897d86) and the branch, the same code, 5 pairs at a load of 8.0–9.1,
200,000 rows ``--no-csv`` 7.96 / 8.06 CPU s (25,130 / 24,820 rows per CPU s; read 2.96 /
3.15, replay 2.52 / 2.61, start-up 1.88 / 1.88), ``--csv`` 3 pairs at 6.4–7.9 10.24 / 10.23;
1,000,000 rows ``--no-csv``, 3 pairs at 6.0–7.4, 31.42 / 30.93 (31,830 / 32,340; read 14.82 /
14.55, replay 12.48 / 11.76); the same md5 in both trees (``804a00c3…``, ``31fec695…``;
1,000,000 rows ``af5a7457…``, which round thirteen's code gives on this session's
historian too).
At these loads every figure is ~3× a quiet machine's. Where the rest goes and what was
tried without gain (batch rows, malloc thresholds, the intervals' pattern, the text
columns, the residuals' copy): the doc's "Round fourteen".
Round fifteen (branch ``i34-diag100k``, 2026-12-02, load 5–15 all session: nothing landed).
With timestamps (load 5.7): every piece was read 0.2–2 s before its replay asked for it, so
the main thread is the critical path — 58 % of the run's CPU, of it start-up 40 %
(imports, the unit, ``scipy.linalg``/``scipy.special``, numba's registries), replay 52 %
(combined T² 0.36–0.42 s of 1.5–2.2, ~300 new patterns of known tests a piece inverted:
0.26; the CHECK_FUNCTION texts ~13 % under cProfile), tail 8 % (intervals 115–150 ms, half
the regex over 13,436 distinct ``why`` texts). With the quiet figures (4.53 CPU s, 2.94 s
wall) an idle 2-core run cannot go below ~2.2 s by either bound (main thread; CPU / 2):
100,000 rows/s at 200,000 rows needs the main thread's CPU *and* the total cut 15–20 %,
not more overlap. Tried, same md5, no gain shown: reading threads at nice +5, the combined
T²'s blocks shared with the replay's helper thread (≤ 0.03 s a run without the GIL), one
reading thread instead of two (worse: read 2.50 → 2.69 CPU s). Not tried: the row kernels
split by columns (~0.1 s idle, estimated).
Round sixteen (2026-12-02, ``main`` 7d400e2 unchanged, the session's first job, load 1.0–1.5):
200,000 rows ``--json`` 2.88 s wall (69,400 rows/s; 4.38 CPU s, main thread 2.18),
``--json --csv`` 3.27 s (61,100); 1,000,000 rows ``--json`` 9.78 s wall (**102,200 rows/s**;
runs 99,900 / 109,000 / 102,200; 16.21 CPU s: read 7.55, replay 6.05, main thread 6.74).
Details: docs/how-to/unit-short-windows.md, "Speed" and "Round sixteen".

Run: ``nice -n 10 python benchmarks/bench_diagnose_cli.py --dir /tmp/diagcli [--runs 5]
[--tree /tmp/main --tree .] [--rolled] [--rows 1000000] [-- --to 2026-06-01T00:03]``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NAME = "replay"

#: the stage timer: runs ``diag`` in this process with its functions wrapped, each stage's CPU
#: seconds to stderr as one JSON line; "imports" is the process's CPU until the command loads
#: the unit (the wrapper imports nothing of the command's ahead of it: the command's own
#: start-up, garbage collection included, is what is timed)
WRAPPER = r"""
import json, resource, sys, time, threading
def cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime
import diag_plugin.cli as dc
import diag_plugin.diagnose.cli as cli
st = {"read": 0.0, "replay": 0.0}
def timed(f, key, add):
    def g(*a, **k):
        t = time.thread_time()
        try:
            return f(*a, **k)
        finally:
            st[key] = st.get(key, 0.0) * add + time.thread_time() - t
    return g
orig_load = cli.load_unit
def load_unit(*a, **k):  # the command's imports are done when it loads the unit (the main
    st["imports"] = time.thread_time()  # thread's: a remembered plan's read may be under way)
    import diag_plugin.diagnose.unit as du
    evaluate = timed(du.Unit.evaluate, "replay", True)
    def first(*a, **k):  # the start-up alone: the main thread's CPU until its first replay
        if "start-up" not in st and threading.current_thread() is threading.main_thread():
            st["start-up"], st["read ahead"] = time.thread_time(), st["read"]
        return evaluate(*a, **k)
    du.Unit.evaluate = first
    try:  # a piece's per-test rows in helper threads too (round nine): their CPU is replay
        import diag_plugin.diagnose.pertest as pt
    except ImportError:
        pt = None
    if pt is not None:
        each = pt.each
        def each_timed(row, n, workers=1):
            def timed_row(j):
                if not threading.current_thread().name.startswith("diagnose-tests"):
                    return row(j)
                t = time.thread_time()
                try:
                    return row(j)
                finally:
                    with lock:
                        st["replay"] += time.thread_time() - t
            return each(timed_row, n, workers)
        pt.each = du.each = each_timed
    return timed(orig_load, "load", False)(*a, **k)
cli.load_unit = load_unit
lock = threading.Lock()
def pooled(f):  # the per-tag reads of a window in the historian's reader threads
    def g(*a, **k):
        if not threading.current_thread().name.startswith("historian-read"):
            return f(*a, **k)
        t = time.thread_time()
        try:
            return f(*a, **k)
        finally:
            with lock:
                st["read"] += time.thread_time() - t
    return g
patched = []
def patch_read():  # before the first read (the command has imported the historian by then)
    import historian.store as hs
    import historian.backends as hb
    if patched:
        return
    patched.append(True)
    hs.Historian._read_pieces = pooled(hs.Historian._read_pieces)
    hs.align_pieces = pooled(hs.align_pieces)
    if hasattr(hb.SqliteBulk, "read_grid"):  # a regular series' values alone (round six)
        hb.SqliteBulk.read_grid = pooled(hb.SqliteBulk.read_grid)
uf = cli.unit_frames
def unit_frames(*a, **k):
    patch_read()
    it = uf(*a, **k)
    while True:
        t = time.thread_time()
        try:
            x = next(it)
        except StopIteration:
            st["read"] += time.thread_time() - t
            return
        st["read"] += time.thread_time() - t
        yield x
cli.unit_frames = unit_frames
cli.write_csv = timed(cli.write_csv, "csv", False)
if hasattr(cli, "CsvPieces"):  # the CSV written piece by piece in a thread (round seven)
    def piece(f):
        def g(*a, **k):
            t = time.thread_time()
            try:
                return f(*a, **k)
            finally:
                st["csv"] = st.get("csv", 0.0) + time.thread_time() - t
        return g
    cli.CsvPieces._write = piece(cli.CsvPieces._write)
rc = dc.main(sys.argv[1:])
st["main"] = time.thread_time()
st["total"] = cpu()
print("STAGES " + json.dumps(st), file=sys.stderr)
sys.exit(rc)
"""


#: ``--rolled``: the same rows end here (the first week of a month, kept in the database) and
#: every month before it is rolled to the Parquet cold store, as a user's history would be
ROLLED_END = "2026-11-08"
ROLLED_BEFORE = "2026-11"


def setup(
    folder: Path, tags: int, rows: int, period: float, rolled: bool = False
) -> tuple[Path, str]:
    """The unit's folder and the historian's URL under ``folder``, made if not there; with
    ``rolled`` also a historian ``rolled/h.db`` of the same values (their times moved to end
    at :data:`ROLLED_END`) whose months before :data:`ROLLED_BEFORE` are rolled to Parquet
    (``Historian.roll_months``, as ``diag historian roll --vacuum`` does), made once."""
    rb = folder / "rulebases"
    db = folder / "h.db"
    url = f"sqlite:///{db}"
    if rolled:
        cold = folder / "rolled" / "h.db"
        if not cold.with_name("done").exists():  # else made and rolled already
            _rolled(cold, tags, rows, period)
        rb, _ = setup(folder, tags, rows, period)
        return rb, f"sqlite:///{cold}"
    if (rb / f"{NAME}.unit.toml").exists() and db.exists():
        return rb, url
    from diag_plugin.simulate import coupled
    from diag_plugin.unitbuild.build import build_unit
    from historian.store import Historian

    rb.mkdir(parents=True, exist_ok=True)
    train, _ = coupled.simulate(10, period_s=period, n_tags=tags, seed=1)
    t = time.perf_counter()
    res = build_unit(NAME, train, folder=rb, period=f"{period:g}s", far=0.01)
    print(f"built {len(res.tests)} tests in {time.perf_counter() - t:.1f} s: {res.path}")
    frame = _frame(tags, rows, period)
    t = time.perf_counter()
    with Historian.open(url) as h:
        h.write_samples(frame)
    print(f"wrote {frame.size:,} samples in {time.perf_counter() - t:.1f} s: {db}")
    return rb, url


def _frame(tags: int, rows: int, period: float):
    """The bench's fault-free rows (the coupled process, seed 7, from 2026-06-01)."""
    from diag_plugin.simulate import coupled

    days = rows * period / 86400
    frame, _ = coupled.simulate(days, period_s=period, n_tags=tags, seed=7, start="2026-06-01")
    return frame.iloc[:rows]


def _rolled(db: Path, tags: int, rows: int, period: float) -> None:
    """The historian of ``--rolled``: the bench's rows moved in time to end at
    :data:`ROLLED_END`, written, and the months before :data:`ROLLED_BEFORE` rolled."""
    import pandas as pd

    from historian.store import Historian

    frame = _frame(tags, rows, period)
    end = pd.Timestamp(ROLLED_END, tz="UTC")
    frame.index = frame.index + (end - frame.index[-1] - pd.Timedelta(seconds=period))
    if db.parent.exists():  # an interrupted set-up
        shutil.rmtree(db.parent)
    db.parent.mkdir(parents=True)
    t = time.perf_counter()
    with Historian.open(f"sqlite:///{db}") as h:  # the cold store beside it: h.db.cold
        h.write_samples(frame)
        months = h.roll_months(pd.Timestamp(f"{ROLLED_BEFORE}-01", tz="UTC"))
        h.vacuum()
        store = h.storage()
    print(
        f"wrote {frame.size:,} samples {frame.index[0]} … {frame.index[-1]} and rolled "
        f"{len(months)} months ({store['cold_rows']:,} samples, {store['cold_bytes'] / 1e6:.0f}"
        f" MB of Parquet; {store['db_bytes'] / 1e6:.0f} MB left in the database) in "
        f"{time.perf_counter() - t:.1f} s: {db}"
    )
    db.with_name("done").touch()


def run_once(
    tree: Path, rb: Path, url: str, out: Path, extra: list[str], csv_too: bool = True
) -> dict:
    """One ``diag diagnose`` process: wall, CPU, peak RSS, stages, outputs' md5."""
    csv, js = out / "out.csv", out / "out.json"
    csv.unlink(missing_ok=True)
    cmd = [sys.executable, "-c", WRAPPER, "--db", url, "--rulebases", str(rb)]
    cmd += ["diagnose", NAME, "--json", *(["--csv", str(csv)] if csv_too else []), *extra]
    env = child_env(tree)
    load0 = os.getloadavg()[0]
    t = time.perf_counter()
    with open(js, "wb") as fo, open(out / "err.txt", "wb") as fe:
        p = subprocess.Popen(cmd, cwd=tree, env=env, stdout=fo, stderr=fe)
        _, status, ru = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t
    err = (out / "err.txt").read_text()
    if status != 0:
        raise SystemExit(f"diag diagnose failed ({status}):\n{err}")
    stages = json.loads(next(x for x in err.splitlines() if x.startswith("STAGES "))[7:])
    samples = json.loads(js.read_text())["samples"]
    return {
        "wall": wall,
        "cpu": ru.ru_utime + ru.ru_stime,
        "rss_mb": ru.ru_maxrss / 1024,
        "load": (load0 + os.getloadavg()[0]) / 2,
        "samples": samples,
        "stages": stages,
        "md5_json": hashlib.md5(js.read_bytes()).hexdigest(),
        "md5_csv": hashlib.md5(csv.read_bytes()).hexdigest() if csv_too else "-",
    }


def child_env(tree: Path) -> dict[str, str]:
    """The command's environment: this one, the checkout on ``PYTHONPATH``, and without
    ``PYTHONDONTWRITEBYTECODE`` — with it a checkout that has no bytecode yet (a ``git
    archive`` snapshot) compiles every module from source in every run (~0.3–0.6 CPU s of a
    200,000-row run, round fourteen), where an installed package reads its ``.pyc``; the
    untimed ``--warm`` run writes them."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPATH"] = str(tree)
    return env


def split(st: dict) -> dict[str, float]:
    """CPU seconds per stage from the wrapper's figures."""
    imports = st["imports"]
    load, read, replay = st.get("load", 0.0), st["read"], st["replay"]
    csv = st.get("csv", 0.0)
    output = st["total"] - imports - load - read - replay - csv
    out = {"imports": imports, "load": load, "read": read, "replay": replay, "csv": csv,
           "other": output}  # fmt: skip
    if "main" in st:  # the main thread's own CPU (imports, load, replay, its share of other)
        out["main thread"] = st["main"]
    for key in ("start-up", "read ahead"):  # not parts of the sum: the main thread's CPU
        if key in st:  # before its first replay, and the read's CPU done by then
            out[key] = st[key]
    return out


def show(label: str, r: dict) -> None:
    n = r["samples"]
    s = " ".join(f"{k} {v:.2f}" for k, v in split(r["stages"]).items())
    print(
        f"{label}: load {r['load']:.1f}  wall {r['wall']:.2f} s ({n / r['wall']:,.0f} rows/s)  "
        f"CPU {r['cpu']:.2f} s ({n / r['cpu']:,.0f} rows/CPU s)  peak RSS {r['rss_mb']:.0f} MB"
        f"  | CPU s: {s}",
        flush=True,
    )


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--dir", required=True, help="folder of the unit and historian (kept)")
    ap.add_argument("--tags", type=int, default=50)
    ap.add_argument("--rows", type=int, default=200_000)
    ap.add_argument("--period", type=float, default=180.0)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--tree", action="append", help="checkout to run (repeat to interleave)")
    ap.add_argument("--no-csv", action="store_true", help="--json only (no --csv FILE)")
    ap.add_argument(
        "--rolled",
        action="store_true",
        help=f"read a historian whose months before {ROLLED_BEFORE} are rolled to Parquet",
    )
    ap.add_argument("--warm", type=int, default=1, help="untimed runs per tree first (numba)")
    ap.add_argument("extra", nargs="*", help="more options for diag diagnose (after --)")
    a = ap.parse_args()
    folder = Path(a.dir).resolve()
    folder.mkdir(parents=True, exist_ok=True)
    rb, url = setup(folder, a.tags, a.rows, a.period, a.rolled)
    trees = [Path(t).resolve() for t in (a.tree or [str(ROOT)])]
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; {url}")
    results: dict[Path, list[dict]] = {t: [] for t in trees}
    outs = {}
    for i, t in enumerate(trees):
        outs[t] = folder / f"out{i}"
        outs[t].mkdir(exist_ok=True)
        for _ in range(a.warm):  # the checkout's numba cache filled, its files read once
            run_once(t, rb, url, outs[t], a.extra, not a.no_csv)
    for k in range(a.runs):
        for t in trees:
            r = run_once(t, rb, url, outs[t], a.extra, not a.no_csv)
            results[t].append(r)
            show(f"run {k + 1} {t.name}", r)
    for t in trees if a.runs else ():
        rs = results[t]
        med = {key: statistics.median(r[key] for r in rs) for key in ("wall", "cpu", "rss_mb")}
        sp = {key: statistics.median(split(r["stages"])[key] for r in rs) for key in split(
            rs[0]["stages"])}  # fmt: skip
        n = rs[0]["samples"]
        loads = [r["load"] for r in rs]
        print(
            f"{t}: median of {len(rs)} at load {min(loads):.1f}–{max(loads):.1f}: wall "
            f"{med['wall']:.2f} s ({n / med['wall']:,.0f} rows/s), CPU {med['cpu']:.2f} s "
            f"({n / med['cpu']:,.0f} rows/CPU s), peak RSS {med['rss_mb']:.0f} MB; CPU s "
            + ", ".join(f"{k} {v:.2f}" for k, v in sp.items())
        )
        print(f"  md5 JSON {rs[-1]['md5_json']}  CSV {rs[-1]['md5_csv']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
