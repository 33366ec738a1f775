"""Frame statistics -> the wire model :class:`schemas.metrics.RenderMetrics`, and its JSON."""

from __future__ import annotations

import statistics
from collections.abc import Sequence
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


def summarize(frames: Sequence[FrameStats] | Sequence[FrameMetrics]) -> MetricsSummary:
    """Medians over the frames (as drawn, or as a chunk's metrics list them); ``gpu_ms`` only
    where every frame has it."""
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
    """The run's figures; a mixed forest's (a renderer with ``layers``) add up over its layers:
    piece types, instances, quads and bones of every layer, the bark sources joined."""
    scene = renderer.scene
    members = (renderer, *renderer.layers)
    quads = sum(int(np.asarray(m.buffers.n_quads)[m.scene.proto_indices].sum()) for m in members)
    sources = list(dict.fromkeys(m.images.source for m in members))
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
        piece_types=sum(len(m.scene.pieces) for m in members),
        instances=sum(m.scene.n_instances for m in members),
        quads=quads,
        bones=sum(m.scene.n_bones for m in members),
        textures="; ".join(sources),
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
    """The foliage's settings; over a mixed forest's layers, clouds, cards of the models and
    pass-1 runs add up."""
    every = [m.foliage for m in (renderer, *renderer.layers) if m.foliage is not None]
    if not every:
        return None
    f = every[0]
    return FoliageSettings(
        mode=f.mode,
        clouds=sum(g.scene.n_foliage for g in every),
        leaf_cards=sum(g.cloud.n_cards for g in every),
        impostor_size=f.impostor_size if f.mode == "impostor" else None,
        impostor_renders=sum(g.impostor_renders for g in every),
    )


def write_metrics(path: Path, metrics: RenderMetrics) -> Path:
    """Write ``metrics`` as indented JSON, whole (:func:`forest.atomic.write_text`)."""
    return write_text(path, metrics.model_dump_json(indent=2) + "\n")
