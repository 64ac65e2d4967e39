"""The model seam: the protocol every identification method implements, the shell of a model
file that all methods share, and the registry from a file's method name to its estimator and
file codec.

The names below load on first use, so a light submodule (the registry the ``diag`` parser
takes its ``--method`` choices from) does not pull in numpy through the protocol.
"""

from __future__ import annotations

import importlib

_LAZY = {
    "Capabilities": "protocol",
    "Model": "protocol",
    "Prediction": "protocol",
    "METHODS": "registry",
    "Method": "registry",
    "get_method": "registry",
    "ModelSpec": "spec",
    "Variable": "spec",
}
__all__ = sorted(_LAZY)


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
