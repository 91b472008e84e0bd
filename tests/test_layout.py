"""The package's layout keeps its promises: small modules, the lower layers know nothing of the pipeline, and no
import circle between its modules, counting every import a module makes (at its top, inside functions, under
``if TYPE_CHECKING:``)."""

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


KNOWN = {_name(p) for p in MODULES}


def _imports(path: Path, top_level_only: bool) -> set[str]:
    """Return the roodi_toolkit modules ``path`` imports (relative imports resolved).

    ``from package import name`` is an import of the submodule ``package.name`` where there is one, else of
    ``package`` itself (a name its ``__init__`` defines).
    """
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
                for alias in node.names:
                    sub = f"{module}.{alias.name}"
                    found.add(sub if sub in KNOWN else module)
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.startswith("roodi_toolkit"))
    return found & KNOWN


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


def _circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Return the circles of ``graph`` as ``[a, b, ..., a]``: in each group of modules that import one another (a
    strongly connected component, found by Tarjan's algorithm), shortest circles until every module of the group is
    on one of them."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    groups = []

    def connect(node: str) -> None:  # recursion depth is bounded by the package's module count
        index[node] = low[node] = len(index)
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if nxt not in index:
                connect(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            group = set()
            while True:
                member = stack.pop()
                group.add(member)
                if member == node:
                    break
            if len(group) > 1:
                groups.append(group)

    for node in sorted(graph):
        if node not in index:
            connect(node)
    circles = []
    for group in groups:
        on_a_circle: set[str] = set()
        for start in sorted(group - on_a_circle):  # every module of the group on at least one named circle
            if start in on_a_circle:
                continue
            came_from: dict[str, str | None] = {start: None}  # breadth first inside the group: the shortest way back
            queue, last = [start], start
            while queue:
                node = queue.pop(0)
                if start in graph[node]:
                    last = node
                    break
                for nxt in sorted(graph[node] & group - came_from.keys()):
                    came_from[nxt] = node
                    queue.append(nxt)
            chain: list[str] = []
            step: str | None = last
            while step is not None:
                chain.append(step)
                step = came_from[step]
            circles.append(chain[::-1] + [start])
            on_a_circle.update(chain)
    return sorted(circles)


def _graph() -> dict[str, set[str]]:
    # a package's __init__ importing its own submodules is no circle of concern; a submodule importing the package is
    return {_name(p): {m for m in _imports(p, top_level_only=False) if m != _name(p)} for p in MODULES}


def test_the_circle_finder_names_a_circle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": set(), "e": {"d"}, "f": {"g"}, "g": {"f"}}
    assert _circles(graph) == [["a", "b", "c", "a"], ["f", "g", "f"]]
    # two circles through "a": the second names "d"
    assert _circles({"a": {"b", "d"}, "b": {"a"}, "d": {"a"}}) == [["a", "b", "a"], ["d", "a", "d"]]
    assert _circles({"a": {"b"}, "b": {"c"}, "c": set()}) == []


def test_imports_inside_functions_count():
    model = ROOT / "io" / "model.py"  # imports the dataset module only inside a function (_quiet_cameras)
    assert "roodi_toolkit.io.dataset" in _imports(model, top_level_only=False)
    assert "roodi_toolkit.io.dataset" not in _imports(model, top_level_only=True)


def test_no_import_cycle():
    """No module of the package imports, through any chain of imports made anywhere in the modules, itself."""
    circles = _circles(_graph())
    assert circles == [], "import circles:\n" + "\n".join(" -> ".join(c) for c in circles)
