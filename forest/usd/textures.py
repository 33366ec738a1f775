"""A USD scene's pictures: the bark tile set and the leaf picture its materials read.

A .usda/.usdc names them (and each tree's impostor pictures, :mod:`forest.usd.lod`) in
``<stem>.textures/`` beside it (the bark as the set's UDIM tiles
``bark.<UDIM>.png``), by asset paths ``./<stem>.textures/...`` anchored to the layer (see
:func:`forest.usd.materials.tile_asset_path`). A .usdz carries them inside, under
``./textures/``: Blender and Quick Look read no UDIM tile inside a package, so its bark is
one atlas (:mod:`forest.bark.atlas`) and the skinned bark's ``st`` is mapped into it.
The pictures are laid out beside the package's layer before packing and named ``./...``:
the packager keeps such paths as they are, where it renamed any other one (``1/bark.<UDIM>.png``,
which Blender 4.2 and 5.2 resolve to nothing).
"""

from __future__ import annotations

import re
import shutil
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from forest.atomic import folder_updated_when_written
from forest.bark.atlas import atlas_uv, make_atlas, read_slices, slice_files, tile_folder
from forest.bark.images import write_png
from forest.errors import OutputError
from forest.geometry.transforms import F64
from forest.growth.foliage import Family
from forest.usd.materials import leaf_texture_name, tile_asset_path, write_leaf_texture

FOLDER_SUFFIX = ".textures"
PACKAGE_FOLDER = "textures"  # inside a .usdz, beside its layer
ATLAS_FILE = "bark.png"
# UDIM st keep this far (in tile widths: an eighth of a 128-pixel tile's texel) inside their
# tile: Blender 4.2's Cycles draws a whole face magenta (a missing tile) whose u reaches 10.0,
# the right edge of tile column 9 (1010, 1020, 1030: every tile set has them)
TILE_INSET = 1.0 / 1024.0
# the names this writer puts in a texture folder: only these are ever replaced or removed (the
# last: each tree's impostor pictures, forest.lod.impostor.write_impostor)
_OURS = re.compile(
    r"bark\.1\d{3}\.png|bark\.png|leaf-[a-z]+\.png|Tree_\d{5}\.(albedo|normal|depth|cards)\.png"
)


def texture_folder(scene: Path) -> Path:
    """Where a .usda/.usdc's pictures live: ``<stem>.textures`` beside ``scene``."""
    return scene.with_name(f"{scene.stem}{FOLDER_SUFFIX}")


@dataclass(frozen=True)
class SceneTextures:
    """What a scene's materials read and the files that hold it.

    bark, leaf : asset paths for the bark and leaf materials (None: a flat colour)
    atlas : (slices, tile size) when ``bark`` is an atlas (a .usdz): :meth:`bark_st` maps
        the UDIM st into it
    folder : where :meth:`write` puts ``sources`` (None: the scene writes no picture)
    sources : file name -> a file to copy, or ``(h, w, c)`` uint8 pixels to write as PNG
    """

    bark: str | None = None
    leaf: str | None = None
    atlas: tuple[int, int] | None = None
    folder: Path | None = None
    sources: dict[str, Path | NDArray[np.uint8]] = field(default_factory=dict)
    family: Family | None = None
    shipped_bark: bool = False  # ``bark`` is a copy of the shipped set, not the user's tiles

    def bark_st(self, st: F64) -> F64:
        """UDIM st ``(q, 4, 2)`` -> the st the bark mesh carries: inside each quad's tile by
        :data:`TILE_INSET`, or into the atlas (t up from the image's bottom row, as USD reads
        a picture)."""
        if self.atlas is None:
            tile = np.floor(st.mean(axis=1, keepdims=True))  # a quad's centre is in its tile
            return tile + TILE_INSET + (st - tile) * (1.0 - 2.0 * TILE_INSET)
        uv = atlas_uv(st, *self.atlas).astype(np.float64)
        return np.stack([uv[..., 0], 1.0 - uv[..., 1]], axis=-1)

    def with_files(self, files: Sequence[Path], folder: Path) -> SceneTextures:
        """These pictures and ``files`` (written elsewhere: copied in by :meth:`write`), into
        :attr:`folder` or, where the scene had no picture, ``folder``."""
        if not files:
            return self
        sources = {**self.sources, **{p.name: p for p in files}}
        return replace(self, folder=self.folder or folder, sources=sources)

    def write(self, staged: bool) -> bool:
        """Write the pictures into :attr:`folder`: straight in (a private folder, as a
        .usdz's), or ``staged``: each file renamed over its old self once all are written,
        so a failure leaves the folder's old pictures as they were. True when this made the
        folder (the caller removes it again if the scene then fails)."""
        if self.folder is None or not self.names():
            return False
        if not staged:
            self.folder.mkdir(exist_ok=True)
            self._write_into(self.folder)
            return False
        made = not self.folder.exists()
        try:
            self.folder.mkdir(exist_ok=True)
            with folder_updated_when_written(self.folder) as staging:
                self._write_into(staging)
        except BaseException:
            if made:
                shutil.rmtree(self.folder, ignore_errors=True)
            raise
        return made

    def _write_into(self, folder: Path) -> None:
        try:
            for name, source in self.sources.items():
                if isinstance(source, Path):
                    shutil.copyfile(source, folder / name)
                else:
                    write_png(folder / name, source)
            if self.family is not None:
                write_leaf_texture(folder, self.family)
        except OSError as exc:
            raise OutputError(f"cannot write: {exc.strerror}", path=str(folder)) from None

    def names(self) -> set[str]:
        """The files :meth:`write` puts in the folder."""
        leaf = {leaf_texture_name(self.family)} if self.family is not None else set()
        return set(self.sources) | leaf

    def prune(self) -> None:
        """Remove the pictures an earlier write of the same scene left that this one did not
        write (another species' leaf, a longer tile set); no other file is touched."""
        if self.folder is None or not self.folder.is_dir():
            return
        keep = self.names()
        for p in self.folder.iterdir():
            if p.is_file() and _OURS.fullmatch(p.name) and p.name not in keep:
                p.unlink(missing_ok=True)


def scene_textures(
    scene: Path,
    layer_folder: Path,
    bark: str,
    n_slices: int,
    family: Family | None,
    *,
    tiles: str | None = None,
    textures: bool = True,
) -> SceneTextures:
    """The pictures of the scene ``scene`` (its final path) whose layer is written in
    ``layer_folder``: the shipped tile set ``bark`` (or the folder ``tiles``, relative to the
    scene) and the leaf picture of ``family`` (None: no foliage). Without ``textures`` the
    materials keep flat colours and no picture is written; a given ``tiles`` is still named
    (a .usda/.usdc) or packed as the atlas (a .usdz)."""
    given = scene.parent / tiles if tiles else None
    if scene.suffix.lower() == ".usdz":
        if not (textures or tiles):
            return SceneTextures()
        folder = layer_folder / PACKAGE_FOLDER
        slices = read_slices(tile_folder(bark, given), n_slices)
        leaf = family if textures else None
        return SceneTextures(
            bark=f"./{PACKAGE_FOLDER}/{ATLAS_FILE}",
            leaf=None if leaf is None else f"./{PACKAGE_FOLDER}/{leaf_texture_name(leaf)}",
            atlas=(len(slices), slices.shape[1]),
            folder=folder,
            sources={ATLAS_FILE: make_atlas(slices)},
            family=leaf,
            shipped_bark=given is None,
        )
    if not textures:
        return SceneTextures(bark=None if tiles is None else tile_asset_path(tiles))
    folder = texture_folder(scene)
    if folder.exists() and not folder.is_dir():
        raise OutputError("is in the way of the scene's texture folder", path=str(folder))
    sources: dict[str, Path | NDArray[np.uint8]] = {}
    if tiles is None:
        shipped = slice_files(tile_folder(bark, None))
        sources = {p.name: p for p in shipped}
    local = f"./{folder.name}"
    return SceneTextures(
        bark=tile_asset_path(tiles if tiles is not None else local),
        leaf=None if family is None else f"{local}/{leaf_texture_name(family)}",
        folder=folder if (sources or family is not None) else None,
        sources=sources,
        family=family,
        shipped_bark=tiles is None,
    )
