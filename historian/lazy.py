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
