"""Responses every operation can give, added to the published OpenAPI in one place: they come
from middleware and dependencies (key check, rate limit, cross-site refusal, body limits, an
unavailable job store or broker), not from the routes that document their own."""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI

from service.security import WRITES

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
        app.openapi_schema = schema
        return schema

    app.openapi = openapi  # type: ignore[method-assign]
