"""Celery as delivery only: the task carries a job id; the job table holds everything else.

Task kinds map to queues: CPU work on ``default``; a render on its pool's queue, ``gpu`` or
``cpu`` (Mesa's llvmpipe), or on ``render``, which workers of both pools consume, so whichever
is free takes it. The worker's registry (``worker/jobs/registry.py``) maps kinds to code. The
service sends tasks by name and never imports worker code.
"""

from __future__ import annotations

import logging
import sqlite3
from contextlib import closing
from pathlib import Path
from typing import Any

from celery import Celery
from kombu import Exchange, Queue

from farm.db import SQLITE_LOCK_S
from farm.settings import FarmSettings

TASK_NAME = "forest.run_job"
KIND_QUEUES: dict[str, str] = {
    "forest": "default",
    "render": "render",
    "forest_tile": "default",
    "render_chunk": "render",
    "tree": "default",
    "tileset": "default",
}
QUEUES = ("default", "render", "gpu", "cpu")


def queue_for(kind: str, pool: str | None = None) -> str:
    """The queue (without the prefix) a job of ``kind`` goes to; a render's ``pool`` picks."""
    if kind in ("render", "render_chunk") and pool in ("gpu", "cpu"):
        return pool
    return KIND_QUEUES[kind]


log = logging.getLogger(__name__)
SQLA_POLL_S = 0.1


def _sqlite_broker_wal(path: str) -> None:
    """Put the embedded broker's file in WAL mode (kept in the file): the workers' polls
    (a read every 0.1 s each) then never block a send, nor a send a poll."""
    try:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        with closing(sqlite3.connect(path, timeout=SQLITE_LOCK_S)) as conn:
            conn.execute("PRAGMA journal_mode=WAL")
    except (OSError, sqlite3.Error) as exc:  # kombu says it again, in its words, when used
        log.warning("embedded broker %s not put in WAL mode: %s", Path(path).name, exc)


def queue(name: str, args: dict[str, Any]) -> Queue:
    """A queue on a direct exchange of its own, bound by its own name. (Celery binds a bare
    ``Queue(name)`` to the default queue's exchange and key, so ``gpu`` showed up bound to
    ``default``'s exchange; tasks are sent by queue name, so that sent nothing astray, but any
    publish to that exchange would have copied into both.)"""
    return Queue(name, Exchange(name, type="direct"), routing_key=name, queue_arguments=args)


def make_celery(settings: FarmSettings) -> Celery:
    app = Celery("forest", broker=settings.broker, set_as_current=False)
    args: dict[str, Any] = {"x-queue-type": "quorum"} if settings.quorum_queues else {}
    if settings.broker.startswith("sqla+"):
        # kombu hands every transport option of this transport to create_engine, so the
        # poll interval (1 s by default: a second of latency per job) is set on the class
        from kombu.transport import sqlalchemy as kombu_sqla

        kombu_sqla.Transport.polling_interval = SQLA_POLL_S
        if settings.broker.startswith("sqla+sqlite:///"):
            _sqlite_broker_wal(settings.broker.removeprefix("sqla+sqlite:///"))
            # sqlite3 gives up on a locked file after 5 s: under load a send then failed and
            # was answered 503; wait as long as the job store does
            app.conf.broker_transport_options = {"connect_args": {"timeout": SQLITE_LOCK_S}}
    if settings.is_redis:
        # Redis redelivers an unacknowledged message only after the visibility timeout (a
        # killed worker's message waits in the ``unacked`` hash until then), so the reaper,
        # which acts after one lease, is what recovers; the key prefix keeps clusters (or test
        # runs) sharing a Redis database apart: queues, the unacked hash, bindings, pidbox
        options: dict[str, Any] = {"visibility_timeout": settings.broker_visibility_timeout_s}
        if settings.queue_prefix:
            options["global_keyprefix"] = settings.queue_prefix
        app.conf.broker_transport_options = options
    app.conf.update(
        task_acks_late=True,
        task_reject_on_worker_lost=True,
        worker_prefetch_multiplier=1,
        task_queues=[queue(settings.queue(q), args) for q in QUEUES],
        task_default_queue=settings.queue("default"),
        task_ignore_result=True,
        result_backend=None,
        broker_connection_retry_on_startup=True,
        worker_hijack_root_logger=False,
        worker_send_task_events=False,
        task_serializer="json",
        accept_content=["json"],
    )
    return app


class Dispatcher:
    """Sends ``forest.run_job(job_id)`` to the queue of the job's kind."""

    def __init__(self, settings: FarmSettings) -> None:
        self.settings = settings
        self.app = make_celery(settings)

    def send(
        self, job_id: str, kind: str, countdown: float | None = None, pool: str | None = None
    ) -> None:
        queue = self.settings.queue(queue_for(kind, pool))
        self.app.send_task(TASK_NAME, args=[job_id], queue=queue, countdown=countdown)

    def ping(self) -> None:
        """Raise unless the broker answers."""
        with self.app.connection_for_write() as conn:
            conn.ensure_connection(max_retries=1, timeout=2)

    def close(self) -> None:
        self.app.close()
