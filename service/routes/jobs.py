"""``/v1/jobs``: list (paged, filtered), read, cancel, and fetch artifacts."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, HTTPException, Query
from fastapi.responses import FileResponse

from schemas.jobs import Job, JobKind, JobPage, JobState
from service.deps import ServicesDep
from service.security import Tenant
from service.views import ERRORS, job_model

router = APIRouter(prefix="/v1/jobs", tags=["jobs"])
ARTIFACT_TYPES = {
    ".png": "image/png",
    ".json": "application/json",
    ".usda": "model/vnd.usda",
    ".usdc": "model/vnd.usd",
    ".usdz": "model/vnd.usdz+zip",
    ".glb": "model/gltf-binary",
    ".mp4": "video/mp4",  # render clips (worker.clip)
    ".webm": "video/webm",
    ".gif": "image/gif",
}


@router.get("", response_model=JobPage)
def list_jobs(
    services: ServicesDep,
    tenant: Tenant,
    state: JobState | None = None,
    kind: JobKind | None = None,
    limit: Annotated[int, Query(ge=1, le=200)] = 50,
    offset: Annotated[int, Query(ge=0, le=10**9)] = 0,
) -> JobPage:
    rows, total = services.store.list_jobs(state, kind, limit, offset, tenant)
    return JobPage(
        items=[job_model(r, services) for r in rows], total=total, limit=limit, offset=offset
    )


@router.get("/{job_id}", response_model=Job, responses=ERRORS)
def get_job(job_id: str, services: ServicesDep, tenant: Tenant) -> Job:
    row = services.store.get(job_id, tenant)
    if row is None:
        raise HTTPException(404, "no such job")
    return job_model(row, services)


@router.delete("/{job_id}", response_model=Job, responses=ERRORS)
def cancel_job(job_id: str, services: ServicesDep, tenant: Tenant) -> Job:
    """Cancel: a queued job is canceled at once; a running one's process is killed at the
    worker's next heartbeat (within seconds)."""
    row = services.store.cancel(job_id, tenant)
    if row is None:
        raise HTTPException(404, "no such job")
    return job_model(row, services)


@router.get(
    "/{job_id}/artifacts/{name}",
    response_class=FileResponse,
    responses={
        200: {
            "description": "The artifact",
            "content": {t: {"schema": {"type": "string", "format": "binary"}}
                        for t in sorted(set(ARTIFACT_TYPES.values()))},
        },
        **ERRORS,
    },
)
def get_artifact(job_id: str, name: str, services: ServicesDep, tenant: Tenant) -> FileResponse:
    row = services.store.get(job_id, tenant)
    if row is None or name not in (row.artifacts or []):
        raise HTTPException(404, "no such artifact")
    path = services.artifacts.path(job_id, name)
    if path is None:
        raise HTTPException(404, "no such artifact")
    media = ARTIFACT_TYPES.get(path.suffix, "application/octet-stream")
    return FileResponse(path, media_type=media, filename=name)
