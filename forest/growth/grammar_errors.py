"""Every error of a grammar at once, each with its JSON path, and "did you mean" for misspelt
fields and symbols: a user fixing a grammar file should need one run, not one run per typo."""

from __future__ import annotations

import difflib
import types
import typing
from collections.abc import Iterable, Sequence
from typing import Any

from pydantic import BaseModel, ValidationError

from forest.errors import GrammarError
from schemas.grammar import Grammar

# pydantic's internal validator names in an error's location, meaningless to a user
_INTERNAL_LOC = ("function-after", "function-before", "function-wrap", "tagged-union")
MAX_REPORTED = 50  # a hostile grammar can hold thousands of errors; a user reads the first


class GrammarErrors(GrammarError):
    """Several grammar errors found in one pass; ``errors`` holds each (path and message).
    ``str()`` and :meth:`lines` give one line per error."""

    def __init__(self, errors: Sequence[GrammarError]) -> None:
        first = errors[0]
        super().__init__(first.message, path=first.path)
        self.errors = tuple(errors)

    def lines(self) -> list[str]:
        return [str(e) for e in self.errors]

    def __str__(self) -> str:
        return "\n".join(self.lines())


def raise_all(errors: Sequence[GrammarError]) -> None:
    """Raise nothing, the one error, or all of them as :class:`GrammarErrors`."""
    if len(errors) == 1:
        raise errors[0]
    if errors:
        raise GrammarErrors(errors[:MAX_REPORTED])


def loc_to_path(loc: Iterable[int | str]) -> str:
    """``("rules", "A", 2, "weight")`` -> ``rules.A[2].weight``."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif part in _INTERNAL_LOC or "[" in str(part):
            continue
        else:
            out += f".{part}" if out else str(part)
    return out


def did_you_mean(word: str, choices: Iterable[str]) -> str:
    """``"; did you mean 'weight'?"`` for the closest choice, or ``""``."""
    close = difflib.get_close_matches(word, sorted(set(choices)), n=1, cutoff=0.6)
    return f"; did you mean {close[0]!r}?" if close else ""


def _models_in(annotation: Any) -> list[type[BaseModel]]:
    """The pydantic models an annotation can hold (through Optional, unions, Annotated)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    origin = typing.get_origin(annotation)
    if origin is typing.Annotated:
        return _models_in(typing.get_args(annotation)[0])
    if origin in (typing.Union, types.UnionType):
        return [m for a in typing.get_args(annotation) for m in _models_in(a)]
    return []


def _step(annotation: Any, part: int | str) -> Any:
    """The annotation one location step inside ``annotation`` (a field, a dict value, an
    item), or None where the location leaves what the annotations describe."""
    origin = typing.get_origin(annotation)
    if origin is typing.Annotated:
        return _step(typing.get_args(annotation)[0], part)
    if origin in (typing.Union, types.UnionType):
        for arg in typing.get_args(annotation):
            found = _step(arg, part)
            if found is not None:
                return found
        return None
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        field = annotation.model_fields.get(str(part))
        return None if field is None else field.annotation
    args = typing.get_args(annotation)
    if origin is dict and len(args) == 2:
        return args[1]
    if origin is tuple and args and isinstance(part, int):  # tuple[A, B]: item by position
        return args[min(part, len(args) - 1)]
    if origin in (list, tuple, set, frozenset) and args:
        return args[0]
    return None


def fields_at(loc: Sequence[int | str], root: type[BaseModel] = Grammar) -> list[str]:
    """The field names allowed at the object that ``loc`` (without its last part) points to."""
    annotation: Any = root
    for part in loc:
        if part in _INTERNAL_LOC or "[" in str(part):
            continue
        annotation = _step(annotation, part)
        if annotation is None:
            return []
    return [name for m in _models_in(annotation) for name in m.model_fields]


def validation_errors(exc: ValidationError) -> list[GrammarError]:
    """Every error of a pydantic validation of a :class:`Grammar`, with suggestions for
    unknown fields."""
    found = []
    for err in exc.errors():
        loc = tuple(err["loc"])
        msg = err["msg"]
        if err["type"] == "extra_forbidden" and loc and isinstance(loc[-1], str):
            msg = f"unknown field{did_you_mean(loc[-1], fields_at(loc[:-1]))}"
        found.append(GrammarError(msg, path=loc_to_path(loc)))
    return found


def reference_errors(data: Any) -> list[GrammarError]:
    """Symbols used but not defined (axiom, foliage, successors), read from a grammar's plain
    JSON data, so they are reported beside its field errors even when the data does not
    validate; parts of the wrong shape are skipped (validation names those)."""
    if not isinstance(data, dict) or not isinstance(data.get("rules"), dict):
        return []
    symbols = [str(s) for s in data["rules"]]
    defined = set(symbols)
    found = []

    def check(symbol: Any, path: str, what: str) -> None:
        if isinstance(symbol, str) and symbol not in defined:
            found.append(
                GrammarError(f"{what} {symbol!r}{did_you_mean(symbol, symbols)}", path=path)
            )

    axiom = data.get("axiom")
    if isinstance(axiom, str) and axiom not in defined:
        found.append(
            GrammarError(
                f"axiom {axiom!r} has no rule (rules: {', '.join(symbols)})"
                f"{did_you_mean(axiom, symbols)}",
                path="axiom",
            )
        )
    foliage = data.get("foliage")
    for i, s in enumerate(foliage if isinstance(foliage, list) else []):
        check(s, f"foliage[{i}]", "unknown symbol")
    for s, alts in data["rules"].items():
        for j, alt in enumerate(alts if isinstance(alts, list) else []):
            succs = alt.get("successors") if isinstance(alt, dict) else None
            for r, succ in enumerate(succs if isinstance(succs, list) else []):
                if isinstance(succ, dict):
                    check(
                        succ.get("symbol"),
                        f"rules.{s}[{j}].successors[{r}].symbol",
                        "unknown symbol",
                    )
    return found
