"""Tables printed into a pipe or a file (a user's walk, issue 37): ``diag explain``'s next
commands whole, so that they can be copied.

Rich lays a table out for 80 columns when stdout is not a terminal; the explain table's
last column then ended in ``…`` (on SKAB: ``diag model add-input flow
'dir(Current,0.025)[k…``). ``diag tags`` and ``diag benchmark`` already print wider there.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd

from historian import Historian

T0 = pd.Timestamp("2026-04-01T00:00:00Z")


def test_explain_prints_every_next_command_whole_into_a_pipe(tmp_path, capsys, monkeypatch):
    from diag_plugin.cli import main

    monkeypatch.delenv("COLUMNS", raising=False)  # pytest-xdist's workers set 80

    db = f"sqlite:///{tmp_path / 'h.db'}"
    rng = np.random.default_rng(4)
    n = 3000
    ts = T0 + pd.to_timedelta(np.arange(n) * 10, unit="s")
    motor = np.cumsum(rng.normal(0, 0.3, n)) % 10
    head = 5 + 3 * np.sin(np.arange(n) / 400)
    flow = 4 * motor + 2 * head + rng.normal(0, 0.2, n)
    with Historian(db) as h:
        for name, v in (("Motor Current A", motor), ("Suction Head", head), ("Flow", flow)):
            h.write_samples(pd.Series(v, index=ts, name=name))
    base = ["--db", db, "--rulebases", str(tmp_path / "rb")]
    spec = '"Motor Current A"[k]'
    assert main([*base, "model", "new", "m", "--output", "Flow", "--input", spec]) == 0
    assert main([*base, "train", "m"]) == 0
    capsys.readouterr()
    assert main([*base, "explain", "m", "--json"]) == 0
    commands = [c["command"] for c in json.loads(capsys.readouterr().out)["candidates"]]
    assert commands
    assert main([*base, "explain", "m"]) == 0
    out = capsys.readouterr().out
    for cmd in commands:
        assert cmd in out, (cmd, out)


def test_a_width_set_in_columns_is_kept(monkeypatch):
    from diag_plugin.cliargs import PIPE_WIDTH, table_console

    monkeypatch.delenv("COLUMNS", raising=False)
    assert table_console().width == PIPE_WIDTH  # pytest's stdout is no terminal
    monkeypatch.setenv("COLUMNS", "260")
    assert table_console().width == 260
