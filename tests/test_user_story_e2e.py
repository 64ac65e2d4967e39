"""The user story end to end, run exactly as a user would: `diag` commands in a fresh folder."""

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import run_diag


def diag(cwd: Path, *args: str, check: bool = True) -> subprocess.CompletedProcess:
    p = run_diag(cwd, *args)
    if check and p.returncode != 0:
        raise AssertionError(f"diag {' '.join(args)} failed ({p.returncode}):\n{p.stderr}")
    return p


#: days simulated for the staircase: 15 (45 until issue 33 item 6) keep every assertion's
#: margin wide on seed 31 (v2/v1 = 0.19 against < 0.5, covered 0.19 against < 1/3; training
#: gives explain's promise to 4e-5 against 2 %) at a third of the cost (20 CPU s of commands)
DAYS = 15


@pytest.mark.slow
def test_error_staircase_from_the_command_line(tmp_path):
    diag(tmp_path, "simulate", "--days", str(DAYS), "--seed", "31", "--out", "plant.parquet")
    diag(tmp_path, "import", "plant.parquet")
    tags = json.loads(diag(tmp_path, "tags", "--json").stdout)
    assert {"CV", "P1", "P2", "F"} <= {t["tag"] for t in tags}

    diag(tmp_path, "model", "new", "valve", "--output", "F", "--input", "CV[k-1]")
    assert (tmp_path / "rulebases" / "valve.toml").exists()
    first = json.loads(diag(tmp_path, "train", "valve", "--json").stdout)
    assert set(first["validation"]) >= {"rmse_pct", "mae_pct", "coverage"}
    assert first["samples"] > 0.9 * DAYS * 8640

    cmp_ = json.loads(diag(tmp_path, "compare", "valve", "--json").stdout)
    assert {"rmse_pct", "coverage", "worst_regions", "worst_periods"} <= set(cmp_)

    ex = json.loads(diag(tmp_path, "explain", "valve", "--json").stdout)
    assert ex["baseline_rmse_pct"] == pytest.approx(first["validation"]["rmse_pct"], rel=0.02)
    best = ex["candidates"][0]
    assert set(best) >= {"input", "kind", "effect", "rmse_pct_if_added", "command"}
    # best first: among candidates that cover the data, the errors rise down the list
    full = [c["rmse_pct_if_added"] for c in ex["candidates"] if c["coverage"] >= 0.95]
    assert full == sorted(full) and best["rmse_pct_if_added"] == full[0]
    # run the suggested command exactly as printed
    cmd = best["command"]
    assert cmd.startswith("diag model add-input valve ")
    subprocess.run(
        [sys.executable, "-m", "diag_plugin", *_split(cmd)[1:]],
        cwd=tmp_path,
        check=True,
        capture_output=True,
        timeout=600,
    )
    second = json.loads(diag(tmp_path, "train", "valve", "--json").stdout)
    # explain's promise is what training gives (both score unsupported samples with the
    # nearest rule), and the error falls over two-fold; three-fold where covered
    v1, v2 = first["validation"], second["validation"]
    assert v2["rmse_pct"] == pytest.approx(best["rmse_pct_if_added"], rel=0.02)
    assert v2["rmse_pct"] < v1["rmse_pct"] / 2
    assert v2["rmse_covered_pct"] < v1["rmse_covered_pct"] / 3

    log = json.loads(diag(tmp_path, "experiments", "valve", "--json").stdout)["experiments"]
    assert [e["version"] for e in log] == ["1", "2"]
    assert log[0]["inputs"] == ["CV[k-1]"] and log[1]["inputs"] == ["CV[k-1]", best["input"]]
    assert log[1]["rmse_pct"] < log[0]["rmse_pct"] / 2  # the staircase

    shown = diag(tmp_path, "rules", "show", "valve").stdout
    assert "CV[k-1]" in shown and best["input"] in shown
    assert diag(tmp_path, "rules", "check", "rulebases/valve.toml").returncode == 0


def _split(cmd: str) -> list[str]:
    import shlex

    return shlex.split(cmd)


def test_bad_input_gets_a_clear_error(tmp_path):
    p = diag(tmp_path, "train", "nosuchmodel", check=False)
    assert p.returncode != 0 and "nosuchmodel" in (p.stderr + p.stdout)
    p = diag(tmp_path, "model", "add-input", "nosuchmodel", "P1[k]", check=False)
    assert p.returncode == 2 and "does not exist" in p.stderr
    (tmp_path / "rulebases").mkdir()
    (tmp_path / "rulebases" / "bad.toml").write_text("[model]\nname = 'bad'\n")
    p = diag(tmp_path, "rules", "check", "rulebases/bad.toml", check=False)
    assert p.returncode == 2 and "bad.toml:" in p.stdout and "missing section [output]" in p.stdout


def test_unreachable_database_is_a_clear_error(tmp_path):
    rules = Path(__file__).resolve().parents[1] / "rulebases"
    url = "postgresql://postgres:secret@127.0.0.1:1/nope"  # nothing listens on port 1
    p = diag(tmp_path, "--db", url, "--rulebases", str(rules), "compare", "valve_b", check=False)
    assert p.returncode == 3
    assert "database error (postgresql://postgres:***@127.0.0.1:1/nope)" in p.stderr
    assert "secret" not in p.stderr and "Traceback" not in p.stderr


def test_demo_runs_end_to_end(tmp_path):
    """`make run` runs `diag demo`: simulate, historian, train, compare, explain, add, report."""
    p = diag(tmp_path, "demo", "--days", "6", "--workdir", "demo")
    out = " ".join(p.stdout.split())  # the console wraps long lines
    # the error it prints falls: step 3 trains F = f(CV[k-1]), step 6 adds the best input
    first = re.search(r"3\. train valve .*?: held-out RMSE ([0-9.]+) % of span", out)
    final = re.search(r"6\. add-input \+ train (\S+): held-out RMSE ([0-9.]+) % of span", out)
    assert first and final, p.stdout
    assert float(final[2]) < float(first[1]) / 2, (first[0], final[0])
    # and so does the experiment log the demo's historian keeps, which the table shows
    url = f"sqlite:///{tmp_path / 'demo' / 'diag.db'}"
    log = json.loads(diag(tmp_path, "--db", url, "experiments", "valve", "--json").stdout)
    log = log["experiments"]
    assert [e["version"] for e in log] == ["1", "2"]
    assert log[1]["inputs"] == ["CV[k-1]", final[1]]
    assert [f"{e['rmse_pct']:.2f}" for e in log] == [first[1], final[2]]
    assert log[-1]["rmse_pct"] < log[0]["rmse_pct"]
    assert "7. experiments: the error falls" in out
    assert (tmp_path / "demo" / "valve.html").stat().st_size > 100_000
    assert (tmp_path / "demo" / "rulebases" / "valve.toml").exists()
