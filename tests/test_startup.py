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
    "unit build": ["unit", "build", "u", "--from", "2026-01-01", "--to", "2026-01-02"],
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
