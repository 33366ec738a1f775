"""``/v1/jobs``: list (paged, filtered), read, cancel, fetch artifacts, read the log."""

from __future__ import annotations

import re
from datetime import UTC
from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Path, Query
from fastapi.responses import FileResponse

from farm import joblog, tiles
from farm.db import JobLogRow
from farm.reaper import delete_artifacts
from farm.store import FINISHED
from schemas.jobs import JOB_ID_PATTERN, Job, JobKind, JobLog, JobPage, JobState, LogLine
from service.deps import ServicesDep
from service.security import CallerDep
from service.views import ERRORS, job_model

router = APIRouter(prefix="/v1/jobs", tags=["jobs"])
ARTIFACT_TYPES = {
    ".png": "image/png",
    ".json": "application/json",
    ".usda": "model/vnd.usda",
    ".usdc": "model/vnd.usd",
    ".usdz": "model/vnd.usdz+zip",
    ".glb": "model/gltf-binary",
    ".mp4": "video/mp4",  # render clips (worker.render.clip)
    ".webm": "video/webm",
    ".gif": "image/gif",
}

_JOB_ID = re.compile(JOB_ID_PATTERN)


def job_id(job_id: Annotated[str, Path(description="A job's `id`")]) -> str:
    """The path's job id; one no job can have (a NUL, a control character, too long) is 404
    here, before the store is asked (PostgreSQL refuses a NUL: that was answered 503)."""
    if not _JOB_ID.fullmatch(job_id):
        raise HTTPException(404, "no such job")
    return job_id


JobIdDep = Annotated[str, Depends(job_id)]


@router.get("", response_model=JobPage)
def list_jobs(
    services: ServicesDep,
    caller: CallerDep,
    state: JobState | None = None,
    kind: JobKind | None = None,
    limit: Annotated[int, Query(ge=1, le=200)] = 50,
    offset: Annotated[int, Query(ge=0, le=10**9)] = 0,
) -> JobPage:
    rows, total = services.store.list_jobs(state, kind, limit, offset, caller.scope)
    return JobPage(
        items=[job_model(r, services) for r in rows], total=total, limit=limit, offset=offset
    )


@router.get("/{job_id}", response_model=Job, responses=ERRORS)
def get_job(services: ServicesDep, caller: CallerDep, job_id: JobIdDep) -> Job:
    row = services.store.get(job_id, caller.scope)
    if row is None:
        raise HTTPException(404, "no such job")
    return job_model(row, services)


@router.get("/{job_id}/log", response_model=JobLog, responses=ERRORS)
def get_job_log(
    services: ServicesDep,
    caller: CallerDep,
    job_id: JobIdDep,
    after: Annotated[int, Query(ge=0, le=2**62)] = 0,
    limit: Annotated[int, Query(ge=1, le=1000)] = 1000,
) -> JobLog:
    """The job's log lines with an id above ``after``, oldest first: each attempt's worker,
    stage changes with the time each stage took, warnings, errors and how it ended. At most
    ``FOREST_JOB_LOG_LINES`` are kept per job (the oldest go; ``dropped`` counts them)."""
    if services.store.get(job_id, caller.scope) is None:
        raise HTTPException(404, "no such job")
    rows, dropped = joblog.read(services.store, job_id, after, limit)
    return JobLog(
        items=[log_line(r) for r in rows],
        dropped=dropped,
        next_after=rows[-1].id if rows else after,
    )


def log_line(row: JobLogRow) -> LogLine:
    return LogLine(
        id=row.id,
        at=row.at.replace(tzinfo=UTC),
        attempt=row.attempt,
        level=row.level,
        message=row.message,
    )


@router.delete("/{job_id}", response_model=Job, responses=ERRORS)
def cancel_job(services: ServicesDep, caller: CallerDep, job_id: JobIdDep) -> Job:
    """Cancel: a queued job is canceled at once; a running one's process is killed at the
    worker's next heartbeat (within seconds)."""
    row = tiles.cancel(services.store, job_id, caller.scope)
    if row is None:
        raise HTTPException(404, "no such job")
    return job_model(row, services)


@router.delete("/{job_id}/artifacts", response_model=Job, responses=ERRORS)
def delete_job_artifacts(services: ServicesDep, caller: CallerDep, job_id: JobIdDep) -> Job:
    """Delete a finished job's artifacts (its files; the job stays and says when). A queued or
    running job's are refused (409): cancel it first. Deleting again changes nothing."""
    row = services.store.get(job_id, caller.scope)
    if row is None:
        raise HTTPException(404, "no such job")
    if row.state not in FINISHED:
        raise HTTPException(409, f"the job is {row.state}: cancel it, or wait until it ends")
    delete_artifacts(services.store, services.artifacts, job_id)
    done = services.store.get(job_id)
    assert done is not None
    return job_model(done, services)


# HEAD: a download manager's size and type first, no body (its own operation in the schema)
@router.head(
    "/{job_id}/artifacts/{name}",
    response_class=FileResponse,
    summary="An artifact's headers (size, type, name, ETag) without its bytes",
    responses={200: {"description": "The artifact's headers; no body"}, **ERRORS},
)
@router.get(
    "/{job_id}/artifacts/{name}",
    response_class=FileResponse,
    responses={
        200: {
            "description": "The artifact",
            "content": {
                t: {"schema": {"type": "string", "format": "binary"}}
                for t in sorted(set(ARTIFACT_TYPES.values()))
            },
        },
        **ERRORS,
    },
)
def get_artifact(
    services: ServicesDep, caller: CallerDep, job_id: JobIdDep, name: str
) -> FileResponse:
    row = services.store.get(job_id, caller.scope)
    if row is None or name not in (row.artifacts or []):
        raise HTTPException(404, "no such artifact")
    path = services.artifacts.path(job_id, name)
    if path is None:
        raise HTTPException(404, "no such artifact")
    media = ARTIFACT_TYPES.get(path.suffix, "application/octet-stream")
    return FileResponse(path, media_type=media, filename=name)
