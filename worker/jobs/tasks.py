"""Celery tasks: ``forest.run_job(job_id)`` claims the job in the job table and runs its kind
(:data:`worker.jobs.registry.KINDS`).

The worker holds a lease on the job and runs the attempt in a child process
(:mod:`worker.jobs.supervise`): the worker heartbeats the lease whatever the child does (and
records its progress, and reads the cancel flag), kills the child on cancel, and tells a crash
or a resource limit of the child (a permanent failure of that job) from a lost worker (the
reaper re-enqueues the job after the lease and another worker runs it from the start). Outputs
are written into a scratch folder and renamed into the artifact store, so a half-written file
never shows. A tiled forest job runs no kind: it joins its tiles (:mod:`farm.tiles`). A write
that finds the data volume full fails the job at once (:mod:`farm.volume`): no retry.

Each attempt writes the job's log (:mod:`farm.joblog`): its start and worker, the child's
stage changes with the time each stage took, its warnings and errors, and how it ended,
batched with the heartbeat; and the worker's row in the registry (:mod:`farm.workers`) names
the job it runs.
"""

from __future__ import annotations

import logging
import os
import shutil
import socket
import time
import uuid
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from farm import chunks, joblog, tiles, volume
from farm.artifacts import ArtifactStore
from farm.dispatch import TASK_NAME, Dispatcher, make_celery
from farm.fair import CHUNK_KIND, TILE_KIND, pump_quietly
from farm.family import with_request
from farm.settings import FarmSettings, get_settings
from farm.store import Claim, JobStore
from farm.workers import Identity, Registry
from schemas.jobs import JobState
from worker.jobs.chunk import assemble
from worker.jobs.context import JobContext, TaskKind
from worker.jobs.registry import KINDS
from worker.jobs.scene_guard import UploadCaps
from worker.jobs.supervise import Event, job_limits, scrub_paths, supervise, under

log = logging.getLogger(__name__)
OWNER = f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:8]}"


class Runtime:
    """Per-process store, artifact store and dispatcher, built from settings on first use."""

    def __init__(self, settings: FarmSettings) -> None:
        self.settings = settings
        self.store = JobStore(settings.db_url)
        self.artifacts = ArtifactStore(settings.artifacts)
        self.dispatcher = Dispatcher(settings)
        self.registry = Registry(self.store)


_runtime: Runtime | None = None
identity: Identity | None = None
"""This worker in the registry (set by ``forest worker``; None: no registry, e.g. a test
calling :func:`execute`)."""
current_job: str | None = None
"""The job this process runs now (the registry's heartbeat reads it)."""


def runtime() -> Runtime:
    global _runtime
    if _runtime is None or _runtime.settings is not get_settings():
        _runtime = Runtime(get_settings())
    return _runtime


def upload_caps(s: FarmSettings) -> UploadCaps:
    """The caps of an uploaded scene, from the settings (its values must decode into half
    the job's memory limit)."""
    return UploadCaps(
        time_samples=s.max_upload_time_samples,
        frames=s.max_upload_frames,
        instances=s.max_upload_instances,
        bones=s.max_upload_bones,
        memory_bytes=s.job_memory_mb << 20 if s.job_memory_mb > 0 else None,
    )


def run_attempt(
    report: Callable[[str, float], None],
    kind: TaskKind,
    job_id: str,
    params: dict[str, Any],
    scratch: Path,
    artifacts_root: Path,
    upload_caps: UploadCaps,
) -> tuple[dict[str, str], dict[str, Any]]:
    """The child's side of an attempt: run ``kind``; its files (names -> paths in the scratch
    folder) and result."""
    ctx = JobContext(
        job_id,
        params,
        scratch,
        ArtifactStore(artifacts_root),
        on_report=report,
        upload_caps=upload_caps,
    )
    ctx.report("started", 0.0)
    outcome = kind(ctx)
    return {name: str(path) for name, path in outcome.files.items()}, outcome.result


class AttemptLog:
    """An attempt's lines of the job's log, kept until the next heartbeat (or the end)
    writes them: a line per stage change with the time the stage before took."""

    def __init__(self, rt: Runtime, claim: Claim) -> None:
        self.rt, self.claim = rt, claim
        self.lines: list[joblog.Line] = []
        self.started = self.stage_at = time.time()
        self.stage: str | None = None

    def add(self, level: str, message: str, at: float | None = None) -> None:
        when = datetime.fromtimestamp(at or time.time(), UTC).replace(tzinfo=None)
        self.lines.append(joblog.Line(level, message, when))

    def event(self, event: Event) -> None:
        kind, at, a, b = event
        if kind != "stage":
            self.add(a, b, at)
            return
        took = f" ({self.stage} took {at - self.stage_at:.2f} s)" if self.stage else ""
        self.add("info", f"stage {a}{took}", at)
        self.stage, self.stage_at = a, at

    def end(self, level: str, message: str) -> None:
        now = time.time()
        last = f"; {self.stage} took {now - self.stage_at:.2f} s" if self.stage else ""
        self.add(
            level, f"{message} (attempt {self.claim.attempt}: {now - self.started:.2f} s{last})"
        )
        self.flush()

    def flush(self) -> None:
        lines, self.lines = self.lines, []
        try:
            joblog.append(
                self.rt.store, self.claim.job_id, self.claim.attempt, lines,
                self.rt.settings.job_log_lines,
            )  # fmt: skip
        except Exception:  # the database is away: the job runs on without these lines
            log.exception("writing the log of job %s failed", self.claim.job_id)


def _registry_beat(rt: Runtime) -> None:
    if identity is None:
        return
    try:
        rt.registry.beat(identity, current_job)
    except Exception:  # the registry heartbeat writes it again within seconds
        log.exception("worker registry update failed")


def execute(job_id: str, kinds: dict[str, TaskKind] | None = None) -> str:
    """Run one delivery of a job; answers what happened (for logs and tests). A job or tile
    that ends frees a place in the fair window: the next is sent (:mod:`farm.fair`)."""
    global current_job
    rt = runtime()
    claim = rt.store.claim(job_id, OWNER, rt.settings.lease_s)
    if claim is None:
        return "skipped"  # finished, canceled, or leased by a live worker
    current_job = job_id
    _registry_beat(rt)  # the registry names the job now, not at the next heartbeat
    try:
        return run_claim(rt, claim, kinds)
    finally:
        current_job = None
        _registry_beat(rt)
        pump_quietly(rt.store, rt.dispatcher, rt.settings)


def run_claim(rt: Runtime, claim: Claim, kinds: dict[str, TaskKind] | None) -> str:
    """Run a claimed job: a tile with its forest job's request, a tiled forest's join, or
    its kind in a supervised child."""
    s, job_id = rt.settings, claim.job_id
    if claim.kind in (TILE_KIND, CHUNK_KIND):
        full = with_request(rt.store, claim)  # a tile's forest request, a chunk's render's
        if full is None:
            parent = "forest" if claim.kind == TILE_KIND else "render"
            rt.store.finish(claim, JobState.FAILED, error=f"its {parent} job is gone")
            return JobState.FAILED
        claim = full
    tiled = tiles.is_tiled(claim.kind, claim.params)
    if tiled or chunks.is_chunked(claim.kind, claim.params, s):
        try:
            if tiled:
                return tiles.join(rt.store, rt.dispatcher, rt.artifacts, claim, s)
            return chunks.join(rt.store, rt.dispatcher, rt.artifacts, claim, s, assemble)
        except Exception as exc:  # the store or broker is away: back to the queue, retried
            log.exception("%s job %s", "tiled forest" if tiled else "chunked render", job_id)
            if volume.is_full(exc):
                return fail_full(rt, claim)
            return retry_or_fail(rt, claim, scrub_paths(f"{type(exc).__name__}: {exc}"))
    alog = AttemptLog(rt, claim)
    who = f" ({identity.name})" if identity is not None else ""
    alog.add("info", f"attempt {claim.attempt} of {claim.max_attempts} on worker {OWNER}{who}")
    alog.flush()  # at once: a client following the job sees who took it
    kind = (kinds or KINDS).get(claim.kind)
    if kind is None:
        error = f"kind: no worker code for job kind {claim.kind!r}"
        alog.end("error", f"failed: {error}")
        rt.store.finish(claim, JobState.FAILED, error=error)
        return JobState.FAILED
    try:
        scratch = rt.artifacts.scratch(job_id)
    except OSError as exc:
        if volume.is_full(exc):
            return fail_full(rt, claim, alog)
        raise

    def heartbeat(progress: float, stage: str) -> bool | None:
        alog.flush()  # the lines since the last beat: one insert every heartbeat_s at most
        try:
            return rt.store.heartbeat(claim, s.lease_s, progress, stage)
        except Exception:  # the database is away: the lease may expire, the reaper decides
            log.exception("heartbeat of job %s failed", claim.job_id)
            return False

    try:
        end = supervise(
            run_attempt,
            (
                kind,
                job_id,
                claim.params,
                scratch,
                rt.artifacts.root,
                upload_caps(s),
            ),
            job_limits(s.job_memory_mb, s.job_cpu_s),
            heartbeat,
            s.heartbeat_s,
            on_event=alog.event,
        )
        if end.status == "ok":
            files = {n: Path(p) for n, p in (end.files or {}).items()}
            if not all(under(scratch, p) for p in files.values()):
                raise RuntimeError("a job's file lies outside its scratch folder")
            owner = tiles.artifact_owner(claim)
            published: list[Path] = []
            try:
                for name, path in files.items():
                    published.append(rt.artifacts.publish(owner, path, name))
            except Exception:  # none of an attempt's files without all of them
                for done_path in published:
                    done_path.unlink(missing_ok=True)
                raise
            # an attempt's last line is written before the job ends: whoever reads the log
            # once the job has ended (the event stream) finds it
            alog.end("info", f"completed: {len(files)} artifact(s)")
            done = rt.store.finish(
                claim, JobState.COMPLETED, artifacts=sorted(files), result=end.result
            )
            if done:
                return JobState.COMPLETED
            alog.end("warning", LEASE_LOST)
            return "lost"
        if end.status == "canceled":
            alog.end("info", "canceled on request")
            rt.store.finish(claim, JobState.CANCELED, error="canceled on request")
            return JobState.CANCELED
        if end.status == "lost":
            alog.end("warning", LEASE_LOST)
            return "lost"
        if end.status in ("bad", "crash"):  # the input cannot work: retrying cannot help
            log.warning("job %s attempt %d failed: %s", job_id, claim.attempt, end.message)
            alog.end("error", f"failed (not retried): {end.message}")
            rt.store.finish(claim, JobState.FAILED, error=end.message)
            return JobState.FAILED
        error = end.message
    except Exception as exc:  # the worker's own side (publish, store): retried
        log.exception("job %s attempt %d", job_id, claim.attempt)
        if volume.is_full(exc):
            return fail_full(rt, claim, alog)
        error = scrub_paths(f"{type(exc).__name__}: {exc}")
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    log.error("job %s attempt %d: %s", job_id, claim.attempt, error)
    return retry_or_fail(rt, claim, error, alog)


LEASE_LOST = "lease lost: the job went to another worker; this attempt's outcome is dropped"


def fail_full(rt: Runtime, claim: Claim, alog: AttemptLog | None = None) -> str:
    """The data volume had no room for the job's files: failed now (a retry finds none
    either, and each would fill it again)."""
    log.error("job %s attempt %d: %s", claim.job_id, claim.attempt, volume.FULL)
    (alog or AttemptLog(rt, claim)).end("error", f"failed (not retried): {volume.FULL}")
    rt.store.finish(claim, JobState.FAILED, error=volume.FULL)
    return JobState.FAILED


def retry_or_fail(rt: Runtime, claim: Claim, error: str, alog: AttemptLog | None = None) -> str:
    """A failed attempt: back to the queue (sent again after ``retry_delay_s``) while
    attempts are left, else failed with ``error``."""
    alog = alog or AttemptLog(rt, claim)
    if claim.attempt < claim.max_attempts:
        alog.end("error", f"attempt failed, retrying: {error}")
        if rt.store.retry(claim, error):
            rt.dispatcher.send(
                claim.job_id,
                claim.kind,
                countdown=rt.settings.retry_delay_s,
                pool=claim.params.get("pool"),
            )
        return "retry"
    alog.end("error", f"failed after {claim.attempt} attempt(s): {error}")
    rt.store.finish(claim, JobState.FAILED, error=error)
    return JobState.FAILED


app = make_celery(get_settings())
# acks_late and reject_on_worker_lost come from make_celery's configuration
run_job: Callable[..., Any] = app.task(name=TASK_NAME)(execute)
