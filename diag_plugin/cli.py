"""Command-line interface ``diag``.

Each area of the product contributes its sub-commands through a module-level
``add_commands(subparsers)`` function; this module only assembles them, sets up
logging and turns errors into a clear message and a non-zero exit status.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import os
import sys
from collections.abc import Sequence

from historian.errors import UserError

#: every command: the modules that add it (``add_commands(subparsers)``; ``diag unit``'s
#: actions come from three packages) and its one-line help. ``diag --help`` lists them from
#: here without importing any command module, and ``diag COMMAND …`` imports only the modules
#: of COMMAND (start-up, issues 8 and 37); tests/test_startup.py checks that this table says
#: what the modules register.
COMMANDS: dict[str, tuple[tuple[str, ...], str]] = {
    "simulate": (
        ("diag_plugin.simulate.cli",),
        "simulate a plant (the DAMADICS servomotor-valve assembly by default)",
    ),
    "rules": (("diag_plugin.rulebase.cli",), "check, show and export rule-base files"),
    "demo": (
        ("diag_plugin.examples.cli",),
        "simulate, train, compare, explain: the product end to end",
    ),
    "import": (
        ("historian.cli",),
        "import a wide CSV or Parquet file (time column + one column per tag)",
    ),
    "tags": (("historian.cli",), "list tags with ranges, coverage and data quality"),
    "historian": (
        ("historian.cli",),
        "roll closed months to the Parquet cold store, check the store, reclaim space",
    ),
    "train": (("diag_plugin.training.cli",), "train a model (or --all) from the historian"),
    "experiments": (("diag_plugin.training.cli",), "versions of a model with inputs and error"),
    "model": (("diag_plugin.workbench.cli",), "create a model or change its inputs"),
    "compare": (("diag_plugin.workbench.cli",), "model against measurements: where it fails"),
    "explain": (("diag_plugin.workbench.cli",), "rank candidate missing effects"),
    "report": (("diag_plugin.workbench.cli",), "self-contained HTML report"),
    "unit": (
        ("diag_plugin.diagnose.cli", "diag_plugin.learn.cli", "diag_plugin.unitbuild.cli"),
        "create, check, show a unit or learn its thresholds",
    ),
    "diagnose": (("diag_plugin.diagnose.cli",), "replay historian data through a unit"),
    "benchmark": (
        ("diag_plugin.bench.cli",),
        "DAMADICS faults f1–f19 against a unit, scored with the benchmark indexes; or "
        "(--plant chemplant) a unit built from the plant's history beside PCA and DPCA",
    ),
    "run": (
        ("diag_plugin.live.cli",),
        "run the live plug-in (no --config: the embedded plant with a scripted fault)",
    ),
    "engine-fdi": (("diag_plugin.engine.cli",), "the seed's engine FDI experiment (Table II)"),
    "compare-methods": (
        ("diag_plugin.engine.cli",),
        "train every method on a model's data (Figs. 3-7)",
    ),
}

#: modules that contribute sub-commands (each has ``add_commands(subparsers)``)
COMMAND_MODULES: tuple[str, ...] = tuple(
    dict.fromkeys(m for mods, _ in COMMANDS.values() for m in mods)
)

#: global options that take a value (skipped when looking for the command word)
_VALUED = ("--db", "--rulebases")


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The ``diag`` parser. Without ``argv``: every command, fully built. With ``argv``: only
    what parsing it needs: the command module of its command word, or (no command word, as
    in ``diag --help``) the command list alone, from :data:`COMMANDS`."""
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
    word = None if argv is None else _command_word(argv)
    if argv is not None and word is None:
        for name, (_, text) in COMMANDS.items():
            sub.add_parser(name, help=text)
        return parser
    modules = COMMANDS[word][0] if word in COMMANDS else COMMAND_MODULES
    for name in modules:
        # an import error here is a bug, never a reason to drop a command group silently
        importlib.import_module(name).add_commands(sub)
    return parser


def _command_word(argv: Sequence[str]) -> str | None:
    """The first argument that is not a global option (nor its value); None when there is
    none or a ``-h``/``--help`` comes first (the top-level help lists every command)."""
    it = iter(argv)
    for arg in it:
        if arg in ("-h", "--help"):
            return None
        if len(arg) > 2 and "=" not in arg and any(v.startswith(arg) for v in _VALUED):
            next(it, None)  # --db URL, or an abbreviation argparse accepts (--rule DIR)
        elif not arg.startswith("-"):
            return arg
    return None


#: the Arrow memory pool a ``diag`` process uses unless ``ARROW_DEFAULT_MEMORY_POOL`` says
#: another: the C library's allocator. With pyarrow's default (mimalloc) the per-tag threads
#: of a window read from the cold store cost 0.51 s CPU instead of 0.36 s for six months of
#: four tags (pages given back and faulted in again); with this one 0.38 s (issue 37)
ARROW_POOL = "system"


def arrow_pool_default(environ, modules) -> None:
    """Choose :data:`ARROW_POOL` for this process where the user chose none; only before
    pyarrow is loaded (it reads the setting once, at its import)."""
    if "pyarrow" not in modules:
        environ.setdefault("ARROW_DEFAULT_MEMORY_POOL", ARROW_POOL)


#: exit statuses, the one contract of every command (docs/reference/cli.md)
EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_ENVIRONMENT = 0, 1, 2, 3


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command; returns its exit status: 0 done, 1 the job failed, 2 bad usage or
    input (the message says what and where), 3 the environment (database unreachable, port
    busy). No traceback reaches the user unless ``-vv`` asks for one."""
    if argv is None:
        argv = sys.argv[1:]
    arrow_pool_default(os.environ, sys.modules)
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    import logging  # after parsing: `diag --help` and usage errors never need it

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
    if type(exc).__module__.startswith(("sqlalchemy", "psycopg", "adbc", "sqlite3")):
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
    import logging

    logging.getLogger("diag").debug("internal error", exc_info=exc)
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
