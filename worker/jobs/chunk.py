"""The ``render_chunk`` job kind: some frames of a chunked render job, and that job's join
(:mod:`farm.chunks` makes the chunks and polls them): the frames back in order into
``preview.png``, ``metrics.json`` and the clip, the files one worker's render writes."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from worker.jobs.context import JobContext, Outcome

CHUNK_KEYS = ("parent", "chunk")  # a chunk's own params, beside its render job's request


def run_render_chunk(ctx: JobContext) -> Outcome:
    """One chunk (``params``: its render job's request, ``parent`` and ``chunk``
    ``[start, stop)``): those measured frames drawn as the whole render draws them, each
    written as ``frame_<k>.png`` into the render job's artifacts; the result carries their
    metrics (None where a still scene draws none of them), the clip's frame rate and the
    files."""
    from schemas.jobs import RenderJob
    from worker.jobs.render import public_metrics, render_request
    from worker.render.render_file import render_chunk

    parent = str(ctx.params["parent"])
    start, stop = (int(v) for v in ctx.params["chunk"])
    job = RenderJob.model_validate({k: v for k, v in ctx.params.items() if k not in CHUNK_KEYS})
    folder = ctx.scratch / "frames"
    folder.mkdir()
    req = render_request(ctx, job, parent, frame_range=(start, stop), frames_dir=folder)

    def frames(name: str, done: int, total: int) -> None:
        if name == "frames":  # the share of its frames drawn: its render job adds them up
            ctx.report(f"render {done}/{total} frames", 0.95 * done / max(total, 1))

    metrics, fps = render_chunk(req, progress=frames)
    files = {p.name: p for p in sorted(folder.glob("frame_*.png"))}
    shown = None if metrics is None else public_metrics(metrics, job, ctx.scratch)
    result: dict[str, Any] = {
        "frames": len(files),
        "fps": fps,
        "files": sorted(files),
        "metrics": None if shown is None else shown.model_dump(mode="json"),
    }
    return Outcome(files, result)


def assemble(
    job_id: str,
    params: dict[str, Any],
    chunks: list[tuple[dict[str, Any], dict[str, Any] | None]],
    scratch: Path,
) -> tuple[dict[str, Path], dict[str, Any]]:
    """A chunked render's join (:data:`farm.chunks.Assemble`): the chunks' frames (read from
    the render job's artifacts, in frame order) -> ``preview.png`` (frame 0), ``metrics.json``
    (every frame's figures, medians over all of them, the chunks' warnings once each) and the
    clip asked for; the render job's files and result, as one worker's render makes them."""
    import shutil

    import imageio.v3 as iio

    from farm.artifacts import ArtifactStore
    from farm.settings import get_settings
    from forest.errors import ForestError
    from schemas.jobs import RenderJob
    from schemas.metrics import RenderMetrics
    from worker.jobs.render import render_result
    from worker.render.clip import write_clip
    from worker.render.metrics import summarize, write_metrics

    artifacts = ArtifactStore(get_settings().artifacts)
    job = RenderJob.model_validate(params)
    parts = [RenderMetrics.model_validate(r["metrics"]) for _, r in chunks if r and r["metrics"]]
    names = [n for _, r in chunks for n in (r or {}).get("files", [])]
    if not parts or not names:
        raise ForestError("the render's chunks drew no frames", path="frames")
    frames = [f for m in parts for f in m.frames]
    warnings = list(dict.fromkeys(w for m in parts for w in m.warnings))
    metrics = parts[0].model_copy(
        update={"frames": frames, "median": summarize(frames), "warnings": warnings}
    )
    paths = []
    for name in names:
        path = artifacts.path(job_id, name)
        if path is None:
            raise RuntimeError(f"the chunk's frame {name} is gone from the artifact store")
        paths.append(path)
    files = {"preview.png": scratch / "preview.png", "metrics.json": scratch / "metrics.json"}
    shutil.copyfile(paths[0], files["preview.png"])
    write_metrics(files["metrics.json"], metrics)
    clip = f"clip.{job.clip}" if job.clip else None
    if clip is not None:
        fps = float(next(r["fps"] for _, r in chunks if r))
        pictures = [iio.imread(p)[..., :3] for p in paths]
        write_clip(scratch / clip, pictures, fps)
        files[clip] = scratch / clip
    result = render_result(metrics, clip)
    result["chunks"] = len(chunks)
    return files, result
