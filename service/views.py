"""Job rows -> wire models, and the shared create-and-enqueue path of job POSTs."""

from __future__ import annotations

import logging
import shutil
from datetime import UTC, datetime
from typing import Any

from fastapi import HTTPException
from fastapi.responses import JSONResponse
from kombu.exceptions import OperationalError as KombuOperationalError
from sqlalchemy.exc import DBAPIError

from farm import volume
from farm.db import JobRow
from farm.error_text import capped
from farm.fair import pump
from farm.store import IdempotencyConflict, scoped_key
from farm.webhooks import refusal
from schemas.jobs import Artifact, Job, JobCost, JobRun, JobState, JobWebhook
from service.deps import Services
from service.errors import RETRY_AFTER_S, field_error
from service.quotas import over_quota

log = logging.getLogger(__name__)
BROKER_UNAVAILABLE = "the broker is unavailable; the job was not submitted; retry later"
NOT_SUBMITTED = "not submitted: the broker was unavailable (the request was answered 503)"
ERRORS: dict[int | str, dict[str, Any]] = {
    400: {"description": "Body that is not JSON (bytes that do not decode)"},
    404: {"description": "No such job or artifact"},
    409: {"description": "Idempotency-Key reused with a different request"},
    413: {"description": "Request body too large"},
    429: {"description": "A tenant quota (named in the detail) or the key's rate limit"},
}
UPLOAD_ERRORS: dict[int | str, dict[str, Any]] = ERRORS | {
    507: {"description": "The data volume is full: the upload was not stored, no job made"},
}


def _utc(t: datetime | None) -> datetime | None:
    """The table keeps naive UTC (SQLite has no zones); the wire says so."""
    return t.replace(tzinfo=UTC) if t is not None else None


DATA_URI_SHOWN = 256  # characters of an inline image a job's params show


def shown_params(value: Any) -> Any:
    """A job's params as answered: an inline image (a recipe's ``data:`` density map or
    heightfield, up to a megabyte) elided to its head and size, so a page of jobs stays
    small; the stored params, which the worker reads, keep it whole."""
    if isinstance(value, dict):
        return {k: shown_params(v) for k, v in value.items()}
    if isinstance(value, list):
        return [shown_params(v) for v in value]
    if isinstance(value, str) and value.startswith("data:") and len(value) > DATA_URI_SHOWN:
        head = value[: value.find(",") + 1] if "," in value[:100] else "data:"
        return f"{head}... ({len(value):,} characters, elided)"
    return value


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
        error=capped(row.error),  # rows stored before errors were capped
        params=shown_params(row.params),
        created_at=row.created_at.replace(tzinfo=UTC),
        started_at=_utc(row.started_at),
        finished_at=_utc(row.finished_at),
        heartbeat_at=_utc(row.heartbeat_at),
        artifacts=arts,
        artifacts_deleted_at=_utc(row.artifacts_deleted_at),
        result=row.result,
        priority=row.priority,
        cost=JobCost.model_validate(row.estimate) if row.estimate else None,
        after=row.after or [],
        then=row.then or [],
        runs=[
            JobRun(
                attempt=r["attempt"],
                worker=r["worker"],
                started_at=datetime.fromisoformat(r["started_at"]).replace(tzinfo=UTC),
            )
            for r in row.runs or []
        ],
        webhook=JobWebhook(
            url=row.webhook_url,
            pending=row.webhook_pending,
            attempts=row.webhook_attempts,
            delivered_at=_utc(row.webhook_done_at),
            error=row.webhook_error,
        )
        if row.webhook_url
        else None,
    )


def _store_inputs(services: Services, job_id: str, inputs: dict[str, bytes]) -> None:
    for name, data in inputs.items():
        scratch = services.artifacts.scratch(job_id)
        try:
            (scratch / name).write_bytes(data)
            services.artifacts.publish(job_id, scratch / name, name)
        finally:
            shutil.rmtree(scratch, ignore_errors=True)


def submit(
    services: Services,
    kind: str,
    params: dict[str, Any],
    key: str | None,
    tenant: str,
    inputs: dict[str, bytes] | None = None,
    cost: JobCost | None = None,
    field: list[str | int] | None = None,
    after: list[str] | None = None,
) -> JSONResponse:
    """Insert (or find, by idempotency key) the job, store its input files, enqueue it, answer
    202 + the job. A new job must fit the tenant's quotas with its ``cost``
    (:mod:`service.quotas`; ``field``: the request field a 422 names); ``after``: the jobs
    it waits for (:func:`check_after` checked them)."""
    row = enqueue(services, kind, params, key, tenant, inputs, cost=cost, field=field, after=after)
    return accepted(row, services)


def check_after(services: Services, ids: list[str], scope: str | None) -> list[str]:
    """The jobs a new job may wait for: each one the caller's (``scope``: its tenant, None
    for an admin) and neither failed nor canceled; 422 naming the first that is not."""
    for k, job_id in enumerate(ids):
        row = services.store.get(job_id, scope)
        if row is None:
            raise field_error(["after", k], "no such job")
        if row.state in (JobState.FAILED, JobState.CANCELED) or row.cancel_requested:
            state = JobState.CANCELED if row.cancel_requested else row.state
            raise field_error(["after", k], f"the job is {state}: nothing would ever run")
    return list(dict.fromkeys(ids))


def check_tiles(services: Services, job_id: str | None, scope: str | None, wait: bool) -> list[str]:
    """A request's ``tiles``: a tile-set job (``POST /v1/tilesets``) of the caller's that has
    not failed. The jobs to wait for: the tile set's while it runs (``wait``: a forest waits;
    a tree, answered at once, needs it completed). 422 at ``tiles``."""
    field: list[str | int] = ["tiles"]
    if job_id is None:
        return []
    row = services.store.get(job_id, scope)
    if row is None:
        raise field_error(field, "no such job")
    if row.kind != "tileset":
        raise field_error(field, f"a {row.kind} job, not a tile set (POST /v1/tilesets)")
    if row.state in (JobState.FAILED, JobState.CANCELED) or row.cancel_requested:
        state = JobState.CANCELED if row.cancel_requested else row.state
        raise field_error(field, f"the tile set job is {state}: make the tile set again")
    if row.state == JobState.COMPLETED:
        return []
    if not wait:
        raise field_error(field, f"the tile set job is {row.state}: a tree needs it completed")
    return [row.id]


def enqueue(
    services: Services,
    kind: str,
    params: dict[str, Any],
    key: str | None,
    tenant: str,
    inputs: dict[str, bytes] | None = None,
    cost: JobCost | None = None,
    field: list[str | int] | None = None,
    after: list[str] | None = None,
) -> JobRow:
    """Insert (or find, by idempotency key) the job, store its input files, enqueue it: the
    job's row (429/422 over a quota, 503 if the broker is away and the job was not sent)."""
    cost = cost or JobCost(pieces=0, frames=0, tiles=0, scene_bytes=0, units=0)
    webhook = params.get("webhook")
    refused_hook = refusal(webhook, services.settings) if webhook else None
    if refused_hook is not None:  # before any work: the farm calls only hosts it allows
        raise field_error(["webhook"], refused_hook)
    known = key is not None and services.store.by_key(scoped_key(tenant, key)) is not None

    def admit(load: tuple[int, int]) -> Exception | None:
        return over_quota(services.settings, cost, load, field or [])

    try:
        row, created = services.store.create(
            kind,
            params,
            services.settings.max_attempts,
            key,
            tenant,
            priority=int(params.get("priority", 5)),
            estimate=cost.model_dump(),
            after=after,
            # a repeat of an accepted request answers its job, quota or not
            admit=None if known else admit,
        )
    except IdempotencyConflict as exc:
        raise HTTPException(409, str(exc)) from None
    if created:
        if inputs:
            try:
                _store_inputs(services, row.id, inputs)
            except Exception as exc:
                # no job without its input: it would only fail (or be sent by the reaper to fail)
                services.store.discard(row.id)
                services.artifacts.remove(row.id)
                if volume.is_full(exc):
                    raise HTTPException(507, volume.FULL) from None
                raise
        try:
            # the fair window sends it now if it has room, else as the tenant's turn comes
            pump(services.store, services.dispatcher, services.settings)
        except (KombuOperationalError, OSError, DBAPIError) as exc:
            # the broker is away: answer 503 and fail the job now rather than leave it for a
            # later pump to send (the client, told to retry, would make it twice); unless its
            # message went out before the failure
            log.warning(
                "broker unavailable for job %s: %s: %.200s", row.id, type(exc).__name__, exc
            )
            abandoned = services.store.abandon(row.id, NOT_SUBMITTED)
            if abandoned is not None:
                services.artifacts.remove(row.id)  # its uploaded input
                raise HTTPException(
                    503, BROKER_UNAVAILABLE, headers={"Retry-After": str(RETRY_AFTER_S)}
                ) from None
        row = services.store.get(row.id) or row  # sent or held: as it is now
    return row


def accepted(row: JobRow, services: Services) -> JSONResponse:
    """202 + the job (as ``GET /v1/jobs/{id}`` answers it) + its Location."""
    job = job_model(row, services)
    return JSONResponse(
        job.model_dump(mode="json"),
        status_code=202,
        headers={"Location": f"/v1/jobs/{row.id}"},
    )
