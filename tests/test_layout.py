"""The package's layout keeps its promises: small modules, functions that read in one screen, floors in one strict
order (a module imports only its own floor and the floors below) and no import circle between its modules, counting
every import a module makes (at its top, inside functions, under ``if TYPE_CHECKING:``)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "roodi_toolkit"
# DESIGN.md's floors, lowest first ("arrows point down this list"), then the click commands. The top-level modules
# (errors, gaussians, cameras, params, lpips, ...) are the core. The package's __init__ is the front door a user
# imports (``import roodi_toolkit as rt``: the public names, re-exported from the core and io), above every floor:
# no module of the package imports it.
# run: the run layer (output folders, stage records and reuse, resume, checkpoints, pictures) walks the stages of pipeline
# and evaluate; the demo (synth), batch and cli call it.
FLOORS = ("core", "io", "render", "prune", "pipeline", "evaluate", "viz", "run", "synth", "batch", "cli",
          "front door")
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


MAX_FUNCTION_LINES = 80
LONG_KERNELS = {  # numba kernels: one loop over pixels or Gaussians each, split only at a cost in speed
    "render/kernels.py:composite_forward", "render/kernels.py:composite_backward",
    "render/projection_kernels.py:project_forward", "render/projection_kernels.py:project_backward",
}


def _lines_of_code(lines: list[str], node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """Return a function's lines that are not blank and not comments, less its docstring's lines."""
    code = [line for line in lines[node.lineno - 1:node.end_lineno] if line.strip()
            and not line.strip().startswith("#")]
    doc = ast.get_docstring(node)
    return len(code) - (len(doc.splitlines()) if doc else 0)


def _long_functions(root: Path) -> dict[str, int]:
    """Return the functions (methods and nested functions too) of the modules under ``root`` over
    :data:`MAX_FUNCTION_LINES` lines of code, as ``module path:name`` -> lines."""
    found = {}
    for path in sorted(p for p in root.rglob("*.py") if "__pycache__" not in p.parts):
        source = path.read_text()
        lines = source.splitlines()
        for node in ast.walk(ast.parse(source)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = _lines_of_code(lines, node)
                if n > MAX_FUNCTION_LINES:
                    found[f"{path.relative_to(root).as_posix()}:{node.name}"] = n
    return found


def test_the_line_count_skips_blanks_comments_and_the_docstring(tmp_path):
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_FUNCTION_LINES - 2))
    (tmp_path / "m.py").write_text(f'''def short():
    """One line.

    Two more.
    """
    # a comment

{body}
    return x0


def long():
    """Doc."""
{body}
    y = 1
    return y
''')
    assert _long_functions(tmp_path) == {"m.py:long": MAX_FUNCTION_LINES + 1}


def test_functions_read_in_one_screen():
    """At most 80 lines of code a function, but for the numba kernels (issue 35: functions read in one screen)."""
    long = _long_functions(ROOT)
    assert set(long) <= LONG_KERNELS, "split along its steps: " + ", ".join(
        f"{name} ({n} lines)" for name, n in sorted(long.items()) if name not in LONG_KERNELS)


def _floor(name: str) -> str:
    """Return the floor of module ``name`` (one of :data:`FLOORS`)."""
    parts = name.split(".")
    if len(parts) == 1:
        return "front door"
    return parts[1] if (ROOT / parts[1]).is_dir() else "core"


def _arrows_up(graph: dict[str, set[str]]) -> list[str]:
    """Return ``"a -> b (floor a -> floor b)"`` for each import of a module ``a`` of a floor below ``b``'s."""
    return sorted(f"{a} -> {b} ({_floor(a)} -> {_floor(b)})" for a, imported in graph.items() for b in imported
                  if FLOORS.index(_floor(b)) > FLOORS.index(_floor(a)))


def test_every_folder_of_the_package_is_a_floor():
    folders = {p.parent.relative_to(ROOT).parts[0] for p in MODULES if p.parent != ROOT}
    assert folders <= set(FLOORS), f"give {sorted(folders - set(FLOORS))} a place in FLOORS (and in DESIGN.md's order)"


def test_the_floor_finder_places_modules_and_finds_arrows_up():
    assert [_floor(m) for m in ("roodi_toolkit", "roodi_toolkit.errors", "roodi_toolkit.io", "roodi_toolkit.io.ply",
                                "roodi_toolkit.cli.main")] == ["front door", "core", "io", "io", "cli"]
    graph = {"roodi_toolkit.io.ply": {"roodi_toolkit.errors", "roodi_toolkit.io.files"},
             "roodi_toolkit.evaluate.benchmark": {"roodi_toolkit.pipeline.extract", "roodi_toolkit.synth.scene"},
             "roodi_toolkit.lpips": {"roodi_toolkit.io.files"}, "roodi_toolkit.cli.cmd_info": {"roodi_toolkit"}}
    assert _arrows_up(graph) == ["roodi_toolkit.cli.cmd_info -> roodi_toolkit (cli -> front door)",
                                 "roodi_toolkit.evaluate.benchmark -> roodi_toolkit.synth.scene (evaluate -> synth)",
                                 "roodi_toolkit.lpips -> roodi_toolkit.io.files (core -> io)"]


def test_floors_import_only_their_own_floor_and_the_floors_below():
    """Every import of the package's modules, made anywhere in them, points down DESIGN.md's order of floors (or
    stays on its floor): what two floors share lives on the lower one, or the upper caller passes it in."""
    arrows = _arrows_up(_graph())
    assert arrows == [], "imports up the floors:\n" + "\n".join(arrows)


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
    upright = ROOT / "render" / "upright.py"  # imports the dataset readers only inside a function (_dataset_cameras)
    assert "roodi_toolkit.io.dataset" in _imports(upright, top_level_only=False)
    assert "roodi_toolkit.io.dataset" not in _imports(upright, top_level_only=True)


def test_no_import_cycle():
    """No module of the package imports, through any chain of imports made anywhere in the modules, itself."""
    circles = _circles(_graph())
    assert circles == [], "import circles:\n" + "\n".join(" -> ".join(c) for c in circles)


MAX_LAZY_IMPORTS = 20
LAZY_REASON = "# lazy:"


def _lazy_imports(source: str) -> list[tuple[int, bool]]:
    """Return ``(line, has a reason)`` for each import made inside a function of ``source`` (once, however deeply
    nested): the reason is a ``# lazy: why`` comment on the import's lines or on the line just above it."""
    lines = source.splitlines()

    def says_why(line: str) -> bool:
        return LAZY_REASON in line and bool(line.split(LAZY_REASON, 1)[1].strip())

    found: dict[int, bool] = {}
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for sub in ast.walk(node):
                if isinstance(sub, (ast.Import, ast.ImportFrom)):
                    above = lines[sub.lineno - 2] if sub.lineno > 1 else ""
                    found[sub.lineno] = (any(says_why(line) for line in lines[sub.lineno - 1:sub.end_lineno])
                                         or (above.strip().startswith("#") and says_why(above)))
    return sorted(found.items())


def test_the_lazy_import_finder_counts_and_reads_reasons():
    source = """import os


def a():
    import json
    from . import b  # lazy: b imports torch
    # lazy: an optional plugin, loaded only when asked for
    import c

    def inner():
        import d  # lazy:
    return json, b, c, inner


x = 1  # lazy: not an import
"""
    assert _lazy_imports(source) == [(5, False), (6, True), (8, True), (11, False)]


def test_imports_inside_functions_are_few_and_say_why():
    """Imports inside functions only for optional heavy dependencies and plugins, each with a ``# lazy:`` reason, at
    most :data:`MAX_LAZY_IMPORTS` in the package (issue 35); everything else at the top, where readers and tools see
    the real graph."""
    lazy, unsaid = 0, []
    for path in MODULES:
        rel = path.relative_to(ROOT).as_posix()
        found = _lazy_imports(path.read_text())
        lazy += len(found)
        unsaid += [f"{rel}:{line}" for line, said in found if not said]
    assert not unsaid, "move to the module's top, or say why it must wait (# lazy: reason): " + ", ".join(unsaid)
    assert lazy <= MAX_LAZY_IMPORTS, f"{lazy} imports inside functions (at most {MAX_LAZY_IMPORTS})"
