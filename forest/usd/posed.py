"""Posed piece instances: per piece instance, the similarity (rotation, uniform scale,
translation) that best fits its skinned vertices in least squares (Umeyama), for the
``posed`` representation that DCCs show without knowing ``forest:bonePalette``.

A piece's skinned vertex is ``q_v = sum_j w_vj M_j P_v`` (``M_j`` the palette matrix of its
joint ``j``, ``P_v`` the homogeneous prototype-space point), so the moments the fit needs are
linear in the palette: ``sum_v q_v P_v^T = sum_j M_j W_j`` with ``W_j = sum_v w_vj P_v P_v^T``
precomputed per prototype. The fit therefore costs a few 4x4 products and one 3x3 SVD per
instance, never a pass over the vertices.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from forest.geometry.pieces import MAX_JOINTS, PieceArrays
from forest.geometry.transforms import F64, matrix_to_quat

CHUNK = 65536  # instances per batch: bounds the (chunk, 3, 4) gathers
# rows per (rows, 4) @ (4, 4) product: OpenBLAS runs one this small on the calling thread
# (m n k <= 4 * 65536); its threads on a shared 2-core machine took 1 to 80 times as long
BLAS_ROWS = 16384


@dataclass(frozen=True)
class PieceMoments:
    """Per prototype: ``w`` (p, MAX_JOINTS, 4, 4) float64 ``sum_v w_vj P_v P_v^T / n_v``,
    ``mean`` (p, 3) the vertex centroid, ``var`` (p,) the mean squared distance to it,
    ``joints`` (p,) how many of its joints (the first ones) weigh anything."""

    w: F64
    mean: F64
    var: F64
    joints: NDArray[np.int64]


def piece_moments(pieces: tuple[PieceArrays, ...]) -> PieceMoments:
    w = np.zeros((len(pieces), MAX_JOINTS, 4, 4))
    mean = np.zeros((len(pieces), 3))
    var = np.zeros(len(pieces))
    for k, p in enumerate(pieces):  # a handful of prototypes
        hom = np.c_[p.positions, np.ones(len(p.positions))]
        outer = hom[:, :, None] * hom[:, None, :]
        dense = np.zeros((len(hom), MAX_JOINTS))
        np.add.at(dense, (np.arange(len(hom))[:, None], p.joint_indices), p.joint_weights)
        w[k] = np.einsum("vj,vab->jab", dense, outer) / len(hom)
        mean[k] = p.positions.mean(axis=0)
        var[k] = ((p.positions - mean[k]) ** 2).sum(axis=1).mean()
    weighs = np.abs(w).reshape(len(pieces), MAX_JOINTS, -1).max(axis=2) > 0
    joints = np.array([int(np.flatnonzero(row).max()) + 1 if row.any() else 0 for row in weighs])
    return PieceMoments(w, mean, var, joints)


def fit_posed(
    moments: PieceMoments,
    proto: NDArray[np.int32],
    bone_offset: NDArray[np.int32],
    palette: F64,
) -> tuple[F64, F64, F64]:
    """Best-fit similarities of every instance to its skinned vertices.

    proto, bone_offset : (n,) int; palette : (b, 4, 4) column-vector skinning matrices.
    Returns translations (n, 3), quaternions (n, 4) xyzw, uniform scales (n,), all float64.
    """
    n = len(proto)
    t_out, q_out, s_out = np.zeros((n, 3)), np.zeros((n, 4)), np.zeros(n)
    top = palette[:, :3, :]  # only the rows the moments need are gathered
    used = moments.joints
    for a in range(0, n, CHUNK):
        z = min(n, a + CHUNK)
        pr = proto[a:z]
        s = np.empty((z - a, 3, 4))
        # per prototype and joint one (k * 3, 4) @ (4, 4) product, summed over the joints in
        # their order: the very sums of a (3, 4) @ (4, 4) product per instance and joint (a
        # BLAS call each, most of the fit's time) with the prototype's unused joints, which
        # weigh 0 (an einsum contracts in another order, which moves float64 ulps that flip
        # a few float32 roundings among millions of samples)
        for k in range(len(used)):
            idx = np.flatnonzero(pr == k)
            if not len(idx):
                continue
            first = bone_offset[a + idx]
            acc = _rows_times(top[first], moments.w[k, 0])
            for j in range(1, int(used[k])):
                acc += _rows_times(top[first + j], moments.w[k, j])
            s[idx] = acc
        p_mean = moments.mean[pr]
        q_mean = s[:, :3, 3]
        h = s[:, :3, :3] - q_mean[:, :, None] * p_mean[:, None, :]
        r = polar_rotation(h)
        scale = np.einsum("nab,nab->n", r, h) / moments.var[pr]
        t_out[a:z] = q_mean - scale[:, None] * np.einsum("nab,nb->na", r, p_mean)
        q_out[a:z] = matrix_to_quat(r)
        s_out[a:z] = scale
    return t_out, q_out, s_out


def _rows_times(m: F64, w: F64) -> F64:
    """``(k, 3, 4) @ (4, 4)`` as ``(3 k, 4) @ (4, 4)`` products of at most
    :data:`BLAS_ROWS` rows."""
    rows = m.reshape(-1, 4)
    out = np.empty_like(rows)
    for a in range(0, len(rows), BLAS_ROWS):
        np.matmul(rows[a : a + BLAS_ROWS], w, out=out[a : a + BLAS_ROWS])
    return out.reshape(-1, 3, 4)


def polar_rotation(h: F64, iterations: int = 8) -> F64:
    """The rotation ``(n, 3, 3)`` nearest each ``h`` (its orthogonal polar factor, so
    ``tr(R^T h)`` is largest): scaled Newton ``X <- (g X + X^-T / g) / 2`` with
    ``g = |det X|^(-1/3)``, on cofactors (no batched SVD, several times faster). The nine
    entries are separate rows of n (structure of arrays), so each step is a few dozen
    whole-row products with no cross products, stacks or small-matrix loops.
    The rare ``h`` with ``det <= 0`` (a reflection, never a skinned piece) take the SVD."""
    x = np.ascontiguousarray(h.transpose(1, 2, 0))  # (3, 3, n): x[i, k] is entry (i, k)
    _, det_h = _cofactors(x)
    x = x / np.maximum(np.abs(det_h), 1e-300) ** (1 / 3)
    for _ in range(iterations):
        cof, det = _cofactors(x)
        g = np.abs(det) ** (-1 / 3)
        x = 0.5 * (g * x + cof / det / g)  # cof / det is X^-T
    out = np.ascontiguousarray(x.transpose(2, 0, 1))
    bad = ~(det_h > 0)
    if bad.any():
        u, _, vt = np.linalg.svd(h[bad])
        d = np.sign(np.linalg.det(u @ vt))
        u[:, :, 2] *= d[:, None]
        out[bad] = u @ vt
    return out


def _cofactors(x: F64) -> tuple[F64, F64]:
    """The cofactor matrices ``(3, 3, n)`` of ``x`` (rows of n) and the determinants
    ``(n,)``: cofactor column k is the cross product of the other two columns."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = x
    c = np.empty_like(x)
    c[0, 0] = a11 * a22 - a21 * a12
    c[1, 0] = a21 * a02 - a01 * a22
    c[2, 0] = a01 * a12 - a11 * a02
    c[0, 1] = a12 * a20 - a22 * a10
    c[1, 1] = a22 * a00 - a02 * a20
    c[2, 1] = a02 * a10 - a12 * a00
    c[0, 2] = a10 * a21 - a20 * a11
    c[1, 2] = a20 * a01 - a00 * a21
    c[2, 2] = a00 * a11 - a10 * a01
    return c, a00 * c[0, 0] + a10 * c[1, 0] + a20 * c[2, 0]
