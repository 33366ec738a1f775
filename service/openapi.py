"""Responses every operation can give, added to the published OpenAPI in one place: they come
from middleware and dependencies (key check, rate limit, cross-site refusal, body limits, an
unavailable job store or broker), not from the routes that document their own. Every error
response is described as what it is: an RFC 9457 problem (``application/problem+json``,
:mod:`schemas.problems`), a 422 with its ``errors``."""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI
from pydantic.json_schema import models_json_schema

from schemas.problems import Problem, ValidationProblem
from service.errors import PROBLEM_JSON
from service.security import WRITES

REF = "#/components/schemas/{model}"
FASTAPI_422 = {"$ref": "#/components/schemas/HTTPValidationError"}

SIGNED_IN = {401: "No valid `X-API-Key` header (when the server has keys)"}
WRITE = {
    403: "A browser sent this from another site (`Origin` not allowed)",
    429: "Rate limit of the key exceeded; `Retry-After` says when to retry",
}
BODY = {
    408: "Request body not received in time",
    413: "Request body too large",
}
API = {503: "The job store or the broker does not answer; `Retry-After` says when to retry"}


def document_shared_responses(app: FastAPI) -> None:
    """Make ``app.openapi()`` list the shared responses of each operation (once built)."""
    build = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is not None:
            return app.openapi_schema
        schema = build()
        for path, item in schema.get("paths", {}).items():
            for method, op in item.items():
                extra: dict[int, str] = {}
                if op.get("security"):
                    extra |= SIGNED_IN
                if method.upper() in WRITES:
                    extra |= WRITE
                if "requestBody" in op:
                    extra |= BODY
                if path.startswith("/v1/"):
                    extra |= API
                responses = op.setdefault("responses", {})
                for code, text in sorted(extra.items()):
                    responses.setdefault(str(code), {"description": text})
                for code, response in responses.items():
                    _as_problem(code, response)
        _problem_schemas(schema)
        app.openapi_schema = schema
        return schema

    app.openapi = openapi  # type: ignore[method-assign]


def _as_problem(code: str, response: dict[str, Any]) -> None:
    """An error response without a body model of its own (or with FastAPI's 422 model) is a
    problem."""
    if not code[:1].isdigit() or int(code) < 400:
        return
    content = response.get("content", {})
    schemas = [c.get("schema") for c in content.values()]
    if content and schemas != [FASTAPI_422]:
        return  # its own model (``/readyz``'s 503 is a Health)
    model = ValidationProblem if code == "422" else Problem
    response["content"] = {PROBLEM_JSON: {"schema": {"$ref": REF.format(model=model.__name__)}}}


def _problem_schemas(schema: dict[str, Any]) -> None:
    """The problem models in ``components``; FastAPI's 422 models, no longer used, out."""
    _, defs = models_json_schema(
        [(Problem, "serialization"), (ValidationProblem, "serialization")], ref_template=REF
    )
    components = schema.setdefault("components", {}).setdefault("schemas", {})
    components.update(defs.get("$defs", {}))
    for name in ("HTTPValidationError", "ValidationError"):
        components.pop(name, None)
