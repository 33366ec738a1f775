"""The worker registry: each worker process writes its row (name, host, queues, GL renderer,
current job) when it starts and every ``worker_heartbeat_s``; a row not written for
``worker_timeout_s`` is a lost worker (killed, or its host gone), one ``worker_forget_s``
old is deleted. The job table stays the source of truth for jobs: this is what an operator
sees of the farm (``GET /v1/workers``)."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta

from sqlalchemy import delete, select, update

from farm.db import WorkerRow, utcnow
from farm.store import JobStore

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Identity:
    id: str  # the lease owner its jobs carry (host:pid:tag)
    name: str
    host: str
    pid: int
    queues: Sequence[str]


def worker_state(row: WorkerRow, timeout_s: float, now: datetime | None = None) -> str:
    """``stopped`` (shut down cleanly), ``lost`` (not seen for ``timeout_s``), ``busy`` or
    ``idle``."""
    if row.stopped_at is not None:
        return "stopped"
    if (now or utcnow()) - row.last_seen > timedelta(seconds=timeout_s):
        return "lost"
    return "busy" if row.current_job else "idle"


class Registry:
    def __init__(self, store: JobStore) -> None:
        self.store = store

    def register(self, who: Identity, renderer: str | None = None) -> None:
        now = utcnow()
        with self.store.session() as s, s.begin():
            s.merge(
                WorkerRow(
                    id=who.id, name=who.name, host=who.host, pid=who.pid, queues=list(who.queues),
                    renderer=renderer, current_job=None, started_at=now, last_seen=now,
                    stopped_at=None,
                )
            )  # fmt: skip

    def beat(self, who: Identity, current_job: str | None, **values: str | None) -> None:
        """Seen now, running ``current_job`` (None: idle); a row deleted meanwhile (a long
        outage, forgotten) is written again."""
        with self.store.session() as s, s.begin():
            res = s.execute(
                update(WorkerRow)
                .where(WorkerRow.id == who.id)
                .values(last_seen=utcnow(), current_job=current_job, **values)
                .execution_options(synchronize_session=False)
            )
        if res.rowcount == 0:  # type: ignore[attr-defined]
            self.register(who, values.get("renderer"))

    def stopped(self, who: Identity) -> None:
        with self.store.session() as s, s.begin():
            s.execute(
                update(WorkerRow)
                .where(WorkerRow.id == who.id)
                .values(stopped_at=utcnow(), last_seen=utcnow(), current_job=None)
                .execution_options(synchronize_session=False)
            )

    def forget(self, older_than_s: float) -> int:
        cutoff = utcnow() - timedelta(seconds=older_than_s)
        with self.store.session() as s, s.begin():
            res = s.execute(
                delete(WorkerRow)
                .where(WorkerRow.last_seen < cutoff)
                .execution_options(synchronize_session=False)
            )
        gone: int = res.rowcount  # type: ignore[attr-defined]
        return gone

    def all(self) -> list[WorkerRow]:
        with self.store.session() as s:
            return list(s.scalars(select(WorkerRow).order_by(WorkerRow.started_at, WorkerRow.id)))


class Heartbeat(threading.Thread):
    """A worker's registry heartbeat: its row every ``interval_s``, whatever its job does
    (the job runs in a child process; this thread only writes a row)."""

    def __init__(
        self,
        registry: Registry,
        who: Identity,
        current_job: Callable[[], str | None],
        interval_s: float,
        forget_s: float,
        renderer: Callable[[], str | None] | None = None,
    ) -> None:
        super().__init__(name="forest-worker-registry", daemon=True)
        self.registry, self.who, self.current_job = registry, who, current_job
        self.interval_s, self.forget_s = interval_s, forget_s
        self.renderer = renderer
        self.stopped = threading.Event()

    def run(self) -> None:
        if self.renderer is not None:  # a GL probe takes a moment: not before the first job
            try:
                found = self.renderer()
                self.registry.beat(self.who, self.current_job(), renderer=found)
            except Exception:
                log.exception("GL renderer probe failed")
        rounds = 0
        while not self.stopped.wait(self.interval_s):
            try:
                self.registry.beat(self.who, self.current_job())
                rounds += 1
                if rounds % 60 == 1:  # every worker tidies, now and then: no reaper needed
                    self.registry.forget(self.forget_s)
            except Exception:  # the database is away: the row ages, the worker shows lost
                log.exception("worker registry heartbeat failed")

    def stop(self) -> None:
        self.stopped.set()
