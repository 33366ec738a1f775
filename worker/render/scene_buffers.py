"""A scene's arrays (:class:`forest.usd.read.SceneArrays`) -> GPU buffers.

================== ============================================================ ==========
buffer             contents                                                      binding
================== ============================================================ ==========
patches (per type) every quad as a patch of 4 vertices: position, normal, st,    attributes
                   joint indices, joint weights (prototype space)
instances          one record per piece instance, sorted by piece type:         SSBO 0
                   transform, bone offset, tile-index offset, scene index, type
palette            the forest's bone palette at the current frame (mat4),       SSBO 1
                   rebuilt from the scene's rig on the GPU (worker.render.bone_kinematics)
tiles              every instance's tile index per quad, instance after         SSBO 2
                   instance (no padding)
================== ============================================================ ==========

The instance records are a storage buffer read at ``u_base_instance + gl_InstanceID`` rather
than divisor-1 vertex attributes: one shader then serves the instanced draw (one call per
piece type, ``u_base_instance`` = the type's first slot) and the naive baseline (one call per
instance), with no rebinding of attribute pointers between draws.

Matrices go to the GPU column-major: GLSL reads a ``mat4`` column by column, so the bytes of
the transpose of a numpy (column-vector, row-major) matrix are exactly the GLSL matrix.

The pure functions here (``patch_vertices``, ``InstanceLayout``, ``gl_matrices``,
``scene_points``, ``scene_bounds``, ``check_scene``) need no GL and are tested alone.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from forest.errors import LimitError, SceneError
from forest.geometry.pieces import QUAD_ST, PieceArrays
from forest.geometry.transforms import F64, transform_points
from forest.usd.contract import (
    BONE_OFFSET,
    BONE_PARENTS,
    JOINT_INDICES,
    JOINT_ROTATIONS,
    PIECE_PROTOTYPES,
    PIECES,
    TILE_INDICES,
    primvar,
)
from forest.usd.read import SceneArrays
from worker.render.bone_kinematics import BONE_DTYPE, MAT4_BYTES, PaletteKinematics
from worker.render.camera import box_corners

if TYPE_CHECKING:
    import moderngl

PATCH_DTYPE = np.dtype(
    [
        ("position", "<f4", 3),
        ("normal", "<f4", 3),
        ("st", "<f4", 2),
        ("joints", "<i4", 4),
        ("weights", "<f4", 4),
    ]
)
PATCH_FORMAT = "3f 3f 2f 4i 4f"
PATCH_ATTRIBUTES = ("in_position", "in_normal", "in_st", "in_joints", "in_weights")
# std430 layout of ``struct Instance`` in shaders/piece.vert (mat4 first: 80 bytes, 16-aligned)
INSTANCE_DTYPE = np.dtype(
    [
        ("transform", "<f4", (4, 4)),
        ("bone_offset", "<i4"),
        ("tile_offset", "<i4"),
        ("id", "<i4"),
        ("piece_type", "<i4"),
    ]
)


def gl_matrices(m: F64) -> NDArray[np.float32]:
    """``(..., 4, 4)`` column-vector matrices -> float32 in GLSL's column-major order."""
    return np.ascontiguousarray(np.swapaxes(np.asarray(m), -1, -2), dtype=np.float32)


def patch_vertices(piece: PieceArrays) -> NDArray[np.void]:
    """``(4 q,)`` PATCH_DTYPE: the corners of every quad in winding order, so patch ``k`` of a
    draw is quad ``k`` of the piece and ``gl_PrimitiveID`` indexes its tile."""
    corners = piece.quads.reshape(-1)
    out = np.empty(len(corners), PATCH_DTYPE)
    out["position"] = piece.positions[corners]
    out["normal"] = piece.normals[corners]
    out["st"] = np.tile(QUAD_ST, (len(piece.quads), 1))
    out["joints"] = piece.joint_indices[corners]
    out["weights"] = piece.joint_weights[corners]
    return out


@dataclass(frozen=True, eq=False)
class InstanceLayout:
    """Instances sorted by piece type, so one draw call covers a type.

    order : (n,) int64, scene index of each sorted slot
    first, count : (p,) int64, the slots of each piece type
    records : (n,) INSTANCE_DTYPE      tiles : (sum of quads,) int32
    """

    order: NDArray[np.int64]
    first: NDArray[np.int64]
    count: NDArray[np.int64]
    records: NDArray[np.void]
    tiles: NDArray[np.int32]

    @classmethod
    def from_scene(cls, scene: SceneArrays) -> InstanceLayout:
        n_types = len(scene.pieces)
        order = np.argsort(scene.proto_indices, kind="stable").astype(np.int64)
        count = np.bincount(scene.proto_indices, minlength=n_types).astype(np.int64)
        first = np.concatenate([[0], np.cumsum(count)[:-1]]).astype(np.int64)
        n_quads = np.array([len(p.quads) for p in scene.pieces], np.int64)
        q = n_quads[scene.proto_indices[order]]
        tile_offset = np.concatenate([[0], np.cumsum(q)[:-1]])
        mask = np.arange(scene.tile_indices.shape[1])[None, :] < q[:, None]
        tiles = np.ascontiguousarray(scene.tile_indices[order][mask], dtype=np.int32)
        rec = np.zeros(len(order), INSTANCE_DTYPE)
        rec["transform"] = gl_matrices(scene.transforms[order])
        rec["bone_offset"] = scene.bone_offset[order]
        rec["tile_offset"] = tile_offset
        rec["id"] = order
        rec["piece_type"] = scene.proto_indices[order]
        return cls(order=order, first=first, count=count, records=rec, tiles=tiles)


def check_scene(scene: SceneArrays, n_slices: int | None = None) -> None:
    """Raise SceneError (naming prim and attribute) where the arrays would make the GPU read
    outside a buffer: joint indices, bone offsets, tile indices, non-finite rotations."""
    n = scene.n_instances
    if n == 0:
        raise SceneError("the forest has no piece instances", path=f"{PIECES}.protoIndices")
    n_bones = scene.n_bones
    top = np.zeros(len(scene.pieces), np.int64)
    for i, p in enumerate(scene.pieces):
        where = f"{PIECE_PROTOTYPES}/{p.name}"
        ji = p.joint_indices
        if ji.size and (ji.min() < 0 or ji.max() >= p.n_joints):
            raise SceneError(
                f"joint indices must lie in [0, {p.n_joints})",
                path=f"{where}.{primvar(JOINT_INDICES)}",
            )
        if not np.isfinite(p.positions).all() or not np.isfinite(p.normals).all():
            raise SceneError("non-finite points or normals", path=f"{where}.points")
        top[i] = int(ji.max()) if ji.size else 0
    last = scene.bone_offset.astype(np.int64) + top[scene.proto_indices]
    bad = np.nonzero((scene.bone_offset < 0) | (last >= n_bones))[0]
    if len(bad):
        raise SceneError(
            f"instance {bad[0]} reaches bone {last[bad[0]]} of a palette of {n_bones}",
            path=f"{PIECES}.{primvar(BONE_OFFSET)}",
        )
    if not np.isfinite(scene.joint_rotations).all():
        raise SceneError("non-finite rotations", path=f"{PIECES}.{JOINT_ROTATIONS}")
    n_quads = np.array([len(p.quads) for p in scene.pieces], np.int64)
    q = n_quads[scene.proto_indices]
    mask = np.arange(scene.tile_indices.shape[1])[None, :] < q[:, None]
    used = np.where(mask, scene.tile_indices, 0)
    limit = n_slices if n_slices is not None else np.iinfo(np.int32).max
    bad = np.nonzero(((used < 0) | (used >= limit)).any(axis=1))[0]
    if len(bad):
        row = used[bad[0]]
        value = int(row[(row < 0) | (row >= limit)][0])
        what = f"the tile set's {n_slices} slices" if n_slices is not None else "int32"
        raise SceneError(
            f"instance {bad[0]} has tile index {value} outside {what}",
            path=f"{PIECES}.{primvar(TILE_INDICES)}",
        )


def scene_points(scene: SceneArrays, frame: int = 0, tree: int | None = None) -> F64:
    """``(m, 3)`` world points enclosing the skinned forest (or its tree ``tree``) at
    ``frame``: every bone of an instance applied to the corners of its piece's box (the
    blended surface lies inside the hull of these, as each skinned vertex is a convex blend of
    its bones' images)."""
    pal = scene.palette(frame)
    boxes = np.stack(
        [np.stack([p.positions.min(axis=0), p.positions.max(axis=0)]) for p in scene.pieces]
    )
    corners = box_corners(boxes[:, 0, None], boxes[:, 1, None])  # (p, 8, 3)
    n_joints = np.array([p.n_joints for p in scene.pieces])
    j = np.arange(n_joints.max())
    out = []
    for t in range(len(scene.pieces)):
        idx = np.nonzero((scene.proto_indices == t) & ((scene.tree == tree) | (tree is None)))[0]
        if not len(idx):
            continue
        bones = pal[scene.bone_offset[idx][:, None] + j[: n_joints[t]]]  # (m, j, 4, 4)
        out.append(transform_points(bones, corners[t]).reshape(-1, 3))
    return np.concatenate(out)


def scene_bounds(scene: SceneArrays, frame: int = 0) -> tuple[F64, F64]:
    """World box ``(lo, hi)`` of :func:`scene_points`."""
    pts = scene_points(scene, frame)
    return pts.min(axis=0), pts.max(axis=0)


class SceneBuffers:
    """GPU buffers of one scene on one context. ``use(frame)`` rebuilds that frame's palette
    on the GPU if it is not the one already there, then binds the storage buffers."""

    def __init__(
        self, ctx: moderngl.Context, scene: SceneArrays, n_slices: int | None = None
    ) -> None:
        """``n_slices``: the slices of the tile images to be bound, if known; tile indices
        must lie within those and within the scene's manifest."""
        check_scene(scene, min(scene.manifest.n_slices, n_slices or scene.manifest.n_slices))
        self.ctx = ctx
        self.scene = scene
        self.layout = InstanceLayout.from_scene(scene)
        n_bones = scene.n_bones
        limit = int(ctx.info.get("GL_MAX_SHADER_STORAGE_BLOCK_SIZE", 2**27))
        for what, size, path in (
            ("the palette", n_bones * MAT4_BYTES, BONE_PARENTS),
            ("the bones", n_bones * BONE_DTYPE.itemsize, BONE_PARENTS),
            ("the instances", self.layout.records.nbytes, "protoIndices"),
            ("the tile indices", self.layout.tiles.nbytes, primvar(TILE_INDICES)),
        ):
            if size > limit:
                raise LimitError(
                    f"{what} need {size / 2**20:.3g} MiB, more than this driver's storage block "
                    f"limit of {limit / 2**20:.3g} MiB: render fewer trees",
                    path=f"{PIECES}.{path}",
                    limit=limit,
                )
        self.n_quads = [len(p.quads) for p in scene.pieces]
        self.patches = [ctx.buffer(patch_vertices(p).tobytes()) for p in scene.pieces]
        self.instances = ctx.buffer(self.layout.records.tobytes())
        self.tiles = ctx.buffer(self.layout.tiles.tobytes())
        self.palette = ctx.buffer(reserve=n_bones * MAT4_BYTES)
        self.kinematics = PaletteKinematics(ctx, scene.rig, self.palette)
        self.frame: int | None = None

    @property
    def n_frames(self) -> int:
        return self.scene.n_frames

    def use(self, frame: int = 0) -> None:
        f = frame % self.n_frames
        if f != self.frame:
            self.kinematics.run(self.scene.joint_rotations[f])
            self.frame = f
        self.bind()

    def bind(self) -> None:
        """Bind the draws' storage buffers (a compute pass in between rebinds some)."""
        self.instances.bind_to_storage_buffer(0)
        self.palette.bind_to_storage_buffer(1)
        self.tiles.bind_to_storage_buffer(2)

    def release(self) -> None:
        self.kinematics.release()
        for b in (*self.patches, self.instances, self.tiles, self.palette):
            b.release()
