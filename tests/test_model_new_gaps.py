"""``diag model new`` on runs with long gaps between them (a user's walk on SKAB, issue 37).

SKAB's runs are 1 s files hours or weeks apart; imported together, the grid between the first
and the last sample holds millions of empty points. The sets are chosen on the samples that
hold data, and the line saying so must count those, not the grid's empty points.
"""

from __future__ import annotations

import re

import numpy as np
import pandas as pd

from historian import Historian

T0 = pd.Timestamp("2026-04-01T00:00:00Z")


def test_model_new_counts_the_samples_with_data_not_the_grid_across_gaps(tmp_path, capsys):
    from diag_plugin.cli import main

    db = f"sqlite:///{tmp_path / 'h.db'}"
    rng = np.random.default_rng(3)
    run = pd.to_timedelta(np.arange(300), unit="s")
    ts = pd.DatetimeIndex(list(T0 + run) + list(T0 + pd.Timedelta(days=3) + run))  # two runs
    x = rng.uniform(0, 10, len(ts))
    with Historian(db) as h:
        h.write_samples(pd.Series(x, index=ts, name="X"))
        h.write_samples(pd.Series(2 * x + rng.normal(0, 0.1, len(ts)), index=ts, name="Y"))
    argv = ["--db", db, "--rulebases", str(tmp_path / "rb"), "model", "new", "m"]
    assert main([*argv, "--output", "Y", "--input", "X[k]", "--shape", "triangular"]) == 0
    out = capsys.readouterr().out
    said = re.search(r"what ([\d,]+) samples can fill", out)
    assert said, out
    assert int(said.group(1).replace(",", "")) == 600, out  # not the 259,500 grid points
