"""Command-line interface ``diag``.

Each area of the product contributes its sub-commands through a module-level
``add_commands(subparsers)`` function; this module only assembles them, sets up
logging and turns errors into a clear message and a non-zero exit status.
"""

from __future__ import annotations

import argparse
import errno
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
    "diag_plugin.learn.cli",
    "diag_plugin.unitbuild.cli",
    "diag_plugin.bench.cli",
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


#: exit statuses, the one contract of every command (docs/cli.md)
EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_ENVIRONMENT = 0, 1, 2, 3


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command; returns its exit status: 0 done, 1 the job failed, 2 bad usage or
    input (the message says what and where), 3 the environment (database unreachable, port
    busy). No traceback reaches the user unless ``-vv`` asks for one."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.WARNING - 10 * min(args.verbose, 2),
        format="%(levelname)s %(name)s: %(message)s",
    )
    if not getattr(args, "func", None):
        parser.print_help()
        return EXIT_USAGE
    try:
        rc = args.func(args)
    except UserError as exc:
        print(f"diag: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # output piped into `head` and the like: stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except Exception as exc:  # noqa: BLE001 - every error becomes a message and a status
        return _failure(args, exc)
    return int(rc or 0)


def _failure(args: argparse.Namespace, exc: Exception) -> int:
    """The message and exit status of an error no command turned into a UserError."""
    first = _first_line(exc)
    if type(exc).__module__.startswith(("sqlalchemy", "psycopg", "adbc")):
        # an unreachable or broken database: say which, without a traceback
        print(f"diag: database error ({_safe(args.db)}): {first}", file=sys.stderr)
        return EXIT_ENVIRONMENT
    if isinstance(exc, OSError) and exc.errno in (errno.EADDRINUSE, errno.EADDRNOTAVAIL):
        print(f"diag: error: a port is busy or not available here: {first}", file=sys.stderr)
        return EXIT_ENVIRONMENT
    if isinstance(exc, (ConnectionError, TimeoutError, PermissionError)):
        print(f"diag: error: {first}", file=sys.stderr)
        return EXIT_ENVIRONMENT
    if isinstance(exc, (ValueError, KeyError, LookupError, FileNotFoundError, IsADirectoryError)):
        print(f"diag: error: {first}", file=sys.stderr)
        return EXIT_USAGE
    log.debug("internal error", exc_info=exc)
    print(
        f"diag: internal error: {type(exc).__name__}: {first}"
        + ("" if args.verbose >= 2 else " (diag -vv … shows where)"),
        file=sys.stderr,
    )
    if args.verbose >= 2:
        import traceback

        traceback.print_exception(exc, file=sys.stderr)
    return EXIT_FAILED


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().strip("'\"")
    return text.splitlines()[0] if text else type(exc).__name__


def _safe(url: str) -> str:
    try:
        from sqlalchemy.engine import make_url

        return make_url(url).render_as_string(hide_password=True)
    except Exception:  # noqa: BLE001 - not a URL: show nothing of it
        return "the --db URL"


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
