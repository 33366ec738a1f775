"""Minimum-error boundary cut of image quilting (Efros and Freeman 2001; paper 5.2).

Two images ``a`` and ``b`` overlap in a band of ``h`` rows and ``w`` columns. A *cut* is one
column per row, moving at most one column between consecutive rows (8-connected), from the
first row to the last; pixels before the cut (columns ``< path[row]``) come from ``a``, the
rest from ``b``. The minimum-error cut minimises the sum of the error surface along the path,
found by dynamic programming over rows.

Every function takes a stack of bands (``...`` leading axes) and works on all of them at once:
the dynamic programme loops over rows only, each row one numpy step over every band and column.
Errors on integer images are integers, so costs are exact and the cut is the same on every
machine.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray


def squared_error(a: ArrayLike, b: ArrayLike) -> NDArray[np.integer] | NDArray[np.float64]:
    """Per-pixel error surface of two overlapping bands: squared difference summed over
    channels.

    a, b : (..., h, w, c) integer or float
    returns : (..., h, w); int32 for 8-bit inputs (at most 3 * 255**2 per pixel for 3
    channels), int64 for wider integers (exact either way), float64 otherwise
    """
    a = np.asarray(a)
    b = np.asarray(b)
    if a.shape != b.shape:
        raise ValueError(f"bands differ in shape: {a.shape} and {b.shape}")
    if np.issubdtype(a.dtype, np.integer) and np.issubdtype(b.dtype, np.integer):
        small = a.dtype.itemsize == b.dtype.itemsize == 1 and a.shape[-1] <= 1024
        dtype: type = np.int32 if small else np.int64
    else:
        dtype = np.float64
    d = np.subtract(a, b, dtype=dtype)
    d *= d
    return d.sum(axis=-1, dtype=dtype)


def _accumulator(e: NDArray) -> tuple[type, int | float]:
    """The dtype the dynamic programme sums in, and a pad value above every sum."""
    if not (np.issubdtype(e.dtype, np.integer) or e.dtype == np.bool_):
        return np.float64, np.inf
    if e.size and int(e.min()) < 0:
        return np.int64, np.iinfo(np.int64).max
    # int32 halves the memory traffic when no path sum can reach 2**31 - 1
    worst = int(e.max(initial=0)) * e.shape[-2]
    if worst < np.iinfo(np.int32).max // 2:
        return np.int32, np.iinfo(np.int32).max
    return np.int64, np.iinfo(np.int64).max


def min_cut_paths(errors: ArrayLike) -> NDArray[np.int64]:
    """Minimum-error 8-connected top-to-bottom cut through each band.

    errors : (..., h, w) integer or float, h >= 1, w >= 1
    returns : (..., h) int64, the cut's column in each row

    Ties are broken the same way everywhere: the lowest end column wins, and walking back a
    row prefers straight up, then up-left, then up-right.
    """
    e = np.asarray(errors)
    if e.ndim < 2 or e.shape[-1] < 1 or e.shape[-2] < 1:
        raise ValueError(f"errors must be (..., h, w) with h, w >= 1, got shape {e.shape}")
    *batch, h, w = e.shape
    dtype, big = _accumulator(e)
    flat = e.reshape(-1, h, w)
    n = flat.shape[0]
    # acc[i, b, 1 + j]: least cost of a cut from row 0 to (i, j); columns 0 and w + 1 pad
    acc = np.full((h, n, w + 2), big, dtype)
    acc[:, :, 1:-1] = np.moveaxis(flat, 1, 0)
    best: NDArray[Any] = np.empty((n, w), dtype)
    for i in range(1, h):
        prev = acc[i - 1]
        np.minimum(prev[:, :-2], prev[:, 1:-1], out=best)
        np.minimum(best, prev[:, 2:], out=best)
        # the centre is always finite, so ``best`` is too: no overflow past ``big``
        acc[i, :, 1:-1] += best
    paths = np.empty((h, n), np.int64)
    paths[-1] = np.argmin(acc[-1, :, 1:-1], axis=1)
    # walking back: the predecessors of padded column j + 1 in the order centre, left, right,
    # so argmin (first of equal minima) applies the tie rule; ``move`` maps that order back
    flat_rows = acc.reshape(h, n * (w + 2))
    offsets = np.arange(n)[:, None] * (w + 2) + np.array([1, 0, 2])
    move = np.array([0, -1, 1])
    for i in range(h - 1, 0, -1):
        around = flat_rows[i - 1].take(offsets + paths[i][:, None])
        paths[i - 1] = paths[i] + move.take(around.argmin(axis=1))
    return np.moveaxis(paths, 0, 1).reshape(*batch, h)


def path_cost(errors: ArrayLike, paths: ArrayLike) -> NDArray[np.int64] | NDArray[np.float64]:
    """Sum of the error surface along each cut.

    errors : (..., h, w)   paths : (..., h) int
    returns : (...,) int64 for integer errors, float64 otherwise
    """
    e = np.asarray(errors)
    p = np.asarray(paths, dtype=np.int64)
    dtype = np.int64 if np.issubdtype(e.dtype, np.integer) else np.float64
    picked = np.take_along_axis(e.astype(dtype), p[..., None], axis=-1)[..., 0]
    return picked.sum(axis=-1)


def is_connected(paths: ArrayLike, width: int) -> NDArray[np.bool_]:
    """Whether each cut stays inside the band and moves at most one column per row.

    paths : (..., h) int   returns : (...,) bool
    """
    p = np.asarray(paths, dtype=np.int64)
    inside = ((p >= 0) & (p < width)).all(axis=-1)
    return np.asarray(inside & (np.abs(np.diff(p, axis=-1)) <= 1).all(axis=-1))


def cut_mask(paths: ArrayLike, width: int) -> NDArray[np.bool_]:
    """Which band pixels lie before the cut (and so come from image ``a``).

    paths : (..., h) int   returns : (..., h, width) bool, True where column < path[row]
    """
    p = np.asarray(paths, dtype=np.int64)
    return np.asarray(np.arange(width) < p[..., None])
