"""Placing a mixed stand: which species stands where, how big, never too close to another.

Dart throwing, layer by layer in tiers: canopy layers first (their trees interleaved, so no
species takes the best ground before another), then edge layers, then the understorey, which
sees the light the canopy leaves (:func:`light_map`). A candidate spot comes from its layer's
own random stream; it is kept with the chance the layer gives it there (density map x light
x nearness to the border) if it meets the layer's terrain rules and no trunk stands closer
than the larger of the two trees' spacings. Counts are exact (shares are met to the tree), so
a failing spot is redrawn, up to :data:`TRIES_PER_TREE` times per tree before the recipe is
refused as too dense for its area.

Everything is drawn over the whole area from the seed alone, so every tile of a tiled stand
computes the same placement and keeps the trees that stand in it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from forest.errors import ForestError, LimitError
from forest.geometry.transforms import rotation_y, scaling, translation
from forest.stand.terrain import Heightfield
from schemas.grammar import Grammar
from schemas.recipe import SIZE_MAX, SIZE_MIN, Recipe, RecipeLayer

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
TRIES_PER_TREE = 400
CHECKS_PER_TREE = 16  # spacing checks per tree of the stand (1-5 in use; near jamming, more)
MIN_SPACING_M = 0.5
UNDERSTOREY_LIGHT = 0.35
CROWN_OPACITY = 0.6  # one crown lets 40 % of the light through; two, 16 %
MAX_STAND_TREES = 200_000
TIERS = ("canopy", "edge", "understorey")
BATCH = 512

# Crown radius (metres) of each shipped species at size 1 in a closed stand: narrower than
# open-grown (SPECIES.md gives those), as neighbours crowd it. Spacing defaults to it.
CROWN_RADIUS_M = {
    "oak": 6.5,
    "birch": 3.0,
    "pine": 3.5,
    "spruce": 3.0,
    "willow": 5.0,
    "poplar": 2.0,
    "hazel": 2.0,
    "almond": 3.0,
    "alternating": 2.0,
    "uniform": 2.0,
}


@dataclass(frozen=True)
class LayerTrees:
    """One layer's trees: global ids ``(t,)`` (ascending), positions ``(t, 3)`` (their
    bases on the ground), headings ``(t,)`` radians and sizes ``(t,)``."""

    ids: I64
    positions: F64
    headings: F64
    sizes: F64

    def __len__(self) -> int:
        return len(self.ids)

    def transforms(self, trunk_radius: float) -> F64:
        """``(t, 4, 4)`` model transforms: base on the ground, trunk upright, scale
        ``trunk_radius x size``."""
        return (
            translation(self.positions)
            @ rotation_y(self.headings)
            @ scaling(trunk_radius * self.sizes)
        )

    def within(
        self,
        rect: tuple[float, float, float, float],
        closed: tuple[bool, bool],
        area: tuple[float, float],
    ) -> LayerTrees:
        """The trees standing in ``rect`` ``(x0, x1, z0, z1)``, area coordinates from the
        area's corner (``[0, width]``; half-open unless ``closed`` along x, z), as a tile
        (:class:`forest.growth.tiling.TilePlan`) cuts it."""
        x = self.positions[:, 0] + area[0] / 2
        z = self.positions[:, 2] + area[1] / 2
        x0, x1, z0, z1 = rect
        keep = (x >= x0) & ((x < x1) | closed[0]) & (z >= z0) & ((z < z1) | closed[1])
        return LayerTrees(
            self.ids[keep], self.positions[keep], self.headings[keep], self.sizes[keep]
        )


@dataclass(frozen=True)
class Placement:
    """A stand's trees, layer by layer (the recipe's order), and the ground's light."""

    layers: tuple[LayerTrees, ...]
    light: F64
    """``(rows, cols)`` light over the area after the canopy (1 = open sky)."""

    @property
    def trees(self) -> int:
        return sum(len(t) for t in self.layers)


def crown_radius(layer: RecipeLayer, grammar: Grammar) -> float:
    """Metres: the layer's crown radius at size 1 in a stand."""
    if layer.preset is not None and layer.preset in CROWN_RADIUS_M:
        return CROWN_RADIUS_M[layer.preset]
    if grammar.crown is not None:
        return 0.25 * sum(grammar.crown.height) / 2
    return 2.0


def layer_counts(recipe: Recipe, trees: int, area: tuple[float, float]) -> list[int]:
    """Each layer's number of trees: its share of ``trees`` (largest remainders, so they sum
    to ``trees``) or its density over the area."""
    if recipe.by_density:
        hectares = area[0] * area[1] / 10_000
        return [round((layer.density or 0.0) * hectares) for layer in recipe.layers]
    want = [trees * (layer.share or 0.0) for layer in recipe.layers]
    counts = [math.floor(w) for w in want]
    order = sorted(range(len(want)), key=lambda k: (counts[k] - want[k], k))
    for k in order[: trees - sum(counts)]:
        counts[k] += 1
    return counts


def _sizes(layer: RecipeLayer, n: int, rng: np.random.Generator) -> F64:
    dist = layer.size
    if dist.range is not None:
        lo, hi = dist.range
        s = lo + rng.random(n) * (hi - lo)
    else:
        mean, sd = dist.normal or (1.0, 0.0)
        s = mean + sd * rng.standard_normal(n)
    return np.clip(s, SIZE_MIN, SIZE_MAX)


def _sample_map(grid: F64, area: tuple[float, float], x: F64, z: F64) -> F64:
    """Nearest value of ``grid`` (rows, cols; row 0 at the area's -z edge) at area-corner
    coordinates ``x``, ``z``."""
    rows, cols = grid.shape
    w, d = area
    c = np.clip((x / w * cols).astype(np.int64), 0, cols - 1)
    r = np.clip((z / d * rows).astype(np.int64), 0, rows - 1)
    return np.asarray(grid[r, c], np.float64)


class _Stream:
    """A layer's candidate spots, drawn in batches from its own generator, each with the
    chance the layer keeps it there."""

    def __init__(
        self,
        layer: RecipeLayer,
        rng: np.random.Generator,
        area: tuple[float, float],
        ground: Heightfield,
        density: F64 | None,
        light: F64 | None,
    ) -> None:
        self.layer, self.rng, self.area, self.ground = layer, rng, area, ground
        self.density, self.light = density, light
        self.buf: list[tuple[float, float, float]] = []
        self.drawn = 0
        self.slots: tuple[F64, F64] | None = None  # an orchard's planting slots, in order

    def _batch(self) -> None:
        w, d = self.area
        layer = self.layer
        x = self.rng.random(BATCH) * w
        z = self.rng.random(BATCH) * d
        keep_u = self.rng.random(BATCH)
        if layer.rows is not None:  # an orchard: spots on rows along x
            n_rows = max(1, int(d // layer.rows))
            margin = (d - (n_rows - 1) * layer.rows) / 2
            z = margin + np.floor(z / d * n_rows) * layer.rows
            if layer.spacing is not None:  # planted: slots along each row, the block filled
                x, z = self._slots(n_rows, margin)
        chance = np.ones(BATCH)
        if self.density is not None:
            chance *= _sample_map(self.density, self.area, x, z)
        if layer.role == "edge":
            border = np.minimum.reduce([x, w - x, z, d - z])
            chance *= np.exp(-border / layer.edge_width)
        if self.light is not None and layer.role != "canopy":
            lit = _sample_map(self.light, self.area, x, z)
            if layer.role == "understorey":  # more where more light reaches the ground
                least = UNDERSTOREY_LIGHT if layer.light is None else layer.light
                chance *= np.where(lit >= least, lit, 0.0)
            elif layer.light is not None:
                chance *= lit >= layer.light
        cx, cz = x - w / 2, z - d / 2
        y = self.ground.height(cx, cz)
        if layer.altitude is not None:
            lo, hi = layer.altitude
            chance *= (y >= lo) & (y <= hi)
        if layer.slope is not None:
            lo, hi = layer.slope
            s = self.ground.slope(cx, cz)
            chance *= (s >= lo) & (s <= hi)
        ok = keep_u < chance
        fresh = list(zip(x[ok].tolist(), z[ok].tolist(), y[ok].tolist(), strict=True))
        fresh.reverse()  # pop() from the end takes them in drawn order
        self.buf = fresh + self.buf
        self.drawn += BATCH

    def _slots(self, n_rows: int, margin: float) -> tuple[F64, F64]:
        """The next :data:`BATCH` planting slots (rows ``rows`` apart, ``spacing`` apart along
        a row), nearest the area's middle first (a square block), then row by row."""
        w, d = self.area
        rows, spacing = self.layer.rows or 1.0, self.layer.spacing or 1.0
        if self.slots is None:
            n_cols = max(1, int(w // spacing))
            x_margin = (w - (n_cols - 1) * spacing) / 2
            zz, xx = np.meshgrid(
                margin + np.arange(n_rows) * rows,
                x_margin + np.arange(n_cols) * spacing,
                indexing="ij",
            )
            xx, zz = xx.ravel(), zz.ravel()
            ring = np.maximum(np.abs(xx - w / 2) / w, np.abs(zz - d / 2) / d)
            order = np.lexsort((xx, zz, np.round(ring, 9)))
            self.slots = (xx[order], zz[order])
        xs, zs = self.slots
        take = np.arange(self.drawn, self.drawn + BATCH) % len(xs)
        return xs[take], zs[take]

    def next(self, budget: int) -> tuple[float, float, float] | None:
        while not self.buf:
            if self.drawn >= budget:
                return None
            self._batch()
        return self.buf.pop()


class _Spacing:
    """Trunks placed so far, one hash of cells per layer, each as wide as the layer's
    largest spacing: a check scans a few cells of each layer whatever the other layers'
    spacings (a single grid as wide as the largest spacing would hold thousands of small
    trees per cell)."""

    def __init__(self, cells: list[float]) -> None:
        self.size = cells
        self.grids: list[dict[tuple[int, int], list[tuple[float, float, float]]]] = [
            {} for _ in cells
        ]
        self.checks = 0

    def free(self, x: float, z: float, r: float) -> bool:
        self.checks += 1
        for cell, grid in zip(self.size, self.grids, strict=True):
            if not grid:
                continue
            reach = math.ceil(max(r, cell) / cell)
            ci, cj = int(x // cell), int(z // cell)
            for i in range(ci - reach, ci + reach + 1):
                for j in range(cj - reach, cj + reach + 1):
                    for px, pz, pr in grid.get((i, j), ()):
                        m = r if r > pr else pr
                        if (px - x) ** 2 + (pz - z) ** 2 < m * m:
                            return False
        return True

    def add(self, layer: int, x: float, z: float, r: float) -> None:
        cell = self.size[layer]
        self.grids[layer].setdefault((int(x // cell), int(z // cell)), []).append((x, z, r))


def light_map(trees: list[tuple[F64, F64]], radii: list[F64], area: tuple[float, float]) -> F64:
    """``(rows, cols)`` light left on the ground by crowns (discs of their radius around each
    trunk ``(x, z)`` from the area's corner; each passes ``1 - CROWN_OPACITY``), cells about
    2 m, at most 256 a side."""
    w, d = area
    cell = max(2.0, max(w, d) / 256)
    cols, rows = max(1, math.ceil(w / cell)), max(1, math.ceil(d / cell))
    depth = np.zeros((rows, cols))
    for (xs, zs), rs in zip(trees, radii, strict=True):
        for x, z, r in zip(xs.tolist(), zs.tolist(), rs.tolist(), strict=True):
            c0, c1 = max(0, int((x - r) / cell)), min(cols, int((x + r) / cell) + 1)
            r0, r1 = max(0, int((z - r) / cell)), min(rows, int((z + r) / cell) + 1)
            if c0 >= c1 or r0 >= r1:
                continue
            cx = (np.arange(c0, c1) + 0.5) * cell - x
            cz = (np.arange(r0, r1) + 0.5) * cell - z
            inside = cx[None, :] ** 2 + cz[:, None] ** 2 <= r * r
            depth[r0:r1, c0:c1] += inside
    return np.asarray((1 - CROWN_OPACITY) ** depth)


def place_stand(
    recipe: Recipe,
    grammars: list[Grammar],
    trees: int,
    area: tuple[float, float],
    seed: int,
    ground: Heightfield,
    density_maps: list[F64 | None],
) -> Placement:
    """Every tree of the stand, layer by layer (see the module's docstring)."""
    counts = layer_counts(recipe, trees, area)
    total = sum(counts)
    if total < 1:
        raise ForestError("the recipe's densities give no tree on this area", path="recipe.layers")
    if total > MAX_STAND_TREES:
        raise LimitError(
            f"the recipe gives {total:,} trees, over the cap of {MAX_STAND_TREES:,} for a mixed "
            "forest; use a smaller area or lower densities",
            path="trees",
            limit=MAX_STAND_TREES,
        )
    n_layers = len(recipe.layers)
    crowns = [crown_radius(layer, g) for layer, g in zip(recipe.layers, grammars, strict=True)]
    spacing = [
        layer.spacing if layer.spacing is not None else crowns[k]
        for k, layer in enumerate(recipe.layers)
    ]
    rngs = [
        np.random.default_rng(np.random.SeedSequence([seed, k, 0x5_7A_4D])) for k in range(n_layers)
    ]
    sizes = [_sizes(layer, counts[k], rngs[k]) for k, layer in enumerate(recipe.layers)]
    headings = [rngs[k].random(counts[k]) * 2 * np.pi for k in range(n_layers)]
    order_rng = np.random.default_rng(np.random.SeedSequence([seed, 0x0_DE_A1]))
    hashed = _Spacing([max(sp * SIZE_MAX, MIN_SPACING_M) for sp in spacing])
    most_checks = CHECKS_PER_TREE * total + 10_000
    placed: list[list[tuple[float, float, float]]] = [[] for _ in range(n_layers)]
    ids: list[list[int]] = [[] for _ in range(n_layers)]
    light: F64 | None = None
    next_id = 0
    for tier in TIERS:
        members = [k for k, layer in enumerate(recipe.layers) if layer.role == tier]
        if tier != "canopy" and light is None:  # the whole canopy stands: its shade
            canopy = [k for k in range(n_layers) if recipe.layers[k].role == "canopy"]
            light = light_map(
                [
                    (np.array([p[0] for p in placed[k]]), np.array([p[1] for p in placed[k]]))
                    for k in canopy
                ],
                [crowns[k] * sizes[k] for k in canopy],
                area,
            )
        streams = {
            k: _Stream(recipe.layers[k], rngs[k], area, ground, density_maps[k], light)
            for k in members
        }
        # the tier's trees interleaved in a random order, each layer's own sizes in turn
        turns = np.concatenate([np.full(counts[k], k) for k in members] or [np.zeros(0, int)])
        order_rng.shuffle(turns)
        for k in turns.tolist():
            i = len(placed[k])
            r = max(MIN_SPACING_M, spacing[k] * float(sizes[k][i]))
            if recipe.layers[k].rows is not None:  # slots exactly a spacing apart are free
                r *= 0.98
            stream = streams[k]
            budget = stream.drawn + TRIES_PER_TREE * BATCH // 8
            while True:
                spot = stream.next(budget)
                # a stand near jamming is refused, not searched for hours
                if spot is None or hashed.checks > most_checks:
                    layer = recipe.layers[k]
                    raise ForestError(
                        f"found room for only {i} of {counts[k]} trees of layer "
                        f"{layer.name!r} ({r:.1f} m apart, where its density map, terrain "
                        "and light rules allow): give a larger area, fewer trees or a smaller "
                        "spacing",
                        path=f"recipe.layers.{k}",
                    )
                x, z, y = spot
                if hashed.free(x, z, r):
                    hashed.add(k, x, z, r)
                    placed[k].append((x, z, y))
                    ids[k].append(next_id)
                    next_id += 1
                    break
    assert light is not None
    w, d = area
    out = []
    for k in range(n_layers):
        pts = np.array(placed[k], np.float64).reshape(-1, 3)
        pos = np.stack([pts[:, 0] - w / 2, pts[:, 2], pts[:, 1] - d / 2], axis=-1)
        out.append(LayerTrees(np.array(ids[k], np.int64), pos, headings[k], sizes[k]))
    return Placement(tuple(out), light)
