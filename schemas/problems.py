"""Wire models of error answers: RFC 9457 problem details (``application/problem+json``), as
``service.errors`` writes them; published in the OpenAPI document."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field


class Problem(BaseModel):
    """An error answer (RFC 9457). ``type`` is ``about:blank``: the status says what went
    wrong, ``detail`` says it in words."""

    model_config = ConfigDict(extra="allow")  # extension members (RFC 9457 section 3.2)
    type: str = "about:blank"
    title: str
    """The status's phrase (``Not Found``)."""
    status: int
    detail: str
    """What went wrong, in words (a validation error: its first field and message)."""


class FieldError(BaseModel):
    """One invalid field of a request."""

    loc: list[str | int]
    """Where: ``["body", "grammar", "rules", "A", 0, "weight"]``, ``["query", "limit"]``."""
    pointer: str | None = None
    """A body field's JSON Pointer (RFC 6901) into the request body: ``#/grammar/name``."""
    msg: str
    type: str
    input: Any = None
    """The value given, only when short (a long one is never echoed)."""
    ctx: dict[str, Any] | None = None


class ValidationProblem(Problem):
    """A request that is not valid (422): each invalid field, at most 20 of them."""

    errors: list[FieldError]
    errors_left_out: int | None = Field(None, ge=1)
    """How many more errors there were, when over 20."""
