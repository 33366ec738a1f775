"""The core install (``pip install interlocking-forest``, no extras) and the extras.

The core commands run with the extras' packages unimportable: a ``sys.meta_path`` finder
refuses them in a fresh interpreter before ``cli`` loads, so an import chain that reaches one
fails here even though this environment has them all. A command that needs an extra answers
one line naming it, exit code 2, no traceback. The extras in pyproject.toml are checked
against what the code imports.
"""

from __future__ import annotations

import ast
import importlib.metadata
import importlib.util
import json
import os
import re
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
OURS = {"cli", "bench", "service", "worker", "farm", "forest", "schemas", "shaders"}

# what a core install lacks: the GL, service and test stacks, and the dev extra's science
BLOCKED = (
    "moderngl", "glcontext", "imageio", "imageio_ffmpeg", "PIL", "matplotlib", "pyvista",
    "vtk", "vtkmodules", "celery", "kombu", "sqlalchemy", "alembic", "fastapi", "starlette",
    "uvicorn", "psycopg", "httpx", "limits", "prometheus_client", "pytest", "hypothesis",
    "scipy", "trimesh", "pydantic_settings",
)  # fmt: skip

DRIVER = textwrap.dedent(
    """
    import importlib.util, json, sys

    BLOCKED = set(sys.argv[1].split(","))

    class Refuse:
        def find_spec(self, name, path=None, target=None):
            if name.partition(".")[0] in BLOCKED:
                raise ImportError(f"blocked: {name}", name=name)
            return None

    sys.meta_path.insert(0, Refuse())
    from click.testing import CliRunner

    from cli import main

    results = []
    for args in json.loads(sys.argv[2]):
        r = CliRunner().invoke(main, args, prog_name="forest")
        crashed = r.exception is not None and not isinstance(r.exception, SystemExit)
        results.append({"args": args, "code": r.exit_code, "stdout": r.stdout,
                        "stderr": r.stderr, "crashed": repr(r.exception) if crashed else None})
    # the finder was in force all along: nothing blocked was loaded by any command
    results.append({"loaded": sorted(m for m in sys.modules if m.partition(".")[0] in BLOCKED)})
    print(json.dumps(results))
    """
)

CORE = [
    ["--version"],
    ["presets"],
    ["tiles", "--help"],
    ["serve", "--help"],
    ["generate", "--preset", "alternating", "--trees", "1", "-o", "x.usda"],
    ["generate", "--preset", "alternating", "--trees", "1", "-o", "x.glb"],
    ["generate", "--preset", "alternating", "--trees", "1", "-o", "x.usdz"],
]
# (arguments, the command its line names, the extra it names); run after CORE: x.usda exists
NEEDS_EXTRA = [
    (["render", "x.usda", "-o", "x.png"], "forest render", "render"),
    (["render", "x.usda", "-o", "x.png", "--clip", "x.mp4"], "forest render", "render"),
    (["gallery", "-o", "g"], "forest gallery", "render"),
    (["bench", "render"], "forest bench render", "render"),
    (["inspect", "x.usda", "-o", "i.png"], "forest inspect", "inspect"),
    (["serve"], "forest serve", "service"),
    (["worker"], "forest worker", "service"),
    (["keys", "list"], "forest keys list", "service"),
    (["bench", "service"], "forest bench service", "service"),
    (["bench", "tiles"], "forest bench tiles", "dev"),
]


@pytest.fixture(scope="module")
def light_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[list[dict], Path]:
    cwd = tmp_path_factory.mktemp("light")
    commands = CORE + [args for args, _, _ in NEEDS_EXTRA]
    out = subprocess.run(
        [sys.executable, "-c", DRIVER, ",".join(BLOCKED), json.dumps(commands)],
        cwd=cwd,
        env={**os.environ, "PYTHONPATH": str(ROOT), "FOREST_DATA_DIR": str(cwd / "data")},
        capture_output=True,
        text=True,
        timeout=300,  # a blocker that failed would leave `forest serve` serving
    )
    assert out.returncode == 0, out.stderr
    *results, last = json.loads(out.stdout)
    assert last == {"loaded": []}
    return results, cwd


def test_the_blocked_packages_are_installed_here() -> None:
    """Else the light run proves nothing about them: this environment must hold every extra."""
    missing = [m for m in ("moderngl", "pyvista", "celery", "sqlalchemy", "fastapi", "scipy")
               if importlib.util.find_spec(m) is None]  # fmt: skip
    assert not missing


def test_core_commands_run_without_any_extra(light_run: tuple[list[dict], Path]) -> None:
    results, cwd = light_run
    for r in results[: len(CORE)]:
        assert r["crashed"] is None and r["code"] == 0, r
    for name in ("x.usda", "x.glb", "x.usdz"):
        assert (cwd / name).stat().st_size > 1000, name
    assert "alternating" in results[1]["stdout"]


@pytest.mark.parametrize("k", range(len(NEEDS_EXTRA)), ids=[" ".join(a) for a, _, _ in NEEDS_EXTRA])
def test_a_command_names_the_extra_it_needs(light_run: tuple[list[dict], Path], k: int) -> None:
    results, _ = light_run
    r = results[len(CORE) + k]
    args, command, extra = NEEDS_EXTRA[k]
    assert r["args"] == args
    assert r["crashed"] is None and r["code"] == 2, r
    assert r["stdout"] == ""
    line = r["stderr"].strip()
    assert "\n" not in line and "Traceback" not in line
    assert line.startswith(f"error: {command}: "), line
    install = f"pip install 'interlocking-forest[{extra}]'"
    assert line.endswith(f"comes with the {extra} extra: {install}"), line


# --- the extras against the imports -------------------------------------------------------


def _dist(requirement: str) -> str:
    name = re.match(r"[A-Za-z0-9._-]+", requirement.strip())
    assert name is not None, requirement
    return re.sub(r"[-_.]+", "-", name.group()).lower()


def _extras(requirement: str) -> set[str]:
    found = re.match(r"[A-Za-z0-9._-]+\s*\[([^\]]*)\]", requirement.strip())
    return {e.strip() for e in found.group(1).split(",")} if found else set()


def requirements(*extras: str) -> list[str]:
    """The requirements of the core and ``extras`` (the package's own extras that these
    include followed)."""
    reqs = list(PROJECT["dependencies"])
    todo, seen = list(extras), set()
    while todo:
        extra = todo.pop()
        if extra not in seen:
            seen.add(extra)
            for r in PROJECT["optional-dependencies"][extra]:
                if _dist(r) == "interlocking-forest":
                    todo += sorted(_extras(r))
                else:
                    reqs.append(r)
    return reqs


def installed_by(*extras: str) -> set[str]:
    """The distributions :func:`requirements` names and, as installed here, those they require
    in turn (kombu through celery, starlette through FastAPI): what a pip install of
    ``extras`` puts in the environment."""
    todo = [(_dist(r), _extras(r)) for r in requirements(*extras)]
    seen: set[tuple[str, frozenset[str]]] = set()
    while todo:
        name, wanted = todo.pop()
        if (name, frozenset(wanted)) in seen:
            continue
        seen.add((name, frozenset(wanted)))
        try:
            needed = importlib.metadata.requires(name) or []
        except importlib.metadata.PackageNotFoundError:
            continue
        for r in needed:
            req, _, marker = r.partition(";")
            extra = re.search(r"extra\s*==\s*['\"]([^'\"]+)", marker)
            if extra is None or extra.group(1) in wanted:
                todo.append((_dist(req), _extras(req)))
    return {name for name, _ in seen}


PROVIDERS = {
    m: {_dist(d) for d in ds} for m, ds in importlib.metadata.packages_distributions().items()
}

# where a folder's imports must come from: its install's distributions
LAYERS = {
    "worker": (),  # the package's entry point; its sub-packages below
    "forest": (),
    # GL on EGL: the renderer and the impostor bake import it only when they draw
    "forest/gl": ("render",),
    "schemas": (),
    "cli": ("service",),  # forest keys; every other command module imports its extra lazily
    "cli/sheets/gallery.py": ("render",),
    "cli/sheets/inspect.py": ("inspect",),
    "worker/render": ("render",),
    "worker/jobs": ("service",),
    "worker/probe.py": ("service",),  # a worker's liveness: its registry row in the job store
    "worker/jobs/chunk.py": ("service", "render"),  # a chunked render's join encodes the clip
    "farm": ("service",),
    "service": ("service",),
}
# a module that imports beyond its folder's install, and why
EXCEPTIONS = {
    # procedural bark: only rebuilding the shipped tile sets and forest bench tiles make it
    ("forest/bark/barkgen.py", "scipy"): "dev",
}


def third_party_imports(path: Path) -> set[str]:
    """Top-level names of every absolute import in ``path`` (inside functions too), less the
    standard library and this project's packages."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name.partition(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.partition(".")[0])
    return names - OURS - set(sys.stdlib_module_names) - {"__future__"}


def layer_of(rel: str) -> str:
    return max((key for key in LAYERS if rel == key or rel.startswith(key + "/")), key=len)


def test_every_import_comes_with_its_install() -> None:
    wrong = []
    for folder in ("forest", "schemas", "cli", "worker", "farm", "service"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            if "/migrations/" in rel:  # alembic runs them: the service extra
                continue
            for module in third_party_imports(path):
                extras = (EXCEPTIONS.get((rel, module)),) if (rel, module) in EXCEPTIONS else ()
                allowed = installed_by(*LAYERS[layer_of(rel)], *extras)
                if module not in PROVIDERS:
                    wrong.append(f"{rel}: {module} is not installed here")
                elif not PROVIDERS[module] & allowed:
                    wrong.append(f"{rel}: {module} ({', '.join(PROVIDERS[module])}) undeclared")
    assert not wrong


def test_every_core_dependency_is_imported_by_the_core() -> None:
    """No core dependency that only a test or one optional feature uses."""
    used = set()
    for folder in ("forest", "schemas", "cli"):
        for path in (ROOT / folder).rglob("*.py"):
            for module in third_party_imports(path):
                used |= PROVIDERS.get(module, set())
    assert {_dist(r) for r in requirements()} - used == set()


def _named_modules(call: ast.Call, constants: dict[str, list[str]]) -> list[str]:
    """The module names among a call's arguments after the first: strings, also inside an
    expression, and those of a module-level tuple it unpacks (``*SERVICE_MODULES``)."""
    names = []
    for arg in call.args[1:]:
        for node in ast.walk(arg):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                names.append(node.value)
            elif isinstance(node, ast.Starred) and isinstance(node.value, ast.Name):
                names += constants[node.value.id]
    return names


def test_the_extra_a_command_names_brings_the_module() -> None:
    """Every ``needs(extra, module...)`` and ``require(extra, module..., path=)``: the named
    extra installs the module."""
    calls = []
    for folder in ("forest", "cli", "worker"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            tree = ast.parse(path.read_text())
            constants = {
                t.id: [e.value for e in node.value.elts if isinstance(e, ast.Constant)]
                for node in tree.body
                if isinstance(node, ast.Assign) and isinstance(node.value, ast.Tuple)
                for t in node.targets
                if isinstance(t, ast.Name)
            }
            for node in ast.walk(tree):
                if (
                    isinstance(node, ast.Call)
                    and isinstance(node.func, ast.Name)
                    and node.func.id in ("needs", "require")
                    and node.args
                    and isinstance(node.args[0], ast.Constant)
                ):
                    extra = node.args[0].value
                    calls += [(path.name, extra, m) for m in _named_modules(node, constants)]
    assert len(calls) >= 20
    wrong = [c for c in calls if not PROVIDERS.get(c[2], set()) & installed_by(c[1])]
    assert not wrong
