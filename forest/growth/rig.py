"""Compact wind (issue 12): a forest's bone palette as a rig fixed for the whole clip plus one
rotation per animated bone per frame, turned back into the palette by forward kinematics.

Every bone's local transform is ``Tr(t) @ R(q) @ S(s)`` (UsdSkel's decomposition). Wind and
pose never change ``t`` or ``s`` (a piece's offsets and scales), nor the rotation of an
instance's root bone (the tree's model transform, or the rim twist under its parent's
terminal): only hubs and terminals turn. So a scene stores the parents, ``t``, ``s`` and the
roots' rotations once, and per frame the quaternion of every other bone (float32 xyzw, 16
bytes; two bones in three) instead of a 128-byte matrix per bone.

The palette is ``G @ inv(J)`` with ``G = G_parent @ local`` (``J`` the bone's rest joint frame
in its piece), evaluated a hierarchy level at a time: here in numpy (:meth:`BoneRig.palette`,
the scene reader) and in ``shaders/palette.comp`` (the renderer). A child's root reads the very
``G`` of its parent's terminal, so rims still meet exactly in every frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from forest.geometry import affine
from forest.geometry.pieces import MAX_JOINTS, PieceArrays, skinning_rest_inverse
from forest.geometry.transforms import BLOCK, F64

if TYPE_CHECKING:
    from forest.growth.generate import Forest

I32 = NDArray[np.int32]
F32 = NDArray[np.float32]


@dataclass(frozen=True, eq=False)
class BoneRig:
    """The time-independent part of a forest's bones, in palette order.

    parent : (b,) int32 parent bone, -1 for a tree's root
    translation : (b, 3) local translation ``t``      scale : (b,) local uniform scale ``s``
    root : (n,) int32 the bones whose rotation is fixed (each instance's first bone)
    root_rotation : (n, 4) their rotations, unit quaternions xyzw
    rest : (b,) int32 each bone's row of ``inv_rest``      inv_rest : (r, 4, 4) ``inv(J)``
    """

    parent: I32
    translation: F64
    scale: F64
    root: I32
    root_rotation: F64
    rest: I32
    inv_rest: F64

    def __len__(self) -> int:
        return len(self.parent)

    @cached_property
    def animated(self) -> NDArray[np.intp]:
        """``(a,)`` the bones that turn, in palette order: the rows of a frame's rotations."""
        mask = np.ones(len(self), bool)
        mask[self.root] = False
        return np.flatnonzero(mask)

    @cached_property
    def levels(self) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """``(order, starts)``: every bone sorted by depth in the hierarchy (roots first), level
        ``k`` being ``order[starts[k]:starts[k + 1]]``. Raises ValueError when a parent lies
        outside the palette or some bones hang in a cycle."""
        return hierarchy_levels(self.parent)

    @cached_property
    def _parent_position(self) -> NDArray[np.intp]:
        """``(b,)`` per position of ``order``: the position of that bone's parent (-1 none)."""
        order, _ = self.levels
        where = np.empty(len(self), np.intp)
        where[order] = np.arange(len(self))
        par = self.parent[order]
        return np.where(par >= 0, where[np.maximum(par, 0)], -1)

    @cached_property
    def _inv_rest_soa(self) -> F64:
        return affine.from_matrices(self.inv_rest)

    def rotations_of_all(self, rotations: F64 | F32) -> F64:
        """``(b, 4)`` every bone's rotation: the roots' fixed ones and ``rotations`` ``(a, 4)``
        (one frame) for the rest."""
        q = np.empty((len(self), 4))
        q[self.root] = self.root_rotation
        q[self.animated] = rotations
        return q

    def palette(self, rotations: F64 | F32, row_vectors: bool = False) -> F64:
        """``(b, 4, 4)`` skinning matrices ``G @ inv(J)`` for one frame's ``rotations``
        ``(a, 4)``, by forward kinematics in float64; transposed with ``row_vectors``."""
        order, starts = self.levels
        pp = self._parent_position
        q = self.rotations_of_all(rotations)[order]
        local = np.empty((12, len(self)))
        local[affine.LIN] = quaternion_linear(q) * self.scale[order]
        local[affine.TRANS] = self.translation[order].T
        g = np.empty_like(local)
        for k in range(len(starts) - 1):
            lo, hi = int(starts[k]), int(starts[k + 1])
            if k == 0:  # the trees' roots: their local is their world transform
                g[:, lo:hi] = local[:, lo:hi]
            else:
                affine.compose(np.take(g, pp[lo:hi], axis=1), local[:, lo:hi], out=g[:, lo:hi])
        del local
        pal = affine.compose(g, np.take(self._inv_rest_soa, self.rest[order], axis=1))
        del g
        mats = affine.to_matrices(pal, row_vectors=row_vectors)
        out = np.empty_like(mats)
        out[order] = mats
        return out


def hierarchy_levels(parent: I32) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Bones by depth below their roots (see :attr:`BoneRig.levels`), breadth first from the
    roots through a children table (bones sorted by parent)."""
    b = len(parent)
    if b and (parent.min() < -1 or parent.max() >= b):
        raise ValueError(f"parents must lie in [-1, {b})")
    kids = np.argsort(parent, kind="stable")
    sorted_parent = parent[kids]
    keys = np.arange(-1, b)
    first = np.searchsorted(sorted_parent, keys, side="left")
    last = np.searchsorted(sorted_parent, keys, side="right")
    frontier = kids[first[0] : last[0]]
    levels = [frontier]
    seen = len(frontier)
    while len(frontier):
        lo, hi = first[frontier + 1], last[frontier + 1]
        count = hi - lo
        total = int(count.sum())
        if total == 0:
            break
        # the concatenated ranges [lo, hi) of every bone of the frontier
        start = np.repeat(lo - (np.cumsum(count) - count), count)
        frontier = kids[start + np.arange(total)]
        levels.append(frontier)
        seen += total
    if seen != b:
        raise ValueError(f"{b - seen} bones are not below any root (a cycle of parents)")
    sizes = np.array([len(v) for v in levels], np.intp)
    starts = np.concatenate([[0], np.cumsum(sizes)]).astype(np.intp)
    return np.concatenate(levels).astype(np.intp), starts


def quaternion_linear(q: F64) -> F64:
    """``(9, m)`` rotation matrices (affine SoA rows) of quaternions ``(m, 4)`` xyzw, each
    normalised first (float32 storage leaves them unit only to about 1e-7)."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    x, y, z, w = q.T
    return np.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - z * w),
            2 * (x * z + y * w),
            2 * (x * y + z * w),
            1 - 2 * (x * x + z * z),
            2 * (y * z - x * w),
            2 * (x * z - y * w),
            2 * (y * z + x * w),
            1 - 2 * (x * x + y * y),
        ]
    )


def rest_rows(proto: I32, bone_offset: I32, n_bones: int) -> I32:
    """``(b,)`` each bone's row of :func:`rest_table`: its piece times MAX_JOINTS plus its
    joint (bones ``bone_offset[i] ...`` belong to instance ``i``)."""
    owner = np.repeat(np.arange(len(bone_offset)), np.diff(np.append(bone_offset, n_bones)))
    joint = np.arange(n_bones) - bone_offset[owner]
    return (proto[owner] * MAX_JOINTS + joint).astype(np.int32)


def rest_table(pieces: tuple[PieceArrays, ...]) -> F64:
    """``(p * MAX_JOINTS, 4, 4)`` the inverse rest joint frames of every piece's joints."""
    return skinning_rest_inverse(pieces).reshape(-1, 4, 4)


def forest_rig(forest: Forest) -> BoneRig:
    """The rig of a generated forest (its still pose: wind changes no translation, scale or
    root rotation): the poser's translations and scales without its rotations, and no
    ``(b, 4, 4)`` stack of local matrices."""
    bones = forest.bones
    # rotations are kept at the roots only (hubs and terminals turn with the pose and wind)
    translation, scale, root_rotation = forest.poser().rig_parts()
    return BoneRig(
        parent=bones.parent,
        translation=translation,
        scale=scale,
        root=bones.offset,
        root_rotation=root_rotation,
        rest=rest_rows(forest.graph.piece, bones.offset, len(bones)),
        inv_rest=rest_table(forest.pieces),
    )


def joint_rotations(
    forest: Forest, time: float | None = None, dtype: type[np.floating] = np.float64
) -> NDArray[np.floating]:
    """``(a, 4)`` the turning bones' local rotations (unit xyzw) at ``time`` (None: the still
    pose), one frame as a scene stores it (the rows of :attr:`BoneRig.animated`), in
    ``dtype``. Made a block of instances at a time, so the temporaries stay small whatever
    the forest's size and only the result is new memory."""
    wind = None if time is None else forest.options.wind
    poser, n = forest.poser(), forest.n_instances
    out: NDArray[np.floating] = np.empty((len(forest.bones) - n, 4), dtype)
    row = 0
    for start in range(0, n, BLOCK):
        q = linear_quaternions(
            poser.joint_rotations(wind, time or 0.0, start, min(n, start + BLOCK))
        )
        out[row : row + len(q)] = q
        row += len(q)
    return out


def linear_quaternions(lin: F64) -> F64:
    """``(m, 4)`` unit quaternions xyzw (``w >= 0``) of rotations ``(9, m)`` (affine SoA rows):
    Shepperd's method, every candidate evaluated on whole rows and the largest one kept per
    rotation, so no component comes from a small difference."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = lin
    diag = np.stack(
        [1 + r00 - r11 - r22, 1 - r00 + r11 - r22, 1 - r00 - r11 + r22, 1 + r00 + r11 + r22]
    )
    pick = np.argmax(diag, axis=0)[None]
    xy, xz, yz = r10 + r01, r02 + r20, r21 + r12  # 4xy, 4xz, 4yz
    wx, wy, wz = r21 - r12, r02 - r20, r10 - r01  # 4wx, 4wy, 4wz
    # each component times 4 * the picked one, per choice of the picked one
    out = np.empty((len(r00), 4))
    for k, options in enumerate(
        (
            (diag[0], xy, xz, wx),
            (xy, diag[1], yz, wy),
            (xz, yz, diag[2], wz),
            (wx, wy, wz, diag[3]),
        )
    ):
        out[:, k] = np.take_along_axis(np.stack(options), pick, axis=0)[0]
    out *= (0.5 / np.sqrt(np.take_along_axis(diag, pick, axis=0)[0]))[:, None]
    out[out[:, 3] < 0] *= -1.0
    return out
