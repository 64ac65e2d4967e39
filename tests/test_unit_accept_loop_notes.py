"""``diag unit accept`` says each model file's widened span once. A declared loop's test and its
spread test (the loop's error, its running spread) share one model file; the accept widened that
file's spans once per test and printed the note twice (the chilled-water plant's pass,
docs/explanation/acceptance-chiller.md: ``note: chw_CH2_LWT.toml: output: span 0 … 20 → 0 … 22``
two lines running). A small loop of its own: a level held at its set-point by a valve, the
set-point moved to a value the build never saw, then accepted."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd

from historian import Historian

T0 = pd.Timestamp("2026-05-04T00:00:00Z")


def _loop(h: Historian, start: pd.Timestamp, hours: float, sps: list[float], seed: int) -> None:
    """A level ``LVL`` held at ``LVL_SP`` (stepping through ``sps``) by the valve ``V_OUT``
    against an inflow ``Q_IN``; 10 s samples."""
    rng = np.random.default_rng(seed)
    n = int(hours * 360)
    sp = np.repeat(sps, -(-n // len(sps)))[:n]
    q = 30 + 4 * np.sin(np.arange(n) / 300) + rng.normal(0, 0.3, n)
    lvl = np.empty(n)
    x = sp[0]
    for k in range(n):
        x += 0.2 * (sp[k] - x) + rng.normal(0, 0.05)
        lvl[k] = x
    v = 0.8 * q + 0.3 * sp + rng.normal(0, 0.2, n)
    ts = start + pd.to_timedelta(np.arange(n) * 10, unit="s")
    for name, y in (("LVL", lvl), ("LVL_SP", sp), ("V_OUT", v), ("Q_IN", q)):
        h.write_samples(pd.Series(y, index=ts, name=name))


def test_accept_says_a_shared_model_files_widened_span_once(tmp_path, capsys):
    from diag_plugin.cli import main

    db = f"sqlite:///{tmp_path / 'h.db'}"
    with Historian(db) as h:
        _loop(h, T0, 6, [45.0, 50.0, 55.0, 50.0, 45.0, 55.0], 1)
        _loop(h, T0 + pd.Timedelta(days=1), 2, [65.0], 2)  # a set-point the build never saw
    base = ["--db", db, "--rulebases", str(tmp_path / "rb"), "unit"]
    rc = main([*base, "build", "lv", "--from", "2026-05-04", "--to", "2026-05-04T06:00",
               "--loop", "LVL=LVL_SP:V_OUT", "--far", "0.01"])  # fmt: skip
    assert rc == 0, capsys.readouterr().err
    capsys.readouterr()
    unit = (tmp_path / "rb" / "lv.unit.toml").read_text()
    assert "LVL_spread" in unit and unit.count('model = "lv_LVL.toml"') == 2, unit
    window = ["--from", "2026-05-05T00:20", "--to", "2026-05-05T02:00"]
    assert main([*base, "accept", "lv", *window, "--json"]) == 0
    notes = json.loads(capsys.readouterr().out)["warnings"]
    spans = [w for w in notes if w.startswith("lv_LVL.toml: ") and ": span " in w]
    assert spans, notes  # the level's model learned 65, outside what the build saw
    assert len(spans) == len(set(spans)), spans
    assert main([*base, "rollback", "lv"]) == 0
    capsys.readouterr()
    assert main([*base, "accept", "lv", *window]) == 0
    out = [ln for ln in capsys.readouterr().out.splitlines() if "lv_LVL.toml: " in ln]
    assert out and len(out) == len(set(out)), out
