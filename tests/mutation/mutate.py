"""Mutation check of the run-time diagnosis, threshold learning, unit build, the alarm lifecycle
and the importer (cosmic-ray).

Not part of ``make test`` (pytest collects only ``test_*.py``); see
docs/reference/testing.md. Run it
from the repository root, niced, on a machine nobody else is waiting for::

    nice -n 19 python tests/mutation/mutate.py --out /tmp/mutation

Each module is mutated in its own copy of the working tree under ``--out`` (never in place,
so a killed run leaves no mutant in your sources), and only the test files that cover it run
against each mutant (the fast, direct ones first, with ``-x``), PostgreSQL variants left out.
The per-mutant timeout is three times that module's unmutated test run plus 20 s; a mutant
that runs into it counts as killed (an endless loop is caught). Operators: every comparison
boundary and negation, arithmetic ``+ -`` and ``* /``, ``& |`` (numpy masks), removed
``- not ~``, ``not`` added, ``and``/``or``, ``True``/``False``, numbers ±1, loops that never
run, ``continue``/``break``, exceptions that never match. Left out: cross-family operator
swaps (``+`` → ``<<``, ``<`` → ``is``), which only crash, and removed decorators (numba's
``njit`` gives the same results uncompiled).

``--rerun-survivors DIR`` runs the mutants that survived in an earlier ``--out DIR`` again
against today's tests (a mutant a test killed stays killed: tests were only added), and
writes the new score beside the old one. ``--only unit.py`` limits the run to some modules.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sqlite3
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

#: module → the test files that cover it, fastest and most direct first (``-x`` stops at the
#: first failure, so a killed mutant costs little)
TARGETS: dict[str, list[str]] = {
    "diag_plugin/diagnose/isolation.py": ["test_diagnosis_guards.py", "test_units.py"],
    "diag_plugin/diagnose/residuals.py": [
        "test_diagnose_residuals.py",
        "test_diagnose_stage_edges.py",
        "test_diagnosis_guards.py",
        "test_units.py",
    ],
    "diag_plugin/diagnose/symptoms.py": [
        "test_diagnose_residuals.py",
        "test_diagnose_stage_edges.py",
        "test_diagnosis_guards.py",
        "test_units.py",
    ],
    "diag_plugin/diagnose/unit.py": [
        "test_diagnosis_intervals.py",
        "test_diagnosis_guards.py",
        "test_units.py",
        "test_plant.py",
    ],
    "diag_plugin/status.py": ["test_diagnosis_guards.py", "test_units.py"],
    # the independent-value count the thresholds and the budget rest on (moved from symptoms.py)
    "diag_plugin/models/series.py": [
        "test_diagnose_residuals.py",
        "test_learning.py",
        "test_explain_scale.py",
    ],
    "diag_plugin/diagnose/matrix.py": [
        "test_diagnose_matrix.py",
        "test_diagnose_stage_edges.py",
        "test_diagnosis_guards.py",
        "test_units.py",
        "test_valve_isolation.py",
    ],
    "diag_plugin/diagnose/plant.py": ["test_plant.py", "test_diagnosis_guards.py"],
    "diag_plugin/diagnose/unitfile.py": [
        "test_unit_new_text.py",
        "test_diagnosis_guards.py",
        "test_units.py",
    ],
    # issue 38: the combined test, threshold learning and diag unit build
    "diag_plugin/diagnose/unittags.py": ["test_unit_guards.py", "test_unit_tags.py"],
    "diag_plugin/learn/thresholds.py": [
        "test_unit_guards.py",
        "test_learning.py",
        "test_unit_tags.py",
        "test_levels.py",
    ],
    "diag_plugin/learn/budget.py": [
        "test_learning.py",
        "test_unit_guards.py",
        "test_unit_tags.py",
    ],
    "diag_plugin/learn/cli.py": ["test_learning.py", "test_unit_tags.py", "test_unit_guards.py"],
    "diag_plugin/unitbuild/build.py": ["test_unit_guards.py", "test_unit_build.py"],
    "diag_plugin/unitbuild/cli.py": ["test_unit_guards.py", "test_unit_build.py"],
    "connectors/alarms.py": ["test_alarms.py", "test_alarm_edges.py"],
    "historian/importer.py": [
        "test_import_time_units.py",
        "test_historian_import.py",
        "test_import_refuses_to_guess.py",
        "test_import_edges.py",
        "test_import_dialects.py",
    ],
    "diag_plugin/bench/damadics.py": ["test_benchmark.py"],
    "diag_plugin/diagnose/cli.py": [
        "test_diagnosis_guards.py",
        "test_units.py",
        "test_real_unit.py",
    ],
    "diag_plugin/diagnose/leadin.py": ["test_units.py", "test_live_catchup.py"],
    # issue 38: access, trust list, the live loop's historian writer
    "connectors/opcua_access.py": ["test_opcua_login_guards.py", "test_opcua_security.py"],
    "connectors/opcua_server.py": [
        "test_opcua_server.py",
        "test_opcua_login_guards.py",
        "test_opcua_security.py",
        "test_opcua_trust.py",
    ],
    "diag_plugin/live/writer.py": ["test_historian_writer_recovery.py", "test_live.py"],
    # issue 38 (the rest of diagnose/): the operating range and the loops' alarm settings
    "diag_plugin/diagnose/operating.py": [
        "test_unit_operating.py",
        "test_unit_loops.py",
        "test_unit_accept.py",
        "test_units.py",
    ],
    "diag_plugin/diagnose/unitloops.py": [
        "test_unit_loop_settings.py",
        "test_unit_loops.py",
        "test_unit_guards.py",
        "test_units.py",
    ],
}

#: operators left out (see the module doc); cosmic-ray matches these from the start of the name
EXCLUDE_OPERATORS = [
    "core/ReplaceBinaryOperator_(?!(Add_Sub|Sub_Add|Mul_Div|Div_Mul|FloorDiv_Div|Mod_FloorDiv"
    "|Pow_Mul|BitAnd_BitOr|BitOr_BitAnd)$)",
    "core/ReplaceComparisonOperator_(?!(Lt_LtE|Lt_GtE|LtE_Lt|LtE_Gt|Gt_GtE|Gt_LtE|GtE_Gt|GtE_Lt"
    "|Eq_NotEq|NotEq_Eq|Is_IsNot|IsNot_Is|In_NotIn|NotIn_In)$)",
    "core/ReplaceUnaryOperator_(?!(USub_UAdd|Delete_USub|Delete_Not|Delete_Invert)$)",
    "core/RemoveDecorator",
]

CR = Path(sys.executable).with_name("cosmic-ray")
CR_FILTER = Path(sys.executable).with_name("cr-filter-operators")


def _slug(module: str) -> str:
    return module.replace("/", "_").removesuffix(".py")


def _copy_tree(dest: Path, tests_at: str | None) -> None:
    """The working tree as it is (tracked and new files, edits included) into ``dest``;
    with ``tests_at`` (a git revision), ``tests/`` as it was there instead."""
    files = subprocess.run(
        ["git", "ls-files", "-co", "--exclude-standard", "-z"],
        cwd=ROOT,
        capture_output=True,
        check=True,
    ).stdout.split(b"\0")
    if dest.exists():
        shutil.rmtree(dest)
    for f in filter(None, files):
        src = ROOT / f.decode()
        if src.is_file():
            (dest / f.decode()).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / f.decode())
    if tests_at:
        shutil.rmtree(dest / "tests")
        tar = subprocess.run(
            ["git", "archive", tests_at, "tests"], cwd=ROOT, capture_output=True, check=True
        ).stdout
        subprocess.run(["tar", "-x", "-C", dest], input=tar, check=True)


def _test_command(src: Path, tests: list[str]) -> str:
    files = " ".join(f"tests/{t}" for t in tests)
    return (
        f"env PYTHONPATH={src} CI= {sys.executable} -m pytest -x -q -p no:cacheprovider "
        f"--no-header -m 'not postgres and not slow' {files}"
    )


def _config(module: str, src: Path, tests: list[str], timeout: float) -> str:
    ex = ",\n  ".join(json.dumps(e) for e in EXCLUDE_OPERATORS)
    return (
        "[cosmic-ray]\n"
        f"module-path = {json.dumps(module)}\n"
        f"timeout = {timeout:.0f}\n"
        "excluded-modules = []\n"
        f"test-command = {json.dumps(_test_command(src, tests))}\n"
        "[cosmic-ray.distributor]\n"
        'name = "local"\n'
        "[cosmic-ray.filters.operators-filter]\n"
        f"exclude-operators = [\n  {ex},\n]\n"
    )


def counts(session: Path) -> dict[str, int]:
    """Killed (timeouts included), survived, incompetent and skipped mutants of a session."""
    with sqlite3.connect(session) as db:
        rows = db.execute(
            "SELECT worker_outcome, test_outcome, output FROM work_results"
        ).fetchall()
        total = db.execute("SELECT COUNT(*) FROM work_items").fetchone()[0]
    out = dict.fromkeys(
        ("killed", "timeout", "survived", "incompetent", "skipped", "not_sampled"), 0
    )
    for worker, test, output in rows:
        if worker == "SKIPPED":
            out["not_sampled" if output == "not sampled" else "skipped"] += 1
        elif test == "KILLED":
            out["killed"] += 1
            out["timeout"] += output == "timeout"
        elif test == "SURVIVED":
            out["survived"] += 1
        else:
            out["incompetent"] += 1
    out["pending"] = total - len(rows)
    return out


def survivors(session: Path) -> list[dict]:
    """Each surviving mutant: operator, line and diff."""
    with sqlite3.connect(session) as db:
        rows = db.execute(
            "SELECT s.operator_name, s.start_pos_row, r.diff FROM work_results r "
            "JOIN mutation_specs s ON s.job_id = r.job_id "
            "WHERE r.test_outcome = 'SURVIVED' ORDER BY s.start_pos_row"
        ).fetchall()
    return [{"operator": o, "line": ln, "diff": d} for o, ln, d in rows]


def _sample(session: Path, keep: int, seed: int) -> None:
    """Keep a seeded random ``keep`` of the mutants still to run (all if fewer); the others
    are marked skipped as ``not sampled``, so the score is an estimate over that sample."""
    import random

    with sqlite3.connect(session) as db:
        ids = [
            r[0]
            for r in db.execute(
                "SELECT job_id FROM work_items WHERE job_id NOT IN "
                "(SELECT job_id FROM work_results) ORDER BY job_id"
            )
        ]
        if len(ids) <= keep:
            return
        chosen = set(random.Random(seed).sample(ids, keep))
        db.executemany(
            "INSERT INTO work_results (worker_outcome, output, test_outcome, diff, job_id) "
            "VALUES ('SKIPPED', 'not sampled', NULL, NULL, ?)",
            [(i,) for i in ids if i not in chosen],
        )


def score(c: dict[str, int]) -> float:
    done = c["killed"] + c["survived"]
    return c["killed"] / done if done else float("nan")


def run_module(
    module: str, out: Path, rerun_from: Path | None, sample: int, tests_at: str | None
) -> dict:
    slug = _slug(module)
    src = out / "src" / slug
    _copy_tree(src, tests_at)
    tests = [t for t in TARGETS[module] if (src / "tests" / t).exists()]
    start = time.monotonic()
    base = subprocess.run(_test_command(src, tests), shell=True, cwd=src, capture_output=True)
    took = time.monotonic() - start
    if base.returncode != 0:
        raise SystemExit(f"{module}: its tests fail unmutated:\n{base.stdout.decode()[-3000:]}")
    cfg = out / f"{slug}.toml"
    cfg.write_text(_config(module, src, tests, 3 * took + 20))
    session = out / f"{slug}.sqlite"
    if rerun_from is not None:
        shutil.copy(rerun_from / f"{slug}.sqlite", session)
        with sqlite3.connect(session) as db:
            db.execute("DELETE FROM work_results WHERE test_outcome = 'SURVIVED'")
    elif not session.exists():
        subprocess.run([CR, "init", cfg, session], cwd=src, check=True)
        subprocess.run([CR_FILTER, session, cfg], cwd=src, check=True)
        _sample(session, sample, seed=28)
    subprocess.run([CR, "exec", cfg, session], cwd=src, check=True)
    c = counts(session)
    surv = survivors(session)
    (out / f"{slug}.survivors.json").write_text(json.dumps(surv, indent=1))
    c["baseline_s"] = round(took, 1)
    c["tests"] = tests
    print(f"{module}: {c['killed']} killed, {c['survived']} survived ({score(c):.1%})", flush=True)
    return c


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, required=True, help="work folder (copies, sessions)")
    p.add_argument("--only", nargs="*", default=None, help="module file names to run")
    p.add_argument("--jobs", type=int, default=1, help="modules mutated at once (default 1)")
    p.add_argument("--rerun-survivors", type=Path, default=None, metavar="DIR")
    p.add_argument("--tests-at", default=None, metavar="REV", help="tests/ as at this git revision")
    p.add_argument(
        "--sample",
        type=int,
        default=0,
        metavar="N",
        help="run a seeded random N mutants per module (default 0: all)",
    )
    a = p.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    mods = [m for m in TARGETS if a.only is None or Path(m).name in a.only or m in a.only]
    with ThreadPoolExecutor(a.jobs) as pool:
        results = dict(
            zip(
                mods,
                pool.map(
                    lambda m: run_module(
                        m, a.out, a.rerun_survivors, a.sample or 10**9, a.tests_at
                    ),
                    mods,
                ),
                strict=True,
            )
        )
    total = {k: sum(r[k] for r in results.values()) for k in ("killed", "survived", "timeout")}
    summary = {"modules": results, "total": total, "score": round(score(total | {}), 4)}
    (a.out / "summary.json").write_text(json.dumps(summary, indent=1))
    print(f"total: {total['killed']} killed, {total['survived']} survived ({summary['score']:.1%})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
