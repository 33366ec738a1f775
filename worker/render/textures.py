"""The bark texture array (paper 5.1): one slice per tile, addressed by the tile index.

Where the slices come from, first found wins:

1. a tile-set folder (``forest tiles``): its texture array (``files.array`` of its
   ``manifest.json``, default ``bark_array.tif``: one subimage per slice), else one image per
   slice (``files.slices``, default ``bark.<1001+k>.png``); the folder is given, or found
   through the scene's bark material (``/World/Looks/Bark/Tiles.inputs:file`` =
   ``DIR/bark.<UDIM>.png``), or is the package's shipped set the scene names
   (``SceneArrays.bark_tile_set``, from the grammar's ``bark``: ``forest.bark.tilesets``) when
   the scene uses the default tile classes;
2. a procedural placeholder made here in numpy, with one slice per tile of the scene's
   manifest (at least max tile index + 1). Its slices share one periodic border pattern and
   differ only inside, so neighbouring quads meet without seams, as the paper's tiles do.

Images are read with OpenImageIO, 8-bit sRGB RGBA.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from forest.bark.images import read_subimages
from forest.bark.tiles import manifest_for
from forest.errors import ForestError
from schemas.tileset import (
    ARRAY_FILE,
    DEFAULT_MANIFEST,
    UDIM_PATTERN,
    TileSetManifest,
    udim_file,
)

if TYPE_CHECKING:
    import moderngl

PLACEHOLDER_SIZE = 64
BARK_RGB = np.array([0.50, 0.36, 0.24])
FORK_RGB = np.array([0.46, 0.38, 0.26])


class TileSetError(ForestError):
    """A tile-set folder cannot be used; ``path`` is the file."""


@dataclass(frozen=True, eq=False)
class TileImages:
    """slices : (n, h, w, 4) uint8, row 0 at the top (v = 1)."""

    slices: NDArray[np.uint8]
    source: str

    @property
    def n_slices(self) -> int:
        return int(self.slices.shape[0])


def _fade(x: NDArray[np.float64], width: float = 0.2) -> NDArray[np.float64]:
    """0 at the border, 1 from ``width`` inwards (smoothstep)."""
    t = np.clip(x / width, 0.0, 1.0)
    return t * t * (3 - 2 * t)


def procedural_tiles(
    manifest: TileSetManifest, n_slices: int, size: int = PLACEHOLDER_SIZE, seed: int = 0
) -> TileImages:
    """Placeholder bark: a border pattern periodic in u and v shared by every slice, plus
    per-slice grooves and blotches that fade to nothing at the border."""
    u, v = np.meshgrid((np.arange(size) + 0.5) / size, (np.arange(size) + 0.5) / size)
    v = v[::-1]  # row 0 is the top of the image (v = 1)
    tau = 2 * np.pi
    base = (
        0.5
        + 0.22 * np.sin(tau * (3 * u + 0.35 * np.sin(tau * v)))
        + 0.08 * np.sin(tau * 7 * u) * np.sin(tau * 2 * v)
    )
    window = _fade(u) * _fade(1 - u) * _fade(v) * _fade(1 - v)
    tint = np.broadcast_to(BARK_RGB, (n_slices, 3)).copy()
    for c in manifest.classes:
        if c.name != "bark" and c.first < n_slices:
            tint[c.first : c.first + c.count] = FORK_RGB
    rng = np.random.default_rng(seed)
    out = np.empty((n_slices, size, size, 4), np.uint8)
    for k in range(n_slices):
        inside = np.zeros_like(u)
        for _ in range(4):  # smooth blotches: integer frequencies, random phases
            fx, fy = rng.integers(1, 5, size=2)
            inside += 0.12 * np.sin(tau * (fx * u + fy * v) + rng.uniform(0, tau))
        for u0 in rng.uniform(0.15, 0.85, size=rng.integers(1, 4)):  # dark vertical grooves
            wobble = 0.03 * np.sin(tau * (v + rng.uniform()))
            inside -= 0.45 * np.exp(-(((u - u0 - wobble) / 0.035) ** 2))
        value = np.clip(base + window * inside, 0.0, 1.0)
        rgb = tint[k] * (0.45 + 1.1 * value[..., None])
        out[k, ..., :3] = np.clip(rgb * 255 + 0.5, 0, 255).astype(np.uint8)
        out[k, ..., 3] = 255
    return TileImages(out, f"procedural placeholder ({n_slices} slices)")


def _rgba(pixels: NDArray[np.uint8], where: str) -> NDArray[np.uint8]:
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    c = pixels.shape[-1]
    if c == 1:
        pixels = np.repeat(pixels, 3, axis=-1)
    if pixels.shape[-1] == 3:
        alpha = np.full((*pixels.shape[:2], 1), 255, np.uint8)
        pixels = np.concatenate([pixels, alpha], axis=-1)
    if pixels.shape[-1] != 4:
        raise TileSetError(f"unsupported channel count {c}", path=where)
    return pixels


def read_image_subimages(path: Path) -> list[NDArray[np.uint8]]:
    """Every subimage of ``path`` as ``(h, w, 4)`` uint8."""
    return [_rgba(pixels, str(path)) for pixels in read_subimages(path)]


def _folder_files(folder: Path, n_slices: int) -> tuple[str | None, list[str]]:
    """The array file and per-slice files the folder's manifest declares (``files``), else
    the defaults ``bark_array.tif`` and ``bark.<1001+k>.png``."""
    files = manifest_for(folder).files
    if files is None:
        return ARRAY_FILE, [udim_file(UDIM_PATTERN, k) for k in range(n_slices)]
    return files.array, files.slices


def load_tile_folder(folder: Path, n_slices: int) -> TileImages:
    """Slices of a tile-set folder: its texture-array TIFF, else its per-slice PNGs."""
    array_name, slice_names = _folder_files(folder, n_slices)
    array = folder / array_name if array_name else None
    if array is not None and array.is_file():
        images = read_image_subimages(array)
        source = str(array)
    else:
        images = []
        for k in range(min(n_slices, len(slice_names))):
            path = folder / slice_names[k]
            if not path.is_file():
                raise TileSetError(
                    f"tile set has no {array_name or 'texture array'} and slice {k} is missing",
                    path=str(path),
                )
            images.extend(read_image_subimages(path)[:1])
        source = str(folder / UDIM_PATTERN)
    if len(images) < n_slices:
        raise TileSetError(f"{len(images)} slices, the scene's tiles need {n_slices}", path=source)
    shapes = {im.shape for im in images}
    if len(shapes) != 1:
        raise TileSetError(f"slices differ in size: {sorted(shapes)}", path=source)
    return TileImages(np.stack(images), source)


def shipped_tile_folder(manifest: TileSetManifest, name: str = "default") -> Path | None:
    """The package's tile set ``name`` (``forest.bark.tilesets``) when it has the scene's
    tile classes (None: a scene of other classes, which the shipped tiles do not fit). An
    unknown name, or a shipped set missing from this installation, is
    an error naming the set (never its folder): placeholder bark in its stead would hide
    a broken install."""
    from forest.bark.tilesets import SETS, installed_set_dir

    if name not in SETS:
        raise TileSetError(
            f"no shipped bark tile set {name!r} (shipped: {', '.join(SETS)})", path="bark"
        )
    same = [(c.id, c.first, c.count) for c in manifest.classes] == [
        (c.id, c.first, c.count) for c in DEFAULT_MANIFEST.classes
    ]
    if not same:
        return None
    return installed_set_dir(name)


def tile_images(
    manifest: TileSetManifest,
    folder: Path | None = None,
    scene_folder: Path | None = None,
    shipped: bool = True,
    bark: str = "default",
) -> TileImages:
    """The scene's slices (``manifest.n_slices``): from ``folder``, else the folder the
    scene's material names (``SceneArrays.tile_folder``) if it exists, else the package's
    tile set ``bark`` (``SceneArrays.bark_tile_set``; with ``shipped``), else the procedural
    placeholder."""
    n_slices = manifest.n_slices
    if folder is None and scene_folder is not None and scene_folder.is_dir():
        folder = scene_folder
    if folder is None and shipped:
        folder = shipped_tile_folder(manifest, bark)
    if folder is not None:
        if not folder.is_dir():
            raise TileSetError("tile-set folder does not exist", path=str(folder))
        return load_tile_folder(folder, n_slices)
    return procedural_tiles(manifest, n_slices)


def upload(ctx: moderngl.Context, images: TileImages) -> moderngl.TextureArray:
    """A mipmapped RGBA8 texture array; GL rows go bottom-up, so each slice is flipped."""
    import moderngl

    n, h, w, _ = images.slices.shape
    data = np.ascontiguousarray(images.slices[:, ::-1])
    tex = ctx.texture_array((w, h, n), 4, data.tobytes())
    tex.repeat_x = False  # a tile belongs to one quad: clamp, never bleed the opposite border
    tex.repeat_y = False
    tex.build_mipmaps()
    tex.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
    return tex
