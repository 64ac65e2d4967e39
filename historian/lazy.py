"""Names a package loads on first use (PEP 562), so that importing a light module of it does
not pull in its heavy ones; the historian, the model seam and the simulators share it."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any


def lazy(package: str, table: str) -> tuple[Callable[[str], Any], list[str]]:
    """The package's ``__getattr__`` and ``__all__`` from ``table``: a line per submodule,
    ``module: Name Name …``."""
    where = {
        name: module.strip()
        for module, names in (line.split(":") for line in table.strip().splitlines())
        for name in names.split()
    }

    def __getattr__(name: str) -> Any:
        if name in where:
            return getattr(importlib.import_module(f"{package}.{where[name]}"), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return __getattr__, sorted(where)


class LazyModule:
    """A module imported on its first attribute's use (``sa = LazyModule("sqlalchemy")``,
    then ``sa.select(…)``): a module that needs a heavy one on some paths only does not
    import it with itself (issue 34: SQLAlchemy, on a SQLite historian's replay)."""

    def __init__(self, name: str) -> None:
        self.__dict__["_name"] = name

    def __getattr__(self, attr: str) -> Any:
        return getattr(importlib.import_module(self.__dict__["_name"]), attr)

    def __repr__(self) -> str:
        return f"<LazyModule {self.__dict__['_name']!r}>"
