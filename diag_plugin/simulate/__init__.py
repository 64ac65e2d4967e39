"""Simulators of plant units; first the DAMADICS servomotor–valve assembly.

``simulate_valve`` returns months of measured tags (CV, P1, P2, T1, X, F, P0, Pch)
with the DAMADICS faults f1–f19 on demand; ``diag simulate`` writes them to a file.
``simulate_chemplant`` is a chemical plant with recycle (44 tags, 15 fault types).

The names below load on first use, so ``diag`` building its parser (which imports
``diag_plugin.simulate.cli``) does not pull in numba, pandas and scipy.signal.
"""

from __future__ import annotations

import importlib

_LAZY = {
    "FAULTS": "faults",
    "FaultSpec": "faults",
    "fault_truth": "faults",
    "parse_fault": "faults",
    "TAGS": "valve",
    "ValveParams": "valve",
    "simulate_valve": "valve",
    "EngineFault": "engine",
    "simulate_engine": "engine",
    "CHEMPLANT_TAGS": "chemplant",
    "simulate_chemplant": "chemplant",
}
__all__ = sorted(_LAZY)


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
