"""Start-up (issue 8): building the ``diag`` parser, ``--help`` of every command and parsing
any command's arguments import no heavy library; each command imports what it uses when it
runs. Behaviour only: the time itself is printed by benchmarks/bench_startup.py."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

#: not imported before a command runs (argparse-level start)
HEAVY = (
    "scipy",
    "numba",
    "dask",
    "distributed",
    "pyarrow",
    "sqlalchemy",
    "pandas",
    "numpy",
    "rich",
    "tomlkit",
)

#: arguments that parse for every command (and sub-action); nothing runs
ARGV = {
    "simulate": ["simulate", "--days", "1", "--out", "x.csv", "--fault", "f17:0.5"],
    "rules check": ["rules", "check", "a.toml"],
    "rules show": ["rules", "show", "valve"],
    "rules export-fcl": ["rules", "export-fcl", "valve", "-o", "v.fcl"],
    "demo": ["demo", "--days", "1"],
    "import": ["import", "x.csv", "--time-column", "ts", "--strict"],
    "tags": ["tags", "--json"],
    "historian roll": ["historian", "roll", "--before", "2024-03", "--cold-dir", "c", "--json"],
    "historian check": ["historian", "check", "--json"],
    "historian vacuum": ["historian", "vacuum", "--full"],
    "train": ["train", "valve", "--engine", "dask", "--chunk", "1D"],
    "experiments": ["experiments", "valve", "--json"],
    "model new": ["model", "new", "m", "--output", "F", "--input", "CV[k-1]", "--sets", "9"],
    "model add-input": ["model", "add-input", "m", "P1[k]"],
    "model set-input": ["model", "set-input", "m", "P1[k]", "--span", "0", "4000"],
    "model remove-input": ["model", "remove-input", "m", "P1[k]"],
    "compare": ["compare", "valve", "--json"],
    "explain": ["explain", "valve", "--top", "3"],
    "report": ["report", "valve", "--out", "r.html"],
    "unit new": ["unit", "new", "u", "--model", "r1=valve_r1", "--matrix", "m.toml"],
    "unit check": ["unit", "check", "u.unit.toml", "--json"],
    "unit show": ["unit", "show", "u", "--json"],
    "unit learn": ["unit", "learn", "u", "--from", "2026-01-01", "--to", "2026-01-02"],
    "unit build": ["unit", "build", "u", "--from", "2026-01", "--to", "2026-02", "--dask", "h:1"],
    "unit accept": ["unit", "accept", "u", "--from", "2026-01-01", "--to", "2026-01-02"],
    "unit rollback": ["unit", "rollback", "u"],
    "diagnose": ["diagnose", "u", "--csv", "d.csv", "--from", "2026-01-01"],
    "benchmark": ["benchmark", "--quick", "--json"],
    "engine-fdi": ["engine-fdi", "--seed", "1", "--method", "narmax2", "--json"],
    "compare-methods": ["compare-methods", "valve", "--holdout", "0.3", "--json"],
    "run": ["run", "--duration", "5"],
}

PROBE = textwrap.dedent(
    """
    import argparse, contextlib, io, json, sys

    from diag_plugin.cli import build_parser

    def commands(parser, prefix=()):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    subs = [a for a in sub._actions if isinstance(a, argparse._SubParsersAction)]
                    if subs:
                        yield from commands(sub, (*prefix, name))
                    else:
                        yield " ".join((*prefix, name))

    argv = json.loads(sys.argv[1])
    parser = build_parser()
    found = sorted(commands(parser))
    with contextlib.redirect_stdout(io.StringIO()):
        for args in [[]] + [cmd.split() for cmd in found]:
            try:
                parser.parse_args([*args, "--help"])
            except SystemExit:
                pass
    parsed = {cmd: callable(parser.parse_args(argv[cmd]).func) for cmd in found if cmd in argv}
    loaded = sorted({m.split(".")[0] for m in sys.modules})
    print(json.dumps({"commands": found, "parsed": parsed, "loaded": loaded}))
    """
)


def test_parser_help_and_arguments_import_no_heavy_library():
    res = subprocess.run(
        [sys.executable, "-c", PROBE, json.dumps(ARGV)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    assert set(out["commands"]) <= set(ARGV), "give each new command its line in ARGV"
    assert len(out["commands"]) >= 15 and all(out["parsed"].values()), out["parsed"]
    heavy = sorted(set(HEAVY) & set(out["loaded"]))
    assert not heavy, f"imported before any command runs: {heavy}"


PROBE_ONE = textwrap.dedent(
    """
    import contextlib, io, json, sys

    from diag_plugin import cli

    base = set(sys.modules)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        try:
            cli.main(sys.argv[1:])
        except SystemExit:
            pass
    new = sorted(m for m in set(sys.modules) - base)
    print(json.dumps({"help": out.getvalue(), "modules": new}))
    """
)


def _probe(*argv: str) -> dict:
    res = subprocess.run(
        [sys.executable, "-c", PROBE_ONE, *argv], capture_output=True, text=True, timeout=120
    )
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout)


def test_top_level_help_imports_no_command_module_and_lists_every_command():
    from diag_plugin import cli

    out = _probe("--help")
    loaded = set(out["modules"])
    assert not loaded & set(cli.COMMAND_MODULES), sorted(loaded & set(cli.COMMAND_MODULES))
    assert "logging" not in loaded
    # the listing is the one the fully built parser prints
    full = cli.build_parser().format_help()
    assert out["help"] == full
    for name in cli.COMMANDS:
        assert f"\n    {name} " in out["help"], name


def test_a_command_imports_only_its_own_command_module():
    from diag_plugin import cli

    for argv, module in (
        (["train", "--help"], "diag_plugin.training.cli"),
        (["--db", "sqlite:///x.db", "tags", "--help"], "historian.cli"),
        (["--rul", "rb", "explain", "--help"], "diag_plugin.workbench.cli"),
    ):
        out = _probe(*argv)
        assert out["help"].startswith(f"usage: diag {argv[-2]} "), out["help"][:80]
        assert set(out["modules"]) & set(cli.COMMAND_MODULES) == {module}, argv


def test_the_command_table_says_what_the_modules_register():
    """COMMANDS (the light `diag --help` listing) holds each command's module and help
    exactly as its module registers them: a new or reworded command shows at once."""
    import argparse
    import importlib

    from diag_plugin import cli

    registered: dict[str, tuple[tuple[str, ...], str]] = {}
    for module in cli.COMMAND_MODULES:
        parser = argparse.ArgumentParser()
        sub = parser.add_subparsers()
        importlib.import_module(module).add_commands(sub)
        for action in sub._choices_actions:
            mods, text = registered.get(action.dest, ((), action.help))
            # a command several packages add to (diag unit) has one help, whoever adds it
            assert text == action.help, (action.dest, module)
            registered[action.dest] = (*mods, module), text
    assert registered == cli.COMMANDS


def test_tags_of_an_empty_historian_imports_neither_pandas_nor_sqlalchemy(tmp_path):
    """``diag tags`` on a SQLite historian holding no tag answers from the standard library;
    once a tag is stored the full report runs (and lists it)."""
    from historian.store import Historian

    url = f"sqlite:///{tmp_path / 'h.db'}"
    Historian.open(url).close()  # the file and its schema, no tag
    out = _probe("--db", url, "tags", "--json")
    assert json.loads(out["help"]) == []
    heavy = sorted({m.split(".")[0] for m in out["modules"]} & set(HEAVY))
    assert not heavy, heavy
    with Historian.open(url) as h:
        h.ensure_tag("FI101", unit="t/h", lo=0, hi=10)
    out = _probe("--db", url, "tags", "--json")
    assert [r["tag"] for r in json.loads(out["help"])] == ["FI101"]
    assert "pandas" in {m.split(".")[0] for m in out["modules"]}


def test_a_diag_process_allocates_arrow_memory_with_the_system_pool_unless_told():
    """``diag`` chooses the C library's allocator for Arrow (the per-tag threads of a
    cold-store read cost 40 % more CPU with pyarrow's mimalloc, issue 37) where the user
    named none; a pool the user names is kept."""
    import os

    probe = textwrap.dedent(
        """
        from diag_plugin import cli
        try:
            cli.main(["tags", "--help"])
        except SystemExit:
            pass
        import pyarrow as pa
        print(pa.default_memory_pool().backend_name)
        """
    )
    env = {k: v for k, v in os.environ.items() if k != "ARROW_DEFAULT_MEMORY_POOL"}
    for given, want in ((None, "system"), ("mimalloc", "mimalloc")):
        e = env if given is None else {**env, "ARROW_DEFAULT_MEMORY_POOL": given}
        res = subprocess.run(
            [sys.executable, "-c", probe], capture_output=True, text=True, env=e, check=True
        )
        assert res.stdout.split()[-1] == want, res.stdout


def test_diag_train_to_a_pipe_imports_no_rich(tmp_path):
    """``diag train`` shows its progress bar only on a terminal, so where stderr is a pipe
    (cron, a benchmark) it does not import rich (0.07 s of the process's CPU, issue 37);
    ``FORCE_COLOR`` makes rich's console count as a terminal, and then it is used."""
    import os

    import numpy as np
    import pandas as pd

    from diag_plugin import cli
    from historian.store import Historian

    url = f"sqlite:///{tmp_path / 'h.db'}"
    idx = pd.date_range("2026-03-01", periods=4000, freq="10s", tz="UTC")
    cv = np.random.default_rng(0).uniform(0, 100, len(idx))
    with Historian.open(url) as h:
        h.ensure_tag("CV", lo=0, hi=100)
        h.ensure_tag("F", lo=0, hi=40)
        h.write_samples(pd.DataFrame({"CV": cv, "F": 0.3 * cv}, index=idx))
    rules = tmp_path / "rulebases"
    new = ["model", "new", "m", "--output", "F", "--input", "CV[k-1]", "--sets", "9"]
    assert cli.main(["--db", url, "--rulebases", str(rules), *new]) == 0
    env = {k: v for k, v in os.environ.items() if k not in ("FORCE_COLOR", "TTY_COMPATIBLE")}
    # without the HistGradientBoosting baseline: scikit-learn (1.9's sklearn.callback) imports
    # rich itself; the baseline costs more than rich does, and --no-baseline skips both
    argv = ["--db", url, "--rulebases", str(rules), "train", "m", "--no-baseline"]
    for extra, rich in (({}, False), ({"FORCE_COLOR": "1"}, True)):
        res = subprocess.run(
            [sys.executable, "-c", PROBE_ONE, *argv],
            capture_output=True,
            text=True,
            timeout=300,
            env={**env, **extra},
        )
        assert res.returncode == 0, res.stderr
        out = json.loads(res.stdout)
        assert "held-out RMSE" in out["help"], out["help"]
        assert ("rich" in {m.split(".")[0] for m in out["modules"]}) is rich, extra


def test_reading_a_unit_and_its_models_imports_no_tomlkit(tmp_path):
    """``diag unit check`` (and ``diag diagnose``, which loads the unit the same way) reads
    the unit file and its rule bases with the stdlib's ``tomllib``; tomlkit, which keeps a
    file's comments and layout, is imported only where a file is edited (issue 34: the
    unit's load 0.28 → 0.10 CPU s for 45 tests). Its problems still name file:line."""
    out = _probe("--rulebases", "rulebases", "unit", "check", "valve_t4", "--json")
    assert json.loads(out["help"])["ok"], out["help"]
    assert "tomlkit" not in {m.split(".")[0] for m in out["modules"]}
    unit = tmp_path / "valve_t4.unit.toml"
    text = open("rulebases/valve_t4.unit.toml", encoding="utf-8").read()
    unit.write_text(text.replace("[evaluation]", "[evaluation", 1), encoding="utf-8")
    for name in ("valve_t4.matrix.toml", *(f"valve_t4_r{i}.toml" for i in range(1, 5))):
        (tmp_path / name).write_text(open(f"rulebases/{name}", encoding="utf-8").read())
    out = _probe("--rulebases", str(tmp_path), "unit", "check", str(unit), "--json")
    (problem,) = json.loads(out["help"])["problems"]
    line = text.splitlines().index("[evaluation]") + 1
    assert problem.startswith(f"{unit}:{line}: TOML syntax error: "), problem
