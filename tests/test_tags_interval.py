"""``diag tags``' interval column as a person reads it (a user's walk, issue 37): a 1 s export
jittered by ±20 % read ``1.01409 s``, classic TEP's 3 min ``180 s``."""

from __future__ import annotations

import numpy as np
import pandas as pd

from historian import Historian

T0 = pd.Timestamp("2026-04-01T00:00:00Z")


def test_tags_prints_the_interval_rounded_and_in_minutes(tmp_path, capsys):
    from diag_plugin.cli import main

    db = f"sqlite:///{tmp_path / 'h.db'}"
    rng = np.random.default_rng(8)
    n = 2000
    jit = T0 + pd.to_timedelta(np.arange(n) + rng.uniform(-0.2, 0.2, n), unit="s")
    keep = rng.uniform(size=n) > 0.3  # rows dropped: the median spacing is off 1 s
    slow = T0 + pd.to_timedelta(np.arange(200) * 180, unit="s")
    with Historian(db) as h:
        h.write_samples(pd.Series(rng.normal(size=keep.sum()), index=jit[keep], name="FAST"))
        h.write_samples(pd.Series(rng.normal(size=200), index=slow, name="SLOW"))
    assert main(["--db", db, "tags"]) == 0
    rows = {
        ln.split("│")[1].strip(): ln for ln in capsys.readouterr().out.splitlines() if "│" in ln
    }
    fast = rows["FAST"].split("│")[7].strip()
    assert fast.endswith(" s") and len(fast.split()[0]) <= 4, rows["FAST"]
    assert rows["SLOW"].split("│")[7].strip() == "3 min", rows["SLOW"]


def test_tags_lists_numbered_tags_in_number_order(tmp_path, capsys):
    """Classic TEP's tags came out XMEAS1, XMEAS10, XMEAS11, …, XMEAS2 (text order)."""
    from diag_plugin.cli import main

    db = f"sqlite:///{tmp_path / 'h.db'}"
    ts = T0 + pd.to_timedelta(np.arange(50) * 180, unit="s")
    names = ["XMEAS10", "XMV2", "XMEAS2", "XMEAS1", "XMV11"]
    with Historian(db) as h:
        for k, name in enumerate(names):
            h.write_samples(pd.Series(np.arange(50.0) + k, index=ts, name=name))
    assert main(["--db", db, "tags", "--json"]) == 0
    import json

    got = [r["tag"] for r in json.loads(capsys.readouterr().out)]
    assert got == ["XMEAS1", "XMEAS2", "XMEAS10", "XMV2", "XMV11"]
    assert main(["--db", db, "tags"]) == 0
    table = [ln.split("│")[1].strip() for ln in capsys.readouterr().out.splitlines() if "│" in ln]
    assert table == got
