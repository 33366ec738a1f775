"""Linear-blend skinning of piece instances with a forest's bone palette, for tests.

A palette entry maps prototype (model-space) points straight to world space (``G @ inv(J)``),
so a vertex lands at ``sum_j w_j * P[offset + joint_j] @ p`` and its normal goes through the
inverse transpose of that weighted blend matrix.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from pxr import Usd, UsdGeom, UsdSkel, Vt

from forest.geometry.pieces import PieceArrays
from forest.growth.generate import Forest
from forest.usd.skinned import dcc_joints

F64 = NDArray[np.float64]


def blend_matrices(
    palette: F64,
    offsets: NDArray[np.integer],
    piece: PieceArrays,
    verts: NDArray[np.integer] | None = None,
) -> F64:
    """``(m, v, 4, 4)`` weighted blend matrix of every vertex ``verts`` (all if None) of ``m``
    instances of ``piece`` whose first bones are ``offsets : (m,)``."""
    idx = np.arange(len(piece.positions)) if verts is None else np.asarray(verts)
    ji = piece.joint_indices[idx]  # (v, 4)
    jw = piece.joint_weights[idx]  # (v, 4)
    mats = palette[np.asarray(offsets)[:, None, None] + ji[None]]  # (m, v, 4, 4, 4)
    return np.einsum("vk,mvkab->mvab", jw, mats)


def skin(
    palette: F64,
    offsets: NDArray[np.integer],
    piece: PieceArrays,
    verts: NDArray[np.integer] | None = None,
) -> tuple[F64, F64]:
    """Skinned positions and unit normals ``(m, v, 3)`` of ``verts`` of ``m`` instances."""
    idx = np.arange(len(piece.positions)) if verts is None else np.asarray(verts)
    blend = blend_matrices(palette, offsets, piece, idx)
    lin = blend[..., :3, :3]
    pos = np.einsum("mvab,vb->mva", lin, piece.positions[idx]) + blend[..., :3, 3]
    inv_t = np.swapaxes(np.linalg.inv(lin), -1, -2)
    nrm = np.einsum("mvab,vb->mva", inv_t, piece.normals[idx])
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    return pos, nrm


def skin_forest(forest: Forest, palette: F64) -> tuple[list[F64], list[F64]]:
    """Skinned positions and normals of every instance of ``forest`` (lists indexed by
    instance), batched per piece type."""
    n = forest.n_instances
    pos: list[F64] = [np.empty((0, 3))] * n
    nrm: list[F64] = [np.empty((0, 3))] * n
    for pid, piece in enumerate(forest.pieces):
        inst = np.nonzero(forest.graph.piece == pid)[0]
        if len(inst) == 0:
            continue
        p, q = skin(palette, forest.bones.offset[inst], piece)
        for k, i in enumerate(inst):
            pos[i] = p[k]
            nrm[i] = q[k]
    return pos, nrm


def cut_palette(forest: Forest, palette: F64, budget: int | None) -> F64:
    """``palette`` as the skinned forms with ``budget`` joints per tree apply it: every bone
    moves from the still pose as its kept joint does (``P_k(t) P_k(still)^-1 P_b(still)``,
    ``k`` the joint's bone), so a dropped bone's piece follows its kept ancestor rigidly."""
    dcc = dcc_joints(forest, budget)
    still = forest.palette()
    kept = dcc.bone[dcc.of_bone]
    return palette[kept] @ np.linalg.inv(still[kept]) @ still


def bbox_diagonal(points: F64) -> float:
    return float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))


def usd_skinned_points(root: Usd.Prim, mesh: str, frame: float) -> F64:
    """``(v, 3)`` world points of the mesh ``mesh`` under the SkelRoot ``root`` at ``frame``
    as USD's own skinning (UsdSkel, what every DCC follows) puts them."""
    cache = UsdSkel.Cache()
    cache.Populate(UsdSkel.Root(root), Usd.PrimDefaultPredicate)
    skel = UsdSkel.Skeleton(root.GetChild("Skeleton"))
    query = cache.GetSkelQuery(skel)
    tc = Usd.TimeCode(frame)
    points = Vt.Vec3fArray(UsdGeom.Mesh(root.GetChild(mesh)).GetPointsAttr().Get(tc))
    skin = cache.GetSkinningQuery(root.GetChild(mesh))
    assert skin.ComputeSkinnedPoints(query.ComputeSkinningTransforms(tc), points, tc)
    m = np.asarray(UsdGeom.Xformable(skel).ComputeLocalToWorldTransform(tc)).T
    return np.asarray(points, np.float64) @ m[:3, :3].T + m[:3, 3]
