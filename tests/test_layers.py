"""The floors of the code (docs/design.md §9): every import, at module level or inside
a function, goes to the same floor or one below, and no two modules import each other,
directly or round a longer circle. Read from the source with `ast`, so a lazy import
counts as much as a top-level one."""

from __future__ import annotations

import ast
import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGES = ("app", "backend", "viewer")

# Lowest first. A module may import its own floor and the floors below.
FLOORS: tuple[tuple[str, ...], ...] = (
    ("backend", "backend.common"),
    ("backend.geometry",),
    ("backend.data", "backend.imu"),
    ("backend.frontend", "backend.mapping", "backend.optim", "backend.vio"),
    ("backend.eval",),
    ("backend.pipeline",),
    ("backend.export",),
    ("backend.headless", "backend.sweep"),
    ("viewer",),
    ("app",),
)


def _floor(module: str) -> int:
    """The floor of the longest prefix in FLOORS that names `module` or a package holding it."""
    matches = [(len(p), level) for level, prefixes in enumerate(FLOORS) for p in prefixes if module == p or module.startswith(p + ".")]
    if not matches:
        raise AssertionError(f"{module} is on no floor: add it to FLOORS in {pathlib.Path(__file__).name}")
    return max(matches)[1]


def _modules() -> dict[str, pathlib.Path]:
    found = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def _imports(path: pathlib.Path, known: set[str]) -> set[str]:
    """The project modules `path` imports (a `from package import module` names the module)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [f"{node.module}.{a.name}" for a in node.names] + [node.module]
        else:
            continue
        for name in names:
            while name and name not in known:
                name = name.rpartition(".")[0]
            if name and name.split(".")[0] in PACKAGES:
                out.add(name)
    return out


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    known = set(modules)
    return {m: {i for i in _imports(p, known) if i != m and not m.startswith(i + ".")} for m, p in modules.items()}


def test_no_import_goes_up_a_floor() -> None:
    upward = sorted(f"{m} (floor {_floor(m)}) imports {i} (floor {_floor(i)})" for m, imports in _graph().items() for i in imports if _floor(i) > _floor(m))
    assert not upward, "\n".join(upward)


def test_no_import_circle() -> None:
    graph = _graph()
    # Tarjan's strongly connected components: any with two or more modules is a circle.
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    circles: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                circles.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    assert not circles, "\n".join(" <-> ".join(c) for c in circles)


def test_every_module_is_on_a_floor() -> None:
    for module in _modules():
        _floor(module)
