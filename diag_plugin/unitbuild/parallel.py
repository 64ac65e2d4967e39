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

from diag_plugin.training.dask_connect import DASK_CONNECT_TIMEOUT, connect

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
    workers: int | DaskPool | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[Any]:
    """``[fn(item, *args) for item in items]``, on ``workers`` forked processes when more
    than one (and the platform forks), or on a Dask cluster (a :class:`DaskPool`), in
    order."""
    global _JOB
    if isinstance(workers, DaskPool):
        return workers.map(fn, items, args, progress)
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


#: seconds one map (one stage's tests) may take on the cluster before the build stops
DASK_MAP_TIMEOUT = 3600.0


#: arguments sent with each task as they are (small); any other is scattered once
_INLINE = (int, float, bool, str, bytes, type(None))


def _call(item: Any, fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(item, *args)`` on a Dask worker, BLAS held to one thread as in the local pool."""
    with one_blas_thread():
        return fn(item, *args)


class DaskPool:
    """The build's per-test work on a dask.distributed cluster (``diag unit build --dask``).

    Give it to :func:`map_tests` as ``workers``: each argument of a map (the window, the
    unit) is scattered to the workers once per build (by identity, to every worker so that a
    lost worker loses no copy), each test is one task, and the results are gathered in the
    tests' order, so the unit is the one the local pool builds. A worker lost mid-map has
    its tasks rerun by Dask on another worker (the scheduler's ``allowed-failures``); the
    tasks are pure functions of their arguments, so a rerun gives the same result.

    A cluster runs whatever its clients send: use only one you control (see
    docs/how-to/unit-from-history.md, "Speed"). Nothing here listens on a port.
    """

    def __init__(self, client: Any, address: str, map_timeout: float = DASK_MAP_TIMEOUT):
        self.client = client
        self.address = address
        self.map_timeout = map_timeout
        self._scattered: dict[int, tuple[Any, Any]] = {}  # id → (object, its future)
        self.scattered: list[str] = []  # the type of each object scattered, in order

    @classmethod
    def connect(cls, address: str, timeout: float = DASK_CONNECT_TIMEOUT) -> DaskPool:
        """A pool on the scheduler at ``address``, checked before any work
        (:func:`diag_plugin.training.dask_connect.connect`: reachable within ``timeout`` s, at least
        one worker, this package's version on every worker); raises
        :class:`~historian.errors.UserError` naming the address otherwise."""
        return cls(connect(address, timeout), address)

    def __enter__(self) -> DaskPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Release the scattered data and disconnect (the cluster itself keeps running)."""
        self.release()
        self.client.close()

    def release(self) -> None:
        """Let the cluster drop what was scattered (a build's end)."""
        self._scattered.clear()

    def _scatter(self, obj: Any) -> Any:
        got = self._scattered.get(id(obj))
        if got is None or got[0] is not obj:
            # in a list: a dict, list or tuple is one object, not one per element
            fut = self.client.scatter([obj], broadcast=True, hash=False)[0]
            got = self._scattered[id(obj)] = (obj, fut)
            self.scattered.append(type(obj).__name__)
        return got[1]

    def map(
        self,
        fn: Callable[..., Any],
        items: Sequence[Any],
        args: tuple = (),
        progress: Callable[[int, int], None] | None = None,
    ) -> list[Any]:
        """``[fn(item, *args) for item in items]`` on the cluster, in order. Raises
        :class:`~historian.errors.UserError` when the cluster fails the work (a task's
        own exception is raised as it is)."""
        from distributed import as_completed
        from distributed.client import FutureCancelledError
        from distributed.scheduler import KilledWorker

        from historian.errors import UserError

        n = len(items)
        if n == 0:
            return []
        shared = [a if isinstance(a, _INLINE) else self._scatter(a) for a in args]
        tag = f"{fn.__name__}-{os.urandom(4).hex()}"  # the tasks' keys: the map, the test
        futures = [
            self.client.submit(_call, it, fn, *shared, key=f"{tag}-{i}")
            for i, it in enumerate(items)
        ]
        try:
            done_in = as_completed(futures, loop=self.client.loop, timeout=self.map_timeout)
            for done, _ in enumerate(done_in, 1):
                if progress:
                    progress(done, n)
            return self.client.gather(futures)
        except TimeoutError:
            raise UserError(
                f"--dask {self.address}: {fn.__name__} of {n} tests not done within "
                f"{self.map_timeout:g} s"
            ) from None
        except (KilledWorker, FutureCancelledError, OSError) as exc:
            raise UserError(
                f"--dask {self.address}: the cluster lost the work ({type(exc).__name__}: {exc})"
            ) from None
        finally:
            self.client.cancel(futures)
