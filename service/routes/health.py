"""``/healthz`` (the process answers), ``/readyz`` (database and broker reachable, room on the
data volume), ``/metrics`` (Prometheus text: every tenant's job counts, so an admin key's, or
anyone's on loopback while the API is open)."""

from __future__ import annotations

from fastapi import APIRouter, Depends
from fastapi.responses import JSONResponse, Response
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest
from sqlalchemy import text

from farm import volume
from schemas.jobs import Health
from service.deps import ServicesDep
from service.security import admin_or_open

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health, response_model_exclude_none=True)
def healthz() -> Health:
    return Health(status="ok")


@router.get("/readyz", response_model=Health, responses={503: {"model": Health}})
def readyz(services: ServicesDep) -> JSONResponse:
    checks: dict[str, str] = {}
    try:
        with services.store.engine.connect() as conn:
            conn.execute(text("SELECT 1"))
        checks["database"] = "ok"
    except Exception as exc:
        checks["database"] = f"unreachable: {type(exc).__name__}"
    try:
        services.dispatcher.ping()
        checks["broker"] = "ok"
    except Exception as exc:
        checks["broker"] = f"unreachable: {type(exc).__name__}"
    free: int | None = None
    try:
        free = volume.free_bytes(services.artifacts.root)
        floor = services.settings.min_free_mb << 20
        checks["data_volume"] = (
            "ok"
            if free >= floor
            else f"full: {free >> 20} MiB free, under min_free_mb ({services.settings.min_free_mb})"
        )
    except OSError as exc:
        checks["data_volume"] = f"unreadable: {exc.strerror or type(exc).__name__}"
    ok = all(v == "ok" for v in checks.values())
    body = Health(status="ok" if ok else "unavailable", checks=checks, data_free_bytes=free)
    return JSONResponse(body.model_dump(), status_code=200 if ok else 503)


@router.get(
    "/metrics",
    response_class=Response,
    responses={
        200: {"content": {"text/plain": {"schema": {"type": "string"}}}},
        403: {"description": "Not an admin key"},
    },
    dependencies=[Depends(admin_or_open)],
)
def metrics(services: ServicesDep) -> Response:
    data = generate_latest(services.metrics.registry)
    return Response(data, media_type=CONTENT_TYPE_LATEST)
