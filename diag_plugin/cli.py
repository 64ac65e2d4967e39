"""Command-line interface ``diag``.

Each area of the product contributes its sub-commands through a module-level
``add_commands(subparsers)`` function; this module only assembles them, sets up
logging and turns errors into a clear message and a non-zero exit status.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Sequence

from historian.errors import UserError

log = logging.getLogger("diag")

#: modules that contribute sub-commands (each has ``add_commands(subparsers)``)
COMMAND_MODULES: tuple[str, ...] = (
    "diag_plugin.simulate.cli",
    "diag_plugin.rulebase.cli",
    "diag_plugin.examples.cli",
    "historian.cli",
    "diag_plugin.training.cli",
    "diag_plugin.workbench.cli",
    "diag_plugin.diagnose.cli",
    "diag_plugin.live.cli",
    "diag_plugin.engine.cli",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="diag", description="Fuzzy-model diagnostics for process plants."
    )
    parser.add_argument(
        "--db",
        default=os.environ.get("DIAG_DB", "sqlite:///diag.db"),
        help="historian database URL (env DIAG_DB; default sqlite:///diag.db)",
    )
    parser.add_argument(
        "--rulebases",
        default=os.environ.get("DIAG_RULEBASES", "rulebases"),
        help="rule-base folder (env DIAG_RULEBASES; default ./rulebases)",
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        # an import error here is a bug, never a reason to drop a command group silently
        importlib.import_module(name).add_commands(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.WARNING - 10 * min(args.verbose, 2),
        format="%(levelname)s %(name)s: %(message)s",
    )
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        rc = args.func(args)
    except UserError as exc:
        print(f"diag: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # output piped into `head` and the like: stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except Exception as exc:
        if type(exc).__module__.startswith(("sqlalchemy", "psycopg", "adbc")):
            # an unreachable or broken database: say which, without a traceback
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            print(f"diag: database error ({_safe(args.db)}): {first}", file=sys.stderr)
            return 3
        raise
    return int(rc or 0)


def _safe(url: str) -> str:
    try:
        from sqlalchemy.engine import make_url

        return make_url(url).render_as_string(hide_password=True)
    except Exception:  # noqa: BLE001 - not a URL: show nothing of it
        return "the --db URL"


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
