"""``diag demo``: the arguments only; :mod:`diag_plugin.examples.demo` runs it."""

from __future__ import annotations

import argparse


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="simulate, train, compare, explain: the product end to end")
    p.add_argument("--days", type=float, default=28.0, help="days of 10 s data to simulate")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--workdir", default="out/demo", help="folder for the demo's database and files")
    p.set_defaults(func=cmd_demo)


def cmd_demo(args: argparse.Namespace) -> int:
    from diag_plugin.examples.demo import cmd_demo as run

    return run(args)
