"""``diag diagnose``'s read ahead: the historian's pieces read in a thread of their own, the
first from the moment the reader is made (issue 34, "Speed": a replay of 200,000 rows is
~1 s of start-up before the first row).

The command makes its :class:`ReadAhead` as soon as the unit is loaded, then does the rest
of its start-up — the library only the replay needs (``scipy.special``) and numba's target
registries (:func:`numba_ready`) — while the first piece is read: the
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
    ``numba.cpython.*`` and their typing), here while the first piece is read rather than
    after it arrived. A later kernel's first call finds them loaded (``refresh`` loads a
    registry once). Its BLAS check finds ``scipy.linalg.cython_blas`` loaded on its own
    (:func:`blas_alone`): the replay does not import ``scipy.linalg``."""
    from numba.core.registry import cpu_target

    blas_alone()
    cpu_target.target_context.refresh()


#: the module numba's BLAS check imports (``numba.np.linalg.ensure_blas``, run when its
#: registries load ``numba.np.arraymath``)
CYTHON_BLAS = "scipy.linalg.cython_blas"


def blas_alone() -> None:
    """``scipy.linalg.cython_blas`` loaded without ``scipy.linalg`` (issue 34, "Speed"): numba's
    registries import it to check that a BLAS is there, and importing it ran
    ``scipy.linalg``'s package first — ~0.1 CPU s of each ``diag diagnose`` (its modules
    parse their docstrings at import), for a replay that calls no function of it. The
    extension module alone is a few ms: the same module object (``sys.modules``), whose
    function table numba's compiled BLAS calls read. A later ``import scipy.linalg`` imports
    the package as usual, which finds the module loaded and holds it as its attribute
    (:class:`_BlasParent`). Where it cannot be found or loaded alone, nothing is done (numba
    imports it as before)."""
    import importlib.util
    import sys
    from importlib.machinery import PathFinder

    if CYTHON_BLAS in sys.modules or "scipy.linalg" in sys.modules:
        return
    try:
        import scipy

        pkg = PathFinder.find_spec("scipy.linalg", scipy.__path__)
        spec = pkg and PathFinder.find_spec(CYTHON_BLAS, pkg.submodule_search_locations)
        if spec is None or spec.loader is None:
            return
        module = importlib.util.module_from_spec(spec)
        sys.modules[CYTHON_BLAS] = module
        try:
            spec.loader.exec_module(module)
        except BaseException:
            del sys.modules[CYTHON_BLAS]
            raise
    except Exception:  # noqa: BLE001 - numba imports it the usual way then
        return
    sys.meta_path.insert(0, _BlasParent())


class _BlasParent:
    """The import of ``scipy.linalg`` after :func:`blas_alone`: the package as the path finder
    finds it, with ``cython_blas`` (loaded already) its attribute before its code runs, as an
    import of the submodule through the package would have set it. Used once."""

    def find_spec(self, name, path=None, target=None):
        import sys
        from importlib.machinery import PathFinder

        if name != "scipy.linalg":
            return None
        sys.meta_path.remove(self)
        spec = PathFinder.find_spec(name, path, target)
        blas = sys.modules.get(CYTHON_BLAS)
        if spec is None or spec.loader is None or blas is None:
            return spec
        run = spec.loader.exec_module

        def exec_module(module):
            module.cython_blas = blas
            run(module)

        spec.loader.exec_module = exec_module
        return spec
