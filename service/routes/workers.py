"""``/v1/workers``: the worker registry (:mod:`farm.workers`). Every tenant's workers and the
jobs they run: an admin key's, or anyone's on loopback while the API is open (as
``/metrics``)."""

from __future__ import annotations

from datetime import UTC

from fastapi import APIRouter, Depends

from farm.db import utcnow
from farm.workers import Registry, worker_state
from schemas.jobs import Worker, WorkerList
from service.deps import ServicesDep
from service.security import admin_or_open

router = APIRouter(prefix="/v1/workers", tags=["workers"])


@router.get(
    "",
    response_model=WorkerList,
    responses={403: {"description": "Not an admin key"}},
    dependencies=[Depends(admin_or_open)],
)
def list_workers(services: ServicesDep) -> WorkerList:
    """Every worker the registry knows (forgotten ``FOREST_WORKER_FORGET_S`` after it was
    last seen), oldest first: ``lost`` once not seen for ``FOREST_WORKER_TIMEOUT_S``."""
    timeout = services.settings.worker_timeout_s
    now = utcnow()
    items = [
        Worker(
            id=r.id,
            name=r.name,
            host=r.host,
            pid=r.pid,
            queues=list(r.queues),
            renderer=r.renderer,
            state=worker_state(r, timeout, now),
            current_job=r.current_job if r.stopped_at is None else None,
            started_at=r.started_at.replace(tzinfo=UTC),
            last_seen=r.last_seen.replace(tzinfo=UTC),
        )
        for r in Registry(services.store).all()
    ]
    return WorkerList(items=items, timeout_s=timeout)
