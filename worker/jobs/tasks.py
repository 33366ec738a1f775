"""Celery tasks: ``forest.run_job(job_id)`` claims the job in the job table and runs its kind.

The registry :data:`KINDS` maps a job kind to the code that runs it; a worker lists what it
runs with ``forest worker --list``. The worker holds a lease on the job and runs the attempt in
a child process (:mod:`worker.jobs.supervise`): the worker heartbeats the lease whatever the child
does (and records its progress, and reads the cancel flag), kills the child on cancel, and
tells a crash or a resource limit of the child (a permanent failure of that job) from a lost
worker (the reaper re-enqueues the job after the lease and another worker runs it from the
start). Outputs are written into a scratch folder and renamed into the artifact store, so a
half-written file never shows.
"""

from __future__ import annotations

import logging
import os
import shutil
import socket
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from farm.artifacts import ArtifactStore
from farm.dispatch import TASK_NAME, Dispatcher, make_celery
from farm.settings import FarmSettings, get_settings
from farm.store import Claim, JobStore, tile_job_ids
from forest.errors import ForestError
from worker.jobs.scene_guard import UploadCaps
from worker.jobs.supervise import job_limits, scrub_paths, supervise, under

log = logging.getLogger(__name__)
OWNER = f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:8]}"


@dataclass
class JobContext:
    """What a task kind gets (in the job's child process): its parameters, a scratch folder
    and a way to report progress, which the supervising worker records with its heartbeat.
    Cancel needs no check: the worker kills the child."""

    job_id: str
    params: dict[str, Any]
    scratch: Path
    artifacts: ArtifactStore
    stage: str = "started"
    progress: float = 0.0
    on_report: Callable[[str, float], None] | None = None
    test_hook: str = ""
    upload_caps: UploadCaps = field(default_factory=UploadCaps)

    def report(self, stage: str, fraction: float) -> None:
        self.stage, self.progress = stage, fraction
        if self.on_report is not None:
            self.on_report(stage, fraction)


@dataclass(frozen=True)
class Outcome:
    files: dict[str, Path]  # artifact name -> finished file in the scratch folder
    result: dict[str, Any]


class TaskKind(Protocol):
    def __call__(self, ctx: JobContext) -> Outcome: ...


def run_forest(ctx: JobContext) -> Outcome:
    """A forest job: generate, write the scene (``scene.<format>``: USD, or ``scene.glb``)."""
    from farm.requests import options_from_request
    from forest.growth.generate import generate_forest
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
    if req.format == "glb":
        from forest.gltf.document import write_glb

        out = write_glb(forest, ctx.scratch / name)
    else:
        out = write_scene(forest, ctx.scratch / name, skinned=req.skinned)
    result = {
        "trees": req.trees,
        "pieces": forest.n_instances,
        "bones": len(forest.bones),
        "frames": req.frames,
        "scene": name,
    }
    return Outcome({name: out}, result)


def tile_artifact(i: int, j: int) -> str:
    """A tile's file in its forest job's artifacts (beside the root layer ``scene.*``)."""
    return f"scene_tile_{i}_{j}.usdc"


def run_tile(ctx: JobContext) -> Outcome:
    """One tile of a tiled forest job (``params``: the forest request + ``parent``, ``tile``):
    generate its trees and write ``scene_tile_<i>_<j>.usdc``, published into the parent
    job's artifacts; the result carries the tile's entry of the root layer."""
    from farm.requests import options_from_request
    from forest.growth.presets import load_preset
    from forest.growth.tiling import TilePlan, generate_tile
    from forest.usd.tiled import write_tile_file
    from schemas.jobs import ForestRequest

    p = dict(ctx.params)
    i, j = p.pop("tile")
    p.pop("parent")
    req = ForestRequest.model_validate(p)
    assert req.tile_size is not None
    grammar = req.grammar if req.grammar is not None else load_preset(req.preset or "")
    plan = TilePlan(req.trees, req.area, req.tile_size, req.seed)

    def note(stage: str, done: int, total: int) -> None:
        ctx.report(stage, 0.7 * done / max(total, 1))

    forest = generate_tile(grammar, plan, i, j, options_from_request(req), progress=note)
    ctx.report("write", 0.7)
    name = tile_artifact(i, j)
    skinned = bool(req.skinned)  # tiles stay posed unless asked
    entry = write_tile_file(forest, ctx.scratch / name, f"./{name}", i, j, skinned=skinned)
    pieces = 0 if forest is None else forest.n_instances
    return Outcome({name: ctx.scratch / name}, {"tile": entry.to_json(), "pieces": pieces})


def run_render(ctx: JobContext) -> Outcome:
    """A render job: the scene -> ``preview.png`` + ``metrics.json`` (EGL; GPU or llvmpipe).
    An uploaded scene is untrusted: :func:`worker.jobs.scene_guard.check_scene_file` bounds it
    before the reader runs, and its bark comes from its own package or the shipped set its
    material names, never from a folder its paths name."""
    from worker.jobs.scene_guard import check_scene_file, package_tiles
    from worker.render.camera import CameraSpec
    from worker.render.instance_cull import DEFAULT_LOD_PIXELS
    from worker.render.metrics import write_metrics
    from worker.render.render_file import RenderRequest, render_file

    p = ctx.params
    # a forest job's scene, or the file uploaded with this job
    scene = ctx.artifacts.path(p.get("forest_job") or ctx.job_id, p["scene"])
    if scene is None:
        raise ForestError("the forest job's scene is gone from the artifact store", path="scene")
    ctx.report("check", 0.05)
    uploaded = p.get("forest_job") is None
    tiles = None
    if uploaded:
        checked = check_scene_file(scene, ctx.upload_caps)
        tiles = package_tiles(scene, checked, ctx.scratch / "package-tiles")
    if ctx.test_hook == "abort-on-read":  # tests: a reader that crashes (as pxr can)
        ctx.report("read", 0.1)
        os.abort()
    req = RenderRequest(
        scene=scene,
        output=ctx.scratch / "preview.png",
        metrics=ctx.scratch / "metrics.json",
        width=p["width"],
        height=p["height"],
        tess_max=p["tess_max"],
        frame=p["frame"],
        frames=p["frames"],
        staged=bool(p.get("staged", False)),
        lod_pixels=p.get("lod_pixels", DEFAULT_LOD_PIXELS),
        tiles=tiles,
        scene_tiles=not uploaded,
        camera=CameraSpec(
            view=p.get("view", "overview"),
            eye=p.get("eye"),
            target=p.get("target"),
            fov=p.get("fov", 40.0),
            distance=p.get("distance"),
            tree=p.get("tree"),
        ),
        clip=ctx.scratch / f"clip.{p['clip']}" if p.get("clip") else None,
        orbit=bool(p.get("orbit", False)),
    )

    def stage(name: str) -> None:
        ctx.report(name, {"read": 0.1, "render": 0.3}.get(name, 0.5))
        if name == "render" and ctx.test_hook.startswith("hold-gil:"):
            _hold_gil(float(ctx.test_hook.split(":", 1)[1]))

    def frames(name: str, done: int, total: int) -> None:
        if name == "frames":  # per frame, from 0.3 (scene read) up to 0.95
            ctx.report(f"render {done}/{total} frames", 0.3 + 0.65 * done / max(total, 1))

    metrics = render_file(req, on_stage=stage, progress=frames)
    # metrics.json names the scene by its artifact name and the bark by its set, never by a
    # server path
    metrics = metrics.model_copy(
        update={
            "scene": p["scene"],
            "textures": job_textures(metrics.textures, ctx.scratch),
            "warnings": [scrub_paths(w) for w in metrics.warnings],
        }
    )
    write_metrics(ctx.scratch / "metrics.json", metrics)
    result = {
        "renderer": metrics.renderer,
        "cpu_ms": metrics.median.cpu_ms,
        "gpu_ms": metrics.median.gpu_ms,
        "frame_cpu_ms": [f.cpu_ms for f in metrics.frames],
        "frames": len(metrics.frames),  # one for a still scene, whatever was asked (warnings)
        "primitives": metrics.median.primitives,
    }
    files = {"preview.png": req.output, "metrics.json": ctx.scratch / "metrics.json"}
    if metrics.warnings:
        result["warnings"] = metrics.warnings
    if req.clip is not None:
        files[req.clip.name] = req.clip
        result["clip"] = req.clip.name
    return Outcome(files, result)


def job_textures(source: str, scratch: Path) -> str:
    """Where a job's bark came from, for its metrics: a shipped set by name, the upload's own
    tiles, or the source with any server path cut to its last part."""
    from forest.bark.tilesets import DEFAULT_SET, set_dir

    shipped = set_dir(DEFAULT_SET).parent
    path = Path(source)
    if path.is_absolute() and under(shipped, path):
        name = path.resolve().relative_to(shipped.resolve()).parts[0]
        return f"shipped bark tile set {name!r}"
    if path.is_absolute() and under(scratch, path):
        return "the upload's own bark tiles"
    return scrub_paths(source)


def _hold_gil(seconds: float) -> None:
    """Tests: a C call that keeps the GIL (``sleep`` through ``PyDLL``), as a long GL draw does."""
    import ctypes

    ctypes.PyDLL(None).usleep(int(seconds * 1e6))


KINDS: dict[str, TaskKind] = {"forest": run_forest, "render": run_render, "forest_tile": run_tile}
TILE_POLL_S = 0.5  # how often a tiled forest job looks at its tiles


class Runtime:
    """Per-process store, artifact store and dispatcher, built from settings on first use."""

    def __init__(self, settings: FarmSettings) -> None:
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
    pause_s: float,
    test_hook: str,
    upload_caps: UploadCaps,
) -> tuple[dict[str, str], dict[str, Any]]:
    """The child's side of an attempt: run ``kind``; its files (names -> paths in the scratch
    folder) and result."""
    ctx = JobContext(
        job_id, params, scratch, ArtifactStore(artifacts_root), on_report=report,
        test_hook=test_hook, upload_caps=upload_caps,
    )
    if pause_s > 0:  # test hook: a window in which a test kills or cancels the job
        ctx.report("test-pause", 0.0)
        time.sleep(pause_s)
    ctx.report("started", 0.0)
    outcome = kind(ctx)
    return {name: str(path) for name, path in outcome.files.items()}, outcome.result


def execute(job_id: str, kinds: dict[str, TaskKind] | None = None) -> str:
    """Run one delivery of a job; answers what happened (for logs and tests)."""
    rt = runtime()
    s = rt.settings
    claim = rt.store.claim(job_id, OWNER, s.lease_s)
    if claim is None:
        return "skipped"  # finished, canceled, or leased by a live worker
    if claim.kind == "forest" and claim.params.get("tile_size"):
        return join_tiles(rt, claim)
    kind = (kinds or KINDS).get(claim.kind)
    if kind is None:
        error = f"kind: no worker code for job kind {claim.kind!r}"
        rt.store.finish(claim, "failed", error=error)
        return "failed"
    scratch = rt.artifacts.scratch(job_id)

    def heartbeat(progress: float, stage: str) -> bool | None:
        try:
            return rt.store.heartbeat(claim, s.lease_s, progress, stage)
        except Exception:  # the database is away: the lease may expire, the reaper decides
            log.exception("heartbeat of job %s failed", claim.job_id)
            return False

    pause = s.test_pause_s if claim.attempt == 1 else 0.0
    try:
        end = supervise(
            run_attempt,
            (
                kind, job_id, claim.params, scratch, rt.artifacts.root, pause, s.test_hook,
                upload_caps(s),
            ),
            job_limits(s.job_memory_mb, s.job_cpu_s),
            heartbeat,
            s.heartbeat_s,
        )
        if end.status == "ok":
            files = {n: Path(p) for n, p in (end.files or {}).items()}
            if not all(under(scratch, p) for p in files.values()):
                raise RuntimeError("a job's file lies outside its scratch folder")
            # a tile's file goes beside its forest's root layer
            owner = claim.params.get("parent", job_id) if claim.kind == "forest_tile" else job_id
            for name, path in files.items():
                rt.artifacts.publish(owner, path, name)
            done = rt.store.finish(
                claim, "completed", artifacts=sorted(files), result=end.result
            )
            return "completed" if done else "lost"
        if end.status == "canceled":
            rt.store.finish(claim, "canceled", error="canceled on request")
            return "canceled"
        if end.status == "lost":
            return "lost"
        if end.status in ("bad", "crash"):  # the input cannot work: retrying cannot help
            log.warning("job %s attempt %d failed: %s", job_id, claim.attempt, end.message)
            rt.store.finish(claim, "failed", error=end.message)
            return "failed"
        error = end.message
    except Exception as exc:  # the worker's own side (publish, store): retried
        log.exception("job %s attempt %d", job_id, claim.attempt)
        error = scrub_paths(f"{type(exc).__name__}: {exc}")
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    log.error("job %s attempt %d: %s", job_id, claim.attempt, error)
    if claim.attempt < claim.max_attempts:
        if rt.store.retry(claim, error):
            rt.dispatcher.send(job_id, claim.kind, countdown=s.retry_delay_s)
        return "retry"
    rt.store.finish(claim, "failed", error=error)
    return "failed"


def join_tiles(rt: Runtime, claim: Claim) -> str:
    """A tiled forest job's delivery: create its tile jobs and send them as one Celery group
    (first delivery), then look at them: all completed, write the root layer and complete; a
    tile failed (after its own retries) or canceled, end so; else record their mean progress
    and come back in :data:`TILE_POLL_S` (as Celery's chord_unlock polls a group)."""
    from forest.usd.tiled import TileEntry, write_root
    from schemas.jobs import ForestRequest

    job_id, params = claim.job_id, claim.params
    tiles = tile_job_ids(job_id, params)
    ids = [t for _, _, t in tiles]
    try:
        specs = [(t, {**params, "parent": job_id, "tile": [i, j]}) for i, j, t in tiles]
        new = rt.store.create_tiles(claim, specs)
        if new:
            rt.dispatcher.send_group(new, "forest_tile")
        states = rt.store.tile_states(ids)
        failed = [(k, st) for k, st in enumerate(states) if st.state == "failed"]
        if failed:
            k, st = failed[0]
            rt.store.cancel(job_id)  # the other tiles stop
            i, j, _ = tiles[k]
            rt.store.finish(claim, "failed", error=f"tile {i}_{j}: {st.error}")
            return "failed"
        if any(st.state == "canceled" for st in states):
            rt.store.finish(claim, "canceled", error="canceled on request")
            return "canceled"
        done = sum(st.state == "completed" for st in states)
        if done < len(states):
            progress = sum(1.0 if st.state == "completed" else st.progress for st in states)
            rt.store.park(claim, 0.95 * progress / len(states), f"tiles {done}/{len(states)}")
            rt.dispatcher.send(job_id, "forest", countdown=TILE_POLL_S)
            return "waiting"
        req = ForestRequest.model_validate(params)
        entries = [TileEntry.from_json((st.result or {})["tile"]) for st in states]
        name = f"scene.{req.format}"
        scratch = rt.artifacts.scratch(job_id)
        try:
            root = write_root(
                scratch / name, entries, frames=req.frames, fps=req.fps,
                meta={"trees": req.trees, "area": list(req.area), "tile_size": req.tile_size,
                      "seed": req.seed, "tiles": len(entries)},
            )  # fmt: skip
            rt.artifacts.publish(job_id, root, name)
        finally:
            shutil.rmtree(scratch, ignore_errors=True)
        result = {
            "trees": req.trees,
            "pieces": sum(int((st.result or {}).get("pieces", 0)) for st in states),
            "frames": req.frames,
            "scene": name,
            "tiles": len(states),
        }
        artifacts = sorted([name] + [tile_artifact(i, j) for i, j, _ in tiles])
        ok = rt.store.finish(claim, "completed", artifacts=artifacts, result=result)
        return "completed" if ok else "lost"
    except Exception as exc:  # the store or broker is away: back to the queue, retried
        log.exception("tiled forest job %s", job_id)
        error = scrub_paths(f"{type(exc).__name__}: {exc}")
        if claim.attempt < claim.max_attempts and rt.store.retry(claim, error):
            rt.dispatcher.send(job_id, claim.kind, countdown=rt.settings.retry_delay_s)
            return "retry"
        rt.store.finish(claim, "failed", error=error)
        return "failed"


app = make_celery(get_settings())
# acks_late and reject_on_worker_lost come from make_celery's configuration
run_job: Callable[..., Any] = app.task(name=TASK_NAME)(execute)
