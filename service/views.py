"""Job rows -> wire models, and the shared create-and-enqueue path of job POSTs."""

from __future__ import annotations

import logging
import shutil
from datetime import UTC, datetime
from typing import Any

from fastapi import HTTPException
from fastapi.responses import JSONResponse

from schemas.jobs import Artifact, Job
from service.db import JobRow
from service.deps import Services
from service.store import IdempotencyConflict

log = logging.getLogger(__name__)
ERRORS: dict[int | str, dict[str, Any]] = {
    400: {"description": "Body that is not JSON (bytes that do not decode)"},
    404: {"description": "No such job or artifact"},
    409: {"description": "Idempotency-Key reused with a different request"},
    413: {"description": "Request body too large"},
}


def _utc(t: datetime | None) -> datetime | None:
    """The table keeps naive UTC (SQLite has no zones); the wire says so."""
    return t.replace(tzinfo=UTC) if t is not None else None


def job_model(row: JobRow, services: Services) -> Job:
    arts = [
        Artifact(
            name=name,
            url=f"/v1/jobs/{row.id}/artifacts/{name}",
            size=services.artifacts.size(row.id, name),
        )
        for name in row.artifacts or []
    ]
    return Job(
        id=row.id,
        kind=row.kind,
        state=row.state,
        progress=row.progress,
        stage=row.stage,
        attempts=row.attempts,
        max_attempts=row.max_attempts,
        cancel_requested=row.cancel_requested,
        worker=row.lease_owner,
        error=row.error,
        params=row.params,
        created_at=row.created_at.replace(tzinfo=UTC),
        started_at=_utc(row.started_at),
        finished_at=_utc(row.finished_at),
        heartbeat_at=_utc(row.heartbeat_at),
        artifacts=arts,
        result=row.result,
    )


def submit(
    services: Services,
    kind: str,
    params: dict[str, Any],
    key: str | None,
    tenant: str,
    inputs: dict[str, bytes] | None = None,
) -> JSONResponse:
    """Insert (or find, by idempotency key) the job, store its input files, enqueue it, answer
    202 + the job."""
    try:
        row, created = services.store.create(
            kind, params, services.settings.max_attempts, key, tenant
        )
    except IdempotencyConflict as exc:
        raise HTTPException(409, str(exc)) from None
    if created:
        for name, data in (inputs or {}).items():
            scratch = services.artifacts.scratch(row.id)
            try:
                (scratch / name).write_bytes(data)
                services.artifacts.publish(row.id, scratch / name, name)
            finally:
                shutil.rmtree(scratch, ignore_errors=True)
        # a failed send is not lost: the reaper re-sends queued jobs nobody picked up
        try:
            services.dispatcher.send(row.id, kind)
        except Exception:  # broker away; the job stays queued in the table
            log.exception("could not send job %s; the reaper will", row.id)
    job = job_model(row, services)
    return JSONResponse(
        job.model_dump(mode="json"),
        status_code=202,
        headers={"Location": f"/v1/jobs/{row.id}"},
    )
