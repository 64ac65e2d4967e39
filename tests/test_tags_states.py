"""``diag tags`` and a discrete state held for hours (issue 34, acceptance-filters.md): a
filter's 0/1/2 state that holds 0 for 30 h between washes was listed as flat-lined
(``15 (498.6 h)``), as a frozen transmitter is. It is a state; a frozen analog sensor is still
flat-lined."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd

from historian import Historian

T0 = pd.Timestamp("2026-03-02T00:00:00Z")


def _filter_bank(n_days: float = 3.0, seed: int = 4) -> pd.DataFrame:
    """A filter at 1 min: filtering (0) for 30 h, backwash (1) 12 min, filter-to-waste (2)
    15 min, again; its effluent flow, a noisy analog reading, frozen for 2 h on day 2."""
    rng = np.random.default_rng(seed)
    n = int(n_days * 1440)
    state = np.zeros(n)
    for start in range(600, n, 30 * 60 + 27):
        state[start : start + 12] = 1.0
        state[start + 12 : start + 27] = 2.0
    flow = np.round(400 + 20 * np.sin(np.arange(n) / 90) + rng.normal(0, 3, n), 2)
    flow[state > 0] = np.round(rng.normal(0, 3, int((state > 0).sum())), 2)
    flow[2000:2120] = flow[1999]  # the transmitter freezes for 2 h
    idx = T0 + pd.to_timedelta(np.arange(n), unit="min")
    return pd.DataFrame({"F1_STATE": state, "F1_FLOW": flow}, index=idx)


def test_a_state_held_for_hours_is_no_flat_line(tmp_path, capsys):
    from diag_plugin.cli import main

    db = f"sqlite:///{tmp_path / 'h.db'}"
    with Historian(db) as h:
        h.write_samples(_filter_bank())
    assert main(["--db", db, "tags", "--json"]) == 0
    rows = {r["tag"]: r for r in json.loads(capsys.readouterr().out)}
    st, fl = rows["F1_STATE"], rows["F1_FLOW"]
    assert st["flat"] == 0 and st["flat_s"] == 0, st
    assert st["state"] == "0, 1 or 2" and st["held"] == 0
    assert 29.5 * 3600 <= st["held_s"] <= 30.5 * 3600, st["held_s"]
    # the frozen analog reading is still flat-lined, and no state
    assert fl["flat"] == 1 and fl["flat_s"] == 120 * 60, fl
    assert fl["state"] is None
    assert main(["--db", db, "tags"]) == 0
    table = {
        ln.split("│")[1].strip(): ln for ln in capsys.readouterr().out.splitlines() if "│" in ln
    }
    assert "holds 0 for 30.0 h (a state)" in table["F1_STATE"], table["F1_STATE"]
    assert "1 (2.0 h)" in table["F1_FLOW"], table["F1_FLOW"]


def _reactor(n_days: float = 2.0) -> pd.DataFrame:
    """A batch reactor's recipe phase at 1 min, six values (idle 0 for 8 h, then charge 1,
    heat-up 2, hold 3, cool-down 4, discharge 5): more levels than the rule finds a state by;
    its stirrer's speed, a constant set-point held for the whole window."""
    n = int(n_days * 1440)
    phase = np.zeros(n)
    for start in range(480, n, 16 * 60):
        for k, minutes in enumerate((30, 90, 240, 90, 20), start=1):
            phase[start : start + minutes] = k
            start += minutes
    idx = T0 + pd.to_timedelta(np.arange(n), unit="min")
    return pd.DataFrame({"PHASE": phase, "AGIT_SPEED": np.full(n, 120.0)}, index=idx)


def test_a_phase_declared_in_the_tags_csv_is_a_state(tmp_path, capsys):
    """A recipe's phase (six values) is no state by the rule: ``diag tags`` listed it as
    flat-lined. With ``--tags`` and its role ``phase`` (as ``diag unit build`` reads it), it
    is a state; a tag of no such role is judged as before, and a missing file is said."""
    from diag_plugin.cli import main

    db = f"sqlite:///{tmp_path / 'h.db'}"
    with Historian(db) as h:
        h.write_samples(_reactor())
    tags = tmp_path / "tags.csv"
    tags.write_text("name,unit,role\nPHASE,,phase\nAGIT_SPEED,rpm,\n")
    assert main(["--db", db, "tags", "--json"]) == 0
    rows = {r["tag"]: r for r in json.loads(capsys.readouterr().out)}
    assert rows["PHASE"]["state"] is None and rows["PHASE"]["flat"] >= 1, rows["PHASE"]
    assert main(["--db", db, "tags", "--json", "--tags", str(tags)]) == 0
    rows = {r["tag"]: r for r in json.loads(capsys.readouterr().out)}
    ph = rows["PHASE"]
    assert ph["flat"] == 0 and ph["state"] == "0, 1, 2, 3, 4 or 5", ph
    assert ph["held"] == 0 and 8 * 3600 <= ph["held_s"] <= 8.25 * 3600, ph  # idle between batches
    assert rows["AGIT_SPEED"]["state"] is None and rows["AGIT_SPEED"]["flat"] == 1
    assert main(["--db", db, "tags", "--tags", str(tmp_path / "none.csv")]) == 2
    assert "none.csv: no such file" in capsys.readouterr().err


def test_a_phase_imported_from_a_csv_as_a_user_does_is_a_state(tmp_path):
    """The same reactor as a user has it (H4 item 5): a plain CSV with timestamps off the
    minute grid (each sample 0-25 s late, written to the second: jitter, no gap), the phase
    written as integers and one of its cells as the text ``3.0``, imported into SQLite with
    ``diag import --tags`` and its tags CSV; ``diag tags --tags`` lists the phase as a state
    of six values held 8 h between batches, without ``--tags`` as flat-lined. (Coverage of
    bb998c9 on imported data: passes on main too.)"""
    from tests.test_any_plant_tour import diag

    frame = _reactor()
    rng = np.random.default_rng(5)
    late = pd.to_timedelta(rng.integers(0, 26, len(frame)), unit="s")
    times = (frame.index + late).strftime("%Y-%m-%d %H:%M:%S")
    phase = frame["PHASE"].astype(int).astype(str).to_numpy()
    hold = int(np.flatnonzero(frame["PHASE"].to_numpy() == 3)[10])
    phase[hold] = "3.0"
    csv = tmp_path / "reactor.csv"
    lines = ["time,PHASE,AGIT_SPEED"]
    lines += [f"{t},{p},{s:g}" for t, p, s in zip(times, phase, frame["AGIT_SPEED"], strict=True)]
    csv.write_text("\n".join(lines) + "\n")
    tags = tmp_path / "tags.csv"
    tags.write_text("name,unit,role\nPHASE,,phase\nAGIT_SPEED,rpm,\n")
    g = ["--db", f"sqlite:///{tmp_path / 'h.db'}"]
    rc, text = diag(g, "import", str(csv), "--tags", str(tags))
    assert rc == 0, text
    rc, text = diag(g, "tags", "--json")
    assert rc == 0, text
    rows = {r["tag"]: r for r in json.loads(text)}
    assert rows["PHASE"]["state"] is None and rows["PHASE"]["flat"] >= 1, rows["PHASE"]
    rc, text = diag(g, "tags", "--json", "--tags", str(tags))
    assert rc == 0, text
    rows = {r["tag"]: r for r in json.loads(text)}
    ph = rows["PHASE"]
    assert ph["samples"] == len(frame) and ph["gaps"] == 0 and ph["coverage"] == 1.0, ph
    assert ph["flat"] == 0 and ph["state"] == "0, 1, 2, 3, 4 or 5", ph
    assert ph["held"] == 0 and 7.9 * 3600 <= ph["held_s"] <= 8.25 * 3600, ph
    assert rows["AGIT_SPEED"]["state"] is None and rows["AGIT_SPEED"]["flat"] == 1
    rc, text = diag(g, "tags", "--tags", str(tags))
    assert rc == 0, text
    table = {ln.split("│")[1].strip(): ln for ln in text.splitlines() if "│" in ln}
    assert "(a state)" in table["PHASE"], table["PHASE"]
