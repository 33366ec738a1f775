"""The packages' layers: every import, module level or inside a function, points down.

    forest.cli (composition: the commands)
    service (HTTP)        worker (GL, job tasks)
    farm (job store, dispatch, artifacts, reaper, their settings)
    forest (library), schemas

The service sends tasks by name and never imports the worker; neither farm nor the worker
imports the HTTP package; the library knows nothing of the farm.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

# package (folder) -> top-level packages it must not import
FORBIDDEN: dict[str, frozenset[str]] = {
    "farm": frozenset({"service", "worker", "forest.cli"}),
    "worker": frozenset({"service"}),
    "service": frozenset({"worker"}),
    "forest": frozenset({"service", "worker", "farm"}),
    "schemas": frozenset({"service", "worker", "farm", "forest.cli"}),
}
# the command line composes every layer; ``python -m worker`` is the ``forest worker`` command
EXEMPT = (ROOT / "forest" / "cli", ROOT / "worker" / "__main__.py")


def imported_modules(source: str) -> list[tuple[int, str]]:
    """(line, module) of every absolute import in ``source``."""
    found: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found += [(node.lineno, node.module)]
            # ``from forest import cli`` names forest.cli as well
            found += [(node.lineno, f"{node.module}.{alias.name}") for alias in node.names]
    return found


def violations(package: str) -> list[str]:
    bad = []
    for path in sorted((ROOT / package).rglob("*.py")):
        if any(path == e or e in path.parents for e in EXEMPT):
            continue
        for line, module in imported_modules(path.read_text()):
            for banned in FORBIDDEN[package]:
                if module == banned or module.startswith(banned + "."):
                    bad.append(f"{path.relative_to(ROOT)}:{line} imports {module}")
    return bad


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_imports_point_down(package: str) -> None:
    assert (ROOT / package / "__init__.py").is_file()
    assert violations(package) == []


def test_the_check_sees_nested_and_from_imports() -> None:
    source = (
        "def f():\n    from service.settings import X\n"
        "import worker.tasks\nfrom forest import cli\n"
    )
    modules = {m for _, m in imported_modules(source)}
    assert {"service.settings", "worker.tasks", "forest.cli"} <= modules
