"""What a one-tree ``forest generate`` imports (issue ``write-memory``, item 5: start-up).

Times are never asserted; what is checked is which modules a fresh interpreter holds: the
command group loads a command's module only when that command runs (``cli.app.LazyGroup``),
and one tree pulls in neither the other commands' modules, the service, farm and worker
stacks, pydantic-settings (and its asyncio) nor, without levels of detail and pictures, GL
or OpenImageIO. Each check runs in a new interpreter, so nothing a test imported before
counts.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

from cli.app import BENCH_COMMANDS, COMMANDS

ROOT = Path(__file__).resolve().parents[1]

# modules a one-tree run has no use for; each was imported by one before (the CLI's other
# command modules through cli/__init__, pydantic-settings through forest.settings)
HEAVY = (
    "cli.gallery", "cli.keys", "cli.render", "cli.service", "cli.tiles", "worker", "service",
    "farm", "bench", "schemas.jobs", "schemas.metrics", "pydantic_settings", "asyncio",
    "dotenv", "fastapi", "starlette", "celery", "kombu", "sqlalchemy", "moderngl",
    "glcontext", "OpenImageIO", "scipy", "matplotlib", "PIL", "pyvista", "vtkmodules",
)  # fmt: skip


def _modules(code: str, cwd: Path, *args: str) -> dict:
    """Run ``code`` in a fresh interpreter; it prints a JSON object whose ``modules`` lists
    ``sys.modules`` at its end."""
    out = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code), *args],
        cwd=cwd,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    result: dict = json.loads(out.stdout.splitlines()[-1])
    return result


def _loaded(modules: list[str], names: tuple[str, ...]) -> list[str]:
    return sorted(m for m in modules if any(m == n or m.startswith(n + ".") for n in names))


def test_importing_the_command_line_loads_no_command(tmp_path: Path) -> None:
    got = _modules(
        """
        import json, sys
        import cli
        print(json.dumps({"modules": sorted(sys.modules)}))
        """,
        tmp_path,
    )
    assert "cli.app" in got["modules"]
    assert not _loaded(got["modules"], ("cli.trees", "numpy", "pxr", "pydantic", *HEAVY))


def test_one_tree_imports_nothing_heavy(tmp_path: Path) -> None:
    """The run itself (through click, as the console script runs it): it must have written
    its tree, and loaded pxr and the generator, so an import that failed cannot pass."""
    got = _modules(
        """
        import json, sys
        from click.testing import CliRunner
        from cli import main

        args = ["generate", "--preset", "alternating", "--trees", "1", "--no-lod",
                "--no-textures", "-q", "-o", "one.usdc"]
        r = CliRunner().invoke(main, args, prog_name="forest")
        print(json.dumps({"code": r.exit_code, "out": r.output, "modules": sorted(sys.modules)}))
        """,
        tmp_path,
    )
    assert got["code"] == 0, got["out"]
    assert "wrote one.usdc: 1 tree(s)" in got["out"]
    assert (tmp_path / "one.usdc").stat().st_size > 0
    for needed in ("cli.trees", "forest.growth.generate", "forest.usd.scene", "pxr.Usd"):
        assert needed in got["modules"], needed
    assert not _loaded(got["modules"], HEAVY)


def test_every_command_is_found_in_its_module(tmp_path: Path) -> None:
    """Each module of the lazy maps, imported alone in a fresh interpreter, registers exactly
    the commands the maps give it; together they register every command there is."""
    for module in sorted({*COMMANDS.values(), *BENCH_COMMANDS.values()}):
        got = _modules(
            """
            import importlib, json, sys
            from cli.app import bench, main
            importlib.import_module(sys.argv[1])
            print(json.dumps({"main": sorted(main.commands), "bench": sorted(bench.commands),
                              "modules": []}))
            """,
            tmp_path,
            module,
        )
        assert {n for n in got["main"] if n != "bench"} == {
            n for n, m in COMMANDS.items() if m == module
        }, module
        assert set(got["bench"]) == {n for n, m in BENCH_COMMANDS.items() if m == module}, module
