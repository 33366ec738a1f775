"""``forest worker``: one Celery worker process (solo pool: one task at a time, one GL context)
consuming the given queues, plus a reaper thread. Scale with more processes or replicas."""

from __future__ import annotations

import os
import socket

from farm.db import migrate
from farm.dispatch import QUEUES
from farm.reaper import Reaper, tidy_once
from farm.settings import get_settings
from forest.errors import ForestError


def run_worker(queues: list[str], name: str | None = None, loglevel: str = "info") -> None:
    unknown = [q for q in queues if q not in QUEUES]
    if unknown or not queues:
        raise ForestError(
            f"unknown queue(s) {', '.join(unknown)}; the queues are {QUEUES}", path="queues"
        )
    import forest.usd.scene  # noqa: F401  (heavy imports, pxr above all, before the first job)
    from forest.geometry.pieces import piece_library
    from worker.supervise import preload
    from worker.tasks import app, runtime

    piece_library(1)  # built once per process (about a second): not inside the first job
    preload()  # each job runs in a child of a fork server that imported pxr and forest once
    settings = get_settings()
    migrate(settings.db_url)
    settings.artifacts.mkdir(parents=True, exist_ok=True)
    rt = runtime()
    # a worker killed mid-job (this one's predecessor, say) left its scratch folder behind
    tidy_once(rt.store, rt.artifacts)
    reaper = Reaper(
        rt.store, rt.dispatcher, settings.reaper_interval_s, settings.requeue_after_s,
        artifacts=rt.artifacts, housekeeping_s=settings.housekeeping_s,
        artifact_ttl_s=settings.artifact_ttl_s,
    )
    reaper.start()
    node = name or f"forest-{os.getpid()}@{socket.gethostname()}"
    app.worker_main(
        [
            "worker",
            "-Q", ",".join(settings.queue(q) for q in queues),
            "--pool", "solo",
            "-n", node,
            "-l", loglevel,
            "--without-gossip",
            "--without-mingle",
            "--without-heartbeat",
        ]
    )
