"""Celery tasks: ``forest.run_job(job_id)`` claims the job in the job table and runs its kind.

The registry :data:`KINDS` maps a job kind to the code that runs it; a worker lists what it
runs with ``forest worker --list``. A task holds a lease on its job and a heartbeat thread
extends it (and records progress, and reads the cancel flag); a worker killed mid-task stops
heartbeating, the reaper re-enqueues the job and another worker runs it from the start. Outputs
are written into a scratch folder and renamed into the artifact store, so a half-written file
never shows.
"""

from __future__ import annotations

import logging
import os
import shutil
import socket
import threading
import time
import traceback
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from forest.errors import ForestError
from service.artifacts import ArtifactStore
from service.dispatch import TASK_NAME, Dispatcher, make_celery
from service.settings import ServiceSettings, get_settings
from service.store import Claim, JobStore

log = logging.getLogger(__name__)
OWNER = f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:8]}"


class Canceled(Exception):
    """The job's cancel flag was set: stop and record ``canceled``."""


class LeaseLost(Exception):
    """The reaper handed the job to another worker: stop without recording anything."""


@dataclass
class JobContext:
    """What a task kind gets: its parameters, a scratch folder and a way to report progress
    (which raises :class:`Canceled` once cancel was asked)."""

    job_id: str
    params: dict[str, Any]
    scratch: Path
    artifacts: ArtifactStore
    stage: str = "started"
    progress: float = 0.0
    cancel: threading.Event = field(default_factory=threading.Event)
    lost: threading.Event = field(default_factory=threading.Event)

    def report(self, stage: str, fraction: float) -> None:
        self.stage, self.progress = stage, fraction
        self.check()

    def check(self) -> None:
        if self.lost.is_set():
            raise LeaseLost(self.job_id)
        if self.cancel.is_set():
            raise Canceled(self.job_id)


@dataclass(frozen=True)
class Outcome:
    files: dict[str, Path]  # artifact name -> finished file in the scratch folder
    result: dict[str, Any]


class TaskKind(Protocol):
    def __call__(self, ctx: JobContext) -> Outcome: ...


def run_forest(ctx: JobContext) -> Outcome:
    """A forest job: generate, write the scene (``scene.<format>``)."""
    from forest.growth.generate import generate_forest, options_from_request
    from forest.growth.presets import load_preset
    from forest.usd.scene import write_scene
    from schemas.jobs import ForestRequest

    req = ForestRequest.model_validate(ctx.params)
    grammar = req.grammar if req.grammar is not None else load_preset(req.preset or "")
    options = options_from_request(req)

    def note(stage: str, done: int, total: int) -> None:
        ctx.report(stage, 0.7 * done / max(total, 1))

    forest = generate_forest(grammar, req.seed, options, progress=note)
    ctx.report("write", 0.7)
    name = f"scene.{req.format}"
    out = write_scene(forest, ctx.scratch / name, skinned=req.skinned)
    result = {
        "trees": req.trees,
        "pieces": forest.n_instances,
        "bones": len(forest.bones),
        "frames": req.frames,
        "scene": name,
    }
    return Outcome({name: out}, result)


def run_render(ctx: JobContext) -> Outcome:
    """A render job: the scene -> ``preview.png`` + ``metrics.json`` (EGL; GPU or llvmpipe)."""
    from worker.render_job import RenderRequest, render_file

    p = ctx.params
    # a forest job's scene, or the file uploaded with this job
    scene = ctx.artifacts.path(p.get("forest_job") or ctx.job_id, p["scene"])
    if scene is None:
        raise ForestError("the forest job's scene is gone from the artifact store", path="scene")
    ctx.report("render", 0.1)
    req = RenderRequest(
        scene=scene,
        output=ctx.scratch / "preview.png",
        metrics=ctx.scratch / "metrics.json",
        width=p["width"],
        height=p["height"],
        tess_max=p["tess_max"],
        frame=p["frame"],
        frames=p["frames"],
    )
    metrics = render_file(req)
    result = {
        "renderer": metrics.renderer,
        "cpu_ms": metrics.median.cpu_ms,
        "gpu_ms": metrics.median.gpu_ms,
        "frame_cpu_ms": [f.cpu_ms for f in metrics.frames],
        "primitives": metrics.median.primitives,
    }
    files = {"preview.png": req.output, "metrics.json": ctx.scratch / "metrics.json"}
    return Outcome(files, result)


KINDS: dict[str, TaskKind] = {"forest": run_forest, "render": run_render}


class Runtime:
    """Per-process store, artifact store and dispatcher, built from settings on first use."""

    def __init__(self, settings: ServiceSettings) -> None:
        self.settings = settings
        self.store = JobStore(settings.db_url)
        self.artifacts = ArtifactStore(settings.artifacts)
        self.dispatcher = Dispatcher(settings)


_runtime: Runtime | None = None


def runtime() -> Runtime:
    global _runtime
    if _runtime is None or _runtime.settings is not get_settings():
        _runtime = Runtime(get_settings())
    return _runtime


def _heartbeat(rt: Runtime, claim: Claim, ctx: JobContext, stop: threading.Event) -> None:
    s = rt.settings
    while not stop.wait(s.heartbeat_s):
        try:
            flag = rt.store.heartbeat(claim, s.lease_s, ctx.progress, ctx.stage)
        except Exception:  # the database is away: the lease may expire, the reaper decides
            log.exception("heartbeat of job %s failed", claim.job_id)
            continue
        if flag is None:
            ctx.lost.set()
            return
        if flag:
            ctx.cancel.set()


def _test_pause(ctx: JobContext, seconds: float) -> None:
    end = time.monotonic() + seconds
    ctx.report("test-pause", 0.0)
    while time.monotonic() < end:
        time.sleep(0.05)
        ctx.check()


def execute(job_id: str, kinds: dict[str, TaskKind] | None = None) -> str:
    """Run one delivery of a job; answers what happened (for logs and tests)."""
    rt = runtime()
    s = rt.settings
    claim = rt.store.claim(job_id, OWNER, s.lease_s)
    if claim is None:
        return "skipped"  # finished, canceled, or leased by a live worker
    kind = (kinds or KINDS).get(claim.kind)
    scratch = rt.artifacts.scratch(job_id)
    ctx = JobContext(job_id, claim.params, scratch, rt.artifacts)
    stop = threading.Event()
    beat = threading.Thread(target=_heartbeat, args=(rt, claim, ctx, stop), daemon=True)
    beat.start()
    try:
        if kind is None:
            raise ForestError(f"no worker code for job kind {claim.kind!r}", path="kind")
        if s.test_pause_s > 0 and claim.attempt == 1:
            _test_pause(ctx, s.test_pause_s)
        outcome = kind(ctx)
        ctx.check()
        for name, path in outcome.files.items():
            rt.artifacts.publish(job_id, path, name)
        done = rt.store.finish(
            claim, "completed", artifacts=sorted(outcome.files), result=outcome.result
        )
        return "completed" if done else "lost"
    except Canceled:
        rt.store.finish(claim, "canceled", error="canceled on request")
        return "canceled"
    except LeaseLost:
        return "lost"
    except ForestError as exc:  # bad input: retrying cannot help
        rt.store.finish(claim, "failed", error=str(exc))
        return "failed"
    except Exception as exc:
        error = f"{type(exc).__name__}: {exc}"
        log.error("job %s attempt %d: %s", job_id, claim.attempt, traceback.format_exc())
        if claim.attempt < claim.max_attempts:
            if rt.store.retry(claim, error):
                rt.dispatcher.send(job_id, claim.kind, countdown=s.retry_delay_s)
            return "retry"
        rt.store.finish(claim, "failed", error=error)
        return "failed"
    finally:
        stop.set()
        beat.join(timeout=5)
        shutil.rmtree(scratch, ignore_errors=True)


app = make_celery(get_settings())
# acks_late and reject_on_worker_lost come from make_celery's configuration
run_job: Callable[..., Any] = app.task(name=TASK_NAME)(execute)
