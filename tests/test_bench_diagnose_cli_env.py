"""``benchmarks/bench_diagnose_cli.py`` runs each ``diag diagnose`` with the checkout on
``PYTHONPATH`` and without ``PYTHONDONTWRITEBYTECODE`` (issue 34, "Speed", round fourteen):
with it a ``git archive`` snapshot, which has no bytecode, compiled every module from source
in every timed run, as an installed package does not."""

from __future__ import annotations

import importlib.util
from pathlib import Path

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_diagnose_cli.py"


def _bench():
    spec = importlib.util.spec_from_file_location("bench_diagnose_cli", BENCH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_child_env_writes_bytecode_and_runs_the_checkout(monkeypatch, tmp_path):
    monkeypatch.setenv("PYTHONDONTWRITEBYTECODE", "1")
    monkeypatch.setenv("DIAG_BENCH_KEPT", "yes")
    env = _bench().child_env(tmp_path)
    assert "PYTHONDONTWRITEBYTECODE" not in env
    assert env["PYTHONPATH"] == str(tmp_path)
    assert env["DIAG_BENCH_KEPT"] == "yes"  # the rest of the environment passed on
