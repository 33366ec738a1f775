"""The forest renderer: one instanced draw call of quad patches per piece type, skinned in the
vertex shader, Phong-tessellated with distance-based levels, bark from a texture array by
per-instance, per-quad tile indices (paper 4.3, 4.4, 5.1). Offscreen, on any GL 4.3 context.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from numpy.typing import NDArray

from forest.bark.tile_folder import TileImages
from forest.gl import shaders
from forest.gl.context import elapsed_ms, gl_info
from forest.usd.read import SceneArrays
from schemas.metrics import TessellationSettings
from worker.render.camera import GROUND_SPAN, Camera
from worker.render.foliage import (
    IMPOSTOR_SIZE,
    FoliageMode,
    FoliageRenderer,
    FoliageStats,
    PassStats,
)
from worker.render.instance_cull import InstanceCuller, pixel_size
from worker.render.scene_buffers import PATCH_ATTRIBUTES, PATCH_FORMAT, SceneBuffers, scene_points
from worker.render.staging import StageRenderer, Staging, SunCamera, TerrainMesh, sun_camera
from worker.render.textures import tile_images, upload

if TYPE_CHECKING:
    import moderngl

PROGRAM = "piece"
SUN = np.array([0.45, 0.8, 0.35]) / np.linalg.norm([0.45, 0.8, 0.35])
SKY = np.array([0.52, 0.66, 0.85])  # linear
# fog density as a fraction of the inverse camera-target distance: the target is ~11% hazed
FOG_AT_TARGET = 0.12
CAPTURE_DTYPE = np.dtype(
    [
        ("position", "<f4", 4),
        ("normal", "<f4", 4),
        ("coord", "<f4", 4),  # tess coord u, v, inner levels
        ("outer", "<f4", 4),
        ("ids", "<i4", 4),  # instance id, quad, tile, 0
    ]
)
CAPTURE_HEADER = 16  # count, capacity, two pads (uint)


def fog_density(camera: Camera) -> float:
    """Fog density for ``camera``: ``FOG_AT_TARGET`` over the camera-target distance."""
    return FOG_AT_TARGET / max(float(np.linalg.norm(camera.target - camera.eye)), 1e-6)


def _uniform(prog: moderngl.Program, name: str) -> moderngl.Uniform:
    return cast("moderngl.Uniform", prog[name])


@dataclass(frozen=True)
class TessSettings:
    """See :class:`schemas.metrics.TessellationSettings` for the level formula."""

    max_level: float = 8.0
    alpha: float = 0.75
    lod_near: float = 0.0
    lod_half: float = 0.0

    def __post_init__(self) -> None:
        TessellationSettings(**self.__dict__)  # validate ranges with the wire model

    def schema(self) -> TessellationSettings:
        return TessellationSettings(**self.__dict__)

    def level(self, distance: NDArray[np.float64]) -> NDArray[np.float64]:
        """numpy twin of ``level()`` in shaders/piece.tesc."""
        d = np.maximum(np.asarray(distance, dtype=np.float64) - self.lod_near, 0.0)
        f = np.exp2(-d / self.lod_half) if self.lod_half > 0 else np.ones_like(d)
        return np.clip(self.max_level * f, 1.0, self.max_level)


def auto_lod(
    camera: Camera,
    lo: NDArray[np.float64],
    hi: NDArray[np.float64],
    max_level: float,
    alpha: float = 0.75,
) -> TessSettings:
    """Full detail up to the nearest point of the forest's box, then the level halves every
    quarter of the box's diagonal further away (capped below at 1)."""
    nearest = float(np.linalg.norm(camera.eye - np.clip(camera.eye, lo, hi)))
    return TessSettings(
        max_level=max_level,
        alpha=alpha,
        lod_near=nearest,
        lod_half=max(0.25 * float(np.linalg.norm(hi - lo)), 1e-3),
    )


def combine_foliage(stats: list[FoliageStats]) -> FoliageStats | None:
    """One frame's foliage work over several scenes (a mixed forest's layers): the passes'
    draw calls, primitives and GPU times summed; pass 1 rendered if it ran for any."""
    if len(stats) <= 1:
        return stats[0] if stats else None

    def total(passes: list[PassStats]) -> PassStats:
        times = [p.gpu_ms for p in passes if p.draw_calls]
        gpu = None if any(t is None for t in times) else float(sum(t or 0.0 for t in times))
        return PassStats(sum(p.draw_calls for p in passes), sum(p.primitives for p in passes), gpu)

    return FoliageStats(
        mode=stats[0].mode,
        clouds=sum(s.clouds for s in stats),
        impostor_rendered=any(s.impostor_rendered for s in stats),
        impostor=total([s.impostor for s in stats]),
        billboards=total([s.billboards for s in stats]),
    )


@dataclass(frozen=True)
class FrameStats:
    """One frame; ``primitives`` and ``draw_calls`` count every pass, foliage included
    (``foliage`` has the foliage passes alone)."""

    frame: int
    cpu_ms: float
    gpu_ms: float | None
    primitives: int
    draw_calls: int
    instances: int
    foliage: FoliageStats | None = None
    drawn_instances: int | None = None  # kept by the cull pass (main view), with lod_pixels


class Renderer:
    """Draws one scene into an offscreen framebuffer of ``size = (width, height)``.

    ``ids=True`` adds an integer attachment holding (tile, instance id, quad, 1) per pixel
    (undefined where foliage covers the pixel).

    ``foliage`` draws the scene's leaf clouds as 2.5D impostors (``"impostor"``, the default)
    or as the real leaf-cloud mesh (``"geometry"``); ``None`` leaves them out, as does a scene
    without foliage (see :mod:`worker.render.foliage`).

    ``staging`` draws a sky gradient and a ground under the trees first (see
    :mod:`worker.render.staging`); the id attachment is undefined where only they cover a pixel.
    A staged ``staging`` (shadows, MSAA, tone map) draws into a half-float (multisampled)
    buffer, resolves it and tone-maps it into ``color``; with ``ids`` it skips the MSAA (an
    integer attachment has no meaningful resolve).

    A mixed forest: ``terrain`` is drawn with the staging (see :mod:`worker.render.staging`),
    and :meth:`add_layer` adds a scene per further layer, each a Renderer of its own buffers,
    bark tiles and foliage that draws into this one's framebuffer, shadow map and staging
    (``layers``): :meth:`draw` draws them all in each pass, with one camera and one sun.
    """

    def __init__(
        self,
        ctx: moderngl.Context,
        scene: SceneArrays,
        size: tuple[int, int],
        images: TileImages | None = None,
        ids: bool = False,
        foliage: FoliageMode | None = "impostor",
        impostor_size: int = IMPOSTOR_SIZE,
        staging: Staging | None = None,
        terrain: TerrainMesh | None = None,
        share: Renderer | None = None,
    ) -> None:
        import moderngl

        self.ctx = ctx
        self.info = gl_info(ctx)
        self.scene = scene
        self.size = size
        self.images = images or tile_images(scene.manifest, bark=scene.bark_tile_set)
        self.buffers = SceneBuffers(ctx, scene, self.images.n_slices)
        self.texture = upload(ctx, self.images)
        self.layers: list[Renderer] = []  # further scenes drawn with this one (add_layer)
        self.shared = share is not None
        self._variants: dict[frozenset[str], tuple[Any, list[Any]]] = {}
        self._moderngl = moderngl
        self.query = ctx.query(time=self.info.timer_query, primitives=True)
        self.foliage: FoliageRenderer | None = None
        self._foliage_mode, self._impostor_size = foliage, impostor_size
        if foliage is not None and scene.n_foliage:
            self.foliage = FoliageRenderer(
                ctx, scene, foliage, impostor_size, timer_query=self.info.timer_query
            )
        self._bounds: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None
        # the cull passes of the main view and of the sun's, each with its own lists (made on
        # first use: a renderer that never culls pays nothing)
        self._cullers: dict[str, InstanceCuller] = {}
        self._staged_objects: list[Any] = []
        self.stage: StageRenderer | None
        self.color: moderngl.Texture
        self.id_texture: moderngl.Texture | None
        self.depth: moderngl.Renderbuffer
        self.fbo: moderngl.Framebuffer
        self.draw_fbo: moderngl.Framebuffer
        self.samples: int
        self.resolve_fbo: moderngl.Framebuffer | None = None
        self.hdr: moderngl.Texture | None = None
        self.post_fbo: moderngl.Framebuffer | None = None
        if share is not None:  # a layer: the framebuffers and staging are the first scene's
            self.color, self.id_texture, self.depth = share.color, share.id_texture, share.depth
            self.fbo, self.draw_fbo, self.resolve_fbo = share.fbo, share.draw_fbo, share.resolve_fbo
            self.hdr, self.post_fbo, self.samples = share.hdr, share.post_fbo, share.samples
            self.stage = share.stage
            return
        self.color = ctx.texture(size, 4)
        self.id_texture = ctx.texture(size, 4, dtype="i4") if ids else None
        attachments = [self.color] + ([self.id_texture] if self.id_texture else [])
        self.depth = ctx.depth_renderbuffer(size)
        self.fbo = ctx.framebuffer(attachments, self.depth)
        self.stage = StageRenderer(ctx, staging, terrain) if staging is not None else None
        # the staged mode's targets: draw -> (resolve) -> tone map -> self.color
        self.draw_fbo = self.fbo
        self.samples = 0
        if staging is not None and staging.hdr:
            self.hdr = ctx.texture(size, 4, dtype="f2")
            self.post_fbo = ctx.framebuffer([self.color])
            max_samples = int(ctx.info.get("GL_MAX_SAMPLES", 4))
            self.samples = 0 if ids else min(staging.msaa, max_samples)
            if self.samples > 1:
                ms_color = ctx.renderbuffer(size, 4, samples=self.samples, dtype="f2")
                ms_depth = ctx.depth_renderbuffer(size, samples=self.samples)
                self.draw_fbo = ctx.framebuffer([ms_color], ms_depth)
                self.resolve_fbo = ctx.framebuffer([self.hdr], self.depth)
                self._staged_objects += [self.draw_fbo, self.resolve_fbo, ms_color, ms_depth]
            else:
                self.samples = 0
                extra = [self.id_texture] if self.id_texture else []
                self.draw_fbo = ctx.framebuffer([self.hdr, *extra], self.depth)
                self._staged_objects.append(self.draw_fbo)
            self._staged_objects += [self.post_fbo, self.hdr]

    def add_layer(self, scene: SceneArrays, images: TileImages | None = None) -> Renderer:
        """A further scene (a mixed forest's layer) drawn with this one in every frame, with
        its own bark ``images`` and foliage (this renderer's foliage mode), into this one's
        framebuffer, shadow map and staging."""
        if self.shared:
            raise ValueError("add layers to the first scene's renderer")
        layer = Renderer(
            self.ctx,
            scene,
            self.size,
            images,
            foliage=self._foliage_mode,
            impostor_size=self._impostor_size,
            share=self,
        )
        self.layers.append(layer)
        self._bounds = None
        return layer

    def _cull(
        self, which: str, camera: Camera, height: int, alpha: float, min_pixels: float
    ) -> InstanceCuller:
        if which not in self._cullers:
            self._cullers[which] = InstanceCuller(self.ctx, self.buffers)
        culler = self._cullers[which]
        culler.run(camera, height, alpha, min_pixels)
        self.buffers.bind()  # the pass bound its own buffers: the draws' bindings again
        return culler

    # -- programs -----------------------------------------------------------------------------

    def _variant(self, *defines: str) -> tuple[moderngl.Program, list[moderngl.VertexArray]]:
        key = frozenset(defines)
        if key not in self._variants:
            make: Any = self.ctx.program
            prog = make(**shaders.sources(PROGRAM, dict.fromkeys(defines, True)))
            vaos = [
                self.ctx.vertex_array(prog, [(vbo, PATCH_FORMAT, *PATCH_ATTRIBUTES)])
                for vbo in self.buffers.patches
            ]
            self._variants[key] = (prog, vaos)
        return self._variants[key]

    def _uniforms(
        self,
        prog: moderngl.Program,
        camera: Camera,
        tess: TessSettings,
        skinning: bool,
        cull: bool,
        light: SunCamera | None = None,
        fog: float | None = None,
    ) -> None:
        values: dict[str, Any] = {
            "u_skinning": skinning,
            "u_cull": cull,
            "u_camera": tuple(camera.eye),
            "u_tess_max": tess.max_level,
            "u_lod_near": tess.lod_near,
            "u_lod_half": tess.lod_half,
            "u_alpha": tess.alpha,
            "u_sun": tuple(SUN),
            "u_sky": tuple(SKY),
            "u_fog": fog_density(camera) if fog is None else fog,
            "u_tiles": 0,
        }
        if light is not None and self.stage is not None:
            values.update(self.stage.shadow_uniforms(light, 2))
            self.stage.write_light(prog, light)
        for name, value in values.items():
            if name in prog:
                _uniform(prog, name).value = value
        vp = camera.view_projection().T.astype("f4")
        _uniform(prog, "u_view_projection").write(vp.tobytes())
        _uniform(prog, "u_frustum").write(camera.frustum_planes().astype("f4").tobytes())

    def _draw_all(
        self,
        prog: moderngl.Program,
        vaos: list[moderngl.VertexArray],
        per_instance: bool,
        culler: InstanceCuller | None = None,
    ) -> int:
        """Issue the draw calls; returns how many. With ``culler``, one indirect draw per
        piece type of the instances its last pass kept."""
        mgl = self._moderngl
        base = _uniform(prog, "u_base_instance")
        if "u_culled" in prog:
            _uniform(prog, "u_culled").value = culler is not None
        if culler is not None:
            return culler.draw(vaos, base)
        layout, calls = self.buffers.layout, 0
        for t, vao in enumerate(vaos):
            n, first = int(layout.count[t]), int(layout.first[t])
            if n == 0:
                continue
            vertices = 4 * self.buffers.n_quads[t]
            if per_instance:  # the naive way: one draw call per piece instance
                for slot in range(first, first + n):
                    base.value = slot
                    vao.render(mgl.PATCHES, vertices=vertices, instances=1)
                calls += n
            else:
                base.value = first
                vao.render(mgl.PATCHES, vertices=vertices, instances=n)
                calls += 1
        return calls

    # -- frames -------------------------------------------------------------------------------

    def draw(
        self,
        camera: Camera,
        tess: TessSettings,
        frame: int = 0,
        per_instance: bool = False,
        skinning: bool = True,
        cull: bool = True,
        branches: bool = True,
        force_impostor: bool = False,
        lod_pixels: float | None = None,
    ) -> FrameStats:
        """Draw palette frame ``frame`` and wait for it to finish. ``cull`` drops patches
        wholly outside the view frustum in the tessellation control shader. With
        ``lod_pixels`` (not with ``per_instance``, unskinned or without ``cull``) a compute
        pass first drops whole instances outside the view and, when it is above 0, pieces
        thinner on screen than that many pixels (worker.render.instance_cull); the sun's pass culls
        likewise in its own view.
        Foliage: pass 1 (when the view direction changed, or ``force_impostor``), the
        branches, then pass 2. ``branches=False`` draws the foliage alone."""
        if per_instance or not skinning or not cull:  # it bounds the skinned pose, not the rest
            lod_pixels = None
        mgl, ctx = self._moderngl, self.ctx
        staged = self.stage is not None and self.stage.staging.shadows
        defines = ["ID_OUTPUT"] if self.id_texture else []
        prog, vaos = self._variant(*defines, *(["STAGED"] if staged else []))
        fog = fog_density(camera)
        ground_half = None
        if staged:
            camera, ground_half, fog = self.staged_view(camera)
        t0 = time.perf_counter()
        members = (self, *self.layers)
        for m in reversed(members):  # the palettes of this frame (the first scene's bound last)
            m.buffers.use(frame)
        calls, primitives, gpu_ms = 0, 0, 0.0 if self.info.timer_query else None
        light = None
        if staged:
            light = self.sun_view(camera, frame)
            calls, primitives, gpu_ms = self._shadow_pass(
                light, tess, skinning, branches, lod_pixels
            )
            force_impostor = True  # the shadow pass left the sun's picture in the atlas
        pass1s = [
            None if m.foliage is None else m.foliage.prepare(camera, SUN, SKY, force=force_impostor)
            for m in members
        ]
        fbo = self.draw_fbo
        fbo.use()
        fbo.viewport = (0, 0, *self.size)
        ctx.enable_only(mgl.DEPTH_TEST)
        ctx.patch_vertices = 4
        r, g, b = (float(c) for c in np.power(SKY, 1 / 2.2))
        fbo.clear(color=(r, g, b, 1.0), depth=1.0)
        if self.id_texture is not None:
            self.id_texture.write(np.zeros((*self.size[::-1], 4), np.int32).tobytes())
        if self.stage is not None:
            self.stage.draw(camera, SUN, SKY, fog, light, ground_half)
        focal_px = 1.0 / pixel_size(camera, self.size[1])[1]  # pixels per metre at 1 m
        all_leaves: list[FoliageStats] = []
        cullers: list[InstanceCuller] = []
        for m, pass1 in zip(members, pass1s, strict=True):
            if m is not self:  # after the previous scene's leaves: its buffers, GL state
                m.buffers.bind()
                fbo.use()
                ctx.enable_only(mgl.DEPTH_TEST)
                ctx.patch_vertices = 4
                prog, vaos = m._variant(*defines, *(["STAGED"] if staged else []))
            m.texture.use(0)
            m._uniforms(prog, camera, tess, skinning, cull, light, fog)
            culler = None
            if branches and lod_pixels is not None:
                culler = m._cull("main", camera, self.size[1], tess.alpha, lod_pixels)
                cullers.append(culler)
            if branches:
                with m.query:
                    calls += m._draw_all(prog, vaos, per_instance, culler)
                primitives += int(m.query.primitives)
                branch_ms = elapsed_ms(m.query)
                gpu_ms = None if gpu_ms is None or branch_ms is None else gpu_ms + branch_ms
            if m.foliage is not None and pass1 is not None:
                leaves = m.foliage.frame(camera, SUN, SKY, fog, pass1, fbo, focal_px=focal_px)
                calls += leaves.draw_calls
                primitives += leaves.primitives
                gpu_ms = None if gpu_ms is None or leaves.gpu_ms is None else gpu_ms + leaves.gpu_ms
                all_leaves.append(leaves)
        self._finish_frame()
        ctx.finish()
        cpu_ms = (time.perf_counter() - t0) * 1e3
        return FrameStats(
            frame=frame % self.buffers.n_frames,
            cpu_ms=cpu_ms,
            gpu_ms=gpu_ms,
            primitives=primitives,
            draw_calls=calls,
            instances=sum(m.scene.n_instances for m in members),
            foliage=combine_foliage(all_leaves),
            drawn_instances=sum(int(c.counts().sum()) for c in cullers) if cullers else None,
        )

    # -- the staged mode ------------------------------------------------------------------------

    def scene_box(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(lo, hi)`` the forest's box at frame 0 with its leaf clouds and the ground at
        y = 0 (every layer's and the terrain too), grown by 5 % of its diagonal for the wind
        (the sun's view is fitted to it)."""
        if self._bounds is None:
            parts = []
            for m in (self, *self.layers):
                scene = m.scene
                parts.append(scene_points(scene, 0))
                if scene.n_foliage:
                    r = scene.foliage_sizes.reshape(len(scene.foliage_sizes), -1).max(1)
                    c = scene.foliage_at(0)
                    parts += [c - r[:, None], c + r[:, None]]
            if self.stage is not None and self.stage.terrain is not None:
                parts.append(self.stage.terrain.points)
            pts = np.concatenate(parts)
            lo, hi = pts.min(axis=0), pts.max(axis=0)
            lo[1] = min(lo[1], 0.0)
            pad = 0.05 * float(np.linalg.norm(hi - lo))
            self._bounds = (lo - pad, hi + pad)
        return self._bounds

    def staged_view(self, camera: Camera) -> tuple[Camera, float, float]:
        """``(camera, ground half-size, fog density)`` of the staged mode: the ground reaches
        :data:`GROUND_SPAN` times the larger of the camera-target distance and the scene's
        half-diagonal, fogged to 97 % at its edge (so fog scales with the scene: light in a
        close-up, the horizon hazed in an overview); the far plane moves past the ground."""
        lo, hi = self.scene_box()
        dist = float(np.linalg.norm(camera.target - camera.eye))
        reach = max(dist, 0.5 * float(np.linalg.norm(hi - lo)))
        half = GROUND_SPAN * reach
        far = max(camera.far, 1.5 * half)
        cam = Camera(camera.eye, camera.target, camera.fov_y, camera.aspect, camera.near, far)
        return cam, half, 3.5 / half

    def sun_view(self, camera: Camera, frame: int = 0) -> SunCamera:
        """The sun's camera fitted to ``camera``'s view of the scene (see worker.render.staging)."""
        lo, hi = self.scene_box()
        return sun_camera(camera, lo, hi, SUN)

    def _shadow_pass(
        self,
        light: SunCamera,
        tess: TessSettings,
        skinning: bool,
        branches: bool,
        lod_pixels: float | None = None,
    ) -> tuple[int, int, float | None]:
        """Branches and leaf-cloud billboards into the sun's depth map; returns draw calls,
        primitives and GPU ms of the pass."""
        assert self.stage is not None
        members = (self, *self.layers)
        # the clouds' pictures as the sun sees them, first
        pass1s = [
            None if m.foliage is None else m.foliage.prepare(light, SUN, SKY, force=True)
            for m in members
        ]
        fbo = self.stage.begin_shadows()
        self.ctx.patch_vertices = 4
        # the sun's view needs no fine tessellation: a coarse silhouette casts the same shadow
        coarse = TessSettings(max_level=min(tess.max_level, 4.0), alpha=tess.alpha)
        calls, primitives, gpu_ms = 0, 0, 0.0 if self.info.timer_query else None
        for m, pass1 in zip(members, pass1s, strict=True):
            if m is not self:  # after the previous scene's leaves: its buffers, GL state
                m.buffers.bind()
                fbo.use()
                self.ctx.enable_only(self._moderngl.DEPTH_TEST)
                self.ctx.patch_vertices = 4
            prog, vaos = m._variant()
            culler = None
            if branches and lod_pixels is not None:
                culler = m._cull("shadow", light, 0, coarse.alpha, lod_pixels)
            m._uniforms(prog, light, coarse, skinning, cull=True)
            if branches:
                with m.query:
                    calls += m._draw_all(prog, vaos, per_instance=False, culler=culler)
                primitives += int(m.query.primitives)
                branch_ms = elapsed_ms(m.query)
                gpu_ms = None if gpu_ms is None or branch_ms is None else gpu_ms + branch_ms
            if m.foliage is not None and pass1 is not None:
                leaves = m.foliage.frame(light, SUN, SKY, 0.0, pass1, fbo)
                calls += leaves.draw_calls
                primitives += leaves.primitives
                gpu_ms = None if gpu_ms is None or leaves.gpu_ms is None else gpu_ms + leaves.gpu_ms
        self.stage.end_shadows()
        return calls, primitives, gpu_ms

    def _finish_frame(self) -> None:
        """Resolve the multisampled frame and tone-map it into ``color`` (staged mode)."""
        if self.hdr is None or self.stage is None or self.post_fbo is None:
            return
        if self.resolve_fbo is not None:
            self.ctx.copy_framebuffer(self.resolve_fbo, self.draw_fbo)
        self.stage.tone_map(self.hdr, self.post_fbo)
        self.ctx.enable_only(self._moderngl.DEPTH_TEST)

    def read_depth(self) -> NDArray[np.float32]:
        """``(h, w)`` float32 window depth in [0, 1] (1: nothing drawn), top row first."""
        w, h = self.size
        raw = np.frombuffer(self.fbo.read(components=1, attachment=-1, dtype="f4"), np.float32)
        return raw.reshape(h, w)[::-1].copy()

    def read_color(self) -> NDArray[np.uint8]:
        """``(h, w, 4)`` uint8, top row first."""
        w, h = self.size
        raw = np.frombuffer(self.color.read(), np.uint8).reshape(h, w, 4)
        return raw[::-1].copy()

    def read_ids(self) -> NDArray[np.int32]:
        """``(h, w, 4)`` int32 (tile, instance id, quad, covered), top row first."""
        if self.id_texture is None:
            raise ValueError("the renderer was made without ids=True")
        w, h = self.size
        raw = np.frombuffer(self.id_texture.read(), np.int32).reshape(h, w, 4)
        return raw[::-1].copy()

    def capture(
        self,
        camera: Camera,
        tess: TessSettings,
        frame: int = 0,
        capacity: int = 1 << 20,
        skinning: bool = True,
        cull: bool = False,
    ) -> NDArray[np.void]:
        """Every vertex the tessellation evaluation shader produced (CAPTURE_DTYPE), with the
        rasteriser off. Vertices shared by neighbouring triangles may repeat. Frustum culling
        is off by default, so every patch is there."""
        mgl, ctx = self._moderngl, self.ctx
        prog, vaos = self._variant("CAPTURE")
        head = np.array([0, capacity, 0, 0], np.uint32).tobytes()
        buf = ctx.buffer(reserve=CAPTURE_HEADER + capacity * CAPTURE_DTYPE.itemsize)
        buf.write(head)
        try:
            buf.bind_to_storage_buffer(3)
            self.buffers.use(frame)
            self.fbo.use()  # a complete framebuffer, or the driver may skip the draws
            ctx.enable_only(mgl.RASTERIZER_DISCARD)
            ctx.patch_vertices = 4
            self._uniforms(prog, camera, tess, skinning, cull)
            self._draw_all(prog, vaos, per_instance=False)
            ctx.memory_barrier(mgl.SHADER_STORAGE_BARRIER_BIT)
            count = int(np.frombuffer(buf.read(4), np.uint32)[0])
            if count > capacity:
                raise ValueError(f"capture overflow: {count} vertices, capacity {capacity}")
            data = buf.read(count * CAPTURE_DTYPE.itemsize, offset=CAPTURE_HEADER) if count else b""
        finally:
            ctx.disable(mgl.RASTERIZER_DISCARD)
            buf.release()
        return np.frombuffer(data, CAPTURE_DTYPE).copy()

    def release(self) -> None:
        for layer in self.layers:
            layer.release()
        self.layers.clear()
        for prog, vaos in self._variants.values():
            for vao in vaos:
                vao.release()
            prog.release()
        self._variants.clear()
        for culler in self._cullers.values():
            culler.release()
        self._cullers.clear()
        if self.shared:  # a layer: the framebuffers and staging are the first scene's
            if self.foliage is not None:
                self.foliage.release()
            self.texture.release()
            self.buffers.release()
            return
        # moderngl rebinds the last used framebuffer after creating one: leave GL on the
        # default framebuffer, not on a deleted name (GL_INVALID_OPERATION later)
        self.ctx.detect_framebuffer(0).use()
        if self.foliage is not None:
            self.foliage.release()
        if self.stage is not None:
            self.stage.release()
        for obj in self._staged_objects:
            obj.release()
        for obj in (self.fbo, self.color, self.depth, self.texture):
            obj.release()
        if self.id_texture is not None:
            self.id_texture.release()
        self.buffers.release()
