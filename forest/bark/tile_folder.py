"""Tile-set folders read back as texture slices (paper 5.1: one slice per tile, addressed by
the tile index), the way :mod:`forest.bark.tileset` writes them.

The slices of the tile set a scene uses, first found wins:

1. a tile-set folder (``forest tiles``): its texture array (``files.array`` of its
   ``manifest.json``, default ``bark_array.tif``: one subimage per slice), else one image per
   slice (``files.slices``, default ``bark.<1001+k>.png``); the folder is given, or found
   through the scene's bark material (``/World/Looks/Bark/Tiles.inputs:file`` =
   ``DIR/bark.<UDIM>.png``, ``SceneArrays.tile_folder``);
2. the package's shipped set the scene names (``SceneArrays.bark_tile_set``, from the
   grammar's ``bark``: :mod:`forest.bark.tilesets`) when the scene uses the default tile
   classes;
3. none: the caller draws a placeholder (the renderer's, ``worker.render.textures``).

Images are read with OpenImageIO as 8-bit RGBA (sRGB as stored).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

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


class TileSetError(ForestError):
    """A tile-set folder cannot be used; ``path`` is the file."""


@dataclass(frozen=True, eq=False)
class TileImages:
    """slices : (n, h, w, 4) uint8, row 0 at the top (v = 1); source : where they came from."""

    slices: NDArray[np.uint8]
    source: str

    @property
    def n_slices(self) -> int:
        return int(self.slices.shape[0])


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


def load_tile_folder(folder: Path, n_slices: int, required: int | None = None) -> TileImages:
    """Slices of a tile-set folder: its texture-array TIFF, else its per-slice PNGs; at least
    ``required`` of them (default ``n_slices``), the rest as far as the folder has them."""
    need = n_slices if required is None else required
    array_name, slice_names = _folder_files(folder, n_slices)
    array = folder / array_name if array_name else None
    if array is not None and array.is_file():
        images = read_image_subimages(array)
        source = str(array)
    else:
        images = []
        for k in range(min(n_slices, len(slice_names))):
            path = folder / slice_names[k]
            if not path.is_file() and k >= need:
                break
            if not path.is_file():
                raise TileSetError(
                    f"tile set has no {array_name or 'texture array'} and slice {k} is missing",
                    path=str(path),
                )
            images.extend(read_image_subimages(path)[:1])
        source = str(folder / UDIM_PATTERN)
    if len(images) < need:
        raise TileSetError(f"{len(images)} slices, the scene's tiles need {need}", path=source)
    shapes = {im.shape for im in images}
    if len(shapes) != 1:
        raise TileSetError(f"slices differ in size: {sorted(shapes)}", path=source)
    return TileImages(np.stack(images), source)


def shipped_tile_folder(manifest: TileSetManifest, name: str = "default") -> Path | None:
    """The package's tile set ``name`` (``forest.bark.tilesets``) when it has the scene's
    tile classes: the default manifest's, or the set's own (which may add the lower trunk's
    after them); None for a scene of other classes, which the shipped tiles do not fit. An
    unknown name, or a shipped set missing from this installation, is an error naming the
    set (never its folder): placeholder bark in its stead would hide a broken install."""
    from forest.bark.tilesets import SETS, installed_set_dir, set_dir, shipped_manifest

    if name not in SETS:
        raise TileSetError(
            f"no shipped bark tile set {name!r} (shipped: {', '.join(SETS)})", path="bark"
        )

    def spans(m: TileSetManifest) -> set[tuple[int, int, int]]:
        return {(c.id, c.first, c.count) for c in m.classes}

    wanted = spans(manifest)
    fits = wanted <= spans(DEFAULT_MANIFEST)
    if not fits and (set_dir(name) / "manifest.json").is_file():
        fits = wanted <= spans(shipped_manifest(name))
    return installed_set_dir(name) if fits else None


def scene_tile_images(
    manifest: TileSetManifest,
    folder: Path | None = None,
    scene_folder: Path | None = None,
    shipped: bool = True,
    bark: str = "default",
) -> TileImages | None:
    """The scene's slices (``manifest.n_slices``): from ``folder``, else the folder the
    scene's material names (``SceneArrays.tile_folder``) if it exists, else the package's
    tile set ``bark`` (``SceneArrays.bark_tile_set``; with ``shipped``); None when no set
    fits the scene."""
    if folder is None and scene_folder is not None and scene_folder.is_dir():
        folder = scene_folder
    if folder is None and shipped:
        folder = shipped_tile_folder(manifest, bark)
    if folder is None:
        return None
    if not folder.is_dir():
        raise TileSetError("tile-set folder does not exist", path=str(folder))
    lower = [c for c in manifest.classes if c.stands_for is not None]
    base = min((c.first for c in lower), default=manifest.n_slices)
    images = load_tile_folder(folder, manifest.n_slices, required=base)
    return _with_lower_trunk(images, manifest)


def _with_lower_trunk(images: TileImages, manifest: TileSetManifest) -> TileImages:
    """``images`` with the lower trunk's slices (``TileClass.stands_for``) that a folder
    built without them lacks taken from the classes they stand for: such a set shows its
    one bark down to the ground."""
    n = manifest.n_slices
    if images.n_slices >= n:
        return images
    by_id = {c.id: c for c in manifest.classes}
    slices = np.concatenate(
        [images.slices, np.zeros((n - images.n_slices, *images.slices.shape[1:]), np.uint8)]
    )
    for c in manifest.classes:
        if c.stands_for is None or c.first + c.count <= images.n_slices:
            continue
        base = by_id[c.stands_for]
        for k in range(c.count):
            slices[c.first + k] = slices[base.first + k % base.count]
    return TileImages(slices, f"{images.source} (its bark for the lower trunk's slices)")
