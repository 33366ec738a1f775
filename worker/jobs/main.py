"""``forest worker``: one Celery worker process (solo pool: one task at a time, one GL context)
consuming the given queues, plus a reaper thread and its row in the worker registry
(:mod:`farm.workers`). Scale with more processes or replicas."""

from __future__ import annotations

import logging
import os
import socket
import subprocess
import sys
from typing import Any

import click

from forest.errors import ForestError
from forest.extras import require

# run in a fresh interpreter: the worker process itself never makes a GL context (its jobs'
# children do), and a driver that crashes on the probe takes only the probe down
PROBE = (
    "from forest.gl.context import create_context, gl_info\n"
    "print(gl_info(create_context()).renderer)"
)


def probe_renderer(timeout_s: float = 60.0) -> str:
    """GL_RENDERER of the context a render job would get, or why there is none."""
    try:
        done = subprocess.run(
            [sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=timeout_s
        )
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"unavailable: {type(exc).__name__}"
    if done.returncode == 0 and done.stdout.strip():
        return done.stdout.strip().splitlines()[-1][:200]
    last = (done.stderr.strip().splitlines() or [f"exit status {done.returncode}"])[-1]
    return f"unavailable: {last}"[:200]


def run_worker(queues: list[str], name: str | None = None, loglevel: str = "info") -> None:
    # the farm's packages (Celery, SQLAlchemy) load here, not when the `forest` command starts:
    # a core install without the service extras still runs every other command
    from farm.db import migrate
    from farm.dispatch import QUEUES
    from farm.reaper import Reaper, tidy_once
    from farm.settings import get_settings
    from farm.workers import Heartbeat, Identity

    unknown = [q for q in queues if q not in QUEUES]
    if unknown or not queues:
        raise ForestError(
            f"unknown queue(s) {', '.join(unknown)}; the queues are {QUEUES}", path="queues"
        )
    import forest.usd.scene  # noqa: F401  (heavy imports, pxr above all, before the first job)
    from forest.geometry.pieces import piece_library
    from worker.jobs import tasks
    from worker.jobs.supervise import preload
    from worker.jobs.tasks import OWNER, app, runtime

    piece_library(1)  # built once per process (about a second): not inside the first job
    preload()  # each job runs in a child of a fork server that imported pxr and forest once
    settings = get_settings()
    migrate(settings.db_url)
    settings.artifacts.mkdir(parents=True, exist_ok=True)
    rt = runtime()
    # a worker killed mid-job (this one's predecessor, say) left its scratch folder behind
    tidy_once(rt.store, rt.artifacts)
    reaper = Reaper(
        rt.store,
        rt.dispatcher,
        settings.reaper_interval_s,
        settings.requeue_after_s,
        artifacts=rt.artifacts,
        housekeeping_s=settings.housekeeping_s,
        artifact_ttl_s=settings.artifact_ttl_s,
        settings=settings,
    )
    reaper.start()
    node = name or f"forest-{os.getpid()}@{socket.gethostname()}"
    host = socket.gethostname()
    # the registry's row: %h as Celery expands it in the node name
    who = Identity(OWNER, node.replace("%h", host), host, os.getpid(), queues)
    tasks.identity = who
    renders = bool({"render", "gpu", "cpu"} & set(queues))  # farm.dispatch: the render pools
    rt.registry.register(who, None if renders else "none: no render queue")
    beat = Heartbeat(
        rt.registry,
        who,
        lambda: tasks.current_job,
        settings.worker_heartbeat_s,
        settings.worker_forget_s,
        renderer=probe_renderer if renders else None,
    )
    beat.start()
    try:
        _consume(app, settings, queues, node, loglevel)
    finally:
        beat.stop()
        try:
            rt.registry.stopped(who)  # a clean stop: shown stopped, not lost
        except Exception:  # the store is away: it shows lost once its row ages
            logging.getLogger(__name__).exception("worker registry: marking stopped failed")


def _consume(app: Any, settings: Any, queues: list[str], node: str, loglevel: str) -> None:
    app.worker_main(
        [
            "worker",
            "-Q",
            ",".join(settings.queue(q) for q in queues),
            "--pool",
            "solo",
            "-n",
            node,
            "-l",
            loglevel,
            "--without-gossip",
            "--without-mingle",
            "--without-heartbeat",
        ]
    )


@click.command("worker", context_settings={"help_option_names": ["-h", "--help"]})
@click.option(
    "-Q",
    "--queues",
    default="default,render,cpu",
    show_default=True,
    help="Queues to consume: default (trees, forests, tiles), render (renders of any pool), "
    "gpu or cpu (renders of that pool). A GPU worker: -Q gpu,render.",
)
@click.option("--name", help="Celery node name (default forest-<pid>@<host>).")
@click.option("--loglevel", default="info", show_default=True)
@click.option("--list", "list_kinds", is_flag=True, help="List the job kinds this worker runs.")
@click.option(
    "--check",
    is_flag=True,
    help="Liveness probe: exit 1 when this host's worker has not written its registry row "
    "within FOREST_WORKER_TIMEOUT_S (python -m worker.probe, cheaper: no CLI start-up).",
)
def worker_command(
    queues: str, name: str | None, loglevel: str, list_kinds: bool, check: bool
) -> None:
    """Join a cluster: consume jobs from the broker and job store in the settings
    (FOREST_BROKER_URL, FOREST_DATABASE_URL, FOREST_ARTIFACTS_DIR)."""
    if check:
        from worker.probe import main as probe

        sys.exit(probe([]))
    try:
        # the job store and queue: the one-line answer, not a traceback, on a core install
        require("service", "celery", "sqlalchemy", "alembic", path="forest worker")
        if list_kinds:
            from farm.dispatch import KIND_QUEUES
            from worker.jobs.registry import KINDS

            for kind in KINDS:
                pools = " (pool gpu: gpu, pool cpu: cpu)" if kind.startswith("render") else ""
                click.echo(f"{kind}\tqueue {KIND_QUEUES[kind]}{pools}")
            return
        run_worker([q.strip() for q in queues.split(",") if q.strip()], name, loglevel)
    except ForestError as exc:  # the same one-line answer and exit code as the forest command
        click.echo(f"error: {exc}", err=True)
        sys.exit(2)
