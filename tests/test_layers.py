"""The packages' layers: every import, module level or inside a function, points down, and no
module imports itself back through a cycle.

    cli (the ``forest`` command: composes every layer)
    bench (every benchmark)
    service (HTTP)        worker (render/ GL, jobs/ task kinds)
    farm (job store, dispatch, tiles, artifacts, reaper, their settings)
    forest (the library)  schemas (what crosses a wire or a file)

The service sends tasks by name and never imports the worker; neither farm nor the worker
imports the HTTP package; the library knows nothing of the farm, and of ``schemas`` only the
file formats it reads (grammars, tile sets), never the HTTP request models. No exemptions.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("cli", "bench", "service", "worker", "farm", "forest", "schemas", "shaders")

# package (folder) -> modules it must not import
FORBIDDEN: dict[str, frozenset[str]] = {
    "cli": frozenset(),
    "bench": frozenset({"cli"}),
    "service": frozenset({"worker", "cli", "bench"}),
    "worker": frozenset({"service", "cli", "bench"}),
    "farm": frozenset({"service", "worker", "cli", "bench"}),
    "forest": frozenset(
        {"service", "worker", "farm", "cli", "bench", "schemas.jobs", "schemas.metrics"}
    ),
    "schemas": frozenset({"service", "worker", "farm", "cli", "bench", "forest"}),
    "shaders": frozenset({"service", "worker", "farm", "cli", "bench", "forest", "schemas"}),
}


def imported_modules(source: str) -> list[tuple[int, str]]:
    """(line, module) of every absolute import in ``source``."""
    found: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found += [(node.lineno, node.module)]
            # ``from worker import jobs`` names worker.jobs as well
            found += [(node.lineno, f"{node.module}.{alias.name}") for alias in node.names]
    return found


def violations(package: str) -> list[str]:
    bad = []
    for path in sorted((ROOT / package).rglob("*.py")):
        for line, module in imported_modules(path.read_text()):
            for banned in FORBIDDEN[package]:
                if module == banned or module.startswith(banned + "."):
                    bad.append(f"{path.relative_to(ROOT)}:{line} imports {module}")
    return bad


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_imports_point_down(package: str) -> None:
    assert (ROOT / package / "__init__.py").is_file()
    assert violations(package) == []


def test_every_package_has_a_layer() -> None:
    top = {p.parent.name for p in ROOT.glob("*/__init__.py")} - {"tests", "web", "docs"}
    assert top <= set(FORBIDDEN), f"packages with no layer rule: {top - set(FORBIDDEN)}"


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def import_graph() -> dict[str, set[str]]:
    """Module -> the project modules it imports (``from a import b`` names a.b where that is a
    module, else a)."""
    modules = {module_name(p): p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        edges = set()
        for _, module in imported_modules(path.read_text()):
            target = module
            while target and target not in modules:
                target = target.rpartition(".")[0]
            if target and target != name and not name.startswith(target + "."):
                edges.add(target)
        graph[name] = edges
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

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
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_import_cycles() -> None:
    # a package's __init__ importing its own modules (to register commands, say) is not a
    # cycle of concepts; every other loop is
    graph = {
        m: {t for t in edges if not m.startswith(t + ".") and not t.startswith(m + ".")}
        for m, edges in import_graph().items()
    }
    assert cycles(graph) == []


def test_the_checks_see_nested_and_from_imports_and_cycles() -> None:
    source = (
        "def f():\n    from service.settings import X\n"
        "import worker.jobs.tasks\nfrom worker import jobs\n"
    )
    modules = {m for _, m in imported_modules(source)}
    assert {"service.settings", "worker.jobs.tasks", "worker.jobs"} <= modules
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []
