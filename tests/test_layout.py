"""Data flow one way (issues 7, 33): historian is storage only and imports nothing from
diag_plugin; every package sits in one layer order and imports only what lies below it, except
the arrows the allow-list names with a reason (README, "Layout"); the CLI never hides a broken
command module."""

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
#: publishes, below both; cliargs.py: options every package's cli.py declares alike, such as
#: the CLI contract's --json, so it sits below simulate/ and rulebase/, the lowest packages
#: with commands, and thereby below every package that has a cli.py)
SHARED = {
    "__init__.py",
    "__main__.py",
    "cli.py",
    "cliargs.py",
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
    docs = ROOT / "docs"
    index = (docs / "index.md").read_text(encoding="utf-8")
    kinds = ("tutorial", "how-to", "reference", "explanation")
    found = [*docs.glob("*.md"), *(p for k in kinds for p in (docs / k).glob("*.md"))]
    pages = {p.relative_to(docs).as_posix() for p in found} - {"index.md"}
    missing = {p for p in pages if f"]({p})" not in index}
    assert not missing, sorted(missing)


#: the layer order: each package (or shared loose module) and the ones directly below it; a
#: package may import anything below it, directly or through another (README, "Layout")
BELOW: dict[str, tuple[str, ...]] = {
    "historian": (),
    "diag_plugin.tomllines": (),
    "diag_plugin.metrics": (),
    "diag_plugin.status": (),
    "diag_plugin.cliargs": (),
    "diag_plugin.regressors": ("historian",),
    "diag_plugin.simulate": ("historian", "diag_plugin.cliargs"),
    "connectors": ("diag_plugin.status", "diag_plugin.simulate"),
    "diag_plugin.models": ("diag_plugin.regressors", "diag_plugin.metrics"),
    "diag_plugin.fuzzy": ("diag_plugin.models",),
    "diag_plugin.rulebase": ("diag_plugin.fuzzy", "diag_plugin.tomllines", "diag_plugin.cliargs"),
    "diag_plugin.training": ("diag_plugin.rulebase",),
    "diag_plugin.selection": ("diag_plugin.training",),
    "diag_plugin.workbench": ("diag_plugin.selection",),
    "diag_plugin.diagnose": ("diag_plugin.rulebase", "diag_plugin.status"),
    "diag_plugin.learn": ("diag_plugin.diagnose",),
    "diag_plugin.unitbuild": ("diag_plugin.learn", "diag_plugin.selection"),
    "diag_plugin.bench": ("diag_plugin.unitbuild", "diag_plugin.simulate"),
    "diag_plugin.engine": ("diag_plugin.diagnose", "diag_plugin.training", "diag_plugin.simulate"),
    "diag_plugin.examples": ("diag_plugin.workbench", "diag_plugin.learn", "diag_plugin.engine"),
    "diag_plugin.live": ("connectors", "diag_plugin.examples"),
}
#: above every layer: the ``diag`` command assembles every package's commands
TOP = ("diag_plugin.cli", "diag_plugin.__main__")

_CODEC = "type annotation only: a method's codec reads and writes the rule-base document"
_CHECK = "`diag rules check` checks every file an expert edits, unit files and matrices too"
#: the arrows that run up the layer order, each with its reason; README ("Layout") lists the
#: same arrows with the same reasons
ALLOWED_UP: dict[tuple[str, str], str] = {
    ("diag_plugin.fuzzy.ts_fcm", "diag_plugin.rulebase.document"): _CODEC,
    ("diag_plugin.fuzzy.wm_codec", "diag_plugin.rulebase.document"): _CODEC,
    ("diag_plugin.models.joint", "diag_plugin.rulebase.document"): _CODEC,
    ("diag_plugin.models.linear", "diag_plugin.rulebase.document"): _CODEC,
    ("diag_plugin.models.narmax", "diag_plugin.rulebase.document"): _CODEC,
    ("diag_plugin.models.track", "diag_plugin.rulebase.document"): _CODEC,
    ("diag_plugin.rulebase.cli", "diag_plugin.diagnose.matrix"): _CHECK,
    ("diag_plugin.rulebase.cli", "diag_plugin.diagnose.unit"): _CHECK,
    ("diag_plugin.rulebase.cli", "diag_plugin.diagnose.unitfile"): _CHECK,
}


def _module(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _unit(module: str) -> str:
    """The layer a module belongs to: its package, or itself for a loose module."""
    parts = module.split(".")
    return ".".join(parts[:2]) if parts[0] == "diag_plugin" and len(parts) > 1 else parts[0]


def _is_module(name: str) -> bool:
    p = ROOT / name.replace(".", "/")
    return p.with_suffix(".py").is_file() or (p / "__init__.py").is_file()


def arrows(path: Path) -> set[str]:
    """Every module ``path`` imports, wherever the import stands (module level, inside a
    function, under ``TYPE_CHECKING``); relative imports resolved; ``from P import m`` names
    the module ``P.m`` where ``m`` is one."""
    me = _module(path)
    package = me if path.name == "__init__.py" else me.rpartition(".")[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join(up + ([node.module] if node.module else []))
            for a in node.names:
                out.add(f"{base}.{a.name}" if _is_module(f"{base}.{a.name}") else base)
    return out


def _below(unit: str) -> set[str]:
    seen: set[str] = set()
    todo = list(BELOW[unit])
    while todo:
        u = todo.pop()
        if u not in seen:
            seen.add(u)
            todo.extend(BELOW[u])
    return seen


def _our_files() -> list[Path]:
    dirs = ("diag_plugin", "connectors", "historian")
    return sorted(p for d in dirs for p in (ROOT / d).rglob("*.py"))


def test_every_package_has_a_place_in_the_layer_order():
    units = {_unit(_module(p)) for p in _our_files()} - {"diag_plugin", *TOP}
    assert units, "no modules found"
    assert not units - set(BELOW), sorted(units - set(BELOW))
    for u in BELOW:  # the order has no cycle: nothing lies below itself
        assert u not in _below(u), u


def test_no_import_runs_up_the_layer_order_except_the_allowed_ones():
    up, used = [], set()
    for path in _our_files():
        me = _module(path)
        src = _unit(me)
        for target in arrows(path):
            dst = _unit(target)
            if dst not in BELOW or dst == src or src in TOP or dst in _below(src):
                continue
            if (me, target) in ALLOWED_UP:
                used.add((me, target))
            else:
                up.append(f"{path.relative_to(ROOT)}: imports {target} ({dst} is not below {src})")
    assert not up, "\n".join(sorted(up))
    stale = sorted(set(ALLOWED_UP) - used)
    assert not stale, f"allowed arrows no longer in the code (remove here and in README): {stale}"


def _is_command_module(module: str) -> bool:
    """A command module: a package's ``cli.py`` (its commands' parsers and handlers), or the
    ``diag`` command above them all."""
    return module.rpartition(".")[2] == "cli" or module in TOP


def test_no_library_module_imports_a_command_module():
    """Commands sit on top of the library, never under it: a module that is not a command
    module (``*/cli.py``) imports none (what two of them share belongs in a library module,
    e.g. the lead-in in ``diagnose/leadin.py``, used by ``diag diagnose`` and the live
    catch-up alike)."""
    bad = []
    for path in _our_files():
        me = _module(path)
        if _is_command_module(me):
            continue
        for target in arrows(path):
            if _is_command_module(target) and _is_module(target):
                bad.append(f"{path.relative_to(ROOT)}: imports the command module {target}")
    assert not bad, "\n".join(sorted(bad))


def test_the_readme_lists_each_allowed_arrow_with_its_reason():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    lines = readme.split("## Layout", 1)[1].split("\n## ", 1)[0].splitlines()
    for (src, dst), why in ALLOWED_UP.items():
        arrow = f"`{src}` → `{dst}`"
        hits = [ln for ln in lines if arrow in ln]
        assert hits, f"README Layout does not list {arrow}"
        assert any(why in ln for ln in hits), f"README Layout: {arrow} without its reason: {why}"


def _shown(unit: str) -> str:
    name = unit.removeprefix("diag_plugin.")
    module = (ROOT / unit.replace(".", "/")).with_suffix(".py").is_file()
    return f"{name}.py" if module else f"{name}/"


def test_the_readme_shows_the_layer_order_the_test_holds():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    block = readme.split("### Layer order", 1)[1].split("```", 2)[1]  # the first code block
    rows = {ln.split()[0]: " ".join(ln.split()[1:]) for ln in block.splitlines() if ln.strip()}
    for unit, below in BELOW.items():
        want = ", ".join(_shown(b) for b in below) or "—"
        assert rows.get(_shown(unit)) == want, f"README layer order: {_shown(unit)}  {want}"
