"""Writing a forest to a file whose suffix picks the format: USD (.usda, .usdc, .usdz) or
glTF 2.0 binary (.glb)."""

from __future__ import annotations

from pathlib import Path

from forest.errors import ForestError
from forest.gltf import GLB_SUFFIX
from forest.growth.generate import Forest, Progress
from forest.usd.files import FORMATS

SCENE_SUFFIXES = (*FORMATS, GLB_SUFFIX)


def is_glb(path: str | Path) -> bool:
    return Path(path).suffix.lower() == GLB_SUFFIX


def write_forest(
    forest: Forest,
    path: str | Path,
    *,
    skinned: bool | None = None,
    tiles: str | None = None,
    progress: Progress | None = None,
    lod: bool = False,
) -> Path:
    """Write ``forest`` to ``path`` in the format of its suffix; returns the path.

    ``tiles``: the bark tile-set folder, relative to the file's folder (a USD scene names
    it, a .glb packs its pictures). ``skinned``: USD's choice
    (:func:`forest.usd.scene.write_scene`); a .glb is always skinned. ``lod``: each skinned
    USD tree's levels of detail (:mod:`forest.lod`; USD only so far)."""
    # imported here: a .glb needs none of the USD writer, a USD scene none of glTF's
    if is_glb(path):
        from forest.gltf.document import write_glb

        if lod:
            raise ForestError("levels of detail are written to USD scenes only so far", path="lod")
        folder = Path(path).parent / tiles if tiles else None
        return write_glb(forest, path, tiles=folder, progress=progress)
    from forest.usd.scene import write_scene

    return write_scene(forest, path, skinned=skinned, tiles=tiles, progress=progress, lod=lod)
