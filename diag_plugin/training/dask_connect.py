"""One way to reach a Dask cluster for every command that scales out (issue 34).

``diag unit build`` and ``diag train`` both take ``--dask ADDRESS [--dask-timeout S]``
(:func:`add_dask_args`) and connect through :func:`connect`, which checks the cluster before
any work: the scheduler answers within the timeout, at least one worker is there, and every
worker runs this package's version (a worker with another version would build another
model, or fail deep in a task). Each failure is a :class:`~historian.errors.UserError`
(exit 2) naming the address. ``diag train``'s spelling before it, ``--engine dask
[--scheduler ADDRESS]``, still works (:func:`dask_address`) and is marked deprecated in
its ``--help``.

A cluster runs whatever its clients send: use only one you control
(docs/how-to/unit-from-history.md, "Speed"). Nothing here listens on a port.
"""

from __future__ import annotations

import argparse
import logging
import sys
from typing import Any

log = logging.getLogger(__name__)

#: seconds to reach the scheduler and to see a worker there (``--dask-timeout``)
DASK_CONNECT_TIMEOUT = 10.0


def add_dask_args(p: argparse.ArgumentParser, work: str) -> None:
    """``--dask ADDRESS`` and ``--dask-timeout S`` on a command's parser; ``work`` says
    what runs on the cluster (for the help)."""
    p.add_argument(
        "--dask",
        metavar="ADDRESS",
        help=f"run {work} on the Dask scheduler at ADDRESS, e.g. tls://HOST:8786: the same "
        "result as on this machine; only a cluster you control (it runs what clients send; "
        "docs/how-to/unit-from-history.md)",
    )
    p.add_argument(
        "--dask-timeout",
        type=float,
        default=DASK_CONNECT_TIMEOUT,
        metavar="S",
        help=f"seconds to reach the scheduler and see a worker there ({DASK_CONNECT_TIMEOUT:g})",
    )


def dask_address(args: argparse.Namespace) -> str | None:
    """The scheduler address a command was given: ``--dask``, or ``diag train``'s deprecated
    ``--engine dask --scheduler ADDRESS`` (``--scheduler`` alone says it too); ``local``
    for the deprecated ``--engine dask`` without an address (a cluster in this process);
    None to work on this machine. Two different addresses are refused."""
    from historian.errors import UserError

    old = getattr(args, "scheduler", None)
    engine = getattr(args, "engine", "local")
    if old or engine == "dask":
        print(  # to the user, whatever the log level
            "note: --engine dask and --scheduler are deprecated: say --dask ADDRESS "
            "[--dask-timeout S], as diag unit build does",
            file=sys.stderr,
        )
    if args.dask and old and args.dask != old:
        raise UserError(f"--dask {args.dask} and --scheduler {old}: give one address")
    if args.dask or old:
        return args.dask or old
    return "local" if engine == "dask" else None


def check_timeout(timeout: float) -> None:
    """Refuse a ``--dask-timeout`` that is not a positive number of seconds."""
    from historian.errors import UserError

    if not timeout > 0:
        raise UserError(f"--dask-timeout {timeout:g}: must be positive")


def package_version() -> str:
    """This package's installed version (the client's and each worker's must agree)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("diag-plugin")
    except PackageNotFoundError:  # pragma: no cover - run from a source tree
        return "unknown"


def connect(address: str, timeout: float = DASK_CONNECT_TIMEOUT) -> Any:
    """A ``distributed.Client`` of the scheduler at ``address``, checked before any work:
    reachable within ``timeout`` s, at least one worker there (waited for up to ``timeout``
    s), and this package's version on every worker. Raises
    :class:`~historian.errors.UserError` naming the address otherwise (the client closed).
    The caller closes the client (the cluster itself keeps running)."""
    from distributed import Client

    from historian.errors import UserError

    check_timeout(timeout)
    mine = package_version()
    try:
        client = Client(address, timeout=f"{timeout}s", set_as_default=False)
    except Exception as exc:  # noqa: BLE001 - refused, timed out, a bad address or TLS
        hint = ""
        if address.startswith("tls://"):
            hint = "; a tls:// address needs the distributed.comm.tls settings"
        raise UserError(
            f"--dask {address}: cannot reach the Dask scheduler within {timeout:g} s "
            f"({type(exc).__name__}: {exc}){hint}"
        ) from None
    try:
        try:
            client.wait_for_workers(1, timeout=timeout)
        except (TimeoutError, OSError):
            raise UserError(
                f"--dask {address}: the scheduler has no worker after {timeout:g} s"
            ) from None
        try:
            versions = client.run(package_version)
        except Exception as exc:  # noqa: BLE001 - a worker without the package
            raise UserError(
                f"--dask {address}: the workers cannot import diag_plugin ({exc}); "
                f"install diag-plugin {mine} on every worker"
            ) from None
        other = {w: v for w, v in versions.items() if v != mine}
        if other:
            raise UserError(
                f"--dask {address}: workers run diag-plugin "
                + ", ".join(sorted(set(other.values())))
                + f", this client {mine}: install the same version on every worker"
            )
    except BaseException:
        client.close()
        raise
    log.info("Dask scheduler %s: %d workers", address, len(versions))
    return client
