"""A piece's settle at 1 s, timestamps off the grid (issue 34 review, H4 item 6).

:mod:`tests.test_unit_equipment` runs the twin chillers' piece of equipment (chiller B, staged
on at 07:00) at 1 min; here the same plant simulated at 1 s (:func:`tests.twinplant.simulate`
with ``period_s = step_s = 1``), written to a CSV with every sample 0-0.4 s late, imported and
built with ``diag unit build`` over 6 h (04:00-10:00: B stopped 3 h, started once, running
3 h), judged with ``diag diagnose`` on another seed's same hours with B's leaving-water sensor
reading +1 K from 10 min after B's own settle bound. Measured (seed 1 built, seed 9 judged):
``settle_max_s`` 2,061 s from the one start; B's tests off for 2,061 samples after its start;
no FAILURE in the 600 s between the settle and the onset; the bias named on B (B_CAP) 1,241 s
after its onset, on 39 % of the samples after it.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from diag_plugin.diagnose.unit import Unit
from diag_plugin.status import NE107
from tests import twinplant
from tests.test_any_plant_tour import diag, fmt

B = "B:B_RUN:B_T,B_CAP,B_KW"
#: B starts at 07:00, three hours into each window
START = 3 * 3600


def _hours(day: str, seed: int, fault: str | None = None, onset_s: int = 0) -> pd.DataFrame:
    """04:00-10:00 of ``day`` at 1 s, ``fault`` from ``onset_s`` seconds in."""
    return twinplant.simulate(
        0.25, seed, fault, onset_days=onset_s / 86400, start=f"{day} 04:00", period_s=1.0,
        step_s=1.0,
    )  # fmt: skip


def _import_off_grid(g, frame: pd.DataFrame, path, seed: int) -> None:
    """``frame`` written with each timestamp 0-0.4 s late (microseconds) and imported."""
    rng = np.random.default_rng(seed)
    late = pd.to_timedelta(rng.uniform(0, 0.4, len(frame)), unit="s")
    out = frame.round(4)
    out.index = (frame.index + late).strftime("%Y-%m-%dT%H:%M:%S.%f")
    out.index.name = "time"
    out.to_csv(path)
    rc, text = diag(g, "import", str(path))
    assert rc == 0, text


def test_a_piece_s_settle_at_one_second_off_the_grid(tmp_path):
    g = ["--db", f"sqlite:///{tmp_path / 'h.db'}", "--rulebases", str(tmp_path / "rb")]
    train = _hours("2026-06-01", 1)
    _import_off_grid(g, train, tmp_path / "train.csv", 11)
    t0, t1 = train.index[0], train.index[-1] + pd.Timedelta("1s")
    rc, text = diag(g, "unit", "build", "chw", "--from", fmt(t0), "--to", fmt(t1), "--loop",
                    "A_T=A_SP:A_CAP", "--loop", "B_T=B_SP:B_CAP", "--running", B, "--far",
                    "0.01")  # fmt: skip
    assert rc == 0, text
    unit = Unit.load(tmp_path / "rb" / "chw.unit.toml", tmp_path / "rb")
    (e,) = unit.equipment
    assert unit.period_s == 1.0 and e.settle_max_s is not None, text
    bound = int(e.settle_max_s)  # samples at 1 s
    assert 60 < bound < 3 * 3600 and unit.equipment_holds == [bound]
    onset = START + bound + 600
    judged = _hours("2026-06-03", 9, "b_bias", onset)
    _import_off_grid(g, judged, tmp_path / "judged.csv", 12)
    a, b = judged.index[0], judged.index[-1] + pd.Timedelta("1s")
    csv = tmp_path / "d.csv"
    rc, out = diag(g, "diagnose", "chw", "--from", fmt(a), "--to", fmt(b), "--csv", str(csv))
    assert rc == 0, out
    d = pd.read_csv(csv, low_memory=False)
    assert len(d) == len(judged)  # one row a second, the late samples on their grid points
    why = d["why"].fillna("").astype(str)
    settle = why.str.startswith("B started (B_RUN = 1)").to_numpy()
    (at,) = np.flatnonzero(np.diff(np.r_[0, settle.astype(np.int8)]) == 1)
    n = int(settle.sum())
    # the start holds B's tests from its first sample for at most its own bound
    assert at == START and 0 < n <= bound, (at, n, bound)
    sym = d[[f"s_{t}" for t in ("B_T", "B_CAP", "B_KW")]].to_numpy(float)
    assert np.isnan(sym[at : at + n]).all() and np.isfinite(sym[at + n]).all()
    # judged and quiet from the settle's end to the onset, the bias named on B after it
    status = d["status"].to_numpy()
    on_b = d["top1"].astype(str).str.startswith("B_").to_numpy() & (status == NE107.FAILURE)
    assert not on_b[at + n : onset].any()
    assert (status[at + n : onset] == NE107.FAILURE).sum() == 0
    first = np.flatnonzero(on_b[onset:])
    assert first.size and first[0] <= 1800, first[:3]
    assert on_b[onset:].mean() > 0.25, on_b[onset:].mean()
