"""The ground of a mixed forest: a heightfield over the forest's area, from an image or from a
seed, that trees stand on and that scenes carry as a mesh.

The area is centred on the origin of the XZ plane like every forest (x in ``[-w/2, w/2]``,
z in ``[-d/2, d/2]``); the grid's first row lies at ``-z``, its first column at ``-x`` (an
image's top-left corner). Heights between grid points are bilinear, so a tree's base is on
the mesh a consumer draws, to float precision.
"""

from __future__ import annotations

import base64
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from forest.errors import ForestError
from schemas.recipe import Terrain

F64 = NDArray[np.float64]
MAX_GRID = 513  # points per side of a procedural grid, and of a mesh
OCTAVES = 5
GROUND_CELL_M = 1.0  # the finest procedural grid: hills are tens of metres wide


@dataclass(frozen=True, eq=False)
class Heightfield:
    """Heights ``(rows, cols)`` metres on a regular grid spanning ``area`` (metres)."""

    heights: F64
    area: tuple[float, float]

    @property
    def shape(self) -> tuple[int, int]:
        rows, cols = self.heights.shape
        return rows, cols

    def _grid(self, x: F64, z: F64) -> tuple[F64, F64]:
        rows, cols = self.shape
        w, d = self.area
        gx = np.clip((np.asarray(x, np.float64) / w + 0.5) * (cols - 1), 0, cols - 1)
        gz = np.clip((np.asarray(z, np.float64) / d + 0.5) * (rows - 1), 0, rows - 1)
        return gx, gz

    def height(self, x: F64, z: F64) -> F64:
        """Heights at points ``(x, z)`` (bilinear between grid points; clamped at the border)."""
        gx, gz = self._grid(x, z)
        rows, cols = self.shape
        i0 = np.minimum(gx.astype(np.int64), cols - 2)
        j0 = np.minimum(gz.astype(np.int64), rows - 2)
        fx, fz = gx - i0, gz - j0
        h = self.heights
        top = h[j0, i0] * (1 - fx) + h[j0, i0 + 1] * fx
        bottom = h[j0 + 1, i0] * (1 - fx) + h[j0 + 1, i0 + 1] * fx
        return np.asarray(top * (1 - fz) + bottom * fz)

    def slope(self, x: F64, z: F64) -> F64:
        """Slopes in degrees at points ``(x, z)``: central differences over one grid step."""
        rows, cols = self.shape
        w, d = self.area
        sx, sz = w / (cols - 1), d / (rows - 1)
        dx = (self.height(x + sx / 2, z) - self.height(x - sx / 2, z)) / sx
        dz = (self.height(x, z + sz / 2) - self.height(x, z - sz / 2)) / sz
        return np.degrees(np.arctan(np.hypot(dx, dz)))

    def mesh(self) -> tuple[F64, NDArray[np.int32], F64, F64]:
        """The ground as a quad mesh: points ``(p, 3)``, quad corner indices ``(q, 4)`` (counter
        clockwise seen from above: faces up), st ``(p, 2)`` (0-1 over the area) and normals
        ``(p, 3)``. At most :data:`MAX_GRID` points a side (a larger grid is sampled)."""
        rows, cols = self.shape
        nz, nx = min(rows, MAX_GRID), min(cols, MAX_GRID)
        w, d = self.area
        u, v = np.linspace(0.0, 1.0, nx), np.linspace(0.0, 1.0, nz)
        uu, vv = np.meshgrid(u, v)
        x, z = (uu - 0.5) * w, (vv - 0.5) * d
        y = self.height(x, z)
        points = np.stack([x, y, z], axis=-1).reshape(-1, 3)
        st = np.stack([uu, 1.0 - vv], axis=-1).reshape(-1, 2)
        gz, gx = np.gradient(y, d / max(nz - 1, 1), w / max(nx - 1, 1))
        normals = np.stack([-gx, np.ones_like(y), -gz], axis=-1).reshape(-1, 3)
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        idx = np.arange(nz * nx, dtype=np.int32).reshape(nz, nx)
        a, b = idx[:-1, :-1], idx[:-1, 1:]
        c, e = idx[1:, 1:], idx[1:, :-1]
        # +z rows downward in the grid, so (a, e, c, b) turns counter-clockwise seen from +y
        quads = np.stack([a, e, c, b], axis=-1).reshape(-1, 4)
        return points, quads, st, normals

    @property
    def low_high(self) -> tuple[float, float]:
        return float(self.heights.min()), float(self.heights.max())


def flat(area: tuple[float, float]) -> Heightfield:
    """Level ground at height 0 (a forest without terrain)."""
    return Heightfield(np.zeros((2, 2)), area)


def image_bytes(ref: str, folder: Path | None, field: str) -> bytes:
    """The bytes a recipe's image reference names: a ``data:`` URI (base64), or, only where
    ``folder`` is given (the CLI: the recipe file's folder), a file path relative to it."""
    if ref.startswith("data:"):
        head, sep, body = ref.partition(",")
        if not sep or not head.endswith(";base64"):
            raise ForestError("a data: URI must be base64 (data:image/png;base64,...)", path=field)
        try:
            return base64.b64decode(body, validate=True)
        except ValueError:
            raise ForestError("the data: URI is not valid base64", path=field) from None
    if folder is None:
        # from the API: a path would name a file on the server
        raise ForestError("give the image as a data: URI (base64), not a path", path=field)
    path = folder / ref
    if not path.is_file():
        raise ForestError(f"no image file {ref!r} beside the recipe", path=field)
    try:
        return path.read_bytes()
    except OSError as exc:
        raise ForestError(f"cannot read {ref!r}: {exc.strerror}", path=field) from None


def procedural(area: tuple[float, float], seed: int, relief: float, feature: float) -> F64:
    """Rolling hills: octaves of smoothly interpolated lattice noise, the largest ``feature``
    metres wide, the lowest point at 0 and the highest at ``relief``. Drawn over the whole
    area at once, so every tile of a forest sees the same ground."""
    w, d = area
    cell = max(GROUND_CELL_M, max(w, d) / (MAX_GRID - 1))
    cols = max(2, min(MAX_GRID, math.ceil(w / cell) + 1))
    rows = max(2, min(MAX_GRID, math.ceil(d / cell) + 1))
    x = np.linspace(0.0, w, cols)
    z = np.linspace(0.0, d, rows)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x7E_44_A1_17]))
    total = np.zeros((rows, cols))
    for octave in range(OCTAVES):
        wave = feature / 2**octave
        lx, lz = math.ceil(w / wave) + 2, math.ceil(d / wave) + 2
        if lx * lz > 4 * MAX_GRID * MAX_GRID:
            break  # finer than the grid shows
        lattice = rng.standard_normal((lz, lx))
        total += _smooth_sample(lattice, x / wave, z / wave) * 0.5**octave
    lo, hi = total.min(), total.max()
    if hi - lo < 1e-12:
        return np.zeros((rows, cols))
    return np.asarray((total - lo) / (hi - lo) * relief)


def _smooth_sample(lattice: F64, gx: F64, gz: F64) -> F64:
    """``lattice`` sampled at grid coordinates ``gx`` (columns) x ``gz`` (rows) with a
    smoothstep between lattice points."""
    i0, j0 = np.floor(gx).astype(np.int64), np.floor(gz).astype(np.int64)
    fx, fz = gx - i0, gz - j0
    fx, fz = fx * fx * (3 - 2 * fx), fz * fz * (3 - 2 * fz)
    a = lattice[np.ix_(j0, i0)]
    b = lattice[np.ix_(j0, i0 + 1)]
    c = lattice[np.ix_(j0 + 1, i0)]
    e = lattice[np.ix_(j0 + 1, i0 + 1)]
    top = a * (1 - fx) + b * fx
    bottom = c * (1 - fx) + e * fx
    return np.asarray(top * (1 - fz[:, None]) + bottom * fz[:, None])


def heightfield(
    terrain: Terrain | None, area: tuple[float, float], folder: Path | None
) -> Heightfield:
    """The recipe's ground: its heightfield image, its procedural hills, or level ground when
    it has none; over its ``extent``, or ``area`` (the forest's) by default."""
    if terrain is None:
        return flat(area)
    if terrain.extent is not None:
        w, d = terrain.extent
        if area[0] > w * (1 + 1e-9) or area[1] > d * (1 + 1e-9):
            raise ForestError(
                f"the forest's area {area[0]:g} x {area[1]:g} m does not fit in the terrain's "
                f"extent {w:g} x {d:g} m",
                path="recipe.terrain.extent",
            )
        area = (w, d)
    if terrain.image is not None:
        from forest.bark.images import read_grey

        field = "recipe.terrain.image"
        grey = read_grey(image_bytes(terrain.image, folder, field), field)
        lo, hi = terrain.heights
        return Heightfield(lo + grey.astype(np.float64) * (hi - lo), area)
    base = terrain.heights[0]
    return Heightfield(base + procedural(area, terrain.seed, terrain.relief, terrain.feature), area)
