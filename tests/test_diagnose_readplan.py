"""``diag diagnose`` remembers what it read for a unit (:mod:`~diag_plugin.diagnose.readplan`)
and, the next time, starts that read before it loads the unit (issue 34, "Speed": the
unit's modules and numba are ~0.3 CPU s of start-up with one core working alone); a plan
that no longer fits the unit is dropped and the unit's own read made, so the output is the
same bytes whatever was remembered.

The example valve unit on a simulator seed used nowhere else (813), each test with a model
cache folder of its own (where the plans are kept).
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from helpers import read_probe

#: ``diag`` with its read watched at the first import of numba (helpers.read_probe)
PROBE = read_probe("numba")


@pytest.fixture()
def valve(tmp_path, monkeypatch):
    """The diagnose command's arguments on a day of the valve, and the plans' folder."""
    from helpers import REPO

    from diag_plugin.simulate import simulate_valve
    from historian.store import Historian

    url = f"sqlite:///{tmp_path / 'h.db'}"
    with Historian.open(url) as h:
        h.write_samples(simulate_valve(1, seed=813))
    cache = tmp_path / "cache"
    monkeypatch.setenv("DIAG_MODEL_CACHE", str(cache))
    argv = ["--db", url, "--rulebases", str(REPO / "rulebases"), "diagnose", "valve_unit"]
    return [*argv, "--json"], cache


def _run(argv: list[str]) -> tuple[str, str]:
    """The command in a fresh process under :data:`PROBE`: its stdout and RESULT line."""
    res = subprocess.run(
        [sys.executable, "-c", PROBE, *argv], capture_output=True, text=True, timeout=300
    )
    line = next((x for x in res.stderr.splitlines() if x.startswith("RESULT ")), None)
    assert line is not None, res.stderr
    return res.stdout, line


def _plan(cache) -> tuple:
    (path,) = cache.glob("plan-*.json")
    return path, json.loads(path.read_text())


def test_second_run_reads_before_the_unit_is_loaded(valve):
    """The first run reads after the unit's load (numba imported before any read) and
    remembers the unit's plan; the second reads from before numba is imported; both give
    the same JSON."""
    argv, cache = valve
    first, line = _run(argv)
    assert line == "RESULT 0 [False]", line
    _, plan = _plan(cache)
    assert plan["name"] == "valve_unit" and plan["period"] == "10s" and plan["lead"] > 0
    assert set(plan["tags"]) >= {"CV", "X", "F", "P1", "P2"}
    second, line = _run(argv)
    assert line == "RESULT 0 [True]", line
    assert second == first and '"samples": 8640' in first


@pytest.mark.parametrize(
    "edit",
    [
        {"tags": ["NOPE"]},  # a tag the historian does not hold: the early read fails
        {"period": "20s"},  # another grid: the pieces would differ
        {"lead": 1},  # another lead-in (read only with --from)
    ],
)
def test_a_plan_that_no_longer_fits_is_dropped(valve, edit):
    """A remembered plan unlike the unit's (its rule bases edited since, say) is read from,
    then dropped once the unit is loaded: the unit's own read gives the output, the same
    bytes as without a plan, and the plan is written anew."""
    argv, cache = valve
    argv = [*argv, "--from", "2026-01-01T06:00:00", "--chunk", "3h"]
    want, _ = _run(argv)
    path, plan = _plan(cache)
    path.write_text(json.dumps({**plan, **edit}))
    got, line = _run(argv)
    assert line == "RESULT 0 [True]", line  # the wrong plan was read from
    assert got == want and '"samples":' in got
    assert _plan(cache)[1] == plan
