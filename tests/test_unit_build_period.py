"""``diag unit build --period``: a unit on a coarser grid than the data's (a user's walk,
issue 37: SKAB at 1 s tried at 10 s had to be resampled by hand and imported again; ``diag
model new`` already took ``--period``)."""

from __future__ import annotations

import tomllib

import numpy as np
import pandas as pd

from historian import Historian

T0 = pd.Timestamp("2026-04-01T00:00:00Z")


def _history(db: str, n: int, unit: str, seed: int, scales: tuple[int, int]) -> pd.DatetimeIndex:
    """``n`` samples every one ``unit`` from T0 into the historian ``db``: ``A = X + Y`` and
    noise, X and Y two slow waves with a walk (``scales``: their periods in samples / 2π)."""
    rng = np.random.default_rng(seed)
    ts = T0 + pd.to_timedelta(np.arange(n), unit=unit)
    x = np.sin(np.arange(n) / scales[0]) + np.cumsum(rng.normal(0, 0.01, n))
    y = np.cos(np.arange(n) / scales[1]) + np.cumsum(rng.normal(0, 0.01, n))
    with Historian(db) as h:
        for name, v in (("A", x + y + rng.normal(0, 0.05, n)), ("X", x), ("Y", y)):
            h.write_samples(pd.Series(v, index=ts, name=name))
    return ts


def test_unit_build_takes_a_period_and_averages_the_faster_tags_on_it(tmp_path, capsys):
    from diag_plugin.cli import main

    db = f"sqlite:///{tmp_path / 'h.db'}"
    _history(db, 4 * 3600, "s", 6, (900, 1300))  # four hours at 1 s
    base = ["--db", db, "--rulebases", str(tmp_path / "rb"), "unit", "build"]
    window = ["--from", "2026-04-01T00:00", "--to", "2026-04-01T04:00"]
    assert main([*base, "u", *window, "--period", "10s"]) == 0
    out = capsys.readouterr().out
    assert "(period 10s)" in out and "period 10s (--period)" in out, out
    doc = tomllib.loads((tmp_path / "rb" / "u_A.toml").read_text())
    assert doc["model"]["period"] == "10s", doc["model"]
    assert main([*base, "v", *window, "--period", "ten"]) == 2
    assert "--period 'ten' is not a duration" in capsys.readouterr().err


def test_a_to_at_the_last_sample_is_said_to_leave_it_out(tmp_path):
    """``--to`` is exclusive: typed as the historian's last sample time (an export's last
    stamp), the window leaves that sample out and the build says so, with the ``--to`` that
    takes it in; one period later, nothing is said."""
    from tests.test_any_plant_tour import diag

    db = f"sqlite:///{tmp_path / 'h.db'}"
    ts = _history(db, 2 * 1440, "min", 9, (90, 130))  # two days at 1 min
    g = ["--db", db, "--rulebases", str(tmp_path / "rb")]
    last = ts[-1].strftime("%Y-%m-%dT%H:%M:%SZ")
    rc, text = diag(g, "unit", "build", "u", "--from", "2026-04-01T00:00", "--to", last)
    assert rc == 0, text
    said = "is at or after --to 2026-04-02 23:59:00+00:00, which is exclusive"
    assert said in text and "--to 2026-04-03 00:00:00+00:00 takes it in" in text, text
    rc, text = diag(g, "unit", "build", "u", "--from", "2026-04-01T00:00", "--to",
                    "2026-04-03T00:00Z", "--force")  # fmt: skip
    assert rc == 0, text
    assert "which is exclusive" not in text, text
