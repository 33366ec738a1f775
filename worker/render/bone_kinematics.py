"""The bone palette rebuilt on the GPU from a scene's rig (:mod:`forest.growth.rig`): a compute
shader (``shaders/palette.comp``) runs forward kinematics one hierarchy level per dispatch and
writes the palette storage buffer that the piece and foliage shaders read (binding 1), so a
frame uploads 16 bytes per turning bone instead of a 64-byte matrix per bone.

``bone_records`` (the static per-bone table, in level order) needs no GL and is tested alone.
"""

from __future__ import annotations

from itertools import pairwise
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from numpy.typing import NDArray

from forest.gl import shaders
from forest.growth.rig import BoneRig

if TYPE_CHECKING:
    import moderngl

# std430 layout of ``struct Bone`` in shaders/palette.comp (two vec4 then four ints: 48 bytes)
BONE_DTYPE = np.dtype(
    [
        ("translation_scale", "<f4", 4),
        ("fixed_rotation", "<f4", 4),
        ("parent", "<i4"),
        ("rotation", "<i4"),
        ("palette", "<i4"),
        ("rest", "<i4"),
    ]
)
LOCAL_SIZE = 64  # layout(local_size_x) of palette.comp
# GL guarantees at least this many work groups per dispatch dimension: a wider level (over
# 4 M bones) is dispatched in slices
MAX_GROUPS = 65535
MAT4_BYTES = 64
QUAT_BYTES = 16
# the compute pass's storage bindings (palette.comp): 0 and 2 are the draws' instances and
# tiles, which SceneBuffers.use binds again after this pass
BONES_BINDING, PALETTE_BINDING, ROTATIONS_BINDING = 0, 1, 2
INVERSE_REST_BINDING, GLOBALS_BINDING = 6, 7


def bone_records(rig: BoneRig) -> NDArray[np.void]:
    """``(b,)`` BONE_DTYPE in level order: each bone's local translation and scale, its fixed
    rotation (roots) or its row of a frame's rotations, its parent's position in this order,
    its palette entry and its inverse rest frame."""
    order, _ = rig.levels
    where = np.empty(len(rig), np.int64)
    where[order] = np.arange(len(rig))
    row = np.full(len(rig), -1, np.int64)
    row[rig.animated] = np.arange(len(rig.animated))
    fixed = np.zeros((len(rig), 4))
    fixed[:, 3] = 1.0
    fixed[rig.root] = rig.root_rotation
    parent = rig.parent[order]
    out = np.zeros(len(rig), BONE_DTYPE)
    out["translation_scale"][:, :3] = rig.translation[order]
    out["translation_scale"][:, 3] = rig.scale[order]
    out["fixed_rotation"] = fixed[order]
    out["parent"] = np.where(parent >= 0, where[np.maximum(parent, 0)], -1)
    out["rotation"] = row[order]
    out["palette"] = order
    out["rest"] = rig.rest[order]
    return out


class PaletteKinematics:
    """Writes the palette of one frame's rotations into ``palette`` (a buffer of at least
    ``len(rig)`` mat4) on the GPU. Leaves storage bindings 0, 1, 2, 6 and 7 changed."""

    def __init__(self, ctx: moderngl.Context, rig: BoneRig, palette: moderngl.Buffer) -> None:
        self.ctx = ctx
        self.palette = palette
        _, starts = rig.levels
        self.levels = [(int(a), int(b - a)) for a, b in pairwise(starts)]
        self.program = ctx.compute_shader(shaders.load("palette.comp"))
        # a zero-size buffer is an error: keep one element in every buffer
        self.bones = ctx.buffer(bone_records(rig).tobytes() or bytes(BONE_DTYPE.itemsize))
        inv = np.ascontiguousarray(np.swapaxes(rig.inv_rest, -1, -2), np.float32)  # GLSL order
        self.inverse_rest = ctx.buffer(inv.tobytes() or bytes(MAT4_BYTES))
        self.globals = ctx.buffer(reserve=max(len(rig), 1) * MAT4_BYTES)
        self.rotations = ctx.buffer(reserve=max(len(rig.animated), 1) * QUAT_BYTES)
        self.n_rotations = len(rig.animated)

    def run(self, rotations: NDArray[np.float32]) -> None:
        """Upload ``rotations`` ``(a, 4)`` xyzw and run every level."""
        import moderngl

        if rotations.shape != (self.n_rotations, 4):
            raise ValueError(f"rotations must be ({self.n_rotations}, 4), got {rotations.shape}")
        if self.n_rotations:
            self.rotations.write(np.ascontiguousarray(rotations, np.float32).tobytes())
        self.bones.bind_to_storage_buffer(BONES_BINDING)
        self.palette.bind_to_storage_buffer(PALETTE_BINDING)
        self.rotations.bind_to_storage_buffer(ROTATIONS_BINDING)
        self.inverse_rest.bind_to_storage_buffer(INVERSE_REST_BINDING)
        self.globals.bind_to_storage_buffer(GLOBALS_BINDING)
        first = cast("Any", self.program["u_first"])
        count = cast("Any", self.program["u_count"])
        for lo, n in self.levels:
            for start in range(lo, lo + n, MAX_GROUPS * LOCAL_SIZE):
                m = min(lo + n - start, MAX_GROUPS * LOCAL_SIZE)
                first.value, count.value = start, m
                self.program.run(group_x=(m + LOCAL_SIZE - 1) // LOCAL_SIZE)
            # the next level reads this one's globals; the draws read the palette
            self.ctx.memory_barrier(moderngl.SHADER_STORAGE_BARRIER_BIT)

    def release(self) -> None:
        for obj in (self.program, self.bones, self.inverse_rest, self.globals, self.rotations):
            obj.release()
