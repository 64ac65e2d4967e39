"""A short window's note says how many inputs a controller output's test may take. The build's
note said ``at most 2 inputs per test`` while a controller output's test is chosen up to
``ACTUATOR_MAX_INPUTS`` inputs in a short window too (docs/how-to/unit-loops.md, "From several
inputs"): on the chilled-water plant's 400-sample window (docs/explanation/acceptance-chiller.md)
both chillers' capacity valves were built on three inputs under that note. A valve of its own
here, set by three independent process conditions, 400 samples of 10 s."""

from __future__ import annotations

import json
import re
import tomllib

import numpy as np
import pandas as pd

from historian import Historian

T0 = pd.Timestamp("2026-05-11T00:00:00Z")


def _walk(rng: np.random.Generator, n: int, sd: float) -> np.ndarray:
    return np.cumsum(rng.normal(0, sd, n))


def _plant(h: Historian, n: int, seed: int) -> None:
    """A flow ``F`` held at ``F_SP`` by the valve ``V``, whose opening follows the supply
    pressure ``P``, the fluid's temperature ``T`` and the set-point (three independent
    slow walks); 10 s samples."""
    rng = np.random.default_rng(seed)
    sp = np.repeat([40.0, 45.0, 50.0, 45.0], -(-n // 4))[:n]
    p = 5 + _walk(rng, n, 0.05)
    t = 60 + _walk(rng, n, 0.3)
    v = 20 + 0.6 * sp - 3.0 * p + 0.4 * t + rng.normal(0, 0.2, n)
    f = sp + rng.normal(0, 0.1, n)
    ts = T0 + pd.to_timedelta(np.arange(n) * 10, unit="s")
    for name, y in (("F", f), ("F_SP", sp), ("V", v), ("P", p), ("T", t)):
        h.write_samples(pd.Series(y, index=ts, name=name))


def test_a_short_windows_note_covers_the_controller_outputs_inputs(tmp_path, capsys):
    from diag_plugin.cli import main

    db = f"sqlite:///{tmp_path / 'h.db'}"
    with Historian(db) as h:
        _plant(h, 400, 3)
    base = ["--db", db, "--rulebases", str(tmp_path / "rb"), "unit", "build", "v"]
    args = ["--from", "2026-05-11T00:00", "--to", "2026-05-11T01:06:40", "--far", "0.01"]
    rc = main([*base, *args, "--loop", "F=F_SP:V", "--json"])
    assert rc == 0, capsys.readouterr().err
    res = json.loads(capsys.readouterr().out)
    note = next(n for n in res["notes"] if n.startswith("short window"))
    per_test = int(re.search(r"at most (\d+) inputs per test", note).group(1))
    said = re.search(r"a controller output's test up to (\d+)", note)
    allowed = int(said.group(1)) if said else per_test
    unit = tomllib.loads((tmp_path / "rb" / "v.unit.toml").read_text())
    valve = unit["build"]["tests"]["V"]
    n_in = len(valve["inputs"])
    assert n_in > per_test, valve  # the valve's test took more than the note's per-test limit
    assert n_in <= allowed, (note, valve)
