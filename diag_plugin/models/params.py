"""scikit-learn's parameter protocol, shared by every estimator of the model seam."""

from __future__ import annotations

from typing import Any, Self


class ParamsMixin:
    """``get_params`` / ``set_params`` over the constructor arguments named in ``_params``
    (scikit-learn convention: the constructor only stores them)."""

    _params: tuple[str, ...] = ()

    def _keep(self, args: dict[str, Any]) -> None:
        """Store each constructor argument under its own name, as given (call with
        ``locals()``): all a scikit-learn constructor does."""
        for k in self._params:
            setattr(self, k, args[k])

    def get_params(self, deep: bool = True) -> dict[str, Any]:
        """Constructor parameters (scikit-learn convention)."""
        return {k: getattr(self, k) for k in self._params}

    def set_params(self, **params: Any) -> Self:
        for k, v in params.items():
            if k not in self._params:
                raise ValueError(f"unknown parameter {k!r}")
            setattr(self, k, v)
        return self
