"""From the method name a model file names to the estimator and the file codec that serve it.

Adding a method is a new module with its estimator and codec, and one line here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Method:
    """A method name, the module that implements it and its codec's class name."""

    name: str
    module: str
    codec: str
    summary: str
    #: an identification method (trained from data on any inputs): `diag compare-methods`
    #: trains these; the others serve a fixed structure (``track``: a loop at its set-point)
    identifies: bool = True

    def load(self) -> Any:
        """The codec instance (imported on first use: a CLI start loads no method)."""
        import importlib

        return getattr(importlib.import_module(self.module), self.codec)(self.name)


METHODS: dict[str, Method] = {
    m.name: m
    for m in (
        Method("wm-avg", "diag_plugin.fuzzy.wm_codec", "WangMendelCodec", "averaged Wang–Mendel"),
        Method("wm", "diag_plugin.fuzzy.wm_codec", "WangMendelCodec", "classic Wang–Mendel"),
        Method("ts-fcm", "diag_plugin.fuzzy.ts_fcm", "TakagiSugenoCodec", "Takagi–Sugeno, c-Means"),
        Method("narmax2", "diag_plugin.models.narmax", "NarmaxCodec", "2nd-order NARMAX"),
        Method("linear", "diag_plugin.models.linear", "LinearCodec", "linear (eq. 12, 1st order)"),
        Method(
            "joint",
            "diag_plugin.models.joint",
            "JointCodec",
            "joint test of a collinear group: its score on the first principal component",
            identifies=False,
        ),
        Method(
            "track",
            "diag_plugin.models.track",
            "TrackCodec",
            "control loop: the measurement at its set-point plus the loop's offset",
            identifies=False,
        ),
    )
}


def get_method(name: str):
    """The codec of a method name, or ``KeyError`` naming the known ones."""
    try:
        return METHODS[name].load()
    except KeyError:
        raise KeyError(f"unknown method {name!r} (known: {', '.join(METHODS)})") from None
