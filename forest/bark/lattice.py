"""Bark that tiles one repeating picture (the glTF game profile): welded vertices instead of a
vertex per quad corner.

The atlas (:mod:`forest.bark.atlas`) gives every quad its own tile, so neighbouring quads
read different cells and no vertex can be shared. Every tile of the set's ``bark`` class has
the same edge colours on opposite sides (:mod:`forest.bark.tileset`), so any grid of them is
seamless: a *super tile* of the bark tiles, repeated (glTF's default ``REPEAT`` wrap), covers
a tree if each quad's corners get coordinates that run on across its neighbours'. Those come
from a walk over the quads (:func:`lattice_st`): a quad's lattice cell is its neighbour's
moved one step, so the picture continues across every edge the walk crosses. The walk
crosses only edges where both quads stand the same way up (tubes are built upright, so it
runs along and around each branch); where quads meet turned a quarter (around crotches and
apexes) or where a walk closes on itself (around a tube) the two sides disagree, and the
vertex splits there.

What the game form gives up: the fork, crotch and lower-trunk tiles' patterns (every quad
shows bark tiles); the lower trunk keeps its colour as a tint (:func:`lower_tint`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from forest.bark.atlas import udim_slices
from forest.bark.images import srgb_to_linear
from forest.errors import ForestError
from forest.geometry.pieces import QUAD_ST
from forest.geometry.transforms import F64
from schemas.tileset import TileSetManifest

BARK_ID = 1  # the tile class whose tiles wrap both ways (schemas.tileset.CLASS_EDGES)

_CORNERS = QUAD_ST.astype(np.int64)  # (4, 2) a quad's corners in its own frame


def _neighbours(quads: NDArray[np.integer]) -> NDArray[np.int64]:
    """``(q, 4)`` the quad across each side (side i: corners i, i+1), -1 where there is none
    or where more than two quads share the edge."""
    q = len(quads)
    a = np.asarray(quads, np.int64)
    b = np.roll(a, -1, axis=1)
    lo, hi = np.minimum(a, b).ravel(), np.maximum(a, b).ravel()
    order = np.lexsort((hi, lo))
    key_lo, key_hi = lo[order], hi[order]
    same = (key_lo[1:] == key_lo[:-1]) & (key_hi[1:] == key_hi[:-1])
    out = np.full(q * 4, -1, np.int64)
    # an edge held by exactly two sides: pair them (a third holder leaves it unpaired)
    pair = same.copy()
    pair[1:] &= ~same[:-1]
    pair[:-1] &= ~same[1:]
    i = np.flatnonzero(pair)
    out[order[i]] = order[i + 1] // 4
    out[order[i + 1]] = order[i] // 4
    return out.reshape(q, 4)


def _step_table() -> NDArray[np.int64]:
    """``(4, 4, 4, 3)``: for a quad crossing its side ``side`` into a neighbour whose
    corners ``bx``, ``by`` are that side's two vertices, ``[side, bx, by]`` is the
    neighbour's cell less the quad's and 1, where the two stand the same way up (the
    neighbour's side runs the other way along the same line); 0 0 0 otherwise (a quarter
    turn, around crotches and apexes: the walk stops there, so every quad keeps its upright
    frame and bark runs along each branch)."""
    table = np.zeros((4, 4, 4, 3), np.int64)
    for side in range(4):
        d_a = _CORNERS[(side + 1) % 4] - _CORNERS[side]
        for bx in range(4):
            for by in range(4):
                if bx != by and np.array_equal(_CORNERS[by] - _CORNERS[bx], d_a):
                    table[side, bx, by] = (*(_CORNERS[side] - _CORNERS[bx]), 1)
    return table


_STEP = _step_table()


def _lowest_of_parts(n: int, a: NDArray[np.int64], b: NDArray[np.int64]) -> NDArray[np.int64]:
    """``(n,)`` the lowest node of each node's connected part of the graph with edges
    ``a[i] - b[i]`` (min-label hooking and pointer jumping: a few passes over the edges)."""
    label = np.arange(n)
    while True:
        la, lb = label[a], label[b]
        low = np.minimum(la, lb)
        new = label.copy()
        np.minimum.at(new, la, low)
        np.minimum.at(new, lb, low)
        while not np.array_equal(new, new[new]):
            new = new[new]
        if np.array_equal(new, label):
            return label
        label = new


def lattice_st(quads: NDArray[np.integer]) -> F64:
    """``(q, 4, 2)`` integer coordinates of every quad corner on a lattice: a quad spans one
    cell, upright in its own frame (u along its a -> d side, v along a -> b), and two quads
    that share an edge agree on both of its corners wherever a spanning tree of the upright
    neighbours (breadth first from each connected part's lowest quad index) crosses that
    edge. Deterministic for a mesh."""
    quads = np.asarray(quads, np.int64)
    n = len(quads)
    if n == 0:
        return np.zeros((0, 4, 2))
    nbr = _neighbours(quads)
    a = np.repeat(np.arange(n), 4)
    side = np.tile(np.arange(4), n)
    b = nbr.ravel()
    a, side, b = a[b >= 0], side[b >= 0], b[b >= 0]
    x, y = quads[a, side], quads[a, (side + 1) % 4]
    bx = np.argmax(quads[b] == x[:, None], axis=1)
    by = np.argmax(quads[b] == y[:, None], axis=1)
    step = _STEP[side, bx, by]
    keep = step[:, 2] == 1
    a, b, step = a[keep], b[keep], step[keep, :2]
    # breadth first from each connected part's lowest quad, all parts at once, a level at a
    # time; a quad reached from several takes the lowest (deterministic)
    order = np.lexsort((b, a))
    a, b, step = a[order], b[order], step[order]
    first_edge = np.searchsorted(a, np.arange(n + 1))
    shift = np.zeros((n, 2), np.int64)
    reached = np.zeros(n, bool)
    frontier = np.unique(_lowest_of_parts(n, a, b))
    reached[frontier] = True
    while len(frontier):
        count = first_edge[frontier + 1] - first_edge[frontier]
        if not count.sum():
            break
        edge = np.repeat(first_edge[frontier] - np.cumsum(count) + count, count) + np.arange(
            count.sum()
        )
        to = b[edge]
        fresh = ~reached[to]
        edge, to = edge[fresh], to[fresh]
        to, pick = np.unique(to, return_index=True)  # edges come in source order
        edge = edge[pick]
        shift[to] = shift[a[edge]] + step[edge]
        reached[to] = True
        frontier = to
    return (_CORNERS[None] + shift[:, None]).astype(np.float64)


def super_tile_shape(n: int) -> tuple[int, int]:
    """Columns and rows of a super tile of ``n`` tiles (every tile once): two rows where
    ``n`` is even, else one."""
    if n < 1:
        raise ForestError("the tile set has no bark tiles for a repeating bark picture")
    return (n // 2, 2) if n % 2 == 0 and n > 2 else (n, 1)


def super_tile(tiles: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """``(rows * s, columns * s, c)`` the bark-class tiles ``(n, s, s, c)`` in a grid (row
    major, top-left first): seamless when repeated, as every cell is."""
    columns, rows = super_tile_shape(len(tiles))
    s = tiles.shape[1]
    grid = tiles.reshape(rows, columns, s, s, -1)
    return np.ascontiguousarray(grid.transpose(0, 2, 1, 3, 4).reshape(rows * s, columns * s, -1))


def lattice_uv(st: F64, n: int) -> NDArray[np.float32]:
    """Lattice corners ``(q, 4, 2)`` (u around, v up, one cell a quad) -> glTF UVs on the
    repeating super tile of ``n`` tiles (v down the picture)."""
    columns, rows = super_tile_shape(n)
    u = st[..., 0] / columns
    v = -st[..., 1] / rows
    return np.stack([u, v], axis=-1).astype(np.float32)


def bark_tiles(manifest: TileSetManifest) -> slice:
    """The slices of the set's ``bark`` class (id 1): the tiles that repeat seamlessly."""
    cls = next((c for c in manifest.classes if c.id == BARK_ID), None)
    if cls is None:
        raise ForestError("the tile set has no bark class (id 1)", path="tiles")
    return slice(cls.first, cls.first + cls.count)


def lower_tint(slices: NDArray[np.uint8], manifest: TileSetManifest) -> F64 | None:
    """The colour (linear RGB, each channel at most 1) that turns the bark class's mean into
    the lower trunk's (a class that ``stands_for`` bark: birch's black foot, pine's grey-brown
    plates), for glTF's ``COLOR_0``, which readers multiply into the base colour; None where
    the set has no lower trunk. The repeating picture holds the bark class only: the lower
    trunk keeps its colour, not its own tiles' pattern."""
    lower = [c for c in manifest.classes if c.stands_for == BARK_ID]
    if not lower:
        return None

    def mean(cls: slice) -> F64:
        srgb = slices[cls].reshape(-1, slices.shape[-1])[:, :3] / 255.0
        return np.asarray(srgb_to_linear(srgb).mean(axis=0))

    below = mean(slice(lower[0].first, lower[0].first + lower[0].count))
    return np.clip(below / np.maximum(mean(bark_tiles(manifest)), 1e-6), 0.0, 1.0)


def lower_quads(st: F64, manifest: TileSetManifest) -> NDArray[np.bool_]:
    """``(q,)`` the quads whose UDIM st (:func:`forest.usd.materials.tile_udim_st`) lies in a
    lower-trunk class's tiles."""
    k = udim_slices(st)
    out = np.zeros(len(k), bool)
    for c in manifest.classes:
        if c.stands_for is not None:
            out |= (k >= c.first) & (k < c.first + c.count)
    return out
