"""The tile grid of a tiled forest: its caps and how many tiles cover an area. Shared by the
request models (:mod:`schemas.jobs`), the library's tile planner (:mod:`forest.growth.tiling`)
and the job store, so all three count the same tiles."""

from __future__ import annotations

import math

MAX_TILED_TREES = 10_000_000  # the plan hashes every cell: 80 MB at this cap
MAX_TILES = 100_000


def tile_grid(area: tuple[float, float], tile_size: float) -> tuple[int, int]:
    """How many tiles along x and z cover ``area`` with squares of ``tile_size`` metres."""
    return max(1, math.ceil(area[0] / tile_size)), max(1, math.ceil(area[1] / tile_size))
