"""Every error answer is an RFC 9457 problem (``application/problem+json``): ``type``,
``title``, ``status`` and ``detail`` (always a string); a validation error (422) also lists
``errors``, each with the field's path (``loc``: ``["body", "grammar", "rules", "A", 0]``;
``pointer``: ``#/grammar/rules/A/0``) and ``msg``, so a library error's ``.path`` names the
request field just as pydantic's errors do. Bodies stay small whatever was sent: at most
:data:`MAX_ERRORS` errors, an error's ``input`` only when short, and any string (a lone
surrogate included) encodable as UTF-8."""

from __future__ import annotations

import json
import logging
import math
import re
import sqlite3
from collections.abc import Mapping, Sequence
from http import HTTPStatus
from typing import Any

from fastapi import FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel
from sqlalchemy.exc import DBAPIError
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.responses import Response

from farm.volume import FULL, is_full
from forest.errors import ForestError, LimitError
from forest.growth.grammar_errors import GrammarErrors, did_you_mean, fields_at
from schemas.base import FieldValueError
from schemas.jobs import ForestRequest, RenderRequest, TreeRequest

log = logging.getLogger(__name__)
RETRY_AFTER_S = 5
PROBLEM_JSON = "application/problem+json"
MAX_ERRORS = 20
"""Validation errors listed in one answer; the rest are counted (``errors_left_out``)."""
INPUT_CAP = 256
"""About this many characters of an invalid input are echoed back; a longer one is not."""
NAME_CAP, MSG_CAP = 200, 1000
"""A field name (an unknown one is the client's text, of any length) and a message are cut to
about this many characters: a 900 KB field name was echoed three times (2.7 MB)."""
SEPARATORS = (",", ":")  # as Starlette's JSONResponse writes
_PART = re.compile(r"\[(\d+)\]|\.?([^.\[\]]+)")


def _wire(value: Any) -> Any:
    """``value`` as strict UTF-8 JSON can carry it: NaN and infinities as strings, lone
    surrogates (which JSON text may hold, but UTF-8 cannot) as U+FFFD."""
    if isinstance(value, str):
        try:
            value.encode("utf-8")
        except UnicodeEncodeError:
            return value.encode("utf-16", "surrogatepass").decode("utf-16", "replace")
        return value
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, Mapping):
        return {_wire(str(k)): _wire(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_wire(v) for v in value]
    return value


def problem_body(status: int, detail: str, **extra: Any) -> dict[str, Any]:
    """The problem object (RFC 9457) of ``status``; ``extra``: extension members."""
    title = HTTPStatus(status).phrase if status in HTTPStatus._value2member_map_ else "Error"
    return {"type": "about:blank", "title": title, "status": status, "detail": detail, **extra}


def problem_bytes(status: int, detail: str, **extra: Any) -> bytes:
    """The encoded problem, for ASGI middleware that answers before the app."""
    return _encode(problem_body(status, detail, **extra))


def _encode(content: Any) -> bytes:
    text = json.dumps(_wire(content), ensure_ascii=False, allow_nan=False, separators=SEPARATORS)
    return text.encode()


class ProblemResponse(JSONResponse):
    media_type = PROBLEM_JSON

    def render(self, content: Any) -> bytes:
        return _encode(content)


def problem(
    status: int, detail: str, headers: Mapping[str, str] | None = None, **extra: Any
) -> ProblemResponse:
    return ProblemResponse(problem_body(status, detail, **extra), status, headers=headers)


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


def _fit(value: Any, budget: int = INPUT_CAP) -> int:
    """What is left of ``budget`` (characters, roughly) after ``value``; below zero: over it.
    Stops early, so a 4 MB list costs no more than a short one."""
    if isinstance(value, str | bytes):
        return budget - len(value) - 2
    if isinstance(value, dict):
        budget -= 2
        for k, v in value.items():
            budget = _fit(v, budget - len(str(k)) - 4)
            if budget < 0:
                break
        return budget
    if isinstance(value, list | tuple):
        budget -= 2
        for v in value:
            budget = _fit(v, budget - 1)
            if budget < 0:
                break
        return budget
    return budget - 24  # a number, a bool, None


def _cut(text: str, cap: int = NAME_CAP) -> str:
    return text if len(text) <= cap else text[:cap] + "\u2026"


def _clean_error(raw: Any) -> dict[str, Any]:
    """One validation error for the wire: its field path (a library's or a schema check's own
    path where it names one), its ``input`` only when short, ``ctx`` as text; names and
    messages cut short."""
    err: dict[str, Any] = (
        dict(raw) if isinstance(raw, dict) else {"loc": [], "msg": str(raw), "type": "error"}
    )
    ctx = err.pop("ctx", None)
    found = ctx.get("error") if isinstance(ctx, dict) else None
    if isinstance(found, FieldValueError):
        # a check of the whole body that knows the field: the error is that field's
        err["loc"] = [*err.get("loc", ())[:1], *path_loc(found.path)]
        err["msg"] = found.reason
        err.pop("input", None)
    elif isinstance(ctx, dict):
        err["ctx"] = {
            k: v if isinstance(v, int | float) else _cut(str(v), MSG_CAP) for k, v in ctx.items()
        }
    err["loc"] = [_cut(p) if isinstance(p, str) else p for p in err.get("loc", ())]
    if isinstance(err.get("msg"), str):
        err["msg"] = _cut(err["msg"], MSG_CAP)
    if "input" in err and _fit(err["input"]) < 0:
        del err["input"]  # never echo a large input (a 4 MB list cost 20 s to answer)
    err.pop("url", None)
    return err


def _pointer(loc: Sequence[Any]) -> str | None:
    """A body error's JSON Pointer (RFC 6901) into the request body: ``#/grammar/rules/A/0``."""
    if not loc or loc[0] != "body":
        return None
    parts = (str(p).replace("~", "~0").replace("/", "~1") for p in loc[1:])
    return "#/" + "/".join(parts) if len(loc) > 1 else "#"


def _where(loc: Sequence[Any]) -> str:
    """``["body", "grammar", "rules", "A", 0]`` -> ``grammar.rules.A[0]``."""
    out = ""
    for p in loc[1:] if loc and loc[0] in ("body", "query", "path", "header") else loc:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out or "body"


async def validation_error(request: Request, exc: Exception) -> JSONResponse:
    """422 problem: ``errors`` lists each field's path (``loc``, ``pointer``) and message, at
    most :data:`MAX_ERRORS` of them; ``detail`` says the first in words."""
    assert isinstance(exc, RequestValidationError)
    raw = exc.errors()
    errors = [_clean_error(e) for e in suggest_fields(request.url.path, raw[:MAX_ERRORS])]
    for i, err in enumerate(errors):
        pointer = _pointer(err.get("loc", ()))
        head = {"loc": err.get("loc", []), **({"pointer": pointer} if pointer else {})}
        errors[i] = head | err  # where first, then what
    first = errors[0] if errors else {"loc": ["body"], "msg": "invalid request"}
    detail = f"{_where(first.get('loc', ()))}: {first.get('msg', '')}"
    if len(raw) > 1:
        detail += f" (and {len(raw) - 1} more error{'s' if len(raw) > 2 else ''})"
    extra: dict[str, Any] = {"errors": _wire(jsonable_encoder(errors))}
    if len(raw) > MAX_ERRORS:
        extra["errors_left_out"] = len(raw) - MAX_ERRORS
    return problem(422, detail, **extra)


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


async def http_error(request: Request, exc: Exception) -> Response:
    """Every ``HTTPException`` (the routes', the key check's, Starlette's own 404 and 405) as a
    problem, its headers (``Allow``, ``Retry-After``, ``WWW-Authenticate``) kept."""
    assert isinstance(exc, StarletteHTTPException)
    if exc.status_code in (204, 304):  # no body allowed
        return Response(status_code=exc.status_code, headers=exc.headers)
    detail = exc.detail if isinstance(exc.detail, str) else json.dumps(jsonable_encoder(exc.detail))
    return problem(exc.status_code, detail, headers=exc.headers)


def _store_full(exc: Exception) -> bool:
    """The job store refused a write for want of room: SQLite's SQLITE_FULL ("database or disk
    is full": its file is on the data volume), PostgreSQL's disk_full (53100)."""
    orig = getattr(exc, "orig", None)
    if getattr(orig, "sqlite_errorcode", None) == sqlite3.SQLITE_FULL:
        return True
    return getattr(orig, "sqlstate", None) == "53100" or (orig is not None and is_full(orig))


async def database_unavailable(request: Request, exc: Exception) -> Response:
    """The job store does not answer: 503 with Retry-After, not a 500 or a reset connection;
    a store that has no room to write is 507, as an upload that finds none is."""
    if _store_full(exc):
        log.warning("job store full on %s %s", request.method, request.url.path)
        return problem(507, FULL)
    log.warning(
        "database unavailable on %s %s: %s", request.method, request.url.path, type(exc).__name__
    )
    return problem(
        503,
        "the job store is unavailable; retry later",
        headers={"Retry-After": str(RETRY_AFTER_S)},
    )


async def server_error(request: Request, exc: Exception) -> Response:
    """A bug: 500 as a problem too (Starlette still logs the traceback)."""
    return problem(500, "internal server error")


def install_handlers(app: FastAPI) -> None:
    app.add_exception_handler(RequestValidationError, validation_error)
    app.add_exception_handler(StarletteHTTPException, http_error)
    # OperationalError, InterfaceError and the rest of the DBAPI's errors: the server is away
    app.add_exception_handler(DBAPIError, database_unavailable)
    app.add_exception_handler(Exception, server_error)
