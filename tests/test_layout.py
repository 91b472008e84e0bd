"""The package's layout keeps its promises: small modules, the lower layers know nothing of the pipeline, and no
module-level import cycle."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "roodi_toolkit"
LOWER = ("io", "render", "prune")  # know nothing of what builds on them
UPPER = ("pipeline", "evaluate", "viz", "synth", "batch", "cli")
MODULES = sorted(p for p in ROOT.rglob("*.py") if "__pycache__" not in p.parts)


def _name(path: Path) -> str:
    rel = path.relative_to(ROOT.parent).with_suffix("")
    parts = list(rel.parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path, top_level_only: bool) -> set[str]:
    """Return the roodi_toolkit modules ``path`` imports (relative imports resolved)."""
    tree = ast.parse(path.read_text())
    package = _name(path) if path.name == "__init__.py" else _name(path).rsplit(".", 1)[0]
    nodes = tree.body if top_level_only else list(ast.walk(tree))
    found = set()
    for node in nodes:
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - node.level + 1]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            if module.startswith("roodi_toolkit"):
                found.add(module)
                found.update(f"{module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.startswith("roodi_toolkit"))
    known = {_name(p) for p in MODULES}
    return {m for m in found if m in known}


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_module_over_600_lines(path):
    assert len(path.read_text().splitlines()) <= 600


def test_lower_layers_know_nothing_of_the_pipeline():
    offenders = []
    for path in MODULES:
        name = _name(path)
        layer = name.split(".")[1] if name.count(".") >= 1 else ""
        if layer in LOWER or name.count(".") == 1 and layer not in UPPER + LOWER:
            for imported in _imports(path, top_level_only=False):
                if imported.split(".")[1:2] and imported.split(".")[1] in UPPER:
                    offenders.append(f"{name} -> {imported}")
    assert offenders == []


def test_no_import_cycle():
    graph = {_name(p): {m for m in _imports(p, top_level_only=True) if m != _name(p)} for p in MODULES}
    # a package's __init__ importing its own submodules is no cycle of concern; a submodule importing the package is
    state: dict[str, int] = {}
    cycles = []

    def visit(node: str, stack: list[str]) -> None:
        state[node] = 1
        for nxt in graph.get(node, ()):
            if state.get(nxt) == 1:
                cycles.append(" -> ".join(stack[stack.index(nxt):] + [nxt]) if nxt in stack else f"{node} -> {nxt}")
            elif nxt not in state:
                visit(nxt, stack + [nxt])
        state[node] = 2

    for node in graph:
        if node not in state:
            visit(node, [node])
    assert cycles == []
