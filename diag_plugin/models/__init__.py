"""The model seam: the protocol every identification method implements, the shell of a model
file that all methods share, and the registry from a file's method name to its estimator and
file codec.

The names below load on first use, so a light submodule (the registry the ``diag`` parser
takes its ``--method`` choices from) does not pull in numpy through the protocol.
"""

from __future__ import annotations

from historian.lazy import lazy

__getattr__, __all__ = lazy(
    __name__,
    """
protocol: Capabilities Model Prediction
registry: METHODS Method get_method
spec: ModelSpec Variable
""",
)
