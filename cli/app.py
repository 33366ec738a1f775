"""The ``forest`` command group and shared error handling. The commands live in the sibling
modules, one per concern, and register themselves on import (progress: cli.progress)."""

from __future__ import annotations

import functools
import importlib
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import click

from forest import __version__
from forest.errors import ForestError
from forest.extras import require

F = TypeVar("F", bound=Callable[..., Any])
EXIT_INPUT = 2


def input_errors(fn: F) -> F:
    """Turn a ForestError into ``error: <path>: <message>`` and exit code 2."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except ForestError as exc:
            for line in exc.lines():
                click.echo(f"error: {line}", err=True)
            sys.exit(EXIT_INPUT)

    return wrapper  # type: ignore[return-value]


def needs(extra: str, *modules: str) -> None:
    """Stop the running command with one line naming ``extra`` (exit 2, through
    :func:`input_errors`) when one of ``modules`` is not installed; call it first, before
    any work."""
    ctx: click.Context | None = click.get_current_context()
    names = []
    while ctx is not None and ctx.parent is not None:
        names.append(ctx.info_name or "")
        ctx = ctx.parent
    require(extra, *modules, path=" ".join(["forest", *reversed(names)]))


class LazyGroup(click.Group):
    """A group whose commands live in modules imported only when a command is looked up
    (click's documented lazy-loading pattern, "Advanced Groups"): ``forest generate`` does not
    import the renderer's, the service's or the gallery's command modules. Each module
    registers its commands on import, by decorator, as before; ``modules`` names the module of
    every command (``tests/test_cli_startup.py`` checks the map against the registrations)."""

    def __init__(self, *args: Any, modules: dict[str, str] | None = None, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.modules = modules or {}

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted({*super().list_commands(ctx), *self.modules})

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name not in self.commands and cmd_name in self.modules:
            importlib.import_module(self.modules[cmd_name])
        return super().get_command(ctx, cmd_name)


COMMANDS = {
    "demo": "cli.trees",
    "gallery": "cli.gallery",
    "generate": "cli.trees",
    "inspect": "cli.render",
    "keys": "cli.keys",
    "presets": "cli.trees",
    "recipes": "cli.trees",
    "render": "cli.render",
    "serve": "cli.service",
    "tiles": "cli.tiles",
    "worker": "cli.service",
}
BENCH_COMMANDS = {
    "export": "cli.trees",
    "forest": "cli.trees",
    "generate": "cli.trees",
    "render": "cli.render",
    "service": "cli.service",
    "tiles": "cli.tiles",
}


@click.group(
    cls=LazyGroup,
    modules=COMMANDS,
    context_settings={"help_option_names": ["-h", "--help"]},
)
# the running code's version, not the installed distribution's metadata (which an editable
# install keeps from when it was installed)
@click.version_option(__version__, prog_name="forest")
def main() -> None:
    """Procedural forests from interlocking quad-mesh pieces, written as USD scenes."""
    from forest.memory import keep_freed_memory

    # not the API server: its many threads would share one arena's lock, and it would keep
    # its peak size for nothing (its job workers are processes of their own)
    if click.get_current_context().invoked_subcommand != "serve":
        keep_freed_memory()


@main.group(cls=LazyGroup, modules=BENCH_COMMANDS)
def bench() -> None:
    """Benchmarks: figures and ratios against a baseline run side by side."""


def parse_counts(text: str, path: str) -> list[int]:
    """``"1,10,50"`` -> ``[1, 10, 50]``; anything else is an input error naming ``path``."""
    try:
        counts = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ForestError(f"expected comma-separated integers, got {text!r}", path=path) from None
    if not counts or min(counts) < 1:
        raise ForestError("counts must be positive integers", path=path)
    return counts


def data_option(help: str) -> Callable[[F], F]:
    """``--data DIR`` (``FOREST_DATA_DIR``): the embedded job store's folder, as its
    ``data_dir`` argument; ``serve`` and ``keys`` read the same one."""
    return click.option(
        "--data",
        "data_dir",
        type=click.Path(path_type=Path),
        default=Path("forest-data"),
        show_default=True,
        envvar="FOREST_DATA_DIR",
        help=help,
    )
