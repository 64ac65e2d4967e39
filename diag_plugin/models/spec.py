"""The shell every model file shares, whatever its method: variables and the model spec."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass
class Variable:
    """One model variable: its spec (``CV[k-1]``), set labels, unit, nominal span and sets."""

    spec: str
    label: str
    unit: str
    span: tuple[float, float]
    sets: int = 31

    @property
    def width(self) -> int:
        return max(2, len(str(self.sets - 1)))

    def set_label(self, i: int) -> str:
        return f"{self.label}{i:0{self.width}d}"

    def parse_label(self, text: str) -> int | None:
        if not text.startswith(self.label):
            return None
        rest = text[len(self.label) :]
        if not rest.isdigit():
            return None
        i = int(rest)
        return i if 0 <= i < self.sets else None


@dataclass
class ModelSpec:
    """What a model is, apart from what it learned: output, inputs, method and its options."""

    name: str
    output: Variable
    inputs: list[Variable] = field(default_factory=list)
    method: str = "wm-avg"
    shape: str = "trapezoidal"
    period: str = "10s"
    #: the method's own options (every key of the file's ``[rules]`` table but ``list``)
    options: dict[str, Any] = field(default_factory=dict)
