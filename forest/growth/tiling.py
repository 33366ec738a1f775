"""Tiled forests: a large area cut into square tiles, each generated on its own (any worker,
any order) with placements seamless across tile edges.

Placement is the hashed cell grid of :mod:`forest.growth.scatter` over the whole area: a tree
belongs to the tile its position falls in (half-open tile rectangles), so any tile computes
its own trees from the cells under it, with no gap and no tree twice, and the union of the
tiles equals the untiled forest's placement bit for bit. Each tree's growth and pose are keyed
on the forest's seed and its cell (:mod:`forest.growth.keyed`), so a tiled forest equals the
untiled one tree for tree; a tile's bark tiles and leaf clouds draw from
``SeedSequence([seed, i, j])``, so a tile's file depends only on the seed, the plan and its
own index.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from forest.errors import ForestError, LimitError
from forest.geometry.transforms import F64
from forest.growth.generate import MAX_AREA, Forest, ForestOptions, Progress, generate_forest
from forest.growth.scatter import CellGrid, PlacedTrees, Placement, placed
from forest.settings import ForestSettings, get_settings
from schemas.grammar import Grammar
from schemas.tiles import MAX_TILED_TREES, MAX_TILES, tile_grid
from schemas.tileset import TileSetManifest


@dataclass(frozen=True)
class TilePlan:
    """The tiles and the global cell grid of a tiled forest of ``trees`` over ``area``."""

    trees: int
    area: tuple[float, float]
    tile_size: float
    seed: int

    def __post_init__(self) -> None:
        if not 1 <= self.trees <= MAX_TILED_TREES:
            raise LimitError(
                f"trees must be between 1 and {MAX_TILED_TREES} in a tiled forest, got "
                f"{self.trees}",
                path="trees",
                limit=MAX_TILED_TREES,
            )
        for name, v in zip(("width", "depth"), self.area, strict=True):
            if not (0 < v <= MAX_AREA and math.isfinite(v)):
                raise LimitError(
                    f"area {name} must be in (0, {MAX_AREA:g}] metres, got {v}",
                    path=f"area.{name}",
                    limit=MAX_AREA,
                )
        if not (math.isfinite(self.tile_size) and self.tile_size > 0):
            raise ForestError(
                f"tile_size must be a positive number of metres, got {self.tile_size}",
                path="tile_size",
            )
        if self.nx * self.nz > MAX_TILES:
            raise LimitError(
                f"{self.nx} x {self.nz} tiles exceed the cap of {MAX_TILES}; use a larger "
                "tile_size",
                path="tile_size",
                limit=MAX_TILES,
            )

    @property
    def nx(self) -> int:
        return tile_grid(self.area, self.tile_size)[0]

    @property
    def nz(self) -> int:
        return tile_grid(self.area, self.tile_size)[1]

    def tiles(self) -> Iterator[tuple[int, int]]:
        """Every tile index ``(i, j)`` (``i`` along x, ``j`` along z), row by row."""
        for j in range(self.nz):
            for i in range(self.nx):
                yield i, j

    @property
    def cells(self) -> CellGrid:
        """The forest's placement cells (the same as the untiled forest's)."""
        return CellGrid(self.trees, self.area, self.seed)

    def threshold(self) -> np.uint64:
        """The largest cell rank that bears a tree (see :meth:`CellGrid.threshold`)."""
        return self.cells.threshold()

    def rect(self, i: int, j: int) -> tuple[float, float, float, float]:
        """Tile ``(i, j)``'s ``x0, x1, z0, z1`` in area coordinates (``[0, width]``)."""
        width, depth = self.area
        s = self.tile_size
        return i * s, min((i + 1) * s, width), j * s, min((j + 1) * s, depth)

    def tile_trees(
        self,
        i: int,
        j: int,
        base_scale: float,
        scale_range: tuple[float, float],
        threshold: np.uint64 | None = None,
        placement: Placement = "poisson",
    ) -> tuple[NDArray[np.int64], F64]:
        """Tile ``(i, j)``'s trees: global cell indices ``(k,)`` int64, ascending, and model
        transforms ``(k, 4, 4)`` float64 centred on the area's middle like
        :func:`forest.growth.scatter.tree_transforms`."""
        if not (0 <= i < self.nx and 0 <= j < self.nz):
            raise ForestError(f"tile ({i}, {j}) is outside {self.nx} x {self.nz}", path="tile")
        return self.cells.trees_in(
            self.rect(i, j),
            (i == self.nx - 1, j == self.nz - 1),
            base_scale,
            scale_range,
            placement,
            threshold,
        )

    def min_spacing(self, placement: Placement = "poisson") -> float:
        """The least distance between two trees of the plan, metres."""
        return self.cells.min_spacing(placement)

    def meta(self) -> dict[str, object]:
        """The plan as JSON (the root layer's ``forest:tiling``)."""
        return {
            "trees": self.trees,
            "area": list(self.area),
            "tile_size": self.tile_size,
            "seed": self.seed,
            "tiles": [self.nx, self.nz],
        }

    def tile_seed(self, i: int, j: int) -> int:
        """Tile ``(i, j)``'s own seed (63 bits, from the forest's seed and the index): its bark
        tiles and leaf clouds."""
        state = np.random.SeedSequence([self.seed, i, j]).generate_state(2, np.uint64)
        return int(state[0] >> np.uint64(1))


def generate_tile(
    grammar: Grammar,
    plan: TilePlan,
    i: int,
    j: int,
    options: ForestOptions | None = None,
    manifest: TileSetManifest | None = None,
    settings: ForestSettings | None = None,
    progress: Progress | None = None,
    threshold: np.uint64 | None = None,
) -> Forest | None:
    """Tile ``(i, j)`` of ``plan`` as a forest of its own (its trees at their places in the
    whole area, ``options.trees`` and ``options.area`` taken from the tile); None when no tree
    stands in it."""
    options = options or ForestOptions()
    ids, trees = plan.tile_trees(
        i, j, grammar.trunk_radius, grammar.tree_scale, threshold, options.placement
    )
    if len(trees) == 0:
        return None
    tile_options = replace(options, trees=len(trees), area=plan.area)
    with placed(PlacedTrees(ids, trees, plan.seed)):
        return generate_forest(
            grammar,
            plan.tile_seed(i, j),
            tile_options,
            manifest,
            settings or get_settings(),
            progress,
        )


def tile_name(i: int, j: int) -> str:
    """A tile's file stem: ``<i>_<j>``."""
    return f"{i}_{j}"
