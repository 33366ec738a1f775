"""``forest render``: a scene file -> preview PNG (+ frame-time metrics JSON).

The camera frames the forest automatically, or as a :class:`worker.render.camera.CameraSpec` asks;
wind frames are played from the scene's time-sampled bone palette. Frame ``F`` is drawn once
unmeasured (shader compilation, first uploads), then ``N`` measured frames ``F, F+1, ...``
(wrapping around the palette's samples); the preview is the first measured frame. A still
scene (one pose) draws one frame however many are asked, unless the camera orbits, and says so.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from forest.atomic import all_replaced_when_written
from forest.bark.images import write_png
from forest.bark.tile_folder import shipped_tile_folder
from forest.errors import ForestError, OutputError
from forest.gl.context import create_context, raise_gl_error
from forest.usd.read import SceneArrays, read_scene
from schemas.metrics import RenderMetrics
from worker.render.camera import Camera, CameraSpec, place_camera
from worker.render.clip import DEFAULT_FPS, ORBIT_FRAMES, check_clip, orbit_camera_eyes, write_clip
from worker.render.foliage import FOLIAGE_MODES, IMPOSTOR_SIZE, FoliageMode, foliage_points
from worker.render.instance_cull import DEFAULT_LOD_PIXELS
from worker.render.metrics import render_metrics, write_metrics
from worker.render.renderer import Renderer, TessSettings, auto_lod
from worker.render.scene_buffers import check_scene, scene_points
from worker.render.staging import STAGED, Staging
from worker.render.stand import (
    StandScene,
    is_stand_file,
    is_tiled_file,
    load_stand,
    load_tiled,
    stand_view,
)
from worker.render.textures import tile_images

MAX_SIZE = 8192
MAX_TESS = 64.0  # GL_MAX_TESS_GEN_LEVEL is at least 64 on every GL 4 driver
MAX_FRAMES = 10_000
MAX_LOD_PIXELS = 64.0
Progress = Callable[[str, int, int], None]  # (stage, done, total), as forest.growth.generate's


@dataclass(frozen=True)
class RenderRequest:
    scene: Path
    output: Path
    metrics: Path | None = None
    width: int = 640
    height: int = 480
    tess_max: float = 8.0
    alpha: float = 0.75
    lod_half: float | None = None  # metres; None: a quarter of the forest's diagonal
    frame: int = 0
    frames: int = 1
    warmup: int = 1
    tiles: Path | None = None
    scene_tiles: bool = True
    """Read the bark tiles from the folder the scene's material names. False for an uploaded
    scene, whose paths point into the server: the shipped set its material names instead
    (or ``tiles``, the tiles its package carries)."""
    per_instance: bool = False
    cull: bool = True
    # pieces thinner on screen than this many pixels are skipped (worker.render.instance_cull); 0:
    # whole instances out of view only; None (or cull False, or per_instance): no cull pass
    lod_pixels: float | None = DEFAULT_LOD_PIXELS
    foliage: FoliageMode | None = "impostor"  # None: no foliage
    impostor_size: int = IMPOSTOR_SIZE
    camera: CameraSpec = field(default_factory=CameraSpec)
    ground: bool = False  # a ground under the trees and a sky gradient (worker.render.staging)
    # ground, sky, sun shadows, MSAA, tone map (worker.render.staging.STAGED); the library's
    # default is the bare measurement set-up, `forest render` and render jobs ask for staged
    staged: bool = False
    clip: Path | None = None  # .mp4/.webm/.gif/.webp of the measured frames (worker.render.clip)
    orbit: bool = False  # the camera turns once about the target over the frames
    fps: float | None = None  # the clip's rate; None: the scene's (else 24)
    # a chunk of the run (a render job's frame chunk, farm.chunks): only the measured frames k
    # in [start, stop) of the whole run are drawn, each as the whole run draws it (its palette
    # sample, its orbit camera, after the same warm-up), and written as frame_<k>.png into
    # frames_dir; no preview, metrics file or clip (the join assembles them)
    frame_range: tuple[int, int] | None = None
    frames_dir: Path | None = None

    def check(self) -> None:
        self.camera.check()
        for name, value in (("width", self.width), ("height", self.height)):
            if not 1 <= value <= MAX_SIZE:
                raise ForestError(f"must be in [1, {MAX_SIZE}], got {value}", path=name)
        if not 1.0 <= self.tess_max <= MAX_TESS:
            raise ForestError(f"must be in [1, {MAX_TESS:g}], got {self.tess_max}", path="tess_max")
        if not 0.0 <= self.alpha <= 1.0:
            raise ForestError(f"must be in [0, 1], got {self.alpha}", path="alpha")
        if self.lod_half is not None and not (self.lod_half >= 0 and np.isfinite(self.lod_half)):
            raise ForestError(f"must be >= 0 metres, got {self.lod_half}", path="lod_half")
        if self.lod_pixels is not None and not (
            np.isfinite(self.lod_pixels) and 0 <= self.lod_pixels <= MAX_LOD_PIXELS
        ):
            raise ForestError(
                f"must be in [0, {MAX_LOD_PIXELS:g}] pixels, got {self.lod_pixels}",
                path="lod_pixels",
            )
        if self.frame < 0:
            raise ForestError(f"must be >= 0, got {self.frame}", path="frame")
        if not 1 <= self.frames <= MAX_FRAMES:
            raise ForestError(f"must be in [1, {MAX_FRAMES}], got {self.frames}", path="frames")
        if not 0 <= self.warmup <= 100:
            raise ForestError(f"must be in [0, 100], got {self.warmup}", path="warmup")
        for path in (self.output, self.metrics):
            if path is not None and not path.parent.resolve().is_dir():
                raise OutputError("folder does not exist", path=str(path))
        if self.foliage is not None and self.foliage not in FOLIAGE_MODES:
            raise ForestError(
                f"must be one of {', '.join(FOLIAGE_MODES)}, got {self.foliage!r}", path="foliage"
            )
        if not 8 <= self.impostor_size <= 4096:
            raise ForestError(
                f"must be in [8, 4096], got {self.impostor_size}", path="impostor_size"
            )
        if self.fps is not None and not (np.isfinite(self.fps) and 0 < self.fps <= 120):
            # refused with or without a clip: an option that is given is checked
            raise ForestError(f"must be in (0, 120], got {self.fps}", path="fps")
        if self.frame_range is not None:
            start, stop = self.frame_range
            if not 0 <= start < stop <= self.frames:
                raise ForestError(
                    f"must lie in [0, {self.frames}], got {start}..{stop}", path="frame_range"
                )
            if self.frames_dir is None or not self.frames_dir.is_dir():
                raise OutputError("folder does not exist", path=str(self.frames_dir))
        if self.output.suffix.lower() != ".png":
            raise OutputError("the preview is a PNG: name it *.png", path=str(self.output))
        if self.clip is not None:
            if not self.clip.parent.resolve().is_dir():
                raise OutputError("folder does not exist", path=str(self.clip))
            fps = DEFAULT_FPS if self.fps is None else self.fps
            check_clip(self.clip, (self.width, self.height), fps)
        elif self.orbit:
            raise ForestError("an orbit is a clip: give --clip too", path="orbit")


def preview_view(
    scene: SceneArrays,
    size: tuple[int, int],
    tess_max: float,
    frame: int = 0,
    alpha: float = 0.75,
    lod_half: float | None = None,
    foliage: bool = True,
    spec: CameraSpec | None = None,
    ground: bool = False,
) -> tuple[Camera, TessSettings]:
    """The camera ``spec`` asks for (default: the automatic overview) around the forest at
    ``frame`` (its leaf clouds too, with ``foliage``; far enough for the ground with
    ``ground``) and its level-of-detail settings."""
    tree = spec.tree if spec is not None else None
    n_trees = int(scene.tree.max()) + 1 if len(scene.tree) else 0
    if tree is not None and not 0 <= tree < n_trees:
        raise ForestError(f"the scene has {n_trees} tree(s), numbered from 0", path="tree")
    points = scene_points(scene, frame, tree)
    if foliage and scene.n_foliage:
        points = np.concatenate([points, foliage_points(scene, frame, tree)])
    lo, hi = points.min(axis=0), points.max(axis=0)
    camera = place_camera(spec or CameraSpec(), points, size[0] / size[1], ground)
    tess = auto_lod(camera, lo, hi, tess_max, alpha)
    if lod_half is not None:
        tess = TessSettings(tess_max, alpha, tess.lod_near, lod_half)
    return camera, tess


# what a malformed (or hostile) file makes the USD reader raise besides SceneError
READ_ERRORS = (RuntimeError, TypeError, ValueError, KeyError, IndexError, UnicodeDecodeError)


def load_scene(path: Path) -> SceneArrays:
    """:func:`read_scene`, with the reader's own errors on a malformed file (pxr's
    ``Tf.ErrorException`` is a RuntimeError) as a :class:`ForestError` naming ``scene``."""
    try:
        return read_scene(path)
    except ForestError:
        raise
    except READ_ERRORS as exc:
        lines = str(exc).strip().splitlines()
        why = f"{type(exc).__name__}: {lines[-1][:200]}" if lines else type(exc).__name__
        raise ForestError(f"the scene could not be read ({why})", path="scene") from None


def bark_warnings(req: RenderRequest, scene: SceneArrays) -> list[str]:
    """A scene whose material names a tile folder that is not there (a scene moved without
    its tiles) or is not read (an upload's) renders other bark: say so, naming the folder
    only where the scene is the caller's own file."""
    folder = scene.tile_folder
    if req.tiles is not None or folder is None or (req.scene_tiles and folder.is_dir()):
        return []
    shipped = shipped_tile_folder(scene.manifest, scene.bark_tile_set)
    instead = "placeholder bark" if shipped is None else f"shipped {scene.bark_tile_set} bark"
    if not req.scene_tiles:
        return [f"the upload carries no bark tiles its material names: {instead}"]
    return [f"bark tiles not found: {folder}: {instead}"]


def stand_warnings(req: RenderRequest, stand: StandScene) -> list[str]:
    """:func:`bark_warnings` of every layer, naming it (once per layer)."""
    out: list[str] = []
    for name, scene in zip(stand.names, stand.scenes, strict=True):
        layer = name.partition("[")[0]
        for w in bark_warnings(req, scene):
            if f"layer {layer}: {w}" not in out:
                out.append(f"layer {layer}: {w}")
    return out


def scene_fps(scene: SceneArrays) -> float:
    """The rate the scene's wind was sampled at (its clip loops at it), else DEFAULT_FPS."""
    fps = scene.options.get("fps")
    return float(fps) if isinstance(fps, int | float) and 0 < fps <= 120 else DEFAULT_FPS


def frames_to_draw(req: RenderRequest, scene: SceneArrays) -> tuple[int, str | None]:
    """The frames to draw and measure, and a note when that is fewer than asked. A clip
    without ``frames`` is the whole wind loop (an orbit of a still scene: ORBIT_FRAMES); a
    scene with one pose draws one frame, as every further one would be the same picture,
    unless the camera orbits."""
    n_frames = scene.n_frames
    if req.clip is not None and req.frames == 1:
        return (n_frames if n_frames > 1 else ORBIT_FRAMES if req.orbit else 1), None
    if n_frames == 1 and req.frames > 1 and not req.orbit:
        still = "is still (no wind frames)" if scene.times[0] is None else "has one wind frame"
        return 1, f"the scene {still}: rendering 1 frame instead of {req.frames}"
    return req.frames, None


def frame_png(k: int) -> str:
    """The file of measured frame ``k`` of a chunked render (:attr:`RenderRequest.frames_dir`)."""
    return f"frame_{k:05d}.png"


def render_file(
    req: RenderRequest,
    on_stage: Callable[[str], None] | None = None,
    progress: Progress | None = None,
) -> RenderMetrics:
    """Render ``req``; ``on_stage`` hears ``read`` before the scene is read and ``render``
    after (a supervisor tells a reader crash from a renderer crash by it). ``progress`` hears
    ``(stage, done, total)`` as frames are drawn (a staged frame on a CPU rasteriser takes
    seconds): ``warm-up`` and ``frames``, then ``write`` (the files, with the clip's
    encoding)."""
    if req.frame_range is not None:
        raise ForestError("a chunk of a render is render_chunk's", path="frame_range")
    metrics, _ = _render(req, on_stage, progress)
    assert metrics is not None
    return metrics


def render_chunk(
    req: RenderRequest,
    on_stage: Callable[[str], None] | None = None,
    progress: Progress | None = None,
) -> tuple[RenderMetrics | None, float]:
    """Draw the frames ``req.frame_range`` names of the whole run ``req`` describes, each
    written as :func:`frame_png` into ``req.frames_dir`` (pixel for pixel what the whole run
    draws: a frame depends on its index only); their metrics (None when the scene draws none
    of them: a still scene draws one frame) and the clip's frame rate."""
    if req.frame_range is None or req.frames_dir is None:
        raise ForestError("a chunk needs its frame range and frames folder", path="frame_range")
    return _render(req, on_stage, progress)


def _render(
    req: RenderRequest,
    on_stage: Callable[[str], None] | None,
    progress: Progress | None,
) -> tuple[RenderMetrics | None, float]:
    note = progress or (lambda stage, done, total: None)
    req.check()
    if on_stage is not None:
        on_stage("read")
    # a mixed forest's root layer: every layer's scene and the terrain; a tiled forest's
    # root: every tile's scene on level ground (worker.render.stand)
    stand = None
    if is_stand_file(req.scene):
        stand = load_stand(req.scene, load_scene)
    elif is_tiled_file(req.scene):
        stand = load_tiled(req.scene, load_scene)
    if stand is not None and req.tiles is not None:
        raise ForestError(
            "a mixed forest's layers each use their own bark tiles: leave the tile folder out",
            path="tiles",
        )
    scene = load_scene(req.scene) if stand is None else stand.scenes[0]
    scenes = (scene,) if stand is None else stand.scenes
    if on_stage is not None:
        on_stage("render")
    n_frames = scene.n_frames if stand is None else stand.n_frames
    if req.frame >= n_frames:
        raise ForestError(
            f"the scene has {n_frames} palette sample(s): frame must be below {n_frames}",
            path="frame",
        )
    for s in scenes:
        check_scene(s, s.manifest.n_slices)  # before any GL or texture work
    ctx = create_context()
    try:
        images = [
            tile_images(
                s.manifest,
                req.tiles,
                s.tile_folder if req.scene_tiles else None,
                bark=s.bark_tile_set,
            )
            for s in scenes
        ]
        n_draw, fewer = frames_to_draw(req, scene)
        warnings = bark_warnings(req, scene) if stand is None else stand_warnings(req, stand)
        warnings += [] if fewer is None else [fewer]
        for w in warnings:
            print(f"warning: {w}", file=sys.stderr)
        staging = STAGED if req.staged else Staging() if req.ground else None
        if stand is not None and staging is None:  # the bare mode: the terrain alone
            staging = Staging(ground=False, sky=False)
        renderer = Renderer(
            ctx,
            scene,
            (req.width, req.height),
            images[0],
            foliage=req.foliage,
            impostor_size=req.impostor_size,
            staging=staging,
            terrain=None if stand is None else stand.terrain,
        )
        for s, im in zip(scenes[1:], images[1:], strict=True):
            renderer.add_layer(s, im)
        size = (req.width, req.height)
        framing: dict[str, Any] = {
            "foliage": req.foliage is not None,
            "spec": req.camera,
            "ground": req.ground or req.staged,
        }
        detail = (req.tess_max, req.frame, req.alpha, req.lod_half)
        camera, tess = (
            preview_view(scene, size, *detail, **framing)
            if stand is None
            else stand_view(stand, size, *detail, **framing)
        )
        cameras = [camera] * n_draw
        if req.orbit:
            cameras = [
                Camera(eye, camera.target, camera.fov_y, camera.aspect, camera.near, camera.far)
                for eye in orbit_camera_eyes(camera.eye, camera.target, n_draw)
            ]
        lod = req.lod_pixels  # Renderer.draw leaves it out where the cull pass cannot run
        for i in range(req.warmup):
            note("warm-up", i, req.warmup)
            renderer.draw(camera, tess, req.frame, req.per_instance, cull=req.cull, lod_pixels=lod)
            note("warm-up", i + 1, req.warmup)
        stats = []
        clip_frames = []
        chunk = req.frame_range
        # a chunk of a scene that draws fewer frames than asked (a still one) may draw none
        ks = range(n_draw) if chunk is None else range(chunk[0], min(chunk[1], n_draw))
        note("frames", 0, len(ks))
        for done, k in enumerate(ks):
            stats.append(
                renderer.draw(
                    cameras[k], tess, req.frame + k, req.per_instance, cull=req.cull, lod_pixels=lod
                )
            )
            if chunk is not None:
                assert req.frames_dir is not None
                write_png(req.frames_dir / frame_png(k), renderer.read_color())
            elif k == 0:
                preview = renderer.read_color()
            if req.clip is not None and chunk is None:
                clip_frames.append(renderer.read_color()[..., :3])
            note("frames", done + 1, len(ks))
        raise_gl_error(ctx, "rendering")
        if not stats:  # a chunk past the frames a still scene draws
            renderer.release()
            return None, req.fps if req.fps is not None else scene_fps(scene)
        metrics = render_metrics(
            renderer,
            stats,
            tess,
            per_instance=req.per_instance,
            cull=req.cull,
            warmup_frames=req.warmup,
            lod_pixels=lod if stats and stats[0].drawn_instances is not None else None,
        ).model_copy(update={"warnings": warnings})
        if stand is not None:
            metrics = metrics.model_copy(update={"scene": str(stand.path)})
        fps = req.fps if req.fps is not None else scene_fps(scene)
        if chunk is not None:  # its frames are written; the join writes the rest
            renderer.release()
            return metrics, fps
        # the preview, its figures and the clip are replaced together or, on a failure, none
        outputs = [req.output] if req.metrics is None else [req.output, req.metrics]
        if req.clip is not None:
            outputs.append(req.clip)
        note("write", 0, 1)
        with all_replaced_when_written(outputs) as tmps:
            write_png(tmps[0], preview)
            if req.metrics is not None:
                write_metrics(tmps[1], metrics)
            if req.clip is not None:
                write_clip(tmps[-1], clip_frames, fps)
        note("write", 1, 1)
        renderer.release()
        return metrics, fps
    finally:
        ctx.release()
