"""Tiled forests: a large area cut into square tiles, each generated on its own (any worker,
any order) with placements seamless across tile edges.

Placement is a global jittered grid keyed by cell: the area holds ``cols x rows`` cells
(near-square, at least ``trees`` of them); a hash of ``(seed, cell)`` gives every cell its
jitter, heading, scale and a rank, and the ``trees`` cells of lowest rank bear a tree. A tree
belongs to the tile its position falls in (half-open tile rectangles), so any tile computes
its own trees from the cells under it, with no gap and no tree twice, and the union of the
tiles equals a one-tile plan of the same area bit for bit. The jitter stays within
``[JITTER_MARGIN, 1 - JITTER_MARGIN]`` of a cell, so trees of neighbouring cells, in the same
tile or not, stand at least ``2 * JITTER_MARGIN`` cells apart.

Each tile's growth, pose and bark tiles draw from ``SeedSequence([seed, i, j])``, so a tile's
file depends only on the seed, the plan and its own index.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from forest.errors import ForestError, LimitError
from forest.geometry.transforms import F64, rotation_y, scaling, translation
from forest.growth.generate import MAX_AREA, Forest, ForestOptions, Progress, generate_forest
from forest.growth.scatter import placed
from forest.settings import ForestSettings, get_settings
from schemas.grammar import Grammar
from schemas.jobs import MAX_TILED_TREES, MAX_TILES, tile_grid
from schemas.tileset import DEFAULT_MANIFEST, TileSetManifest

JITTER_MARGIN = 0.15
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


def _mix(x: NDArray[np.uint64]) -> NDArray[np.uint64]:
    """splitmix64's finaliser, elementwise (uint64 arithmetic wraps)."""
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


def _unit(h: NDArray[np.uint64]) -> F64:
    """``[0, 1)`` float64 from the top 53 bits of a hash."""
    return (h >> np.uint64(11)).astype(np.float64) * 2.0**-53


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
    def cols(self) -> int:
        width, depth = self.area
        return max(1, math.ceil(math.sqrt(self.trees * width / depth)))

    @property
    def rows(self) -> int:
        return math.ceil(self.trees / self.cols)

    def _hash(self, cell: NDArray[np.uint64], stream: int) -> NDArray[np.uint64]:
        with np.errstate(over="ignore"):  # uint64 wraps by design
            key = np.array([self.seed], np.uint64) * _GOLDEN + np.uint64(stream)
            return _mix(_mix(cell * _GOLDEN + key))

    def threshold(self) -> np.uint64:
        """The largest rank that bears a tree: exactly ``trees`` cells rank at or below."""
        n_cells = self.rows * self.cols
        rank = self._hash(np.arange(n_cells, dtype=np.uint64), 0)
        if n_cells == self.trees:
            return rank.max()
        return np.partition(rank, self.trees - 1)[self.trees - 1]

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
    ) -> tuple[NDArray[np.int64], F64]:
        """Tile ``(i, j)``'s trees: global cell indices ``(k,)`` int64, ascending, and model
        transforms ``(k, 4, 4)`` float64 centred on the area's middle like
        :func:`forest.growth.scatter.tree_transforms`."""
        if not (0 <= i < self.nx and 0 <= j < self.nz):
            raise ForestError(f"tile ({i}, {j}) is outside {self.nx} x {self.nz}", path="tile")
        thr = self.threshold() if threshold is None else threshold
        width, depth = self.area
        cw, cd = width / self.cols, depth / self.rows
        x0, x1, z0, z1 = self.rect(i, j)
        # cells that can hold a point of the tile: the jitter keeps a point inside its cell
        c0, c1 = max(0, int(x0 // cw) - 1), min(self.cols, int(x1 // cw) + 2)
        r0, r1 = max(0, int(z0 // cd) - 1), min(self.rows, int(z1 // cd) + 2)
        cols2, rows2 = np.meshgrid(np.arange(c0, c1), np.arange(r0, r1))
        col, row = cols2.ravel(), rows2.ravel()
        cell = (row * self.cols + col).astype(np.uint64)
        keep = self._hash(cell, 0) <= thr
        span = 1 - 2 * JITTER_MARGIN
        x = (col + JITTER_MARGIN + span * _unit(self._hash(cell, 1))) * cw
        z = (row + JITTER_MARGIN + span * _unit(self._hash(cell, 2))) * cd
        last_x, last_z = i == self.nx - 1, j == self.nz - 1
        inside = keep & (x >= x0) & ((x < x1) | last_x) & (z >= z0) & ((z < z1) | last_z)
        cell, x, z = cell[inside], x[inside], z[inside]
        order = np.argsort(cell, kind="stable")
        cell, x, z = cell[order], x[order], z[order]
        heading = _unit(self._hash(cell, 3)) * 2 * np.pi
        lo, hi = scale_range
        scale = base_scale * (lo + _unit(self._hash(cell, 4)) * (hi - lo))
        pos = np.stack([x - width / 2, np.zeros(len(x)), z - depth / 2], axis=-1)
        m = translation(pos) @ rotation_y(heading) @ scaling(scale)
        return cell.astype(np.int64), m

    def min_spacing(self) -> float:
        """The least distance between two trees of the plan, metres."""
        width, depth = self.area
        return 2 * JITTER_MARGIN * min(width / self.cols, depth / self.rows)

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
        """Tile ``(i, j)``'s generation seed (63 bits, from the forest's seed and the index)."""
        state = np.random.SeedSequence([self.seed, i, j]).generate_state(2, np.uint64)
        return int(state[0] >> np.uint64(1))


def generate_tile(
    grammar: Grammar,
    plan: TilePlan,
    i: int,
    j: int,
    options: ForestOptions | None = None,
    manifest: TileSetManifest = DEFAULT_MANIFEST,
    settings: ForestSettings | None = None,
    progress: Progress | None = None,
    threshold: np.uint64 | None = None,
) -> Forest | None:
    """Tile ``(i, j)`` of ``plan`` as a forest of its own (its trees at their places in the
    whole area, ``options.trees`` and ``options.area`` taken from the tile); None when no tree
    stands in it."""
    options = options or ForestOptions()
    _, trees = plan.tile_trees(i, j, grammar.trunk_radius, grammar.tree_scale, threshold)
    if len(trees) == 0:
        return None
    tile_options = replace(options, trees=len(trees), area=plan.area)
    with placed(trees):
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
