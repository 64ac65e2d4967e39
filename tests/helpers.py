"""Small synthetic plants shared by tests (not tests themselves)."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd


def run_diag(cwd: Path, *args: str, **env: str) -> subprocess.CompletedProcess:
    """`diag ARGS` as a user runs it: a subprocess in ``cwd``, no DIAG_* from the caller."""
    clean = {k: v for k, v in os.environ.items() if not k.startswith("DIAG_")} | env
    return subprocess.run(
        [sys.executable, "-m", "diag_plugin", *args],
        cwd=cwd,
        env=clean,
        capture_output=True,
        text=True,
        timeout=600,
    )


def valve_frame(days: float, seed: int) -> pd.DataFrame:
    """Flow through a valve from the controller output (1 sample late) and upstream pressure,
    10 s samples, 50 missing CV values."""
    rng = np.random.default_rng(seed)
    n = int(days * 8640)
    idx = pd.date_range("2026-01-01", periods=n, freq="10s", tz="UTC", name="ts")
    cv = np.clip(50 + np.cumsum(rng.normal(0, 1.5, n)) % 100, 0, 100)
    p1 = 500 + 150 * np.sin(np.arange(n) / 8640 * 2 * np.pi) + rng.normal(0, 5, n)
    f = np.r_[0, 30 * (cv[:-1] / 100) ** 2 * np.sqrt(p1[1:] / 650)] + rng.normal(0, 0.1, n)
    frame = pd.DataFrame({"CV": cv, "P1": p1, "F": f}, index=idx)
    frame.iloc[rng.choice(n, 50, replace=False), 0] = np.nan
    return frame
