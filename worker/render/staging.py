"""Staging around the forest: a sky gradient behind it and a ground under it (issue 11), and
in the staged mode (:data:`STAGED`) sun shadows, multisampling and a filmic tone map.

Sky and ground are drawn first, into the renderer's framebuffer: the sky without depth, the
ground with it, so trees (whose bases stand at y = 0) and their leaf clouds cover them where
they should. The ground is a square at y = 0 centred under the camera's target,
:data:`worker.render.camera.GROUND_SPAN` camera-target distances to either side, shaded with the
bark's sun, sky ambient and fog (shaders ``ground.*``, ``sky.*``).

Staged frames (``shadows``, ``msaa``, ``tone_map``): a depth map from the sun (a
:class:`SunCamera`, orthographic, fitted to the part of the scene's box the view sees; branches
and leaf-cloud billboards cast, with a slope-scaled polygon offset against acne), sampled with
3x3 bilinear PCF by the bark and the ground (``STAGED`` in shaders ``piece.frag``,
``ground.frag``); the frame is drawn unclamped into a multisampled half-float buffer, resolved,
and tone-mapped (ACES fit, shaders ``tonemap.*``) into the renderer's 8-bit colour.

A mixed forest's terrain (:class:`TerrainMesh`, its root layer's /World/Terrain) is drawn
after the ground, with the ground's shading (``TERRAIN`` in shaders ``ground.*``: its own
normals, lit and shadowed like the ground); the ground square then lies just under the
terrain's lowest point, so the meadow goes on past the stand's edge. It is drawn in the bare
mode too (a :class:`Staging` without ground or sky).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from forest.geometry.transforms import F64
from forest.gl import shaders
from worker.render.camera import GROUND_SPAN, Camera, box_corners, look_at

if TYPE_CHECKING:
    import moderngl

ZENITH = np.array([0.16, 0.30, 0.62])  # linear


SHADOW_SIZE = 2048  # texels per side of the sun's depth map
# slope-scaled depth bias of the shadow pass (glPolygonOffset factor, units): no acne on faces
# grazing the sun, while a constant bias of a few depth units keeps the trunk base's shadow
# attached (no peter-panning)
SHADOW_OFFSET = (2.0, 4.0)
EXPOSURE = 0.9  # before the ACES fit: keeps mid-greys where the bare mode has them


@dataclass(frozen=True)
class Staging:
    """What to draw around the scene: ``ground`` (the meadow at y = 0) and ``sky`` (a
    gradient instead of the flat sky colour); ``shadows`` from the sun, ``msaa`` samples per
    pixel (0: none) and the filmic ``tone_map`` make the staged mode (:data:`STAGED`)."""

    ground: bool = True
    sky: bool = True
    shadows: bool = False
    msaa: int = 0
    tone_map: bool = False

    @property
    def hdr(self) -> bool:
        """Whether frames go through the half-float buffer and the tone-map pass."""
        return self.shadows or self.msaa > 0 or self.tone_map


STAGED = Staging(ground=True, sky=True, shadows=True, msaa=4, tone_map=True)


@dataclass(frozen=True)
class SunCamera(Camera):
    """An orthographic camera looking along ``-sun``: ``eye`` far up the sun's direction (so
    billboards and ``u_camera`` distances behave), ``half`` = (x, y) half-extent in metres of
    the view box about its axis; ``near``, ``far`` bound the casters along the view."""

    half: tuple[float, float] = (1.0, 1.0)

    def projection(self) -> F64:
        hx, hy = self.half
        n, f = self.near, self.far
        m = np.eye(4)
        m[0, 0], m[1, 1] = 1.0 / hx, 1.0 / hy
        m[2, 2] = -2.0 / (f - n)
        m[2, 3] = -(f + n) / (f - n)
        return m


def sun_camera(camera: Camera, lo: F64, hi: F64, sun: F64) -> SunCamera:
    """The sun's view fitted to what ``camera`` sees of the box ``[lo, hi]`` (the scene's trees
    and the ground under them): the box of the view frustum's corners clamped into the scene's
    box is what receives shadows, seen along the sun; the whole scene box casts."""
    corners_ndc = box_corners(-np.ones(3), np.ones(3))
    inv = np.linalg.inv(camera.view_projection())
    h = np.c_[corners_ndc, np.ones(8)] @ inv.T
    frustum = h[:, :3] / h[:, 3:4]
    seen = np.clip(frustum, lo, hi)
    receivers = box_corners(seen.min(axis=0), seen.max(axis=0))
    centre = 0.5 * (seen.min(axis=0) + seen.max(axis=0))
    radius = max(float(np.linalg.norm(hi - lo)), 1e-3)
    eye = centre + sun * (2.0 * radius)
    rot = look_at(eye, centre)
    rel = (receivers - centre) @ rot[:3, :3].T
    half = np.maximum(np.abs(rel[:, :2]).max(axis=0) * 1.02, 1e-3)
    depth = -((box_corners(lo, hi) - eye) @ rot[2, :3])  # distance along the view
    near = max(float(depth.min()) - 0.01 * radius, 1e-3)
    far = float(depth.max()) + 0.01 * radius
    return SunCamera(eye, centre, 1.0, 1.0, near, far, (float(half[0]), float(half[1])))


# the ground square lies this far under a terrain's lowest point (no z-fighting where they meet)
TERRAIN_CLEARANCE = 0.05


@dataclass(frozen=True, eq=False)
class TerrainMesh:
    """A terrain as triangles: world ``points`` ``(p, 3)``, unit vertex ``normals`` ``(p, 3)``
    and ``triangles`` ``(t, 3)`` indices."""

    points: F64
    normals: F64
    triangles: NDArray[np.int32]

    @classmethod
    def from_quads(cls, points: ArrayLike, quads: ArrayLike) -> TerrainMesh:
        """Quads ``(q, 4)`` (counter-clockwise seen from above) split in two triangles each;
        vertex normals are the area-weighted sum of the faces', turned to face up."""
        pts = np.asarray(points, np.float64).reshape(-1, 3)
        q = np.asarray(quads, np.int64).reshape(-1, 4)
        if len(q) and (q.min() < 0 or q.max() >= len(pts)):
            raise ValueError(f"terrain quads index outside its {len(pts)} points")
        if not np.isfinite(pts).all():
            raise ValueError("non-finite terrain points")
        tris = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]]).astype(np.int32)
        a, b, c = pts[tris[:, 0]], pts[tris[:, 1]], pts[tris[:, 2]]
        face = np.cross(b - a, c - a)
        face[face[:, 1] < 0] *= -1
        normals = np.zeros_like(pts)
        for k in range(3):
            np.add.at(normals, tris[:, k], face)
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        normals = np.where(length > 0, normals / np.maximum(length, 1e-30), [0.0, 1.0, 0.0])
        return cls(pts, normals, tris)

    @property
    def low(self) -> float:
        return float(self.points[:, 1].min()) if len(self.points) else 0.0


def _set(prog: moderngl.Program, values: dict[str, Any]) -> None:
    for name, value in values.items():
        if name in prog:
            cast("moderngl.Uniform", prog[name]).value = value


class StageRenderer:
    """Draws :class:`Staging` for a camera into the bound framebuffer; attribute-less draws,
    and ``terrain`` (if given) from its vertex and index buffers."""

    def __init__(
        self, ctx: moderngl.Context, staging: Staging, terrain: TerrainMesh | None = None
    ) -> None:
        import moderngl

        self.ctx = ctx
        self.staging = staging
        self.terrain = terrain
        self._mgl = moderngl
        make: Any = ctx.program
        self.programs: dict[str, moderngl.Program] = {}
        self.vaos: dict[str, moderngl.VertexArray] = {}
        for name, wanted in (("sky", staging.sky), ("ground", staging.ground)):
            if wanted:
                defines = {"STAGED": True} if name == "ground" and staging.shadows else None
                if name == "ground" and terrain is not None:
                    defines = {**(defines or {}), "UNDER_TERRAIN": True}
                prog = make(**shaders.sources(name, defines))
                self.programs[name] = prog
                self.vaos[name] = ctx.vertex_array(prog, [])
        self._terrain_objects: list[Any] = []
        if terrain is not None and len(terrain.triangles):
            variant = {"TERRAIN": True, "STAGED": staging.shadows}
            prog = make(**shaders.sources("ground", variant))
            vertices = np.ascontiguousarray(np.c_[terrain.points, terrain.normals], np.float32)
            vbo = ctx.buffer(vertices.tobytes())
            ibo = ctx.buffer(np.ascontiguousarray(terrain.triangles, np.int32).tobytes())
            self.programs["terrain"] = prog
            self.vaos["terrain"] = ctx.vertex_array(
                prog, [(vbo, "3f 3f", "in_position", "in_normal")], index_buffer=ibo
            )
            self._terrain_objects = [vbo, ibo]
        self.shadow: moderngl.Texture | None = None
        self.shadow_fbo: moderngl.Framebuffer | None = None
        if staging.shadows:
            self.shadow = ctx.depth_texture((SHADOW_SIZE, SHADOW_SIZE))
            self.shadow.compare_func = "<="
            self.shadow.filter = (moderngl.LINEAR, moderngl.LINEAR)  # bilinear PCF taps
            self.shadow.repeat_x = self.shadow.repeat_y = False
            self.shadow_fbo = ctx.framebuffer(depth_attachment=self.shadow)
        self.tonemap: moderngl.Program | None = None
        self.tonemap_vao: moderngl.VertexArray | None = None
        if staging.hdr:
            self.tonemap = make(**shaders.sources("tonemap"))
            self.tonemap_vao = ctx.vertex_array(self.tonemap, [])

    def begin_shadows(self) -> moderngl.Framebuffer:
        """Bind and clear the sun's depth map, polygon offset on; draw the casters next."""
        assert self.shadow_fbo is not None
        fbo = self.shadow_fbo
        fbo.use()
        fbo.viewport = (0, 0, SHADOW_SIZE, SHADOW_SIZE)
        fbo.clear(depth=1.0)
        self.ctx.enable_only(self._mgl.DEPTH_TEST)
        self.ctx.polygon_offset = SHADOW_OFFSET
        return fbo

    def end_shadows(self) -> None:
        self.ctx.polygon_offset = (0.0, 0.0)

    def shadow_uniforms(self, light: SunCamera | None, unit: int) -> dict[str, Any]:
        """What a ``STAGED`` program samples the depth map with (the map bound to ``unit``)."""
        if light is None or self.shadow is None:
            return {}
        self.shadow.use(unit)
        return {
            "u_shadow": unit,
            "u_shadow_texel": 2.0 * max(light.half) / SHADOW_SIZE,
        }

    def write_light(self, prog: moderngl.Program, light: SunCamera | None) -> None:
        if light is not None and "u_light_vp" in prog:
            m = light.view_projection().T.astype("f4")
            cast("moderngl.Uniform", prog["u_light_vp"]).write(m.tobytes())

    def tone_map(self, frame: moderngl.Texture, target: moderngl.Framebuffer) -> None:
        """The resolved half-float ``frame`` through the ACES fit into ``target``."""
        assert self.tonemap is not None and self.tonemap_vao is not None
        target.use()
        self.ctx.enable_only(0)
        frame.use(0)
        _set(self.tonemap, {"u_frame": 0, "u_exposure": EXPOSURE})
        self.tonemap_vao.render(self._mgl.TRIANGLES, vertices=3)

    def draw(
        self,
        camera: Camera,
        sun: F64,
        sky: F64,
        fog: float,
        light: SunCamera | None = None,
        ground_half: float | None = None,
    ) -> None:
        """Sky, then ground (shadowed by ``light``'s depth map when staged; ``ground_half``
        metres to either side, else GROUND_SPAN camera-target distances); leaves depth
        testing on, as the branch pass wants it."""
        mgl, ctx = self._mgl, self.ctx
        if "sky" in self.programs:
            rows = look_at(camera.eye, camera.target)[:3, :3]  # right, up, back
            tan_v = float(np.tan(np.deg2rad(camera.fov_y) / 2))
            _set(
                self.programs["sky"],
                {
                    "u_right": tuple(rows[0]),
                    "u_up": tuple(rows[1]),
                    "u_forward": tuple(-rows[2]),
                    "u_tan_half": (tan_v * camera.aspect, tan_v),
                    "u_sky": tuple(sky),
                    "u_zenith": tuple(ZENITH),
                },
            )
            ctx.disable(mgl.DEPTH_TEST)
            self.vaos["sky"].render(mgl.TRIANGLES, vertices=3)
        ctx.enable(mgl.DEPTH_TEST)
        if "ground" in self.programs:
            prog = self.programs["ground"]
            dist = float(np.linalg.norm(camera.target - camera.eye))
            _set(
                prog,
                {
                    "u_centre": (float(camera.target[0]), float(camera.target[2])),
                    "u_half": GROUND_SPAN * dist if ground_half is None else ground_half,
                    "u_camera": tuple(camera.eye),
                    "u_sun": tuple(sun),
                    "u_sky": tuple(sky),
                    "u_fog": fog,
                    **self.shadow_uniforms(light, 2),
                },
            )
            if self.terrain is not None:  # under the terrain: its lowest point, a little lower
                _set(prog, {"u_height": self.terrain.low - TERRAIN_CLEARANCE})
            self.write_light(prog, light)
            vp = camera.view_projection().T.astype("f4")
            cast("moderngl.Uniform", prog["u_view_projection"]).write(vp.tobytes())
            self.vaos["ground"].render(mgl.TRIANGLE_STRIP, vertices=4)
        if "terrain" in self.programs:
            prog = self.programs["terrain"]
            _set(
                prog,
                {
                    "u_camera": tuple(camera.eye),
                    "u_sun": tuple(sun),
                    "u_sky": tuple(sky),
                    "u_fog": fog,
                    **self.shadow_uniforms(light, 2),
                },
            )
            self.write_light(prog, light)
            vp = camera.view_projection().T.astype("f4")
            cast("moderngl.Uniform", prog["u_view_projection"]).write(vp.tobytes())
            self.vaos["terrain"].render(mgl.TRIANGLES)

    def release(self) -> None:
        for vao in self.vaos.values():
            vao.release()
        for prog in self.programs.values():
            prog.release()
        for obj in (self.shadow_fbo, self.shadow, self.tonemap_vao, self.tonemap):
            if obj is not None:
                obj.release()
        for obj in self._terrain_objects:
            obj.release()
        self._terrain_objects.clear()
        self.vaos.clear()
        self.programs.clear()
