"""Frame-time metrics of a render (``forest render --metrics``, the render worker's result)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from schemas.base import StrictModel

NonNegative = Annotated[float, Field(ge=0)]
Count = Annotated[int, Field(ge=0)]


class TessellationSettings(StrictModel):
    """Level of detail (paper 4.4): ``level(d) = clamp(max_level * 2^(-max(d - lod_near, 0)
    / lod_half), 1, max_level)`` for the camera distance ``d`` of an edge midpoint (outer
    levels) or the quad centre (inner levels)."""

    max_level: Annotated[float, Field(ge=1, le=64)]
    alpha: Annotated[float, Field(ge=0, le=1)]
    """Phong shape factor: 0 bilinear quads, 1 full projection onto the tangent planes."""
    lod_near: NonNegative
    """Metres from the camera within which every edge gets ``max_level``."""
    lod_half: NonNegative
    """Metres over which the level halves; 0 means no falloff (every edge at max_level)."""
    spacing: Literal["fractional_odd"] = "fractional_odd"


class FoliagePassMetrics(StrictModel):
    draw_calls: Count
    primitives: Count
    """GL_PRIMITIVES_GENERATED of the pass (triangles)."""


class FoliageFrameMetrics(StrictModel):
    """The foliage passes of one frame (paper 6), also counted in the frame's totals."""

    impostor_rendered: bool
    """Whether pass 1 ran this frame: it reruns only when the view direction changed."""
    impostor: FoliagePassMetrics
    """Pass 1: the leaf-cloud model into the off-screen colour + distance target (zeros when
    the picture was reused, and in geometry mode)."""
    billboards: FoliagePassMetrics
    """Pass 2: every camera-facing billboard in one instanced draw; in geometry mode the
    real leaf-cloud mesh at every cloud, also in one instanced draw."""


class FoliageSettings(StrictModel):
    mode: Literal["impostor", "geometry"]
    """2.5D impostors (two passes) or the real leaf-cloud mesh instanced (for comparison)."""
    clouds: Count
    """Leaf clouds (foliage instances) drawn per frame."""
    leaf_cards: Count
    """Cards in the leaf-cloud model (two triangles each)."""
    impostor_size: Annotated[int, Field(ge=1)] | None
    """Side in pixels of the pass-1 target (null in geometry mode)."""
    impostor_renders: Count
    """Times pass 1 ran in the whole run, warm-up frames included."""


class FrameMetrics(StrictModel):
    frame: Count
    """Index into the scene's time-sampled bone palette."""
    time: Annotated[float | None, Field(ge=0)]
    """Seconds of that palette sample; null for a still scene."""
    cpu_ms: NonNegative
    """Wall time from the palette upload to a finished frame (after glFinish)."""
    gpu_ms: NonNegative | None
    """GL_TIME_ELAPSED of the draw calls; null where the driver has no timer queries. On a
    CPU rasteriser (llvmpipe) the timer brackets command submission only: there the
    rasterisation shows in ``cpu_ms`` (which waits for it with glFinish)."""
    primitives: Count
    """GL_PRIMITIVES_GENERATED: triangles out of the tessellator, plus the foliage passes'."""
    draw_calls: Count
    """Every draw call of the frame, foliage passes included."""
    instances: Count
    drawn_instances: Count | None = None
    """Instances the cull pass kept for the view (in it and, with ``lod_pixels``, at
    least that thick on screen); null when no cull pass ran."""
    foliage: FoliageFrameMetrics | None = None
    """The foliage passes alone; null when no foliage was drawn."""


class MetricsSummary(StrictModel):
    cpu_ms: NonNegative
    gpu_ms: NonNegative | None
    primitives: NonNegative
    fps: NonNegative
    """1000 / median cpu_ms."""


class RenderMetrics(StrictModel):
    scene: str
    renderer: str
    """GL_RENDERER, e.g. an NVIDIA board or llvmpipe (CPU rasteriser)."""
    gl_version: str
    width: Annotated[int, Field(ge=1)]
    height: Annotated[int, Field(ge=1)]
    mode: Literal["instanced", "per_instance"]
    """One draw call per piece type (instanced) or one per piece instance (the naive way)."""
    frustum_culling: bool
    """Whether patches wholly outside the view were dropped before tessellation."""
    lod_pixels: NonNegative | None = None
    """Pieces thinner on screen than this were not drawn (whole instances out of view were
    dropped first); null: every instance went through the pipeline."""
    piece_types: Count
    instances: Count
    quads: Count
    """Patches drawn per frame (every instance's quads)."""
    bones: Count
    textures: str
    """Where the bark slices came from (a tile-set file or the procedural placeholder)."""
    tessellation: TessellationSettings
    warmup_frames: Count
    """Frames drawn before the measured ones (shader compilation, first uploads)."""
    foliage: FoliageSettings | None = None
    """Null when no foliage was drawn (``--no-foliage``, or a scene without foliage)."""
    frames: Annotated[list[FrameMetrics], Field(min_length=1)]
    median: MetricsSummary
    warnings: list[str] = []
    """What the render fell back on (e.g. bark tiles not found: placeholder bark; one frame
    of a still scene where more were asked)."""
