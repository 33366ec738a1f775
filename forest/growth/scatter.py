"""Placing trees in an area: a hashed cell grid, each tree's place, heading and scale a hash of
``(seed, cell)``, so any part of the area (a tile) computes its own trees alone.

The area holds ``cols x rows`` cells (near-square, at least ``trees`` of them); a hash of each
cell gives it a rank, and the ``trees`` cells of lowest rank bear a tree. A tree stands in its
cell: ``"poisson"`` keeps it within ``[JITTER_MARGIN, 1 - JITTER_MARGIN]`` of the cell, so
trees stand at least ``2 * JITTER_MARGIN`` cells apart (blue noise at O(1) per tree, with no
sampler to import); ``"grid"`` jitters over the whole cell. A tree's cell index is its stable
identity: growth and pose key their draws on it (:mod:`forest.growth.keyed`), so a tree is the
same whichever tile or forest computes it.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from forest.geometry.transforms import F64, rotation_y, scaling, translation
from forest.growth import keyed

Placement = Literal["poisson", "grid"]
JITTER_MARGIN = 0.15
_MARGIN: dict[str, float] = {"poisson": JITTER_MARGIN, "grid": 0.0}
I64 = NDArray[np.int64]


@dataclass(frozen=True)
class PlacedTrees:
    """Trees a caller placed: ``ids`` ``(t,)`` int64 their stable identities (global cells),
    ``transforms`` ``(t, 4, 4)``, ``seed`` the forest seed their draws are keyed on, ``sizes``
    ``(t,)`` each tree's size relative to the species' mature tree (None: all 1), which
    scales its crown height (the transforms carry its trunk's scale)."""

    ids: I64
    transforms: F64
    seed: int
    sizes: F64 | None = None


# Trees a caller decided (a tile of a tiled forest: forest.growth.tiling); when set,
# place_trees answers them, so generate_forest runs unchanged on given placements.
_PLACED: ContextVar[PlacedTrees | None] = ContextVar("placed_trees", default=None)


@contextmanager
def placed(trees: PlacedTrees) -> Iterator[None]:
    """Within the block, :func:`place_trees` answers ``trees``."""
    token = _PLACED.set(trees)
    try:
        yield
    finally:
        _PLACED.reset(token)


@dataclass(frozen=True)
class CellGrid:
    """The hashed cells of ``trees`` trees over ``area`` (metres) for ``seed``."""

    trees: int
    area: tuple[float, float]
    seed: int

    @property
    def cols(self) -> int:
        width, depth = self.area
        return max(1, math.ceil(math.sqrt(self.trees * width / depth)))

    @property
    def rows(self) -> int:
        return math.ceil(self.trees / self.cols)

    def _keys(self, cell: NDArray[np.uint64]) -> NDArray[np.uint64]:
        return keyed.tree_keys(self.seed, cell, keyed.PLACE)

    def threshold(self) -> np.uint64:
        """The largest rank that bears a tree: exactly ``trees`` cells rank at or below."""
        n_cells = self.rows * self.cols
        rank = keyed.mix(self._keys(np.arange(n_cells, dtype=np.uint64)))
        if n_cells == self.trees:
            return rank.max()
        return np.partition(rank, self.trees - 1)[self.trees - 1]

    def trees_in(
        self,
        rect: tuple[float, float, float, float],
        closed: tuple[bool, bool],
        base_scale: float,
        scale_range: tuple[float, float],
        placement: Placement = "poisson",
        threshold: np.uint64 | None = None,
    ) -> tuple[I64, F64]:
        """The trees standing in ``rect`` ``(x0, x1, z0, z1)`` (area coordinates, half-open
        unless ``closed`` along x, z): cell indices ``(k,)`` ascending and model transforms
        ``(k, 4, 4)`` centred on the area's middle."""
        if placement not in _MARGIN:
            raise ValueError(f"placement must be one of {sorted(_MARGIN)}, got {placement!r}")
        thr = self.threshold() if threshold is None else threshold
        width, depth = self.area
        cw, cd = width / self.cols, depth / self.rows
        x0, x1, z0, z1 = rect
        # cells that can hold a point of the rectangle: the jitter keeps a point in its cell
        c0, c1 = max(0, int(x0 // cw) - 1), min(self.cols, int(x1 // cw) + 2)
        r0, r1 = max(0, int(z0 // cd) - 1), min(self.rows, int(z1 // cd) + 2)
        cols2, rows2 = np.meshgrid(np.arange(c0, c1), np.arange(r0, r1))
        col, row = cols2.ravel(), rows2.ravel()
        key = self._keys((row * self.cols + col).astype(np.uint64))
        keep = keyed.mix(key) <= thr
        margin = _MARGIN[placement]
        span = 1 - 2 * margin
        if self.trees == 1:  # a lone tree stands in the middle
            jx = jz = np.full(len(key), 0.5)
        else:
            jx, jz = keyed.draw(key, 1), keyed.draw(key, 2)
        x = (col + margin + span * jx) * cw
        z = (row + margin + span * jz) * cd
        inside = keep & (x >= x0) & ((x < x1) | closed[0]) & (z >= z0) & ((z < z1) | closed[1])
        cell = (row * self.cols + col)[inside].astype(np.int64)
        order = np.argsort(cell, kind="stable")
        cell, key, x, z = cell[order], key[inside][order], x[inside][order], z[inside][order]
        heading = keyed.draw(key, 3) * 2 * np.pi
        lo, hi = scale_range
        scale = base_scale * (lo + keyed.draw(key, 4) * (hi - lo))
        pos = np.stack([x - width / 2, np.zeros(len(x)), z - depth / 2], axis=-1)
        return cell, translation(pos) @ rotation_y(heading) @ scaling(scale)

    def min_spacing(self, placement: Placement = "poisson") -> float:
        """The least distance between two trees, metres."""
        width, depth = self.area
        return 2 * _MARGIN[placement] * min(width / self.cols, depth / self.rows)


def place_trees(
    n: int,
    area: tuple[float, float],
    base_scale: float,
    scale_range: tuple[float, float],
    seed: int,
    placement: Placement = "poisson",
) -> PlacedTrees:
    """``n`` trees over ``area`` centred on the origin of the XZ plane (or the ones
    :func:`placed` set)."""
    fixed = _PLACED.get()
    if fixed is not None:
        if len(fixed.ids) != n:
            raise ValueError(f"{len(fixed.ids)} placed trees, {n} asked for")
        return fixed
    width, depth = area
    ids, m = CellGrid(n, area, seed).trees_in(
        (0.0, width, 0.0, depth), (True, True), base_scale, scale_range, placement
    )
    return PlacedTrees(ids, m, seed)


def tree_transforms(
    n: int,
    area: tuple[float, float],
    base_scale: float,
    scale_range: tuple[float, float],
    seed: int,
    placement: Placement = "poisson",
) -> F64:
    """``(n, 4, 4)`` model transforms of :func:`place_trees`."""
    return place_trees(n, area, base_scale, scale_range, seed, placement).transforms
