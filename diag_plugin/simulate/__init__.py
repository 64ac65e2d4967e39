"""Simulators of plant units; first the DAMADICS servomotor–valve assembly.

``simulate_valve`` returns months of measured tags (CV, P1, P2, T1, X, F, P0, Pch)
with the DAMADICS faults f1–f19 on demand; ``diag simulate`` writes them to a file.
``simulate_chemplant`` is a chemical plant with recycle (44 tags, 15 fault types).

The names below load on first use, so ``diag`` building its parser (which imports
``diag_plugin.simulate.cli``) does not pull in numba, pandas and scipy.signal.
"""

from __future__ import annotations

from historian.lazy import lazy

__getattr__, __all__ = lazy(
    __name__,
    """
faults: FAULTS FaultSpec fault_truth parse_fault
valve: TAGS ValveParams simulate_valve
engine: EngineFault simulate_engine
chemplant: CHEMPLANT_TAGS simulate_chemplant
""",
)
