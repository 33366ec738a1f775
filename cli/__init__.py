"""The ``forest`` command line. Input errors print one line naming what is wrong and exit 2."""

from cli import gallery, keys, render, service, tiles, trees  # noqa: F401  (register the commands)
from cli.app import main

__all__ = ["main"]
