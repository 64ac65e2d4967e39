"""A replay's per-test residuals on every core (issue 34, "Speed"): ``diag diagnose`` sets
``Unit.workers`` to the cores it may use and :func:`~diag_plugin.diagnose.pertest.each` runs
the tests' rows in the calling thread and helpers. The diagnosis is the same bits with one
thread or several, in one pass or in pieces, and the command's JSON and CSV the same bytes.

The 7-tag line (a flow loop with its spread test, a hand valve, deadband, delays, a combined
test and isolation to tags) on a seed used nowhere else (118); the valve unit's command on
seed 8118.
"""

from __future__ import annotations

import hashlib
import threading
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from diag_plugin.diagnose import pertest
from diag_plugin.diagnose.unit import Unit, concat
from diag_plugin.unitbuild.build import build_unit
from diag_plugin.unitbuild.loops import parse_loop
from tests import line7

SHIPPED = Path(__file__).resolve().parents[1] / "rulebases"


@pytest.mark.parametrize("workers", [1, 2, 3, 8])
def test_each_runs_every_row_once(workers):
    seen: list[int] = []
    lock = threading.Lock()

    def row(j: int) -> None:
        with lock:
            seen.append(j)

    pertest.each(row, 37, workers)
    assert sorted(seen) == list(range(37))
    if workers == 1:
        assert seen == list(range(37))  # in order, in this thread


def test_each_shares_the_rows_between_threads():
    """With two workers two rows run at once: each of the first two waits for the other
    (a barrier the calling thread alone could never pass)."""
    both = threading.Barrier(2, timeout=60)
    names = set()

    def row(j: int) -> None:
        names.add(threading.current_thread().name)
        if j < 2:
            both.wait()

    pertest.each(row, 10, 2)
    assert len(names) == 2
    assert threading.current_thread().name in names


def test_each_raises_a_rows_error_once_every_row_stopped():
    running = []

    def row(j: int) -> None:
        running.append(j)
        if j == 3:
            raise ValueError("row 3")
        running.remove(j)

    with pytest.raises(ValueError, match="row 3"):
        pertest.each(row, 40, 2)
    assert running == [3]  # no other row left half done


@pytest.fixture(scope="module")
def line(tmp_path_factory):
    folder = tmp_path_factory.mktemp("pertest")
    res = build_unit("line", line7.simulate(6.0, seed=1), folder=folder,
                     period=f"{line7.PERIOD_S:g}s", far=0.01,
                     loops=[parse_loop(line7.LOOP)], workers=1)  # fmt: skip
    return Unit.load(res.path, folder)


def _frame(fault: str | None) -> pd.DataFrame:
    frame = line7.simulate(1.5, seed=118, fault=fault, onset_days=0.5)
    rng = np.random.default_rng(118)
    for _ in range(8):  # gaps: a test without its inputs for a while
        j, a = rng.integers(frame.shape[1]), rng.integers(len(frame) - 200)
        frame.iloc[a : a + int(rng.choice([2, 40, 150])), j] = np.nan
    return frame


def _tables(d) -> dict[str, pd.DataFrame]:
    return {"frame": d.to_frame(), "residuals": d.residuals, "intervals": d.intervals(),
            "certainties": d.certainties, "contributions": d.contributions}  # fmt: skip


def _replay(unit: Unit, frame: pd.DataFrame, workers: int, piece: int):
    unit.workers = workers
    unit.reset()
    try:
        parts = [unit.evaluate(frame.iloc[s : s + piece]) for s in range(0, len(frame), piece)]
    finally:
        unit.workers = 1
    return _tables(concat(parts)), unit.to_state()


@pytest.mark.parametrize("fault", [None, "stiction", "manual_moved"])
@pytest.mark.parametrize("piece", [10**9, 613, 1999])
def test_threads_give_the_one_thread_diagnosis(line, fault, piece):
    """Every table bit for bit (no tolerance: the same code on the same inputs), in one pass
    and in pieces, and the state the next piece starts from."""
    frame = _frame(fault)
    one, state = _replay(line, frame, 1, piece)
    for workers in (2, 3):
        got, got_state = _replay(line, frame, workers, piece)
        for key, want in one.items():
            pd.testing.assert_frame_equal(got[key], want, check_exact=True, obj=key)
        assert got_state == state
    if fault is not None:  # not trivially quiet
        assert (one["frame"]["status"] != 0).any()


def test_diagnose_sets_its_workers_and_gives_the_same_bytes(tmp_path, capsys, monkeypatch):
    """``diag diagnose`` replays with a worker per core; with one core its JSON and CSV are
    the same bytes."""
    from diag_plugin.cli import main
    from diag_plugin.diagnose import cli
    from diag_plugin.simulate import FaultSpec, simulate_valve
    from historian.store import Historian

    onset = pd.Timestamp("2026-01-02T06:00", tz="UTC")
    frame = simulate_valve(3, seed=8118, faults=[FaultSpec("f14", -0.3, onset)])
    url = f"sqlite:///{tmp_path / 'h.db'}"
    with Historian.open(url) as h:
        h.write_samples(frame)
    workers = []
    load = cli.load_unit

    def spy(*a, **k):
        unit = load(*a, **k)
        workers.append(unit)
        return unit

    monkeypatch.setattr(cli, "load_unit", spy)
    out = {}
    for cores in (1, 2):
        monkeypatch.setattr(pertest, "cores", lambda c=cores: c)
        csv = tmp_path / f"{cores}.csv"
        args = ["--db", url, "--rulebases", str(SHIPPED), "diagnose", "valve_unit", "--json"]
        assert main([*args, "--chunk", "1D", "--csv", str(csv)]) == 0
        out[cores] = (capsys.readouterr().out, hashlib.md5(csv.read_bytes()).hexdigest())
        assert workers[-1].workers == cores
    assert out[1] == out[2]
    assert '"FAILURE"' in out[1][0]
