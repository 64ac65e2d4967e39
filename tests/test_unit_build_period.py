"""``diag unit build --period``: a unit on a coarser grid than the data's (a user's walk,
issue 37: SKAB at 1 s tried at 10 s had to be resampled by hand and imported again; ``diag
model new`` already took ``--period``)."""

from __future__ import annotations

import tomllib

import numpy as np
import pandas as pd

from historian import Historian

T0 = pd.Timestamp("2026-04-01T00:00:00Z")


def test_unit_build_takes_a_period_and_averages_the_faster_tags_on_it(tmp_path, capsys):
    from diag_plugin.cli import main

    db = f"sqlite:///{tmp_path / 'h.db'}"
    rng = np.random.default_rng(6)
    n = 4 * 3600  # four hours at 1 s
    ts = T0 + pd.to_timedelta(np.arange(n), unit="s")
    x = np.sin(np.arange(n) / 900) + np.cumsum(rng.normal(0, 0.01, n))
    y = np.cos(np.arange(n) / 1300) + np.cumsum(rng.normal(0, 0.01, n))
    with Historian(db) as h:
        for name, v in (("A", x + y + rng.normal(0, 0.05, n)), ("X", x), ("Y", y)):
            h.write_samples(pd.Series(v, index=ts, name=name))
    base = ["--db", db, "--rulebases", str(tmp_path / "rb"), "unit", "build"]
    window = ["--from", "2026-04-01T00:00", "--to", "2026-04-01T04:00"]
    assert main([*base, "u", *window, "--period", "10s"]) == 0
    out = capsys.readouterr().out
    assert "(period 10s)" in out and "period 10s (--period)" in out, out
    doc = tomllib.loads((tmp_path / "rb" / "u_A.toml").read_text())
    assert doc["model"]["period"] == "10s", doc["model"]
    assert main([*base, "v", *window, "--period", "ten"]) == 2
    assert "--period 'ten' is not a duration" in capsys.readouterr().err
