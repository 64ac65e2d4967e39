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

from historian.taginfo import TagInfo

COLUMNS = ("time", "P1", "P2", "T1", "F", "CV", "X")
#: tag metadata: unit, nominal range (transducer ranges), description
TAGS = {
    t.name: t
    for t in (
        TagInfo("P1", "kPa", 3000.0, 4000.0, "inlet pressure"),
        TagInfo("P2", "kPa", 2200.0, 3000.0, "outlet pressure"),
        TagInfo("T1", "°C", 95.0, 105.0, "water temperature"),
        TagInfo("F", "t/h", 0.0, 40.0, "feed-water flow"),
        TagInfo("CV", "%", 0.0, 100.0, "controller output"),
        TagInfo("X", "%", 0.0, 100.0, "rod position"),
    )
}
#: the recording's date is not in the file; frames start here
START = pd.Timestamp("2001-11-17T00:00:00Z")
DEFAULT_PATH = Path(__file__).resolve().parents[3] / "shared" / "data" / "damadics"
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
