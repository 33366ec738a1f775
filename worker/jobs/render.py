"""The ``render`` job kind: a forest job's scene, or an uploaded one, to ``preview.png`` and
``metrics.json`` (and a clip when asked)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from forest.errors import ForestError
from worker.jobs.context import JobContext, Outcome
from worker.jobs.supervise import scrub_paths, under

if TYPE_CHECKING:
    from schemas.jobs import RenderJob
    from schemas.metrics import RenderMetrics
    from worker.render.render_file import RenderRequest


def run_render(ctx: JobContext) -> Outcome:
    """A render job (``params``: :class:`schemas.jobs.RenderJob`): the scene ->
    ``preview.png`` + ``metrics.json`` (EGL; GPU or llvmpipe). An uploaded scene is
    untrusted: :func:`worker.jobs.scene_guard.check_scene_file` bounds it before the reader
    runs, and its bark comes from its own package or the shipped set its material names, never
    from a folder its paths name."""
    from schemas.jobs import RenderJob
    from worker.render.metrics import write_metrics
    from worker.render.render_file import render_file

    job = RenderJob.model_validate(ctx.params)
    req = render_request(ctx, job, ctx.job_id)

    def stage(name: str) -> None:
        ctx.report(name, {"read": 0.1, "render": 0.3}.get(name, 0.5))

    def frames(name: str, done: int, total: int) -> None:
        if name == "frames":  # per frame, from 0.3 (scene read) up to 0.95
            ctx.report(f"render {done}/{total} frames", 0.3 + 0.65 * done / max(total, 1))

    metrics = public_metrics(render_file(req, on_stage=stage, progress=frames), job, ctx.scratch)
    write_metrics(ctx.scratch / "metrics.json", metrics)
    files = {"preview.png": req.output, "metrics.json": ctx.scratch / "metrics.json"}
    if req.clip is not None:
        files[req.clip.name] = req.clip
    result = render_result(metrics, None if req.clip is None else req.clip.name)
    return Outcome(files, result)


def public_metrics(metrics: RenderMetrics, job: RenderJob, scratch: Path) -> RenderMetrics:
    """``metrics`` as a job shows them: the scene by its artifact name and the bark by its
    set, never by a server path."""
    return metrics.model_copy(
        update={
            "scene": job.scene,
            "textures": f"the bark tile set of job {job.tiles}"
            if job.tiles is not None
            else job_textures(metrics.textures, scratch),
            "warnings": [scrub_paths(w) for w in metrics.warnings],
        }
    )


def render_result(metrics: RenderMetrics, clip: str | None) -> dict[str, Any]:
    """A render job's result from its metrics (and its clip's name)."""
    result: dict[str, Any] = {
        "renderer": metrics.renderer,
        "cpu_ms": metrics.median.cpu_ms,
        "gpu_ms": metrics.median.gpu_ms,
        "frame_cpu_ms": [f.cpu_ms for f in metrics.frames],
        "frames": len(metrics.frames),  # one for a still scene, whatever was asked (warnings)
        "primitives": metrics.median.primitives,
    }
    if metrics.warnings:
        result["warnings"] = metrics.warnings
    if clip is not None:
        result["clip"] = clip
    return result


def render_request(ctx: JobContext, job: RenderJob, job_id: str, **extra: Any) -> RenderRequest:
    """The renderer's request of render job ``job_id`` (``job``, its params): its scene (a
    forest job's, or the file uploaded with it, checked first), outputs in the scratch
    folder; ``extra`` fields of :class:`RenderRequest` (a chunk's frame range)."""
    from worker.jobs.scene_guard import check_scene_file, package_tiles
    from worker.jobs.tileset import fetch_tileset
    from worker.render.camera import CameraSpec
    from worker.render.render_file import RenderRequest

    # a forest job's scene, or the file uploaded with this job
    uploaded = job.forest_job is None
    scene = ctx.artifacts.path(job.forest_job or job_id, job.scene)
    if scene is None:
        raise ForestError("the forest job's scene is gone from the artifact store", path="scene")
    ctx.report("check", 0.05)
    tiles = None
    if uploaded:
        checked = check_scene_file(scene, ctx.upload_caps)
        tiles = package_tiles(scene, checked, ctx.scratch / "package-tiles")
    if job.tiles is not None:  # a tile set of the caller's (POST /v1/tilesets)
        tiles = fetch_tileset(ctx, job.tiles)
    return RenderRequest(
        scene=scene,
        output=ctx.scratch / "preview.png",
        metrics=ctx.scratch / "metrics.json",
        width=job.width,
        height=job.height,
        tess_max=job.tess_max,
        frame=job.frame,
        frames=job.frames,
        staged=job.staged,
        lod_pixels=job.lod_pixels,
        tiles=tiles,
        scene_tiles=not uploaded,
        camera=CameraSpec(
            view=job.view,
            eye=job.eye,
            target=job.target,
            fov=job.fov,
            distance=job.distance,
            tree=job.tree,
        ),
        clip=ctx.scratch / f"clip.{job.clip}" if job.clip else None,
        orbit=job.orbit,
        **extra,
    )


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
