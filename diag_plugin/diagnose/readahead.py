"""``diag diagnose``'s read ahead: the historian's pieces read in a thread of their own, the
first from the moment the reader is made (issue 34, "Speed": a replay of 200,000 rows is
~1 s of start-up before the first row).

The command makes its :class:`ReadAhead` as soon as the unit is loaded, then does the rest
of its start-up — the libraries only the replay needs (``scipy.linalg``, ``scipy.special``)
and numba's target registries (:func:`numba_ready`) — while the first piece is read: the
historian's SQLite queries run outside the GIL, so the two overlap where they waited for
each other before (the read started after the last import).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import Any


class ReadAhead:
    """Iterate ``items`` while a thread already reads the next ones, up to ``ahead`` of them
    (one at a time, in order); the first read starts when the reader is made. ``None`` from
    ``items`` ends it (as a piece never is). :meth:`close` (or the ``with`` block's end)
    waits for a read under way and closes ``items``: the historian a generator of pieces
    holds open.

    Two ahead by default (issue 34, "Speed"): with one, the thread read the command's small
    first piece (:func:`~diag_plugin.diagnose.cli.ramped`) and then waited for the
    start-up's end (``scipy.special``, numba's registries: ~0.25 CPU s) to be asked for the
    second, a whole piece, whose read the first replay then waited for; now that read runs
    beside the start-up, on the other core. One more piece is held (46 tags × 41,680 rows:
    15 MB)."""

    def __init__(self, items: Iterable[Any], ahead: int = 2) -> None:
        self._items = iter(items)
        self._ex = ThreadPoolExecutor(1, thread_name_prefix="diagnose-read")
        self._next = deque(self._ex.submit(next, self._items, None) for _ in range(max(1, ahead)))

    def __iter__(self) -> Iterator[Any]:
        while (item := self._next.popleft().result()) is not None:
            self._next.append(self._ex.submit(next, self._items, None))
            yield item

    def close(self) -> None:
        """Wait for the read under way (if any), stop the thread, close ``items``."""
        self._ex.shutdown(wait=True, cancel_futures=True)
        close = getattr(self._items, "close", None)
        if close is not None:
            close()

    def __enter__(self) -> ReadAhead:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def numba_ready() -> None:
    """numba's CPU target with its registries loaded (``BaseContext.refresh``), what the
    first call of a compiled kernel does first: ~0.1 CPU s (it imports ``numba.np.*``,
    ``numba.cpython.*``, their typing, and ``scipy.linalg`` for the BLAS check), here while
    the first piece is read rather than after it arrived. A later kernel's first call finds
    them loaded (``refresh`` loads a registry once)."""
    from numba.core.registry import cpu_target

    cpu_target.target_context.refresh()
