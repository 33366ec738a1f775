"""Placing trees in an area: Poisson-disk (scipy's QMC engine) or a jittered grid, and each
tree's random model transform (rotation about +Y, uniform scale)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from typing import Literal

import numpy as np

from forest.geometry.transforms import F64, rotation_y, scaling, translation

Placement = Literal["poisson", "grid"]
# Poisson-disk sampling is O(n) with a large constant in Python; past this many trees the
# jittered grid looks the same from any viewpoint and is instant.
POISSON_MAX_TREES = 5_000
# Transforms a caller decided (a tile of a tiled forest: forest.growth.tiling); when set,
# tree_transforms answers them, so generate_forest runs unchanged on given placements.
_PLACED: ContextVar[F64 | None] = ContextVar("placed_trees", default=None)


@contextmanager
def placed(transforms: F64) -> Iterator[None]:
    """Within the block, :func:`tree_transforms` answers ``transforms`` ``(n, 4, 4)``."""
    token = _PLACED.set(transforms)
    try:
        yield
    finally:
        _PLACED.reset(token)


def jittered_grid(n: int, width: float, depth: float, rng: np.random.Generator) -> F64:
    """``(n, 2)`` points in ``[0, width] x [0, depth]``: one per cell of a near-square grid."""
    cols = max(1, int(np.ceil(np.sqrt(n * width / max(depth, 1e-9)))))
    rows = int(np.ceil(n / cols))
    cell = rng.permutation(rows * cols)[:n]
    jitter = rng.random((n, 2))
    return np.stack(
        [(cell % cols + jitter[:, 0]) * width / cols, (cell // cols + jitter[:, 1]) * depth / rows],
        axis=-1,
    )


def poisson_disk(n: int, width: float, depth: float, rng: np.random.Generator) -> F64:
    """``(n, 2)`` points at least a fixed distance apart, the distance chosen so ``n`` fit;
    falls back to a jittered grid for whatever the disk sampler could not place."""
    if n == 0:
        return np.zeros((0, 2))
    # scipy.stats takes about a second to import: pay it only when the disk sampler runs
    from scipy.stats import qmc

    aspect = np.array([width, depth]) / max(width, depth)
    # packing density of random Poisson-disk sets is ~0.7 of the hexagonal optimum
    radius = 0.75 * np.sqrt(aspect.prod() / n)
    engine = qmc.PoissonDisk(d=2, radius=radius, l_bounds=[0, 0], u_bounds=aspect, seed=rng)
    pts = engine.random(n)[:n] / aspect * np.array([width, depth])
    if len(pts) < n:
        pts = np.concatenate([pts, jittered_grid(n - len(pts), width, depth, rng)])
    return pts


def tree_transforms(
    n: int,
    area: tuple[float, float],
    base_scale: float,
    scale_range: tuple[float, float],
    rng: np.random.Generator,
    placement: Placement = "poisson",
) -> F64:
    """``(n, 4, 4)`` model transforms of ``n`` trees centred on the origin of the XZ plane
    (or the ones :func:`placed` set)."""
    fixed = _PLACED.get()
    if fixed is not None:
        if len(fixed) != n:
            raise ValueError(f"{len(fixed)} placed trees, {n} asked for")
        return fixed
    width, depth = area
    if n == 1:
        xy = np.array([[width / 2, depth / 2]])
    elif placement == "poisson" and n <= POISSON_MAX_TREES:
        xy = poisson_disk(n, width, depth, rng)
    else:
        xy = jittered_grid(n, width, depth, rng)
    pos = np.stack([xy[:, 0] - width / 2, np.zeros(n), xy[:, 1] - depth / 2], axis=-1)
    heading = rng.random(n) * 2 * np.pi
    scale = base_scale * (scale_range[0] + rng.random(n) * (scale_range[1] - scale_range[0]))
    return translation(pos) @ rotation_y(heading) @ scaling(scale)
