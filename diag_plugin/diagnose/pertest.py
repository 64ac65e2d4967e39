"""A replay's per-test work shared between the calling thread and helper threads (issue 34,
"Speed": ``diag diagnose`` of a 50-tag unit at 100,000 rows/s on 2 cores).

:meth:`~diag_plugin.diagnose.unit.Unit._residuals` computes, test by test, the design
matrix, the Wang–Mendel inference and the residual of a piece, each test writing its own row
of the residuals. The inference and the residual are compiled loops that release the GIL
(``nogil``): about two thirds of a replay's CPU. :func:`each` runs the tests' rows in the
calling thread and ``workers - 1`` helpers, each taking the next test not yet taken: every
row is written by the same code on the same inputs, so the residuals are the same bits
however many threads and in whatever order they ran (tests/test_diagnose_pertest.py).
"""

from __future__ import annotations

import contextvars
import itertools
import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

#: the helper threads, made at the first call that asks for them and kept for the process's
#: life (a replay calls :func:`each` once a piece); ``workers - 1`` of them at most
_pool: ThreadPoolExecutor | None = None
_pool_size = 0


def cores() -> int:
    """The cores this process may run on."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1  # pragma: no cover


def _helpers(n: int) -> ThreadPoolExecutor:
    """A pool of at least ``n`` helper threads."""
    global _pool, _pool_size
    if _pool is None or _pool_size < n:
        if _pool is not None:
            _pool.shutdown(wait=True)
        _pool = ThreadPoolExecutor(n, thread_name_prefix="diagnose-tests")
        _pool_size = n
    return _pool


def each(row: Callable[[int], None], n: int, workers: int = 1) -> None:
    """``row(j)`` for every ``j < n``: in this thread alone where ``workers`` is 1 (in
    order), else in this thread and ``workers - 1`` helpers, each taking the next ``j``
    (``itertools.count`` hands each ``j`` out once under the GIL). The helpers run in a copy
    of this thread's context (context variables the inference reads). Returns when every
    row is done; the first error raised by a row is raised here after the others stopped."""
    helpers = min(workers, n) - 1
    if helpers <= 0:
        for j in range(n):
            row(j)
        return
    todo = itertools.count()
    failed: list[BaseException] = []

    def work() -> None:
        while not failed and (j := next(todo)) < n:
            try:
                row(j)
            except BaseException as exc:
                failed.append(exc)
                raise

    pool = _helpers(helpers)
    futures = [pool.submit(contextvars.copy_context().run, work) for _ in range(helpers)]
    try:
        work()
    finally:
        for f in futures:  # no helper writes after this returns
            f.exception()
    if failed:
        raise failed[0]
