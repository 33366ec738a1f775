"""Typed errors that carry what went wrong and where. The CLI prints them as one line and
exits 2; the service maps them to 422/413."""

from __future__ import annotations


class ForestError(Exception):
    """Base of every error caused by input (a grammar, an option, a file)."""

    def __init__(self, message: str, *, path: str = "") -> None:
        super().__init__(message)
        self.message = message
        self.path = path

    def __str__(self) -> str:
        return f"{self.path}: {self.message}" if self.path else self.message

    def __repr__(self) -> str:
        return f"{type(self).__name__}(path={self.path!r}, message={self.message!r})"

    def lines(self) -> list[str]:
        """One line per error (several where one pass found several)."""
        return [str(self)]


class GrammarError(ForestError):
    """A grammar is malformed or inconsistent; ``path`` is like ``rules.A[2].weight``."""


class LimitError(ForestError):
    """A request exceeds a configured cap; ``path`` names the setting or option."""

    def __init__(self, message: str, *, path: str, limit: int | float) -> None:
        super().__init__(message, path=path)
        self.limit = limit


class SceneError(ForestError):
    """A USD scene breaks the contract; ``path`` is ``<prim path>.<attribute>``."""


class OutputError(ForestError):
    """An output cannot be written; ``path`` is the file."""
