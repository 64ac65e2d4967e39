"""docs/tutorial.md reproduces: its commands run as written and print its numbers."""

import json
import re
import shlex
from pathlib import Path

import pytest
from helpers import run_diag

DOC = Path(__file__).resolve().parents[1] / "docs" / "tutorial.md"


def commands(text: str) -> list[list[str]]:
    return [shlex.split(m) for m in re.findall(r"^\$ diag (.+)$", text, flags=re.M)]


def staircase(text: str) -> list[tuple[str, list[str], float]]:
    rows = re.findall(r"^\| (\d+) \| ([^|]+) \| ([\d.]+) \|$", text, flags=re.M)
    return [(v, [s.strip() for s in inputs.split(", ")], float(e)) for v, inputs, e in rows]


@pytest.mark.slow
def test_tutorial_reproduces(tmp_path):
    text = DOC.read_text()
    out = {}
    for args in commands(text):
        p = run_diag(tmp_path, *args, COLUMNS="260")  # the explain table unwrapped
        assert p.returncode == 0, (args, p.stderr)
        out.setdefault(args[0], []).append(p.stdout + p.stderr)
    stated = re.search(
        r"valve v1: held-out RMSE ([\d.]+) % of span, MAE ([\d.]+) %.*; "
        r"([\d,]+) samples, (\d+) rules",
        text,
    )
    printed = re.search(
        r"valve v1: held-out RMSE ([\d.]+) % of span, MAE ([\d.]+) %.*; "
        r"([\d,]+) samples, (\d+) rules",
        out["train"][0],
    )
    assert printed, out["train"][0]
    for a, b in zip(stated.groups()[:2], printed.groups()[:2], strict=True):
        assert float(b) == pytest.approx(float(a), abs=0.05)
    assert printed.groups()[2:] == stated.groups()[2:]
    log = run_diag(tmp_path, "experiments", "valve", "--json")
    got = json.loads(log.stdout)["experiments"]
    want = staircase(text)
    assert len(want) == 2 == len(got)
    for (v, inputs, err), g in zip(want, got, strict=True):
        assert (g["version"], g["inputs"]) == (v, inputs)
        assert g["rmse_pct"] == pytest.approx(err, abs=0.05)
    explained = out["explain"][0]
    assert (
        "diff(P1,P2)[k] would cut the error" in explained and "7.7 % to 1.6 % of span" in explained
    )
    assert (tmp_path / "valve.html").stat().st_size > 100_000
