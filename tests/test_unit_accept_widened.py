"""``diag unit accept`` names a test whose band it widened many times over (a user's walk on
SKAB, issue 37): the pump's current is modelled from its voltage, and the accepted valve1
run, at a third of the anomaly-free run's flow, draws less current at the same voltage; the
merged model answers both points with one rule per voltage and the current's band went from
-7.1 … +6.0 to -59.1 … +9.3 % of span, with nothing said: the test then passed what it had
flagged before."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd

from historian import Historian

T0 = pd.Timestamp("2026-04-01T00:00:00Z")


def _run(h: Historian, start: pd.Timestamp, hours: float, offset: float, seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(hours * 3600 / 10)
    ts = start + pd.to_timedelta(np.arange(n) * 10, unit="s")
    v = 230 + 5 * np.sin(np.arange(n) / 50) + rng.normal(0, 0.5, n)
    u = 50 + 3 * np.cos(np.arange(n) / 70) + rng.normal(0, 0.3, n)
    cur = 0.02 * v + 0.05 * u - offset + rng.normal(0, 0.02, n)  # offset: a lighter load
    for name, x in (("V", v), ("U", u), ("I", cur)):
        h.write_samples(pd.Series(x, index=ts, name=name))


def test_accept_names_a_test_whose_band_it_widened(tmp_path, capsys):
    from diag_plugin.cli import main

    db = f"sqlite:///{tmp_path / 'h.db'}"
    with Historian(db) as h:
        _run(h, T0, 12, 0.0, 1)
        _run(h, T0 + pd.Timedelta(days=1), 2, 1.5, 2)  # the same voltages, less current
    base = ["--db", db, "--rulebases", str(tmp_path / "rb"), "unit"]
    rc = main([*base, "build", "p", "--from", "2026-04-01", "--to", "2026-04-01T12:00",
               "--tags", "I", "--far", "0.01"])  # fmt: skip
    assert rc == 0, capsys.readouterr().err
    capsys.readouterr()
    window = ["--from", "2026-04-02T00:00", "--to", "2026-04-02T02:00"]
    assert main([*base, "accept", "p", *window, "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert set(res["widened"]) == {"I"} and res["widened"]["I"] > 3, res
    assert main([*base, "rollback", "p"]) == 0
    assert main([*base, "accept", "p", *window]) == 0
    out = capsys.readouterr().out
    assert "⚠ I: its band is" in out and "diag unit rollback p" in out, out
