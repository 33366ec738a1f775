"""Batched affine transforms in structure-of-arrays layout, for the hot loops of posing.

An affine batch is ``(12, n)`` float64: the top three rows of the 4x4 column-vector matrices,
row-major (``r00 r01 r02 tx r10 r11 r12 ty r20 r21 r22 tz``), so converting to ``(n, 4, 4)``
is one strided copy. A linear batch (rotations) is ``(9, n)``: ``r00 r01 r02 r10 ... r22``.
Composition is ``einsum`` over contiguous rows, which numpy runs as SIMD sum-of-products
loops in a handful of calls: several times faster than ``np.matmul`` on ``(n, 4, 4)`` stacks,
whose per-matrix inner loop is scalar, and than one ufunc call per multiply-add.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]
LIN = np.array([0, 1, 2, 4, 5, 6, 8, 9, 10])  # rows of an affine batch holding the linear part
TRANS = np.array([3, 7, 11])


def from_matrices(m: F64) -> F64:
    """``(n, 4, 4)`` column-vector matrices -> ``(12, n)``."""
    return np.ascontiguousarray(m[:, :3, :].reshape(len(m), 12).T)


def to_matrices(a: F64, out: F64 | None = None, row_vectors: bool = False) -> F64:
    """``(12, n)`` -> ``(n, 4, 4)``, written into ``out`` (contiguous) if given; with
    ``row_vectors`` the matrices are transposed (the convention of USD's Gf types)."""
    n = a.shape[1]
    if out is None:
        out = np.empty((n, 4, 4))
    if row_vectors:  # a strided copy: twice as fast as scattering 12 flat columns
        out[:, :, :3] = a.reshape(3, 4, n).transpose(2, 1, 0)
        out[:, :, 3] = (0.0, 0.0, 0.0, 1.0)
    else:
        flat = out.reshape(n, 16)
        flat[:, :12] = a.T
        flat[:, 12:] = (0.0, 0.0, 0.0, 1.0)
    return out


def compose(a: F64, b: F64, out: F64 | None = None) -> F64:
    """``a @ b`` for affine batches ``(12, n)``, written into ``out`` if given (any ``(12, n)``
    view, e.g. columns of a larger batch)."""
    n = a.shape[1]
    if out is None:
        out = np.empty((12, n))
    # one einsum over the (3, 3) x (3, 4) products: a few calls instead of sixty ufunc calls,
    # which dominate at the few thousand columns a depth level of a block holds
    out3 = np.reshape(out, (3, 4, n), copy=False)  # raises rather than write to a copy
    np.einsum("ikn,kjn->ijn", a.reshape(3, 4, n)[:, :3], b.reshape(3, 4, n), out=out3)
    out[TRANS] += a[TRANS]
    return out


def compose_linear(a: F64, b: F64) -> F64:
    """``a @ b`` for linear batches ``(9, n)``."""
    n = a.shape[1]
    return np.einsum("ikn,kjn->ijn", a.reshape(3, 3, n), b.reshape(3, 3, n)).reshape(9, n)


def apply_linear(a: F64, v: F64) -> F64:
    """Linear batch ``(9, n)`` times vectors ``(3, n)`` -> ``(3, n)``."""
    n = a.shape[1]
    return np.einsum("ikn,kn->in", a.reshape(3, 3, n), v)


def transpose_linear(a: F64) -> F64:
    """Transposes of a linear batch ``(9, n)`` (inverse rotations)."""
    return a[[0, 3, 6, 1, 4, 7, 2, 5, 8]]


def cos_sin(angle: F64) -> tuple[F64, F64]:
    """Cosine and sine of ``angle`` ``(n,)``, a unit pair to double precision.

    Evaluated in float32, which numpy vectorises (about fifteen times faster than its scalar
    float64 libm calls on this kind of machine), after reducing the angle modulo 2 pi in
    float64, then renormalised in float64: the pair is exactly that of an angle within 3e-7
    rad of the one asked, and rotations built from it are orthonormal to 1e-16. Pose and wind
    angles are random or sampled, so the difference is no loss.
    """
    if len(angle) and np.abs(angle).max() > 2 * np.pi:
        angle = np.remainder(angle, 2 * np.pi)
    a = angle.astype(np.float32)
    c = np.cos(a).astype(np.float64)
    s = np.sin(a).astype(np.float64)
    inv = 1.0 / np.sqrt(c * c + s * s)  # c, s are far from overflow: no need for hypot
    c *= inv
    s *= inv
    return c, s


def axis_angle(axis: F64, angle: F64) -> F64:
    """``(9, n)`` rotations about unit axes ``(3, n)`` by ``angle`` ``(n,)`` radians."""
    x, y, z = axis
    c, s = cos_sin(angle)
    k = 1.0 - c
    xk, yk, zk = x * k, y * k, z * k
    xs, ys, zs = x * s, y * s, z * s
    return np.stack(
        [
            c + x * xk,
            y * xk - zs,
            z * xk + ys,
            x * yk + zs,
            c + y * yk,
            z * yk - xs,
            x * zk - ys,
            y * zk + xs,
            c + z * zk,
        ]
    )


def horizontal_rotation(azimuth: F64, angle: F64) -> F64:
    """``(9, n)`` rotations by ``angle`` about the horizontal axis ``(cos az, 0, sin az)``."""
    x, z = cos_sin(azimuth)
    c, s = cos_sin(angle)
    out = np.empty((9, len(c)))
    xk = x * (1.0 - c)
    np.multiply(x, xk, out=out[0])
    out[0] += c  # c + x x k
    np.multiply(z, s, out=out[3])  # z s
    np.negative(out[3], out=out[1])
    np.multiply(xk, z, out=out[2])  # x z k
    out[6] = out[2]
    out[4] = c
    np.multiply(x, s, out=out[7])  # x s
    np.negative(out[7], out=out[5])
    np.multiply(z, z * (1.0 - c), out=out[8])
    out[8] += c  # c + z z k
    return out
