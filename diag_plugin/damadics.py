"""The real DAMADICS hour: Lublin sugar factory, actuator 3 (boiler feed-water valve).

``OneHourTestData_ExampleII.mat`` holds an 11 × 3600 matrix sampled at 1 s:
time (s), P1 (kPa), P2 (kPa), T1 (°C), F (t/h), CV (%), X (%), then four
unused channels. The data are fault-free. They are read from ``shared/``
where a deployment keeps them; nothing of them is copied into the repository.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import scipy.io

COLUMNS = ("time", "P1", "P2", "T1", "F", "CV", "X")
#: tag metadata: unit, nominal range (transducer ranges), description
TAGS = {
    "P1": {"unit": "kPa", "lo": 3000.0, "hi": 4000.0, "description": "inlet pressure"},
    "P2": {"unit": "kPa", "lo": 2200.0, "hi": 3000.0, "description": "outlet pressure"},
    "T1": {"unit": "°C", "lo": 95.0, "hi": 105.0, "description": "water temperature"},
    "F": {"unit": "t/h", "lo": 0.0, "hi": 40.0, "description": "feed-water flow"},
    "CV": {"unit": "%", "lo": 0.0, "hi": 100.0, "description": "controller output"},
    "X": {"unit": "%", "lo": 0.0, "hi": 100.0, "description": "rod position"},
}
#: the recording's date is not in the file; frames start here
START = pd.Timestamp("2001-11-17T00:00:00Z")
DEFAULT_PATH = Path(__file__).resolve().parents[2] / "shared" / "data" / "damadics"
FILE = "OneHourTestData_ExampleII.mat"


def find_file() -> Path | None:
    """The .mat file beside the repository (``../shared/data/damadics``), if present."""
    p = DEFAULT_PATH / FILE
    return p if p.exists() else None


def load_hour(path: str | Path, period: str | None = None) -> pd.DataFrame:
    """The hour as a frame indexed by UTC timestamps; averaged to ``period`` if given."""
    mat = scipy.io.loadmat(str(path))
    arrays = [v for k, v in mat.items() if not k.startswith("__") and isinstance(v, np.ndarray)]
    if not arrays or arrays[0].ndim != 2 or arrays[0].shape[0] < len(COLUMNS):
        raise ValueError(f"{path}: expected an 11 × N matrix of the DAMADICS actuator data")
    m = arrays[0]
    idx = START + pd.to_timedelta(m[0], unit="s")
    frame = pd.DataFrame(
        {c: m[i] for i, c in enumerate(COLUMNS) if c != "time"},
        index=pd.DatetimeIndex(idx, name="ts"),
    )
    if period:
        frame = frame.resample(period).mean()
    return frame
