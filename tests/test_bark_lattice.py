"""The repeating bark picture of the glTF game profile (forest.bark.lattice): lattice corners
that run on across every edge the walk crosses, quarter turns included, and a super tile
that is the set's bark tiles."""

from __future__ import annotations

import numpy as np
import pytest

from forest.bark.lattice import lattice_st, lattice_uv, super_tile, super_tile_shape
from forest.errors import ForestError
from forest.gltf.primitive import split_corners


def tube(around: int, rings: int) -> np.ndarray:
    """Quads of an upright tube (corners a b c d: u runs a -> d, v runs a -> b, as
    forest.geometry.pieces.QUAD_ST), vertex ``ring * around + j``."""
    quads = []
    for i in range(rings):
        for j in range(around):
            a, d = i * around + j, i * around + (j + 1) % around
            quads.append([a, a + around, d + around, d])
    return np.array(quads)


def agreeing_edges(quads: np.ndarray, st: np.ndarray) -> tuple[int, int]:
    """Shared edges whose two quads give both its vertices the same lattice point, and all
    shared edges."""
    seen: dict[tuple[int, int], tuple[int, int]] = {}
    agree = total = 0
    for q, quad in enumerate(quads):
        for c in range(4):
            x, y = int(quad[c]), int(quad[(c + 1) % 4])
            key = (min(x, y), max(x, y))
            if key in seen:
                p, _ = seen[key]
                other = {int(quads[p][k]): st[p, k] for k in range(4)}
                total += 1
                agree += bool(
                    np.array_equal(other[x], st[q, c])
                    and np.array_equal(other[y], st[q, (c + 1) % 4])
                )
            else:
                seen[key] = (q, c)
    return agree, total


def test_a_tube_splits_only_along_one_seam() -> None:
    quads = tube(8, 5)
    st = lattice_st(quads)
    agree, total = agreeing_edges(quads, st)
    # every edge but the 5 that close the rings (the atlas agrees on none)
    assert (agree, total) == (total - 5, 8 * 5 + 8 * 4)
    src, _, _ = split_corners(quads, lattice_uv(st, 8))
    assert len(src) == 9 * 6  # a ring's seam vertex twice: 9 per ring, 6 rings
    # one cell per quad, whole numbers
    assert np.array_equal(st, np.round(st))
    assert np.allclose(np.ptp(st, axis=1), 1.0)


def test_a_quarter_turn_stops_the_walk() -> None:
    """Two quads whose shared edge is one's top and the other's left side (a neighbour
    turned a quarter, as around a crotch): each keeps its own upright frame (bark runs along
    each branch), so the edge splits; upright neighbours agree."""
    # quad A: corners 0 1 2 3; quad B shares A's top edge (1, 2) as its left side (0 -> 1)
    quads = np.array([[0, 1, 2, 3], [1, 4, 5, 2]])
    quads[1] = [2, 1, 4, 5]  # B turned: its a -> b side runs 2 -> 1
    st = lattice_st(quads)
    assert agreeing_edges(quads, st) == (0, 1)
    assert np.array_equal(st[1], st[0])  # both upright in their own frames
    upright = np.array([[0, 1, 2, 3], [1, 4, 5, 2]])  # B on A's top, the same way up
    assert agreeing_edges(upright, lattice_st(upright)) == (1, 1)


def test_the_walk_is_deterministic() -> None:
    quads = tube(6, 4)
    assert np.array_equal(lattice_st(quads), lattice_st(quads.copy()))


def test_super_tile_holds_each_bark_tile_once() -> None:
    tiles = np.arange(8 * 4 * 4 * 3, dtype=np.uint8).reshape(8, 4, 4, 3)
    picture = super_tile(tiles)
    assert super_tile_shape(8) == (4, 2) and picture.shape == (8, 16, 3)
    for k in range(8):
        r, c = divmod(k, 4)
        assert np.array_equal(picture[4 * r : 4 * r + 4, 4 * c : 4 * c + 4], tiles[k])
    assert super_tile_shape(3) == (3, 1)
    with pytest.raises(ForestError, match="no bark tiles"):
        super_tile_shape(0)
