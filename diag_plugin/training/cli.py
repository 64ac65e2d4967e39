"""``diag train NAME|--all`` and ``diag experiments NAME``: the arguments only.

The jobs themselves live in :mod:`diag_plugin.training.jobs`, imported when a command runs, so
building the ``diag`` parser loads no pandas, SQLAlchemy, numba or rich.
"""

from __future__ import annotations

import argparse

from diag_plugin.cliargs import add_json
from diag_plugin.training.dask_connect import add_dask_args


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("train", help="train a model (or --all) from the historian")
    p.add_argument("name", nargs="?", help="model name in the rule-base folder, or a file")
    p.add_argument("--all", action="store_true", help="retrain every model in the folder")
    p.add_argument("--from", dest="start", help="start of the training range (default: all)")
    p.add_argument("--to", dest="end", help="end of the training range")
    p.add_argument(
        "--holdout",
        type=float,
        default=0.2,
        help="share of the range, at its end, held out to validate (default 0.2; 0: train on "
        "all of it, no validation figure)",
    )
    p.add_argument(
        "--chunk",
        help="time span read at once (default: 262,144 periods of the model, 30 days at 10 s)",
    )
    p.add_argument(
        "--no-baseline",
        action="store_true",
        help="skip scikit-learn's HistGradientBoosting on the same rows beside the held-out error",
    )
    add_dask_args(p, "the chunks' training")
    p.add_argument(
        "--engine",
        choices=["local", "dask"],
        default="local",
        help="deprecated: say --dask ADDRESS (--engine dask alone: a cluster in this process)",
    )
    p.add_argument(
        "--scheduler", metavar="ADDRESS", help="deprecated: say --dask ADDRESS (the same)"
    )
    add_json(p, "print the result as JSON")
    p.set_defaults(func=cmd_train)
    p = sub.add_parser("experiments", help="versions of a model with inputs and error")
    p.add_argument("name")
    add_json(p)
    p.set_defaults(func=cmd_experiments)


def cmd_train(args: argparse.Namespace) -> int:
    from diag_plugin.training.jobs import cmd_train

    return cmd_train(args)


def cmd_experiments(args: argparse.Namespace) -> int:
    from diag_plugin.training.jobs import cmd_experiments

    return cmd_experiments(args)
