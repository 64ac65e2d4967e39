"""The build's per-test work on every core (issue 34, speed).

Each test's choice of inputs is independent of the others' (it reads the shared window and
writes its own :class:`~diag_plugin.unitbuild.build.TestChoice`), and so are the training of
its model (which writes its own model file) and its cross-fitted residuals for the thresholds
(:func:`~diag_plugin.learn.thresholds.test_residuals`), so :func:`map_tests` runs each of
the three in a pool of worker processes — forked, so each worker starts with the window (and
the unit) already in memory; only the test names or choices go out and the results come back
(a trained test's model too, as the unit reads it from the file the worker wrote and read
back: the parent parses no model file; an in-memory transfer between our own processes, never
a file a user loads).
The workers' results are assembled in the tests' order, so the unit is the same as one process
builds.

Each process (the parent too, :func:`one_blas_thread`) keeps BLAS to one thread: the build
makes thousands of small dense solves (a Wang–Mendel model's coarse levels, fitted for every
candidate), which on a loaded machine run 10–100 times slower when BLAS starts a thread per
core for each (measured: 0.7 ms → 92 ms for a 100 × 100 solve at a load of 19 on 2 cores).
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
from collections.abc import Callable, Iterator, Sequence
from typing import Any

log = logging.getLogger(__name__)

#: the function and arguments the forked workers call (set before the pool forks)
_JOB: tuple[Callable[..., Any], tuple] | None = None


def default_workers() -> int:
    """Worker processes: the cores this process may use (``DIAG_WORKERS`` overrides)."""
    env = os.environ.get("DIAG_WORKERS")
    if env and env.isdigit() and int(env) > 0:
        return int(env)
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """BLAS and OpenMP pools held to one thread (no-op without threadpoolctl)."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - threadpoolctl is a dependency
        yield
        return
    with threadpool_limits(1):
        yield


def _run(item: Any) -> Any:
    fn, args = _JOB
    with one_blas_thread():
        return fn(item, *args)


def map_tests(
    fn: Callable[..., Any],
    items: Sequence[Any],
    args: tuple = (),
    *,
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[Any]:
    """``[fn(item, *args) for item in items]``, on ``workers`` forked processes when more
    than one (and the platform forks), in order."""
    global _JOB
    workers = default_workers() if workers is None else workers
    n = len(items)
    if workers <= 1 or n <= 1 or "fork" not in multiprocessing.get_all_start_methods():
        out = []
        with one_blas_thread():
            for i, it in enumerate(items):
                out.append(fn(it, *args))
                if progress:
                    progress(i + 1, n)
        return out
    from concurrent.futures import ProcessPoolExecutor

    _JOB = (fn, args)
    try:
        ctx = multiprocessing.get_context("fork")
        with ProcessPoolExecutor(min(workers, n), mp_context=ctx) as pool:
            out = []
            for i, r in enumerate(pool.map(_run, items, chunksize=1)):
                out.append(r)
                if progress:
                    progress(i + 1, n)
            return out
    finally:
        _JOB = None
