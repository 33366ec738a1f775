"""The package's optional extras (pyproject.toml) and the one-line error a command gives when
the extra it needs is not installed.

A core install generates forests and bark tile sets and writes USD and glTF; the extras add
``render`` (the GL renderer, clips, plots), ``inspect`` (pyvista and VTK for the diagnostic
sheet), ``service`` (the HTTP API and the job stack) and ``dev`` (all of them, test and lint
tools, and what the shipped tile sets are made with).
"""

from __future__ import annotations

import importlib.util

from forest.errors import ForestError

DIST = "interlocking-forest"


def install_line(extra: str) -> str:
    """The pip command that adds ``extra``."""
    return f"pip install '{DIST}[{extra}]'"


class MissingExtraError(ForestError):
    """A module the command needs is not installed; ``extra`` brings it."""

    def __init__(self, extra: str, module: str, *, path: str) -> None:
        super().__init__(
            f"{module} is not installed; it comes with the {extra} extra: {install_line(extra)}",
            path=path,
        )
        self.extra = extra
        self.module = module


def installed(module: str) -> bool:
    """Whether top-level ``module`` can be imported, found without importing it."""
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):  # a finder that refuses it; a module without a spec
        return False


def require(extra: str, *modules: str, path: str) -> None:
    """Raise :class:`MissingExtraError` for the first of ``modules`` that is not installed:
    before any work, so a command stops at once and says what to install."""
    for module in modules:
        if not installed(module):
            raise MissingExtraError(extra, module, path=path)
