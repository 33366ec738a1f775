"""Writing a forest to a file whose suffix picks the format: USD (.usda, .usdc, .usdz) or
glTF 2.0 binary (.glb)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from forest.errors import ForestError
from forest.gltf import GLB_SUFFIX
from forest.growth.generate import Forest, Progress
from forest.usd.files import FORMATS

if TYPE_CHECKING:
    from forest.gltf.compress import Packing
    from forest.gltf.document import Profile

SCENE_SUFFIXES = (*FORMATS, GLB_SUFFIX)


def is_glb(path: str | Path) -> bool:
    return Path(path).suffix.lower() == GLB_SUFFIX


def single_file(path: str | Path) -> bool:
    """Whether ``path``'s format carries its pictures inside (.usdz, .glb): what a writer that
    hands back one file (the HTTP API, a job's artifact) asks for ``textures``, since a
    .usda/.usdc would name a ``<stem>.textures/`` folder that does not travel with it."""
    return Path(path).suffix.lower() in (".usdz", GLB_SUFFIX)


def write_forest(
    forest: Forest,
    path: str | Path,
    *,
    skinned: bool | None = None,
    tiles: str | None = None,
    textures: bool = True,
    progress: Progress | None = None,
    packing: Packing | None = None,
    lod: bool | None = None,
    profile: Profile | None = None,
    lod0_triangles: int | None = None,
) -> Path:
    """Write ``forest`` to ``path`` in the format of its suffix; returns the path.

    ``tiles``: the bark tile-set folder, relative to the file's folder (a USD scene names
    it, a .glb packs its pictures). ``textures``: a USD scene's bark and leaf pictures
    (:func:`forest.usd.scene.write_scene`; False: flat colours); a .glb always packs its
    own. ``skinned``: USD's choice; a .glb is always skinned. ``packing``: how a .glb
    stores its data (:mod:`forest.gltf.compress`, its default when None); USD ignores it.
    ``lod``: each skinned USD tree's levels of detail (:mod:`forest.lod`; None means yes; a
    .glb's follow its ``profile``, and it refuses ``lod``). ``profile``: a .glb's ``game``
    (its default: levels of detail, at most 256 joints per tree) or ``film`` (the full tree on
    every joint), :mod:`forest.gltf.document`; USD refuses it. ``lod0_triangles``: the game
    profile's LOD0 budget (:func:`forest.gltf.document.forest_gltf`); None for its default."""
    # imported here: a .glb needs none of the USD writer, a USD scene none of glTF's
    if is_glb(path):
        from forest.gltf.document import write_glb

        if lod:
            raise ForestError(
                "a .glb's levels of detail are written by its --profile (game: LOD0-LOD3, "
                "film: none), not --lod",
                path="lod",
            )
        folder = Path(path).parent / tiles if tiles else None
        extra: dict[str, Any] = {} if packing is None else {"packing": packing}
        if profile is not None:
            extra["profile"] = profile
        if lod0_triangles is not None:
            extra["lod0_triangles"] = lod0_triangles
        return write_glb(forest, path, tiles=folder, progress=progress, **extra)
    if profile is not None:
        raise ForestError("--profile applies to a .glb only", path="profile")
    if lod0_triangles is not None:
        raise ForestError("--lod0-triangles applies to a .glb only", path="lod0_triangles")
    from forest.usd.scene import write_scene

    return write_scene(
        forest,
        path,
        skinned=skinned,
        tiles=tiles,
        textures=textures,
        progress=progress,
        lod=lod is not False,
    )
