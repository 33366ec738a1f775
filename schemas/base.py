"""The base of every wire model: unknown fields are errors, instances are immutable."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class StrictModel(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class FieldValueError(ValueError):
    """A check of a whole request that knows the field at fault (``path``:
    ``grammar.rules.A[0].weight``; ``""``: the whole request), so the service reports the
    error at that field."""

    def __init__(self, path: str, reason: str) -> None:
        super().__init__(f"{path or 'body'}: {reason}")
        self.path, self.reason = path, reason
