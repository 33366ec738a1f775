"""Per-instance culling and level of detail for whole pieces, on the GPU before the draws.

The tessellation control shader already drops patches outside the view, but every patch of
every instance still runs the vertex and control stages: a forest of 1,000 oaks is 3.9 M
pieces and 140 M patches a frame whatever the camera sees. A compute pass
(``shaders/cull.comp``) tests each instance once, a sphere about its posed skeleton against
the frustum and, optionally, its tube's thickness on screen against ``min_pixels`` (a twig
100 m away is a hundredth of a pixel), and appends the survivors to a list that the
instanced draws read through an indirect command per piece type. What is dropped below
``min_pixels`` is geometry thinner than that on screen; the leaf clouds, drawn apart, hide
most of it anyway.

``piece_bounds`` and ``visible_reference`` (the numpy twin of the shader's rule) need no GL
and are tested alone.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, cast

import numpy as np
from numpy.typing import NDArray

from forest.geometry.pieces import MAX_JOINTS, PieceArrays
from forest.geometry.transforms import F64
from forest.gl import shaders
from worker.render.camera import Camera
from worker.render.staging import SHADOW_SIZE, SunCamera

if TYPE_CHECKING:
    import moderngl

    from worker.render.scene_buffers import SceneBuffers

# what `forest render` and render jobs skip by default: pieces under half a pixel thick, which
# change a distant forest's picture by a few pixels in ten thousand with its leaves drawn
DEFAULT_LOD_PIXELS = 0.5
LOCAL_SIZE = 64  # layout(local_size_x) of cull.comp
MAX_GROUPS = 65535  # work groups GL guarantees per dispatch dimension
# std430 layout of ``struct PieceBound`` in shaders/cull.comp
PIECE_BOUND_DTYPE = np.dtype(
    [
        ("joints", "<f4", (MAX_JOINTS, 4)),
        ("n_joints", "<i4"),
        ("radius", "<f4"),
        ("first", "<i4"),
        ("pad", "<i4"),
    ]
)
COMMAND_DTYPE = np.dtype([(name, "<u4") for name in ("count", "instances", "first", "base", "pad")])
# the pass's storage bindings; SceneBuffers.use and the draws bind 0-2 again, and the piece
# shader reads the visible list at VISIBLE_BINDING
COMMANDS_BINDING, PIECES_BINDING, VISIBLE_BINDING = 3, 6, 7


def tube_radius(piece: PieceArrays) -> float:
    """How far the piece's surface lies from the polyline through its joints at rest (the
    root joint to the hub, the hub to each terminal): its tube radius, flares included."""
    origins = piece.joint_rest[:, :3, 3]
    seg = [(0, 1)] + [(1, j) for j in range(2, piece.n_joints)]
    a = origins[[s for s, _ in seg]]
    b = origins[[e for _, e in seg]]
    ab = b - a
    t = np.einsum("vsk,sk->vs", piece.positions[:, None] - a, ab) / np.maximum(
        np.einsum("sk,sk->s", ab, ab), 1e-30
    )
    nearest = a + np.clip(t, 0.0, 1.0)[..., None] * ab
    return float(np.linalg.norm(piece.positions[:, None] - nearest, axis=2).min(axis=1).max())


def piece_bounds(pieces: tuple[PieceArrays, ...], first: NDArray[np.int64]) -> NDArray[np.void]:
    """``(p,)`` PIECE_BOUND_DTYPE: each piece type's joint origins, tube radius and first
    instance slot (``first``, as :class:`worker.render.scene_buffers.InstanceLayout` sorts them)."""
    out = np.zeros(len(pieces), PIECE_BOUND_DTYPE)
    for t, p in enumerate(pieces):
        out["joints"][t, : p.n_joints, :3] = p.joint_rest[:, :3, 3]
        out["n_joints"][t] = p.n_joints
        out["radius"][t] = tube_radius(p)
        out["first"][t] = first[t]
    return out


def pixel_size(camera: Camera, height: int) -> tuple[bool, float]:
    """``(ortho, size)``: the sun's orthographic view has pixels of ``size`` metres at any
    distance; a perspective view ``size`` metres per pixel per metre of distance."""
    if isinstance(camera, SunCamera):  # square map: the finer of its two pixel sizes
        return True, 2.0 * min(camera.half) / SHADOW_SIZE
    return False, 2.0 * float(np.tan(np.radians(camera.fov_y) / 2)) / max(height, 1)


def visible_reference(
    palette: F64,
    bone_offset: NDArray[np.integer],
    proto_indices: NDArray[np.integer],
    bounds: NDArray[np.void],
    camera: Camera,
    height: int,
    alpha: float,
    min_pixels: float,
) -> NDArray[np.bool_]:
    """``(n,)`` which instances the cull pass keeps (scene order), in float64: the numpy
    twin of ``shaders/cull.comp``."""
    lo = np.full((len(bone_offset), 3), np.inf)
    hi = np.full((len(bone_offset), 3), -np.inf)
    n_joints = bounds["n_joints"][proto_indices]
    joints = bounds["joints"][proto_indices][..., :3].astype(np.float64)
    for j in range(MAX_JOINTS):
        has = n_joints > j
        m = palette[bone_offset[has] + j]
        p = np.einsum("nij,nj->ni", m[:, :3, :3], joints[has, j]) + m[:, :3, 3]
        lo[has] = np.minimum(lo[has], p)
        hi[has] = np.maximum(hi[has], p)
    thick = bounds["radius"][proto_indices] * np.linalg.norm(palette[bone_offset, :3, 0], axis=1)
    c = 0.5 * (lo + hi)
    r = 0.5 * np.linalg.norm(hi - lo, axis=1) + 1.25 * thick * (1.0 + 2.0 * alpha)
    planes = camera.frustum_planes()
    keep = ((c @ planes[:, :3].T + planes[:, 3]) >= -r[:, None]).all(axis=1)
    if min_pixels > 0:
        ortho, size = pixel_size(camera, height)
        depth = (c - camera.eye) @ camera.forward - r
        px = size if ortho else np.maximum(depth, 0) * size
        keep &= ~(2.0 * thick < min_pixels * px)
    return keep


class InstanceCuller:
    """The cull pass of one scene's buffers: ``run`` fills the visible list and the indirect
    commands for one camera; ``draw`` issues one indirect draw per piece type."""

    def __init__(self, ctx: moderngl.Context, buffers: SceneBuffers) -> None:
        self.ctx = ctx
        self.buffers = buffers
        layout = buffers.layout
        self.n = len(layout.order)
        self.program = ctx.compute_shader(shaders.load("cull.comp"))
        bounds = piece_bounds(buffers.scene.pieces, layout.first)
        self.pieces = ctx.buffer(bounds.tobytes())
        self.visible = ctx.buffer(reserve=max(self.n, 1) * 4)
        self.reset = np.zeros(len(layout.count), COMMAND_DTYPE)
        self.reset["count"] = 4 * np.asarray(buffers.n_quads, np.uint32)
        self.commands = ctx.buffer(self.reset.tobytes())

    def run(self, camera: Camera, height: int, alpha: float, min_pixels: float) -> None:
        """Cull for ``camera`` (the palette of the frame must be in place: after
        ``SceneBuffers.use``)."""
        import moderngl

        self.commands.write(self.reset.tobytes())
        self.buffers.instances.bind_to_storage_buffer(0)
        self.buffers.palette.bind_to_storage_buffer(1)
        self.commands.bind_to_storage_buffer(COMMANDS_BINDING)
        self.pieces.bind_to_storage_buffer(PIECES_BINDING)
        self.visible.bind_to_storage_buffer(VISIBLE_BINDING)
        ortho, size = pixel_size(camera, height)
        prog = self.program
        for name, value in (
            ("u_count", self.n),
            ("u_camera", tuple(camera.eye)),
            ("u_forward", tuple(camera.forward)),
            ("u_alpha", alpha),
            ("u_ortho", ortho),
            ("u_pixel", size),
            ("u_min_pixels", min_pixels),
        ):
            cast("Any", prog[name]).value = value
        cast("Any", prog["u_frustum"]).write(camera.frustum_planes().astype("f4").tobytes())
        groups = (self.n + LOCAL_SIZE - 1) // LOCAL_SIZE
        if groups > MAX_GROUPS:  # 4 M instances and more: two dimensions of groups
            prog.run(group_x=MAX_GROUPS, group_y=(groups + MAX_GROUPS - 1) // MAX_GROUPS)
        else:
            prog.run(group_x=max(groups, 1))
        self.ctx.memory_barrier(moderngl.SHADER_STORAGE_BARRIER_BIT | moderngl.COMMAND_BARRIER_BIT)

    def draw(self, vaos: list[moderngl.VertexArray], base: moderngl.Uniform) -> int:
        """One indirect draw per piece type that has instances; returns the calls."""
        import moderngl

        self.visible.bind_to_storage_buffer(VISIBLE_BINDING)
        layout, calls = self.buffers.layout, 0
        for t, vao in enumerate(vaos):
            if layout.count[t] == 0:
                continue
            base.value = int(layout.first[t])
            vao.render_indirect(self.commands, moderngl.PATCHES, count=1, first=t)
            calls += 1
        return calls

    def counts(self) -> NDArray[np.int64]:
        """``(p,)`` instances kept per piece type by the last ``run`` (reads the GPU back)."""
        got = np.frombuffer(self.commands.read(), COMMAND_DTYPE)
        return got["instances"].astype(np.int64)

    def kept(self) -> NDArray[np.int64]:
        """Scene indices of the instances kept by the last ``run``, sorted."""
        layout = self.buffers.layout
        slots = np.frombuffer(self.visible.read(), np.int32)
        runs = [slots[f : f + c] for f, c in zip(layout.first, self.counts(), strict=True) if c]
        return np.sort(layout.order[np.concatenate(runs)]) if runs else np.zeros(0, np.int64)

    def release(self) -> None:
        for obj in (self.program, self.pieces, self.visible, self.commands):
            obj.release()
