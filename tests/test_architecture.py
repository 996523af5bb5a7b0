"""The package's architecture as docs/architecture.md states it: subpackages in layers, every
import (at the top, inside a function or under TYPE_CHECKING alike) running from a layer to a
lower one or within one subpackage, no import circle among modules, and small modules.

The layer table is read from docs/architecture.md, so the docs and the code cannot drift apart.
"""

from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "feltool"
DOC = ROOT / "docs" / "architecture.md"
MAX_LINES = 600


def layers() -> dict[str, int]:
    """``{unit: layer}`` from the doc's table rows ``| 3 | `robot` | ... |`` (a unit is a
    subpackage or a root module of feltool)."""
    out = {}
    for line in DOC.read_text().splitlines():
        m = re.match(r"^\|\s*(\d+)\s*\|([^|]*)\|", line)
        if m:
            for name in re.findall(r"`([\w.]+)`", m.group(2)):
                out[name] = int(m.group(1))
    assert out, "docs/architecture.md has no layer table"
    return out


def modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(ROOT).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = path
    return out


def unit(module: str) -> str:
    """The table's unit of a module: ``feltool.runs.seed`` -> ``runs``; ``feltool.errors`` ->
    ``errors``; the package's face ``feltool`` -> ``feltool``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "feltool"


def imports(path: Path, known: set[str]) -> set[str]:
    """Every feltool module ``path`` imports, wherever the import statement stands."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module and \
                node.module.split(".")[0] == "feltool":
            names = [f"{node.module}.{a.name}" for a in node.names] + [node.module]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names if a.name.split(".")[0] == "feltool"]
        for name in names:
            while name not in known and "." in name:
                name = name.rsplit(".", 1)[0]
            if name in known:
                out.add(name)
    return out


def graph() -> dict[str, set[str]]:
    mods = modules()
    return {m: imports(p, set(mods)) - {m} for m, p in mods.items()}


def test_every_module_belongs_to_a_layer_of_the_doc():
    table = layers()
    missing = sorted({unit(m) for m in modules()} - set(table))
    assert not missing, f"not in docs/architecture.md's layer table: {missing}"


def test_imports_run_from_a_layer_to_a_lower_one():
    """Lazy and TYPE_CHECKING imports count: an upward import is a circle however it is made."""
    table, bad = layers(), []
    for m, targets in graph().items():
        for t in targets:
            a, b = unit(m), unit(t)
            if a != b and not table[b] < table[a]:
                bad.append(f"{m} (layer {table[a]}) imports {t} (layer {table[b]})")
    assert not bad, "\n".join(sorted(bad))


def test_no_import_circle_among_modules():
    g = graph()
    state: dict[str, int] = {}
    path: list[str] = []

    def visit(m):
        state[m] = 1
        path.append(m)
        for t in sorted(g[m]):
            if state.get(t) == 1:
                raise AssertionError("import circle: " + " -> ".join(path[path.index(t):] + [t]))
            if t not in state:
                visit(t)
        path.pop()
        state[m] = 2

    for m in sorted(g):
        if m not in state:
            visit(m)


def test_the_check_itself_finds_a_circle_and_an_upward_import(tmp_path, monkeypatch):
    """The checks above fail on a package that has an upward lazy import."""
    pkg = tmp_path / "feltool"
    (pkg / "robot").mkdir(parents=True)
    (pkg / "runs").mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "robot" / "__init__.py").write_text("")
    (pkg / "runs" / "__init__.py").write_text("")
    (pkg / "robot" / "robot.py").write_text("def f():\n    from feltool.runs.seed import g\n")
    (pkg / "runs" / "seed.py").write_text("from feltool.robot.robot import f\n")
    doc = tmp_path / "docs" / "architecture.md"
    doc.parent.mkdir()
    doc.write_text("| 1 | `robot` | |\n| 2 | `runs` | |\n| 3 | `feltool` | |\n")
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE", pkg)
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    monkeypatch.setattr(sys.modules[__name__], "DOC", doc)
    with pytest.raises(AssertionError, match="robot.robot .layer 1. imports feltool.runs.seed"):
        test_imports_run_from_a_layer_to_a_lower_one()
    with pytest.raises(AssertionError, match="import circle"):
        test_no_import_circle_among_modules()


def test_no_module_is_over_600_lines():
    long = {str(p.relative_to(ROOT)): n for p in PACKAGE.rglob("*.py")
            if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert not long, long


@pytest.mark.parametrize("init", sorted(PACKAGE.glob("*/**/__init__.py")),
                         ids=lambda p: str(p.parent.relative_to(PACKAGE)))
def test_each_subpackage_says_what_lives_there_and_what_it_may_import(init):
    tree = ast.parse(init.read_text())
    doc = ast.get_docstring(tree)
    assert doc and "Imports from feltool:" in doc, init
    assert not any(isinstance(n, (ast.Import, ast.ImportFrom)) for n in tree.body), \
        f"{init} imports: a subpackage's __init__ only describes it"
