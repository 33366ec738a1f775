"""Client errors answered in FastAPI's 422 shape (``{"detail": [{"loc", "msg", "type"}]}``),
so a library error's ``.path`` names the request field just as pydantic's errors do."""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Mapping, Sequence
from http import HTTPStatus
from typing import Any

from fastapi import FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel
from sqlalchemy.exc import DBAPIError

from forest.errors import ForestError, LimitError
from forest.growth.grammar_errors import GrammarErrors, did_you_mean, fields_at
from schemas.jobs import ForestRequest, RenderRequest, TreeRequest

log = logging.getLogger(__name__)
RETRY_AFTER_S = 5
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
    """A library error as a 422; a grammar with several errors gives one entry each."""
    errors = exc.errors if isinstance(exc, GrammarErrors) else (exc,)
    return RequestValidationError(
        [
            {
                "loc": ["body", *(prefix or []), *path_loc(e.path)],
                "msg": e.message,
                "type": "limit_error" if isinstance(e, LimitError) else "value_error",
            }
            for e in errors
        ]
    )


def _finite_json(value: Any) -> Any:
    """``value`` with NaN and infinities as strings (strict JSON has no such numbers)."""
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, dict):
        return {str(k): _finite_json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite_json(v) for v in value]
    return value


async def validation_error(request: Request, exc: Exception) -> JSONResponse:
    """FastAPI's 422 body, made serialisable whatever the input held (NaN, 1e400, bytes)."""
    assert isinstance(exc, RequestValidationError)
    errors = suggest_fields(request.url.path, exc.errors())
    body = {"detail": _finite_json(jsonable_encoder(_finite_json(errors)))}
    return JSONResponse(body, status_code=422)


# the JSON bodies the API reads, by route: an unknown field gets "did you mean" from its model
BODY_MODELS: dict[str, type[BaseModel]] = {
    "/v1/trees": TreeRequest,
    "/v1/forests": ForestRequest,
    "/v1/renders": RenderRequest,
}


def suggest_fields(route: str, errors: Sequence[Any]) -> list[Any]:
    """``errors`` with "did you mean" added to unknown fields of a known body (a grammar's
    too: ``body.grammar.rules.A[0].wieght``)."""
    model = BODY_MODELS.get(route.rstrip("/"))
    out = []
    for err in errors:
        loc = err.get("loc") if isinstance(err, dict) else None
        if (
            model is not None
            and err.get("type") == "extra_forbidden"
            and isinstance(loc, list | tuple)
            and len(loc) >= 2
            and loc[0] == "body"
            and isinstance(loc[-1], str)
        ):
            hint = did_you_mean(loc[-1], fields_at(tuple(loc[1:-1]), root=model))
            if hint:
                err = {**err, "msg": f"{err['msg']}{hint}"}
        out.append(err)
    return out


async def database_unavailable(request: Request, exc: Exception) -> JSONResponse:
    """The job store does not answer: 503 with Retry-After, not a 500 or a reset connection."""
    log.warning(
        "database unavailable on %s %s: %s", request.method, request.url.path, type(exc).__name__
    )
    return JSONResponse(
        {"detail": "the job store is unavailable; retry later"},
        status_code=503,
        headers={"Retry-After": str(RETRY_AFTER_S)},
    )


def install_handlers(app: FastAPI) -> None:
    app.add_exception_handler(RequestValidationError, validation_error)
    # OperationalError, InterfaceError and the rest of the DBAPI's errors: the server is away
    app.add_exception_handler(DBAPIError, database_unavailable)


def problem(status: int, detail: str, headers: Mapping[str, str] | None = None) -> JSONResponse:
    """An error answered by middleware, before any route (so no exception handler runs): an
    RFC 9457 problem with a string ``detail``."""
    body = {"type": "about:blank", "title": HTTPStatus(status).phrase, "status": status}
    return JSONResponse(
        body | {"detail": detail},
        status_code=status,
        headers=headers,
        media_type="application/problem+json",
    )
