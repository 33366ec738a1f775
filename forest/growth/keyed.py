"""Counter-based random numbers keyed per tree and per piece: a tree's draws depend on the
forest's seed and the tree's own identity alone, never on which other trees share its forest
or tile, nor on how many were drawn before it.

A tree has a 64-bit key per stage (:func:`tree_keys`); its root piece takes the tree's key and
each child piece the hash of its parent's key and its rim (:func:`hashes`), so a piece's key
names its path from the root. A draw is splitmix64's output at a stream of a key,
``mix(key + stream * GOLDEN)``: whole levels of many trees are drawn with a few uint64 array
operations, in any order.
"""

from __future__ import annotations

from functools import cache

import numpy as np
from numpy.typing import NDArray

U64 = NDArray[np.uint64]
F64 = NDArray[np.float64]
GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)

# stages: each has keys of its own, so a change in one never reshuffles another
PLACE, GROW = 0, 1


def mix(x: U64) -> U64:
    """splitmix64's finaliser, elementwise, into a new array (uint64 arithmetic wraps)."""
    return _mix_in_place(x.copy())


def _mix_in_place(x: U64) -> U64:
    """:func:`mix` in place, with one work array (fresh temporaries page-fault anew)."""
    t = x >> _S30
    x ^= t
    x *= _M1
    np.right_shift(x, _S27, out=t)
    x ^= t
    x *= _M2
    np.right_shift(x, _S31, out=t)
    x ^= t
    return x


def tree_keys(seed: int, ids: NDArray[np.integer], stage: int) -> U64:
    """``(t,)`` keys of the trees ``ids`` (stable identities: a tree's global placement cell)
    for one ``stage`` of generation."""
    salt = mix(np.array([seed % 2**64], np.uint64) * GOLDEN + np.uint64(stage))
    return mix(np.asarray(ids).astype(np.uint64) * GOLDEN + salt)


@cache
def offsets(stream: int, count: int) -> U64:
    """``(count,)`` what a key adds to reach streams ``stream .. stream + count - 1``
    (read-only: cached)."""
    out = np.array([(stream + k) * int(GOLDEN) % 2**64 for k in range(count)], np.uint64)
    out.setflags(write=False)
    return out


def hashes(keys: U64, stream: int, count: int | None = None) -> U64:
    """Raw 64-bit draws at ``stream`` of each key: ``(m,)``, or ``(m, count)`` for streams
    ``stream .. stream + count - 1``."""
    if count is None:
        return _mix_in_place(keys + offsets(stream, 1)[0])
    return _mix_in_place(keys[:, None] + offsets(stream, count))


def draw(keys: U64, stream: int) -> F64:
    """``(m,)`` uniforms in ``[0, 1)`` with 53 bits, at ``stream`` of each key."""
    h = hashes(keys, stream) >> _S11
    return h.view(np.int64).astype(np.float64) * 2.0**-53


def pairs(keys: U64, stream: int, count: int | None = None) -> F64:
    """Two independent uniforms in ``[0, 1)`` (32 bits each) per draw of :func:`hashes`:
    ``(m, 2)`` or ``(m, count, 2)``; half the hashing of two draws."""
    h = hashes(keys, stream, count)
    u = h.view(np.uint32).reshape(*h.shape, 2).astype(np.float64)
    u *= 2.0**-32
    return u


def lane(h: U64, q: int) -> F64:
    """Uniforms in ``[0, 1)`` of 16 bits from lane ``q`` (0-3) of each hash: four independent
    ones per hash, each a contiguous array of ``h``'s shape (columns of one array of all
    four would be strided, and slow in everything after). 16 bits are 1/65536 of a
    parameter's range, far below anything a tree shows."""
    u = h.view(np.uint16).reshape(*h.shape, 4)[..., q].astype(np.float64)
    u *= 2.0**-16
    return u
