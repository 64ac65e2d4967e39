"""``diag model new`` says when an input's data fill a sliver of its span (a user's walk on
classic TEP, issue 37): a valve's range 0–100 % from the tags CSV, the data at 39.5–42.8 %,
31 sets over the range — two of them held data and the model trained 2 rules, a staircase,
with nothing said until ``diag compare``."""

from __future__ import annotations

import numpy as np
import pandas as pd


def test_model_new_names_an_input_whose_data_use_a_sliver_of_its_span(tmp_path, capsys):
    from diag_plugin.cli import main

    rng = np.random.default_rng(2)
    n = 2000
    valve = 41 + 1.5 * np.sin(np.arange(n) / 60) + rng.normal(0, 0.1, n)
    frame = pd.DataFrame(
        {
            "time": pd.date_range("2026-01-01", periods=n, freq="3min"),
            "XMV10": valve,
            "XMEAS21": 100 - valve + rng.normal(0, 0.05, n),
        }
    )
    frame.to_csv(tmp_path / "p.csv", index=False)
    (tmp_path / "tags.csv").write_text(
        "name,unit,lo,hi,description\nXMV10,%,0,100,cooling water valve\nXMEAS21,degC,,,\n"
    )
    db = f"sqlite:///{tmp_path / 'h.db'}"
    base = ["--db", db, "--rulebases", str(tmp_path / "rb")]
    assert (
        main([*base, "import", str(tmp_path / "p.csv"), "--tags", str(tmp_path / "tags.csv")]) == 0
    )
    capsys.readouterr()
    assert main([*base, "model", "new", "cw", "--output", "XMEAS21", "--input", "XMV10[k]"]) == 0
    out = capsys.readouterr().out
    assert "XMV10[k]: the data use" in out, out
    assert "of its span 0 … 100" in out and "--span" in out, out
