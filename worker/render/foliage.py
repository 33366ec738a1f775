"""Foliage as 2.5D impostors (paper 6), and the real leaf-cloud geometry to compare with.

A scene's foliage shows a few leaf-cloud models (the PointInstancer's prototypes, unit
diameter, one leaf family); every cloud shows one model turned about the vertical by its yaw,
scaled by its diameter, tinted by its colour, at its centre: the palette entry of its piece's
hub bone applied to its rest point, so clouds follow the wind with their branches.

``impostor`` mode, two passes:

1. every model at each of YAW_STEPS headings, alone, through an orthographic camera looking
   along the main camera's view direction (with the main camera's right and up) into one
   tile of an RGBA32F atlas (column: heading, row: model; one instanced draw call per model,
   an instance per heading): the linear lit colour of the untinted leaves, and in alpha where
   the nearest leaf lies between the front (0) and the back (1) of the cloud's bounding
   sphere, -1 where no leaf is. It reruns only when the view direction (the camera's
   rotation) changes: wind and camera moves along the same direction reuse the pictures.
2. one camera-facing billboard per cloud in one instanced draw call, showing its model's
   tile at its heading, tinted by its colour (lighting is linear in the albedo, so the tint
   may come after); the fragment shader discards empty texels and writes ``gl_FragDepth`` of
   the point at the stored distance from the billboard plane along the pixel's view ray, so
   billboards depth-test against the branches and each other.

Why headings are pre-rendered pictures (yaw buckets) rather than a per-instance view
direction turned into the model's frame: the pictures depend only on the camera's rotation,
so a turn of a cloud is exactly a turn of its model by the same yaw seen along the same view
direction (one tile), with the world's lighting; looking up the nearest of a few view
directions per instance would show wrong lighting and wrong parallax for every cloud. The
generator draws yaws from the same YAW_STEPS headings, so impostors show exactly what the
real geometry shows; a yaw between headings (a scene made elsewhere) shows the nearest one.
The cost is YAW_STEPS pictures per model in pass 1 (a few thousand leaf triangles each time
the view turns), against one picture before.

Close to the camera (``near_clouds``: a cloud larger on screen than its picture) impostor
mode draws the real leaf cards instead, as geometry mode does, so close-ups show smooth leaf
edges rather than magnified texels; those few clouds are chosen on the CPU from their
first-frame centres whenever the camera moves.

``geometry`` mode draws the leaf-cloud meshes themselves at every cloud, turned and tinted,
one instanced draw call per model (the reference for tests, and the benchmark's baseline).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal, cast

import numpy as np
from numpy.typing import NDArray

from forest.errors import LimitError
from forest.geometry.transforms import F64
from forest.gl import shaders
from forest.gl.context import elapsed_ms
from forest.growth.foliage import YAW_STEPS, LeafCloud, cloud_models, leaf_texture
from forest.usd.contract import FOLIAGE
from forest.usd.read import SceneArrays
from worker.render.camera import Camera, box_corners

if TYPE_CHECKING:
    import moderngl

FoliageMode = Literal["impostor", "geometry"]
FOLIAGE_MODES: tuple[FoliageMode, ...] = ("impostor", "geometry")
# std430 ``struct Cloud`` in shaders/leaves.vert and billboard.vert
CLOUD_DTYPE = np.dtype(
    [("rest_size", "<f4", 4), ("bone", "<i4", 4), ("tint", "<f4", 4), ("turn", "<f4", 4)]
)
LEAF_DTYPE = np.dtype([("position", "<f4", 3), ("normal", "<f4", 3), ("st", "<f4", 2)])
LEAF_FORMAT = "3f 3f 2f"
LEAF_ATTRIBUTES = ("in_position", "in_normal", "in_st")
IMPOSTOR_SIZE = 128  # texels per side of one picture (a model at a heading) in the atlas
# a cloud whose bounding sphere would cover more screen pixels than this many of its picture's
# texels is drawn as its real leaf cards: magnified, the nearest-sampled picture shows texel
# steps along every leaf edge (close-ups). The billboard pass hides a cloud only past
# NEAR_MARGIN times that, so wind moving a cloud between the two tests never leaves a hole
# (a cloud in between shows both ways, the same leaves at the same place)
NEAR_TEXELS = 1.0
NEAR_MARGIN = 1.25
CAPTURE_BINDING = 3
# largest change of a camera rotation entry that keeps the pass-1 picture (about 1e-6 rad:
# far below a texel; float noise of look_at for a camera moved along its view direction)
VIEW_TOLERANCE = 1e-6
CLOUD_BINDING = 4
ORDER_BINDING = 5


@dataclass(frozen=True)
class PassStats:
    draw_calls: int = 0
    primitives: int = 0
    gpu_ms: float | None = None


@dataclass(frozen=True)
class FoliageStats:
    """One frame's foliage work: pass 1 (``impostor``, zero when the picture was reused and
    in geometry mode) and pass 2 (``billboards``: the instanced billboards, or in geometry mode
    the instanced leaf clouds)."""

    mode: FoliageMode
    clouds: int
    impostor_rendered: bool
    impostor: PassStats
    billboards: PassStats

    @property
    def draw_calls(self) -> int:
        return self.impostor.draw_calls + self.billboards.draw_calls

    @property
    def primitives(self) -> int:
        return self.impostor.primitives + self.billboards.primitives

    @property
    def gpu_ms(self) -> float | None:
        times = [p.gpu_ms for p in (self.impostor, self.billboards) if p.draw_calls]
        if any(t is None for t in times):
            return None
        return float(sum(t for t in times if t is not None))


def scene_models(scene: SceneArrays) -> tuple[LeafCloud, ...]:
    """The scene's cloud models (its prototypes; broad leaves for foliage without any)."""
    return scene.foliage_clouds or cloud_models("broadleaf")


def yaw_bucket(yaw: F64) -> NDArray[np.int32]:
    """``(k,)`` the nearest of the YAW_STEPS headings (index) to each ``yaw`` (radians)."""
    step = 2 * np.pi / YAW_STEPS
    return (np.round(np.asarray(yaw) / step).astype(np.int64) % YAW_STEPS).astype(np.int32)


def cloud_records(scene: SceneArrays) -> NDArray[np.void]:
    """``(k,)`` CLOUD_DTYPE: rest point and diameter, palette entry, atlas tile (model row,
    heading column) and model, colour, yaw and the model's bounding radius of every cloud."""
    models = scene_models(scene)
    radii = np.array([m.radius for m in models])
    rec = np.zeros(scene.n_foliage, CLOUD_DTYPE)
    rec["rest_size"][:, :3] = scene.foliage_rest
    rec["rest_size"][:, 3] = scene.foliage_sizes
    rec["bone"][:, 0] = scene.foliage_bone
    rec["bone"][:, 1] = scene.foliage_model * YAW_STEPS + yaw_bucket(scene.foliage_yaw)
    rec["bone"][:, 2] = scene.foliage_model
    rec["tint"][:, :3] = scene.foliage_color
    rec["turn"][:, 0] = scene.foliage_yaw
    rec["turn"][:, 1] = radii[scene.foliage_model]
    return rec


def leaf_vertices(
    models: tuple[LeafCloud, ...],
) -> tuple[NDArray[np.void], NDArray[np.int32], NDArray[np.int64]]:
    """Interleaved vertices and triangle indices of all ``models`` in one buffer, and the
    ``(m + 1,)`` index offsets of each model's triangles (model i: indices
    ``offsets[i]:offsets[i + 1]``)."""
    v = np.zeros(sum(len(c.positions) for c in models), LEAF_DTYPE)
    v["position"] = np.concatenate([c.positions for c in models])
    v["normal"] = np.concatenate([c.normals for c in models])
    v["st"] = np.concatenate([c.st for c in models])
    first = np.cumsum([0] + [len(c.positions) for c in models])
    tris = np.concatenate([c.triangles() + f for c, f in zip(models, first, strict=False)])
    offsets = np.cumsum([0] + [3 * len(c.triangles()) for c in models]).astype(np.int64)
    return v, tris.astype(np.int32), offsets


def impostor_basis(camera: Camera) -> tuple[F64, F64, F64]:
    """The camera's right, up and forward (unit world vectors): pass 1 looks along forward
    with this right and up, and the billboards span right and up."""
    r = camera.view()[:3, :3]
    return r[0].copy(), r[1].copy(), -r[2]


def impostor_view_projection(camera: Camera, radius: float) -> F64:
    """Pass 1's camera for the unit cloud at the origin: the main camera's rotation, the eye
    ``2 radius`` back along the view direction, orthographic over the bounding sphere (x, y in
    ``[-radius, radius]``, depth from ``radius`` to ``3 radius``)."""
    view = np.eye(4)
    view[:3, :3] = camera.view()[:3, :3]
    view[2, 3] = -2.0 * radius
    proj = np.diag([1.0 / radius, 1.0 / radius, -1.0 / radius, 1.0])
    proj[2, 3] = -2.0
    return proj @ view


def foliage_points(scene: SceneArrays, frame: int = 0, tree: int | None = None) -> F64:
    """``(8 k, 3)`` corners of every cloud's box at ``frame`` (for framing the camera): a box
    that holds every model at any yaw (the largest distance from the vertical axis across,
    the lowest and highest leaf up)."""
    if scene.n_foliage == 0:
        return np.zeros((0, 3))
    pts = np.concatenate([c.positions for c in scene_models(scene)])
    r = float(np.hypot(pts[:, 0], pts[:, 2]).max())
    corners = box_corners(np.array([-r, pts[:, 1].min(), -r]), np.array([r, pts[:, 1].max(), r]))
    c, size = scene.foliage_at(frame), scene.foliage_sizes
    if tree is not None:  # the clouds of one tree
        mine = scene.tree[scene.foliage_instance] == tree
        c, size = c[mine], size[mine]
    return (c[:, None] + size[:, None, None] * corners[None]).reshape(-1, 3)


def _uniform(prog: moderngl.Program, name: str) -> moderngl.Uniform:
    return cast("moderngl.Uniform", prog[name])


def _set(prog: moderngl.Program, values: dict[str, Any]) -> None:
    for name, value in values.items():
        if name not in prog:
            continue
        if isinstance(value, np.ndarray) and value.shape == (4, 4):
            _uniform(prog, name).write(value.T.astype("f4").tobytes())
        elif isinstance(value, np.ndarray):
            _uniform(prog, name).value = tuple(float(x) for x in value)
        else:
            _uniform(prog, name).value = value


class FoliageRenderer:
    """The foliage of one scene on one context. The palette storage buffer (binding 1) must
    be bound by the caller (``SceneBuffers.use``) before drawing."""

    def __init__(
        self,
        ctx: moderngl.Context,
        scene: SceneArrays,
        mode: FoliageMode = "impostor",
        impostor_size: int = IMPOSTOR_SIZE,
        timer_query: bool = True,
    ) -> None:
        import moderngl

        if mode not in FOLIAGE_MODES:
            raise ValueError(f"foliage mode must be one of {FOLIAGE_MODES}, got {mode!r}")
        self._mgl = moderngl
        self.ctx = ctx
        self.scene = scene
        self.mode: FoliageMode = mode
        self.models = scene_models(scene)
        self.radii = [c.radius for c in self.models]
        records = cloud_records(scene)
        limit = int(ctx.info.get("GL_MAX_SHADER_STORAGE_BLOCK_SIZE", 2**27))
        if records.nbytes > limit:
            raise LimitError(
                f"{scene.n_foliage} leaf clouds need {records.nbytes / 2**20:.3g} MiB, more than "
                f"this driver's storage block limit of {limit / 2**20:.3g} MiB",
                path=f"{FOLIAGE}.positions",
                limit=limit,
            )
        self.records = ctx.buffer(records.tobytes() if len(records) else b"\0" * 64)
        # clouds by model, for geometry mode's one instanced draw per model
        order = np.argsort(scene.foliage_model, kind="stable").astype(np.int32)
        counts = np.bincount(scene.foliage_model, minlength=len(self.models))
        self.model_counts = counts.astype(np.int64)
        self.order = ctx.buffer(order.tobytes() if len(order) else b"\0" * 4)
        verts, tris, self.index_offsets = leaf_vertices(self.models)
        self.n_triangles = len(tris)
        self.vbo = ctx.buffer(verts.tobytes())
        self.ibo = ctx.buffer(tris.astype(np.int32).tobytes())
        self.textures: dict[str, moderngl.Texture] = {}
        for family in sorted({c.family for c in self.models}):
            tex = leaf_texture(family)
            t = ctx.texture(tex.shape[1::-1], 4, np.ascontiguousarray(tex).tobytes())
            t.build_mipmaps()
            t.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
            t.repeat_x = t.repeat_y = False
            self.textures[family] = t
        self._programs: dict[str, Any] = {}
        self._vaos: dict[str, Any] = {}
        self.impostor_size = impostor_size
        self.impostor: moderngl.Texture | None = None
        self.impostor_fbo: moderngl.Framebuffer | None = None
        self._impostor_depth: moderngl.Renderbuffer | None = None
        if mode == "impostor":
            n = impostor_size
            atlas = (n * YAW_STEPS, n * len(self.models))
            max_size = int(ctx.info.get("GL_MAX_TEXTURE_SIZE", 16384))
            if max(atlas) > max_size:
                raise LimitError(
                    f"an impostor atlas of {atlas[0]}x{atlas[1]} texels is more than this "
                    f"driver's texture size limit of {max_size}",
                    path="impostor_size",
                    limit=max_size,
                )
            self.impostor = ctx.texture(atlas, 4, dtype="f4")
            # nearest in every mode: alpha is a leaf's depth or the empty marker -1, and any
            # filtering (mip levels above all) averages the two into a negative value where a
            # cloud is sparse, discarding it (distant willow curtains vanished)
            self.impostor.filter = (moderngl.NEAREST, moderngl.NEAREST)
            self.impostor.repeat_x = self.impostor.repeat_y = False
            self._impostor_depth = ctx.depth_renderbuffer(atlas)
            self.impostor_fbo = ctx.framebuffer([self.impostor], self._impostor_depth)
        self._rotation: F64 | None = None
        self.impostor_renders = 0
        # for near_clouds: first-frame cloud centres (made on first use) and bounding radii
        # (the billboards' half sizes)
        self._centres: F64 | None = None
        self._half = scene.foliage_sizes * np.take(self.radii, scene.foliage_model)
        self._near_key: tuple[float, ...] | None = None
        self._near_counts = np.zeros(len(self.models), np.int64)
        self.near_order: moderngl.Buffer | None = None
        self._timer = timer_query
        self.queries = [ctx.query(time=timer_query, primitives=True) for _ in range(2)]

    @property
    def cloud(self) -> LeafCloud:
        """The first cloud model (what callers of a one-model renderer read its card count
        from; the generator's models all have CARDS cards)."""
        return self.models[0]

    # -- programs ---------------------------------------------------------------------------

    def _program(self, stem: str, *defines: str) -> tuple[moderngl.Program, moderngl.VertexArray]:
        key = "/".join((stem, *sorted(defines)))
        if key not in self._programs:
            make: Any = self.ctx.program
            prog = make(**shaders.sources(stem, dict.fromkeys(defines, True)))
            if stem == "leaves":
                vao = self.ctx.vertex_array(
                    prog, [(self.vbo, LEAF_FORMAT, *LEAF_ATTRIBUTES)], index_buffer=self.ibo
                )
            else:
                vao = self.ctx.vertex_array(prog, [])
            self._programs[key], self._vaos[key] = prog, vao
        return self._programs[key], self._vaos[key]

    # -- passes -----------------------------------------------------------------------------

    def needs_update(self, camera: Camera) -> bool:
        """Whether pass 1 must run for ``camera``: its rotation (view direction, right and
        up) differs from the last picture's by more than VIEW_TOLERANCE, or there is none.
        A camera moving along its view direction keeps the picture."""
        if self._rotation is None:
            return True
        return bool(np.abs(camera.view()[:3, :3] - self._rotation).max() > VIEW_TOLERANCE)

    def prepare(self, camera: Camera, sun: F64, sky: F64, force: bool = False) -> PassStats:
        """Pass 1, if the view direction changed since the last one (or ``force``): the
        cloud's picture and distances for this view. Leaves the impostor framebuffer bound."""
        if self.mode != "impostor" or self.scene.n_foliage == 0:
            return PassStats()
        if not (force or self.needs_update(camera)):
            return PassStats()
        assert self.impostor_fbo is not None
        mgl, ctx = self._mgl, self.ctx
        prog, vao = self._program("leaves", "IMPOSTOR")
        forward = impostor_basis(camera)[2]
        fbo = self.impostor_fbo
        fbo.use()
        fbo.viewport = (0, 0, *fbo.size)
        fbo.clear(0.0, 0.0, 0.0, -1.0, depth=1.0)
        ctx.enable_only(mgl.DEPTH_TEST)
        _set(
            prog,
            {
                "u_forward": forward,
                "u_sun": np.asarray(sun),
                "u_sky": np.asarray(sky),
                "u_leaf": 0,
                "u_steps": YAW_STEPS,
                "u_rows": len(self.models),
            },
        )
        q = self.queries[0]
        with q:
            for m, cloud in enumerate(self.models):
                self.textures[cloud.family].use(0)
                r = self.radii[m]
                _set(
                    prog,
                    {
                        "u_view_projection": impostor_view_projection(camera, r),
                        "u_radius": r,
                        "u_row": m,
                    },
                )
                lo, hi = self.index_offsets[m], self.index_offsets[m + 1]
                vao.render(mgl.TRIANGLES, vertices=int(hi - lo), first=int(lo),
                           instances=YAW_STEPS)  # fmt: skip
        self._rotation = camera.view()[:3, :3].copy()
        self.impostor_renders += 1
        return PassStats(
            draw_calls=len(self.models),
            primitives=int(q.primitives),
            gpu_ms=elapsed_ms(q) if self._timer else None,
        )

    def near_clouds(self, camera: Camera, focal_px: float) -> NDArray[np.int32]:
        """``(j,)`` the clouds, by model, that ``camera`` sees larger than NEAR_TEXELS times
        the impostor's resolution (``focal_px``: the viewport's height over ``2 tan(fov/2)``,
        pixels per metre at one metre's depth), measured at their first-frame centres; ones
        wholly behind the camera are left out."""
        if self._centres is None:
            self._centres = self.scene.foliage_at(0)
        forward = impostor_basis(camera)[2]
        half = self._half
        depth = (self._centres - np.asarray(camera.eye)) @ forward
        limit = NEAR_TEXELS * self.impostor_size
        near = (depth > -half) & (2.0 * half * focal_px > limit * depth)
        idx = np.flatnonzero(near)
        return idx[np.argsort(self.scene.foliage_model[idx], kind="stable")].astype(np.int32)

    def _update_near(self, camera: Camera, focal_px: float) -> None:
        key = (*np.asarray(camera.eye, float), *camera.view()[:3, :3].ravel(), focal_px)
        if key == self._near_key:
            return
        order = self.near_clouds(camera, focal_px)
        self._near_counts = np.bincount(
            self.scene.foliage_model[order], minlength=len(self.models)
        ).astype(np.int64)
        data = order.tobytes() if len(order) else b"\0" * 4
        if self.near_order is None or self.near_order.size < len(data):
            if self.near_order is not None:
                self.near_order.release()
            self.near_order = self.ctx.buffer(reserve=max(len(data), 4096))
        self.near_order.write(data)
        self._near_key = key

    def _draw_clouds(
        self, order: moderngl.Buffer, counts: NDArray[np.int64], common: dict[str, Any]
    ) -> int:
        """The real leaf cards of the clouds listed in ``order``, ``counts[m]`` of model m
        after those of the models before it: one instanced draw call per model."""
        mgl = self._mgl
        prog, vao = self._program("leaves")
        order.bind_to_storage_buffer(ORDER_BINDING)
        _set(prog, {**common, "u_leaf": 0})
        first = np.cumsum(counts) - counts
        calls = 0
        for m, cloud in enumerate(self.models):
            n = int(counts[m])
            if n == 0:
                continue
            self.textures[cloud.family].use(0)
            _set(prog, {"u_first": int(first[m])})
            lo, hi = self.index_offsets[m], self.index_offsets[m + 1]
            vao.render(mgl.TRIANGLES, vertices=int(hi - lo), first=int(lo), instances=n)
            calls += 1
        return calls

    def draw(
        self,
        camera: Camera,
        sun: F64,
        sky: F64,
        fog: float,
        capture: Any = None,
        focal_px: float | None = None,
    ) -> PassStats:
        """Pass 2 (or the real clouds) into the framebuffer bound now, depth test on. With
        ``focal_px`` (the main view's; not the sun's) impostor mode draws the clouds near the
        camera as real leaf cards (:meth:`near_clouds`) and their billboards not."""
        k = self.scene.n_foliage
        if k == 0:
            return PassStats()
        mgl = self._mgl
        self.records.bind_to_storage_buffer(CLOUD_BINDING)
        right, up, forward = impostor_basis(camera)
        common: dict[str, Any] = {
            "u_view_projection": camera.view_projection(),
            "u_camera": np.asarray(camera.eye),
            "u_sun": np.asarray(sun),
            "u_sky": np.asarray(sky),
            "u_fog": fog,
        }
        q = self.queries[1]
        if self.mode == "impostor":
            assert self.impostor is not None
            if self._rotation is None and capture is None:
                raise RuntimeError("pass 1 (prepare) must run before the billboards")
            defines = ("CAPTURE",) if capture is not None else ()
            prog, vao = self._program("billboard", *defines)
            if capture is not None:
                capture.bind_to_storage_buffer(CAPTURE_BINDING)
            near_focal = 0.0 if focal_px is None or capture is not None else float(focal_px)
            if near_focal > 0:
                self._update_near(camera, near_focal)
            self.impostor.use(1)
            _set(
                prog,
                {
                    **common,
                    "u_right": right,
                    "u_up": up,
                    "u_forward": forward,
                    "u_tiles": (YAW_STEPS, len(self.models)),
                    "u_impostor": 1,
                    "u_focal": near_focal,  # 0: every billboard drawn
                    "u_near_pixels": NEAR_MARGIN * NEAR_TEXELS * self.impostor_size,
                },
            )
            with q:
                vao.render(mgl.TRIANGLE_STRIP, vertices=4, instances=k)
                calls = 1
                if near_focal > 0 and self._near_counts.any():
                    assert self.near_order is not None
                    calls += self._draw_clouds(self.near_order, self._near_counts, common)
        else:
            with q:
                calls = self._draw_clouds(self.order, self.model_counts, common)
        return PassStats(
            draw_calls=calls,
            primitives=int(q.primitives),
            gpu_ms=elapsed_ms(q) if self._timer else None,
        )

    def frame(
        self,
        camera: Camera,
        sun: F64,
        sky: F64,
        fog: float,
        pass1: PassStats,
        target: moderngl.Framebuffer,
        focal_px: float | None = None,
    ) -> FoliageStats:
        """Pass 2 into ``target`` after ``prepare`` gave ``pass1`` (``focal_px``: see
        :meth:`draw`)."""
        target.use()
        self.ctx.enable_only(self._mgl.DEPTH_TEST)
        pass2 = self.draw(camera, sun, sky, fog, focal_px=focal_px)
        return FoliageStats(
            mode=self.mode,
            clouds=self.scene.n_foliage,
            impostor_rendered=pass1.draw_calls > 0,
            impostor=pass1,
            billboards=pass2,
        )

    def read_impostor(self) -> NDArray[np.float32]:
        """``(m n, YAW_STEPS n, 4)`` float32 pass-1 atlas (a row of n x n tiles per model, a
        tile per heading), bottom row (t = 0) first."""
        if self.impostor is None:
            raise ValueError("no impostor target in geometry mode")
        w, h = self.impostor.size
        return np.frombuffer(self.impostor.read(), np.float32).reshape(h, w, 4).copy()

    def capture_centres(self, camera: Camera) -> NDArray[np.float32]:
        """``(k, 4)`` every cloud's centre and diameter as the billboard shader computed them
        (with the palette bound now), rasteriser off."""
        if self.mode != "impostor":
            raise ValueError("capture needs the impostor mode")
        mgl, ctx = self._mgl, self.ctx
        k = self.scene.n_foliage
        buf = ctx.buffer(reserve=max(k, 1) * 16)
        try:
            assert self.impostor_fbo is not None
            self.impostor_fbo.use()  # a complete framebuffer, or the driver may skip the draw
            ctx.enable_only(mgl.RASTERIZER_DISCARD)
            self.draw(camera, np.zeros(3), np.zeros(3), 0.0, capture=buf)
            ctx.memory_barrier(mgl.SHADER_STORAGE_BARRIER_BIT)
            data = np.frombuffer(buf.read(k * 16), np.float32).reshape(k, 4).copy()
        finally:
            ctx.disable(mgl.RASTERIZER_DISCARD)
            buf.release()
        return data

    def release(self) -> None:
        for vao in self._vaos.values():
            vao.release()
        for prog in self._programs.values():
            prog.release()
        self._vaos.clear()
        self._programs.clear()
        if self.impostor_fbo is not None:
            self.impostor_fbo.release()
        if self.impostor is not None:
            self.impostor.release()
        if self._impostor_depth is not None:
            self._impostor_depth.release()
        for buf in (self.records, self.order, self.vbo, self.ibo):
            buf.release()
        if self.near_order is not None:
            self.near_order.release()
        for tex in self.textures.values():
            tex.release()
