"""Each job's log: stage changes, warnings, errors and timings, one row per line, capped per
job (``job_log_lines``: past it the oldest go, and the job counts them in ``log_dropped``).

Lines are written by the worker that runs an attempt (in batches, with its heartbeat) and by
the reaper (a lost worker); the API reads them (``GET /v1/jobs/{id}/log``) and the event
stream follows them by id (``GET /v1/jobs/{id}/events``)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime

from sqlalchemy import delete, insert, select, update

from farm.db import JobLogRow, JobRow, utcnow
from farm.store import JobStore

LEVELS = ("info", "warning", "error")
LINE_CHARS = 1000  # one line's text; a longer one is cut (an error is capped apart: 4 KiB)


@dataclass(frozen=True)
class Line:
    level: str
    message: str
    at: datetime | None = None  # None: now


def _cut(message: str) -> str:
    message = message.replace("\x00", "")  # PostgreSQL's text refuses a NUL
    return message if len(message) <= LINE_CHARS else message[: LINE_CHARS - 1] + "…"


def append(store: JobStore, job_id: str, attempt: int, lines: Sequence[Line], cap: int) -> None:
    """Add ``lines`` to the job's log, then drop its oldest lines past ``cap``."""
    if not lines:
        return
    now = utcnow()
    rows = [
        {
            "job_id": job_id,
            "attempt": attempt,
            "at": line.at or now,
            "level": line.level if line.level in LEVELS else "info",
            "message": _cut(line.message),
        }
        for line in lines
    ]
    with store.session() as s, s.begin():
        s.execute(insert(JobLogRow.metadata.tables["job_logs"]), rows)
        # the newest line that falls off: the cap-th from the end (the (job_id, id) index)
        cutoff = s.scalar(
            select(JobLogRow.id)
            .where(JobLogRow.job_id == job_id)
            .order_by(JobLogRow.id.desc())
            .offset(cap)
            .limit(1)
        )
        if cutoff is None:
            return
        res = s.execute(
            delete(JobLogRow)
            .where(JobLogRow.job_id == job_id, JobLogRow.id <= cutoff)
            .execution_options(synchronize_session=False)
        )
        dropped: int = res.rowcount  # type: ignore[attr-defined]
        s.execute(
            update(JobRow)
            .where(JobRow.id == job_id)
            .values(log_dropped=JobRow.log_dropped + dropped)
            .execution_options(synchronize_session=False)
        )


def read(
    store: JobStore, job_id: str, after: int = 0, limit: int = 1000
) -> tuple[list[JobLogRow], int]:
    """The job's lines with an id above ``after``, oldest first, and how many were dropped."""
    with store.session() as s:
        rows = list(
            s.scalars(
                select(JobLogRow)
                .where(JobLogRow.job_id == job_id, JobLogRow.id > after)
                .order_by(JobLogRow.id)
                .limit(limit)
            )
        )
        dropped = s.scalar(select(JobRow.log_dropped).where(JobRow.id == job_id)) or 0
    return rows, int(dropped)
