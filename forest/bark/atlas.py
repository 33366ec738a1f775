"""The bark tile set as one picture (a non-UDIM atlas, for files that cannot carry UDIM tiles:
glTF, and the pictures inside a .usdz): the set's slices baked into one image, and each
quad's UDIM st mapped into it.

The atlas holds slice k in cell (k % columns, k // columns); each cell is the tile with a
:data:`PAD_FRACTION`-sized border of its own edge pixels around it, so mipmaps and linear
filtering near a tile's edge do not bleed in the neighbouring cell.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from forest.bark.images import read_pixels
from forest.bark.tilesets import installed_set_dir
from forest.errors import ForestError
from forest.geometry.transforms import F64

PAD_FRACTION = 16  # border of a cell: 1/16 of the tile size
SLICE_FILE = re.compile(r"bark\.(1\d{3})\.png")


def slice_files(folder: Path) -> list[Path]:
    """The folder's ``bark.<UDIM>.png`` slices, in slice order (gaps included as found)."""
    found = sorted(
        (int(m.group(1)), p)
        for p in (folder.iterdir() if folder.is_dir() else [])
        if (m := SLICE_FILE.fullmatch(p.name))
    )
    return [p for _, p in found]


def tile_folder(bark: str, tiles: Path | None) -> Path:
    """The folder whose ``bark.<UDIM>.png`` the atlas is made of: ``tiles``, else the
    shipped set the grammar's ``bark`` names (an error naming the set, not its folder, when
    the installation lacks it)."""
    if tiles is not None:
        return tiles
    return installed_set_dir(bark)


def read_slices(folder: Path, needed: int) -> NDArray[np.uint8]:
    """``(n, h, w, 3)`` the folder's slices ``bark.1001.png`` on, in slice order; at least
    ``needed`` of them, all the same size."""
    found = [(int(p.name[5:9]) - 1001, p) for p in slice_files(folder)]
    if [k for k, _ in found] != list(range(len(found))) or len(found) < needed:
        raise ForestError(
            f"needs bark.1001.png .. bark.{1000 + needed}.png without gaps, found {len(found)}",
            path=str(folder),
        )
    tiles = [read_pixels(p) for _, p in found]
    shape = tiles[0].shape[:2]
    if any(t.shape[:2] != shape for t in tiles):
        raise ForestError("bark tiles differ in size", path=str(folder))
    rgb = [t[..., :3] if t.shape[2] >= 3 else np.repeat(t[..., :1], 3, axis=2) for t in tiles]
    return np.stack(rgb)


def atlas_layout(n: int, size: int) -> tuple[int, int, int, int]:
    """Columns, rows, cell size and pad (pixels) of an atlas of ``n`` square tiles."""
    columns = int(np.ceil(np.sqrt(n)))
    rows = -(-n // columns)
    pad = max(size // PAD_FRACTION, 1)
    return columns, rows, size + 2 * pad, pad


def make_atlas(slices: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """``(rows * cell, columns * cell, 3)`` uint8: every slice padded by its own edge pixels,
    row-major in cells (top-left first)."""
    n, size = len(slices), slices.shape[1]
    columns, rows, cell, pad = atlas_layout(n, size)
    padded = np.pad(slices, ((0, columns * rows - n), (pad, pad), (pad, pad), (0, 0)), "edge")
    grid = padded.reshape(rows, columns, cell, cell, 3)
    return np.ascontiguousarray(
        grid.transpose(0, 2, 1, 3, 4).reshape(rows * cell, columns * cell, 3)
    )


def udim_slices(st: F64) -> NDArray[np.int64]:
    """``(q,)`` the slice each quad's UDIM st ``(q, 4, 2)`` reads (its centre lies inside its
    tile ``1001 + k``: u in [k % 10, k % 10 + 1], v in [k // 10, k // 10 + 1])."""
    cell_xy = np.floor(np.asarray(st).mean(axis=1))
    return (cell_xy[:, 0] + 10 * cell_xy[:, 1]).astype(np.int64)


def atlas_uv(st: F64, n: int, size: int) -> NDArray[np.float32]:
    """UDIM st ``(q, 4, 2)`` (tile ``1001 + k`` spans u in [k % 10, k % 10 + 1], v in
    [k // 10, k // 10 + 1], v up, as :func:`forest.usd.materials.tile_udim_st` makes them) ->
    atlas UVs ``(q, 4, 2)`` float32 (glTF: v down from the image's top row; USD's st is
    ``(u, 1 - v)``)."""
    k = udim_slices(st)
    cell_xy = np.stack([k % 10, k // 10], axis=-1).astype(np.float64)
    if len(k) and (k.max() >= n):
        raise ForestError(f"a quad uses slice {int(k.max())} of a set of {n}", path="tiles")
    local = st - cell_xy[:, None]
    columns, rows, cell, pad = atlas_layout(n, size)
    col, row = k % columns, k // columns
    x = col[:, None] * cell + pad + local[..., 0] * size
    y = row[:, None] * cell + pad + (1.0 - local[..., 1]) * size
    return np.stack([x / (columns * cell), y / (rows * cell)], axis=-1).astype(np.float32)
