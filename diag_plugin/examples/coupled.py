"""A small coupled process of six tags for units made of one model per tag (issue 25).

Two driven inputs A, B (set-points held 30–240 min, 5-min lags) and four tags computed from them
in a chain, each measured with its own noise, sampled every minute::

    C = 0.8 A + 0.6 B + 0.004 A B      D = 1.1 C − 0.5 B + 40
    E = 0.7 D + 0.9 A + 20             F = 0.5 E + 0.4 C + 30

:data:`TESTS` is a unit of five wm-avg models, one per tag but B, each from the tags the process
couples it to (as a unit built from the plant's history would choose them). :func:`process`
simulates it with sensor biases from an onset; :func:`build` trains the models and writes the
unit file. Used by ``tests/test_unit_tags.py`` and ``benchmarks/bench_unit_tags.py``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from diag_plugin.diagnose.unitfile import new_unit_text
from diag_plugin.examples.rigs import held_levels
from diag_plugin.training.chunked import train
from diag_plugin.workbench.model_edit import new_model

START = pd.Timestamp("2026-05-04", tz="UTC")
TAGS = {"A": (0, 100), "B": (0, 100), "C": (0, 200), "D": (0, 200), "E": (0, 300), "F": (0, 300)}
#: test → (output, inputs): each tag from the tags the process couples it to
TESTS = {
    "rA": ("A[k]", ["C[k]", "B[k]"]),
    "rC": ("C[k]", ["A[k]", "B[k]"]),
    "rD": ("D[k]", ["C[k]", "B[k]"]),
    "rE": ("E[k]", ["D[k]", "A[k]"]),
    "rF": ("F[k]", ["E[k]", "C[k]"]),
}
DAY = 1440  # samples a day at 60 s


def process(
    n: int,
    seed: int,
    bias: dict[str, float] | None = None,
    onset: int = 0,
    *,
    loss: float = 0.0,
):
    """``n`` minutes of the process: A, B follow set-points held 30–240 min (5 min lags), the
    others are static couplings (one bilinear). Faults from sample ``onset`` on: ``bias``,
    sensor offsets per tag; ``loss``, a process fault: D's gain on C falls by that share (and
    E, F downstream follow the true D)."""
    rng = np.random.default_rng([seed, 25])

    def steps(lo: float, hi: float) -> np.ndarray:
        return held_levels(rng, n, lo, hi, (30, 240))

    def lag(x: np.ndarray, tau: float) -> np.ndarray:
        a = math.exp(-1 / tau)
        y = np.empty_like(x)
        v = x[0]
        for k in range(len(x)):
            v = a * v + (1 - a) * x[k]
            y[k] = v
        return y

    A, B = lag(steps(20, 80), 5), lag(steps(20, 80), 5)
    C = 0.8 * A + 0.6 * B + 0.004 * A * B
    D = 1.1 * C * (1 - loss * (np.arange(n) >= onset)) - 0.5 * B + 40
    E = 0.7 * D + 0.9 * A + 20
    F = 0.5 * E + 0.4 * C + 30
    true = {"A": A, "B": B, "C": C, "D": D, "E": E, "F": F}
    noise = {"A": 0.4, "B": 0.4, "C": 0.8, "D": 0.8, "E": 1.0, "F": 1.0}
    idx = pd.date_range(START, periods=n, freq="60s", name="ts")
    f = pd.DataFrame({k: v + noise[k] * rng.standard_normal(n) for k, v in true.items()}, idx)
    for tag, b in (bias or {}).items():
        f.iloc[onset:, f.columns.get_loc(tag)] += b
    return f


def build(
    folder: str | Path,
    frame: pd.DataFrame,
    evaluation: dict | None = None,
    matrix=None,
    *,
    tests: dict[str, tuple[str, list[str]]] | None = None,
    tags: dict[str, tuple[float, float]] | None = None,
):
    """The process's models trained on ``frame`` and a unit file (no thresholds yet); ``tests``
    and ``tags`` (ranges) replace :data:`TESTS` and :data:`TAGS` for another small process."""
    from historian.taginfo import TagInfo

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    info = {
        k: TagInfo(k, unit="u", lo=lo, hi=hi, description=k)
        for k, (lo, hi) in (tags or TAGS).items()
    }
    a, b = frame.index[0], frame.index[-1] + pd.Timedelta("60s")
    names = {}
    for test, (out, ins) in (tests or TESTS).items():
        path = folder / f"p_{test}.toml"
        if not path.exists():
            rb = new_model(path, f"p_{test}", out, ins, frame=frame, tag_info=info, period="60s")
            res = train(rb, lambda x, y: frame[(frame.index >= x) & (frame.index < y)], a, b)
            rb.apply_training(res.model, {"from": a.isoformat(), "to": b.isoformat()})
            rb.save()
        names[test] = path.name
    p = folder / "p.unit.toml"
    p.write_text(new_unit_text("p", names, evaluation=evaluation, matrix=matrix))
    return p
