"""Batched 4x4 similarity transforms and quaternions in numpy.

Convention: column vectors, ``p_world = M @ p``. Quaternions are ``(x, y, z, w)`` like USD's
numpy layout. USD's Gf matrices use row vectors, so ``forest.usd`` transposes at the boundary.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]


def translation(t_in: ArrayLike) -> F64:
    """``t : (..., 3)`` -> ``(..., 4, 4)`` translation matrices."""
    t = np.asarray(t_in, dtype=np.float64)
    m = np.zeros((*t.shape[:-1], 4, 4))
    m[..., 0, 0] = m[..., 1, 1] = m[..., 2, 2] = m[..., 3, 3] = 1.0
    m[..., :3, 3] = t
    return m


def scaling(s_in: ArrayLike) -> F64:
    """Uniform scale ``s : (...)`` -> ``(..., 4, 4)``."""
    s = np.asarray(s_in, dtype=np.float64)
    m = np.zeros((*s.shape, 4, 4))
    m[..., 0, 0] = m[..., 1, 1] = m[..., 2, 2] = s
    m[..., 3, 3] = 1.0
    return m


def axis_angle_matrix(axis_in: ArrayLike, angle_in: ArrayLike) -> F64:
    """Rotation about unit ``axis : (..., 3)`` by ``angle : (...)`` radians -> ``(..., 4, 4)``."""
    axis = np.asarray(axis_in, dtype=np.float64)
    angle = np.asarray(angle_in, dtype=np.float64)
    axis = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
    x, y, z = axis[..., 0], axis[..., 1], axis[..., 2]
    c, s = np.cos(angle), np.sin(angle)
    k = 1.0 - c
    shape = np.broadcast_shapes(x.shape, c.shape)
    m = np.zeros((*shape, 4, 4))
    m[..., 0, 0] = c + x * x * k
    m[..., 0, 1] = x * y * k - z * s
    m[..., 0, 2] = x * z * k + y * s
    m[..., 1, 0] = y * x * k + z * s
    m[..., 1, 1] = c + y * y * k
    m[..., 1, 2] = y * z * k - x * s
    m[..., 2, 0] = z * x * k - y * s
    m[..., 2, 1] = z * y * k + x * s
    m[..., 2, 2] = c + z * z * k
    m[..., 3, 3] = 1.0
    return m


def rotation_y(angle: ArrayLike) -> F64:
    """Rotation about +Y (the up axis) by ``angle`` radians."""
    return axis_angle_matrix([0.0, 1.0, 0.0], angle)


def transform_points(m: F64, p_in: ArrayLike) -> F64:
    """``m : (..., 4, 4)``, ``p : (..., k, 3)`` -> ``(..., k, 3)``."""
    p = np.asarray(p_in, dtype=np.float64)
    return np.einsum("...ij,...kj->...ki", m[..., :3, :3], p) + m[..., None, :3, 3]


def transform_vectors(m: F64, v_in: ArrayLike) -> F64:
    """Directions through the linear part, renormalised (valid for similarities)."""
    v = np.asarray(v_in, dtype=np.float64)
    out = np.einsum("...ij,...kj->...ki", m[..., :3, :3], v)
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def invert_similarity(m: F64) -> F64:
    """Inverse of ``(..., 4, 4)`` similarities ``s R | t`` without a general inverse."""
    lin = m[..., :3, :3]
    s2 = np.einsum("...ij,...ij->...j", lin, lin)[..., :1]  # squared column norm = s^2
    inv_lin = np.swapaxes(lin, -1, -2) / s2[..., None]
    out = np.zeros_like(m)
    out[..., :3, :3] = inv_lin
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", inv_lin, m[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


# rows per block of the batched conversions below: their temporaries (a dozen arrays per
# row) stay a few MB however many matrices come in; results are the same row for row
BLOCK = 65536


def similarity_scale(m: F64) -> F64:
    """``(..., 4, 4)`` similarities -> uniform scale ``(...)``, the cube root of the
    linear part's determinant."""
    if m.ndim != 3 or len(m) <= BLOCK:
        return np.cbrt(np.linalg.det(m[..., :3, :3]))
    out = np.empty(len(m))
    for a in range(0, len(m), BLOCK):
        out[a : a + BLOCK] = np.cbrt(np.linalg.det(m[a : a + BLOCK, :3, :3]))
    return out


def decompose_similarity(m: F64) -> tuple[F64, F64, F64]:
    """``(..., 4, 4)`` similarities -> translation ``(..., 3)``, quaternion xyzw ``(..., 4)``,
    uniform scale ``(...)``. A stack of many is done in blocks of :data:`BLOCK` rows."""
    if m.ndim == 3 and len(m) > BLOCK:
        t, q, s = np.empty((len(m), 3)), np.empty((len(m), 4)), np.empty(len(m))
        for a in range(0, len(m), BLOCK):
            t[a : a + BLOCK], q[a : a + BLOCK], s[a : a + BLOCK] = decompose_similarity(
                m[a : a + BLOCK]
            )
        return t, q, s
    lin = m[..., :3, :3]
    scale = similarity_scale(m)
    rot = lin / scale[..., None, None]
    return m[..., :3, 3].copy(), matrix_to_quat(rot), scale


def compose_similarity(t: ArrayLike, q: ArrayLike, s: ArrayLike) -> F64:
    """Inverse of :func:`decompose_similarity`."""
    m = quat_to_matrix(q)
    m[..., :3, :3] *= np.asarray(s, dtype=np.float64)[..., None, None]
    m[..., :3, 3] = np.asarray(t, dtype=np.float64)
    return m


def quat_to_matrix(q_in: ArrayLike) -> F64:
    """Unit quaternions ``(..., 4)`` xyzw -> ``(..., 4, 4)`` rotations."""
    q = np.asarray(q_in, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    m = np.zeros((*q.shape[:-1], 4, 4))
    m[..., 0, 0] = 1 - 2 * (y * y + z * z)
    m[..., 0, 1] = 2 * (x * y - z * w)
    m[..., 0, 2] = 2 * (x * z + y * w)
    m[..., 1, 0] = 2 * (x * y + z * w)
    m[..., 1, 1] = 1 - 2 * (x * x + z * z)
    m[..., 1, 2] = 2 * (y * z - x * w)
    m[..., 2, 0] = 2 * (x * z - y * w)
    m[..., 2, 1] = 2 * (y * z + x * w)
    m[..., 2, 2] = 1 - 2 * (x * x + y * y)
    m[..., 3, 3] = 1.0
    return m


def matrix_to_quat(r_in: ArrayLike) -> F64:
    """Rotation matrices ``(..., 3+, 3+)`` -> unit quaternions xyzw with ``w >= 0``.

    Shepperd's method: pick the largest of the four candidates per matrix so no branch
    divides by a small number.
    """
    r = np.asarray(r_in, dtype=np.float64)[..., :3, :3]
    m00, m11, m22 = r[..., 0, 0], r[..., 1, 1], r[..., 2, 2]
    cand = np.stack(
        [1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22, 1 + m00 + m11 + m22],
        axis=-1,
    )
    pick = np.argmax(cand, axis=-1)
    # each candidate column gives the full quaternion up to a common factor
    qx = np.stack(
        [
            cand[..., 0],
            r[..., 1, 0] + r[..., 0, 1],
            r[..., 0, 2] + r[..., 2, 0],
            r[..., 2, 1] - r[..., 1, 2],
        ],
        axis=-1,
    )
    qy = np.stack(
        [
            r[..., 1, 0] + r[..., 0, 1],
            cand[..., 1],
            r[..., 2, 1] + r[..., 1, 2],
            r[..., 0, 2] - r[..., 2, 0],
        ],
        axis=-1,
    )
    qz = np.stack(
        [
            r[..., 0, 2] + r[..., 2, 0],
            r[..., 2, 1] + r[..., 1, 2],
            cand[..., 2],
            r[..., 1, 0] - r[..., 0, 1],
        ],
        axis=-1,
    )
    qw = np.stack(
        [
            r[..., 2, 1] - r[..., 1, 2],
            r[..., 0, 2] - r[..., 2, 0],
            r[..., 1, 0] - r[..., 0, 1],
            cand[..., 3],
        ],
        axis=-1,
    )
    allq = np.stack([qx, qy, qz, qw], axis=-2)
    q = np.take_along_axis(allq, pick[..., None, None], axis=-2)[..., 0, :]
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    q *= np.where(q[..., 3:] < 0, -1.0, 1.0)
    return q
