"""Data flow one way (issue 7): historian is storage only and imports nothing from
diag_plugin; the CLI never hides a broken command module."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def imported_modules(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.add(node.module)
    return out


def test_historian_imports_nothing_from_diag_plugin():
    files = sorted((ROOT / "historian").rglob("*.py"))
    assert len(files) > 5
    bad = {
        f"{p.relative_to(ROOT)}: {m}"
        for p in files
        for m in imported_modules(p)
        if m.split(".")[0] in ("diag_plugin", "connectors")
    }
    assert not bad, sorted(bad)


def test_a_broken_command_module_is_an_error_not_a_missing_command(monkeypatch):
    from diag_plugin import cli

    monkeypatch.setattr(cli, "COMMAND_MODULES", (*cli.COMMAND_MODULES, "diag_plugin.no_such"))
    with pytest.raises(ModuleNotFoundError, match="diag_plugin.no_such"):
        cli.build_parser()


#: the small modules every stage shares, the only loose modules beside the stage packages
#: (status.py: the NE 107 status vocabulary the run-time diagnosis produces and connectors/
#: publishes, below both)
SHARED = {
    "__init__.py",
    "__main__.py",
    "cli.py",
    "regressors.py",
    "metrics.py",
    "tomllines.py",
    "status.py",
}


def test_each_stage_is_a_package_with_its_commands_in_its_own_cli():
    pkg = ROOT / "diag_plugin"
    loose = {p.name for p in pkg.glob("*.py")}
    assert loose <= SHARED, sorted(loose - SHARED)
    from diag_plugin import cli

    for name in cli.COMMAND_MODULES:
        assert name.endswith(".cli"), name


def test_docs_index_lists_every_page():
    index = (ROOT / "docs" / "index.md").read_text(encoding="utf-8")
    pages = {p.name for p in (ROOT / "docs").glob("*.md")} - {"index.md"}
    missing = {p for p in pages if f"]({p})" not in index}
    assert not missing, sorted(missing)
