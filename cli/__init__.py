"""The ``forest`` command line. Input errors print one line naming what is wrong and exit 2.

The commands' modules (``cli.trees``, ``cli.render``, ...) are imported when their command is
run or listed (:class:`cli.app.LazyGroup`), so one command's start-up does not pay for the
others' imports."""

from cli.app import main

__all__ = ["main"]
