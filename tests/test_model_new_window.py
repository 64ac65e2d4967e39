"""``diag model new --from/--to`` (a user's walk, issue 37): the period, spans, sets and shape
are chosen on the stretch the user names, not over a fault that follows it."""

from __future__ import annotations

import tomllib

import numpy as np
import pandas as pd

from historian import Historian

T0 = pd.Timestamp("2026-04-01T00:00:00Z")


def test_model_new_chooses_on_the_window_given(tmp_path, capsys):
    from diag_plugin.cli import main

    db = f"sqlite:///{tmp_path / 'h.db'}"
    rng = np.random.default_rng(3)
    n = 2 * 8640  # two days at 10 s
    ts = T0 + pd.to_timedelta(np.arange(n) * 10, unit="s")
    u = rng.uniform(0, 10, n)
    u[n // 2 :] = rng.uniform(100, 200, n - n // 2)  # the second day: a fault, far off
    y = 2 * u + rng.normal(0, 0.1, n)
    with Historian(db) as h:
        h.write_samples(pd.Series(u, index=ts, name="U"))
        h.write_samples(pd.Series(y, index=ts, name="Y"))
    base = ["--db", db, "--rulebases", str(tmp_path / "rb")]
    args = ["model", "new", "m", "--output", "Y", "--input", "U[k]"]
    assert main([*base, *args, "--to", "2026-04-02T00:00:00"]) == 0
    assert main([*base, *args[:2], "all", *args[3:]]) == 0
    capsys.readouterr()

    def span(name: str) -> tuple[float, float]:
        doc = tomllib.loads((tmp_path / "rb" / f"{name}.toml").read_text())
        lo, hi = doc["inputs"][0]["span"]
        return lo, hi

    assert span("m")[1] < 11, span("m")  # the first day only
    assert span("all")[1] > 150, span("all")
