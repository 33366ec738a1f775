"""Frame statistics -> the wire model :class:`schemas.metrics.RenderMetrics`, and its JSON."""

from __future__ import annotations

import statistics
from pathlib import Path

import numpy as np

from forest.atomic import write_text
from schemas.metrics import (
    FoliageFrameMetrics,
    FoliagePassMetrics,
    FoliageSettings,
    FrameMetrics,
    MetricsSummary,
    RenderMetrics,
)
from worker.render.foliage import FoliageStats
from worker.render.renderer import FrameStats, Renderer, TessSettings


def summarize(frames: list[FrameStats]) -> MetricsSummary:
    """Medians over the frames; ``gpu_ms`` only where every frame has it."""
    cpu = statistics.median(f.cpu_ms for f in frames)
    gpu_values = [f.gpu_ms for f in frames if f.gpu_ms is not None]
    gpu = statistics.median(gpu_values) if len(gpu_values) == len(frames) else None
    return MetricsSummary(
        cpu_ms=cpu,
        gpu_ms=gpu,
        primitives=statistics.median(f.primitives for f in frames),
        fps=1e3 / cpu if cpu > 0 else 0.0,
    )


def render_metrics(
    renderer: Renderer,
    frames: list[FrameStats],
    tess: TessSettings,
    *,
    per_instance: bool = False,
    cull: bool = True,
    warmup_frames: int = 0,
    lod_pixels: float | None = None,
) -> RenderMetrics:
    scene = renderer.scene
    n_quads = renderer.buffers.n_quads
    times = scene.times
    return RenderMetrics(
        scene=scene.path,
        renderer=renderer.info.renderer,
        gl_version=renderer.info.version,
        width=renderer.size[0],
        height=renderer.size[1],
        mode="per_instance" if per_instance else "instanced",
        frustum_culling=cull,
        lod_pixels=lod_pixels,
        piece_types=len(scene.pieces),
        instances=scene.n_instances,
        quads=int(np.asarray(n_quads)[scene.proto_indices].sum()),
        bones=scene.n_bones,
        textures=renderer.images.source,
        tessellation=tess.schema(),
        warmup_frames=warmup_frames,
        foliage=_foliage_settings(renderer),
        frames=[
            FrameMetrics(
                frame=f.frame,
                time=times[f.frame],
                cpu_ms=f.cpu_ms,
                gpu_ms=f.gpu_ms,
                primitives=f.primitives,
                draw_calls=f.draw_calls,
                instances=f.instances,
                drawn_instances=f.drawn_instances,
                foliage=_foliage_frame(f.foliage),
            )
            for f in frames
        ],
        median=summarize(frames),
    )


def _foliage_frame(stats: FoliageStats | None) -> FoliageFrameMetrics | None:
    if stats is None:
        return None
    return FoliageFrameMetrics(
        impostor_rendered=stats.impostor_rendered,
        impostor=FoliagePassMetrics(
            draw_calls=stats.impostor.draw_calls, primitives=stats.impostor.primitives
        ),
        billboards=FoliagePassMetrics(
            draw_calls=stats.billboards.draw_calls, primitives=stats.billboards.primitives
        ),
    )


def _foliage_settings(renderer: Renderer) -> FoliageSettings | None:
    f = renderer.foliage
    if f is None:
        return None
    return FoliageSettings(
        mode=f.mode,
        clouds=f.scene.n_foliage,
        leaf_cards=f.cloud.n_cards,
        impostor_size=f.impostor_size if f.mode == "impostor" else None,
        impostor_renders=f.impostor_renders,
    )


def write_metrics(path: Path, metrics: RenderMetrics) -> Path:
    """Write ``metrics`` as indented JSON, whole (:func:`forest.atomic.write_text`)."""
    return write_text(path, metrics.model_dump_json(indent=2) + "\n")
