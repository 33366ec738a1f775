"""``GET /v1/jobs/{id}/events``: a job's state, stage, progress and log lines pushed as
Server-Sent Events (sse-starlette speaks the protocol: framing, pings, disconnects).

The stream reads the job table and the job's new log lines every ``events_poll_s`` (no
database notifications: the store stays plain SQL on SQLite and PostgreSQL alike) and sends
what changed. It ends when the job ends (an ``end`` event), or after ``events_max_s`` while
the job runs: the client reconnects, and ``Last-Event-ID`` (a log line's id: log events carry
one) resumes the log where it stopped. The caller is checked as for ``GET /v1/jobs/{id}``
(the job's tenant or an admin) when the stream opens."""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import AsyncIterator
from typing import Annotated, Any

from fastapi import APIRouter, Header, HTTPException
from sse_starlette import EventSourceResponse, ServerSentEvent
from starlette.concurrency import run_in_threadpool

from farm import joblog
from farm.db import JobLogRow, JobRow
from farm.store import FINISHED
from schemas.jobs import JobState
from service.deps import Services, ServicesDep
from service.routes.jobs import JobIdDep, log_line
from service.security import CallerDep
from service.views import ERRORS

router = APIRouter(prefix="/v1/jobs", tags=["jobs"])
PING_S = 15  # a comment line this often keeps proxies from closing a quiet stream
SEND_TIMEOUT_S = 30
LOG_BATCH = 200  # log lines read per poll (a backlog is sent over a few polls)


def transitions(prev: tuple[str, int] | None, now: tuple[str, int]) -> list[tuple[str, int]]:
    """The state changes from ``prev`` (state, attempts) to ``now``, in order, including
    those a poll fell between: a job that was queued and is completed now was active first
    (its attempts counted up); one whose attempt failed went back to queued before the next.
    None: the stream's first look, the state as it is."""
    if prev is None:
        return [now]
    state, attempts = prev
    out: list[tuple[str, int]] = []
    while attempts < now[1]:
        if state == JobState.ACTIVE:  # that attempt ended, and the job was queued again
            out.append((JobState.QUEUED, attempts))
        attempts += 1
        state = JobState.ACTIVE
        out.append((state, attempts))
    if now[0] != state:
        out.append(now)
    return out


def _event(kind: str, data: dict[str, Any], event_id: str | None = None) -> ServerSentEvent:
    data_text = json.dumps(data, separators=(",", ":"))
    return ServerSentEvent(data=data_text, event=kind, id=event_id, sep="\n")


async def _lines(services: Services, job_id: str, after: int) -> list[JobLogRow]:
    lines, _ = await run_in_threadpool(joblog.read, services.store, job_id, after, LOG_BATCH)
    return lines


async def job_stream(services: Services, job_id: str, after: int) -> AsyncIterator[ServerSentEvent]:
    settings = services.settings
    ends = time.monotonic() + settings.events_max_s
    seen: tuple[str, int] | None = None
    shown: tuple[str, float] | None = None
    while True:
        # the lines first, then the row: every line read was written before the state seen
        # (a worker writes an attempt's last line before it ends the job)
        lines = await _lines(services, job_id, after)
        row: JobRow | None = await run_in_threadpool(services.store.get, job_id)
        if row is None:  # deleted meanwhile (a held tile of a canceled forest)
            yield _event("end", {"state": None})
            return
        if row.state in FINISHED:  # every line up to the end, so none comes after "end"
            while more := await _lines(services, job_id, lines[-1].id if lines else after):
                lines += more
        now = (str(row.state), int(row.attempts))
        changes = transitions(seen, now)
        seen = now
        last = changes[-1] if changes and changes[-1][0] in FINISHED else None
        for state, attempts in changes[:-1] if last else changes:
            yield _event("state", {"state": state, "attempts": attempts})
        for line in lines:  # between the start of an attempt and its end
            yield _event("log", log_line(line).model_dump(mode="json"), str(line.id))
            after = line.id
        progress = (row.stage, round(row.progress, 4))
        if progress != shown:
            shown = progress
            yield _event("progress", {"stage": row.stage, "progress": row.progress})
        if last is not None:
            yield _event("state", {"state": last[0], "attempts": last[1], "error": row.error})
        if row.state in FINISHED:
            yield _event("end", {"state": row.state})
            return
        if time.monotonic() >= ends:
            return  # capped: the client reconnects (Last-Event-ID: the log's last id)
        await asyncio.sleep(settings.events_poll_s)


@router.get(
    "/{job_id}/events",
    response_class=EventSourceResponse,
    responses={
        200: {
            "description": "Server-Sent Events: `state`, `progress`, `log`, then `end`",
            "content": {"text/event-stream": {"schema": {"type": "string"}}},
        },
        **ERRORS,
    },
)
async def job_events(
    services: ServicesDep,
    caller: CallerDep,
    job_id: JobIdDep,
    last_event_id: Annotated[
        str | None,
        Header(alias="Last-Event-ID", max_length=20, description="Resume the log after this id"),
    ] = None,
) -> EventSourceResponse:
    """The job's changes as they happen: ``state`` (``{"state", "attempts"}``, every change
    in order, the first the state as the stream opens; a finished one, after the job's last
    log lines, with its ``error``),
    ``progress`` (``{"stage", "progress"}``), ``log`` (a log line, its ``id`` the event's id),
    and last ``end`` (``{"state"}``) once the job has ended and its log is sent. A stream
    ends after ``FOREST_EVENTS_MAX_S`` while the job runs: reconnect (with
    ``Last-Event-ID``)."""
    row = await run_in_threadpool(services.store.get, job_id, caller.scope)
    if row is None:
        raise HTTPException(404, "no such job")
    after = int(last_event_id) if last_event_id and last_event_id.isdigit() else 0
    # send_timeout: a client that stops reading is dropped, not waited on with a thread
    return EventSourceResponse(
        job_stream(services, job_id, after), ping=PING_S, sep="\n", send_timeout=SEND_TIMEOUT_S
    )
