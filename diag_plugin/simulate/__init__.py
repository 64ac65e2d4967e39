"""Simulators of plant units; first the DAMADICS servomotor–valve assembly.

``simulate_valve`` returns months of measured tags (CV, P1, P2, T1, X, F, P0, Pch)
with the DAMADICS faults f1–f19 on demand; ``diag simulate`` writes them to a file.
"""

from .faults import FAULTS, FaultSpec, fault_truth, parse_fault
from .valve import TAGS, ValveParams, simulate_valve

__all__ = [
    "FAULTS",
    "TAGS",
    "FaultSpec",
    "ValveParams",
    "fault_truth",
    "parse_fault",
    "simulate_valve",
]
