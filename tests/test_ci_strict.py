"""CI=true turns a skip for a missing peer or system part into a failure (conftest.py)."""

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
PROBE = """
import pytest
from helpers import require, requires

HOW = "Debian package 'frob'; .ci/sysdeps installs it"


@requires("the frob command", False, HOW)
def test_marked():
    pass


def test_required():
    require("the frob command", False, HOW)


def test_present():
    require("the frob command", True, HOW)


def test_other_skip():
    pytest.skip("not on this platform")
"""


def _run(tmp_path: Path, ci: str | None) -> tuple[dict[str, str], str]:
    """Outcome of each probe test with this suite's conftest.py and helpers.py."""
    for name in ("conftest.py", "helpers.py"):
        shutil.copy(HERE / name, tmp_path / name)
    (tmp_path / "test_probe.py").write_text(PROBE)
    env = {k: v for k, v in os.environ.items() if k != "CI"}
    if ci is not None:
        env["CI"] = ci
    p = subprocess.run(
        [sys.executable, "-m", "pytest", "-v", "-rA", "-p", "no:cacheprovider", "test_probe.py"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    found = re.findall(r"^test_probe\.py::(\w+) (PASSED|FAILED|ERROR|SKIPPED)", p.stdout, re.M)
    return dict(found), p.stdout


@pytest.mark.parametrize("ci", [None, "false"])
def test_missing_parts_skip_off_ci(tmp_path, ci):
    outcomes, out = _run(tmp_path, ci)
    assert outcomes == {
        "test_marked": "SKIPPED",
        "test_required": "SKIPPED",
        "test_present": "PASSED",
        "test_other_skip": "SKIPPED",
    }, out
    assert "missing peer/system part: the frob command (Debian package 'frob'" in out


@pytest.mark.parametrize("ci", ["true"])
def test_missing_parts_fail_on_ci(tmp_path, ci):
    outcomes, out = _run(tmp_path, ci)
    assert outcomes == {
        "test_marked": "ERROR",  # a skip mark acts in set-up: pytest calls that an error
        "test_required": "FAILED",
        "test_present": "PASSED",
        "test_other_skip": "SKIPPED",  # other skips stay skips
    }, out
    why = "CI=true: this test would skip, but on CI nothing may be missing: missing "
    why += "peer/system part: the frob command (Debian package 'frob'; .ci/sysdeps installs it)"
    assert f"ERROR test_probe.py::test_marked - {why}" in out
    assert f"FAILED test_probe.py::test_required - {why}" in out
