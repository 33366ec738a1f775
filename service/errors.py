"""Client errors answered in FastAPI's 422 shape (``{"detail": [{"loc", "msg", "type"}]}``),
so a library error's ``.path`` names the request field just as pydantic's errors do."""

from __future__ import annotations

import re

from fastapi.exceptions import RequestValidationError

from forest.errors import ForestError, LimitError

_PART = re.compile(r"\[(\d+)\]|\.?([^.\[\]]+)")


def path_loc(path: str) -> list[str | int]:
    """``rules.A[2].weight`` -> ``["rules", "A", 2, "weight"]``."""
    loc: list[str | int] = []
    for index, name in _PART.findall(path):
        loc.append(int(index) if index else name)
    return loc


def field_error(
    loc: list[str | int], msg: str, kind: str = "value_error"
) -> RequestValidationError:
    return RequestValidationError([{"loc": ["body", *loc], "msg": msg, "type": kind}])


def forest_error(exc: ForestError, prefix: list[str | int] | None = None) -> RequestValidationError:
    kind = "limit_error" if isinstance(exc, LimitError) else "value_error"
    return field_error([*(prefix or []), *path_loc(exc.path)], exc.message, kind)
