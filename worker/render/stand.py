"""A mixed forest (a recipe's stand, :mod:`forest.usd.stand`) for the renderer: its root layer
names one scene file per layer (per layer and tile when tiled) and carries the terrain mesh.

Each layer file is read on its own, as any forest scene (:func:`forest.usd.read.read_scene`),
and drawn by a :class:`worker.render.renderer.Renderer` of its own (its bark tile set, its
leaf picture) into the first layer's framebuffer, with the terrain in the staging
(:meth:`Renderer.add_layer`); one camera frames the whole stand.

The root layer is read without composing it (its references are never opened by pxr), and
every layer file must resolve inside the root's own folder: a reference with ``..``, an
absolute one or a link out of the folder is refused, naming the layer. A root whose layer files
are absent (a root uploaded alone) is refused with a clear error that names no server path.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from forest.errors import ForestError
from forest.geometry.transforms import F64
from forest.stand.terrain import Heightfield
from forest.usd.contract import FOREST, TILES, TILING
from forest.usd.read import SceneArrays
from worker.render.camera import Camera, CameraSpec, place_camera
from worker.render.foliage import foliage_points
from worker.render.renderer import TessSettings, auto_lod
from worker.render.scene_buffers import scene_points
from worker.render.staging import TerrainMesh

# what a malformed (or hostile) root layer makes pxr's Sdf raise (Tf.ErrorException is a
# RuntimeError)
READ_ERRORS = (RuntimeError, TypeError, ValueError, KeyError, IndexError, UnicodeDecodeError)
Floor = Callable[[F64, F64], F64]


@dataclass(frozen=True, eq=False)
class StandScene:
    """A stand's root ``path``, its layer scenes (``names[k]`` is the layer, with the tile
    when tiled, of ``scenes[k]``; layers without trees are left out) and its terrain."""

    path: Path
    names: tuple[str, ...]
    scenes: tuple[SceneArrays, ...]
    terrain: TerrainMesh

    @property
    def n_frames(self) -> int:
        return min(s.n_frames for s in self.scenes)

    def floor(self) -> Floor:
        """The terrain's height under points ``(x, z)``: bilinear on its grid (the mesh a
        :class:`forest.stand.terrain.Heightfield` makes), else the nearest point's height."""
        return terrain_floor(self.terrain.points)


def terrain_floor(points: F64) -> Floor:
    """See :meth:`StandScene.floor`."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    xs, zs = np.unique(pts[:, 0]), np.unique(pts[:, 2])
    grid = len(xs) >= 2 and len(zs) >= 2 and len(xs) * len(zs) == len(pts)
    if grid:
        order = np.lexsort((pts[:, 0], pts[:, 2]))  # rows of z, x along a row
        sorted_pts = pts[order]
        grid = bool(
            np.allclose(sorted_pts[:, 0].reshape(len(zs), len(xs)), xs[None, :])
            and np.allclose(xs + xs[::-1], 0.0, atol=1e-3)
            and np.allclose(zs + zs[::-1], 0.0, atol=1e-3)
        )
    if grid:
        heights = sorted_pts[:, 1].reshape(len(zs), len(xs))
        field = Heightfield(heights, (float(np.ptp(xs)), float(np.ptp(zs))))
        return lambda x, z: field.height(np.asarray(x, np.float64), np.asarray(z, np.float64))

    def nearest(x: F64, z: F64) -> F64:
        xa, za = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(z, np.float64))
        q = np.stack([xa.ravel(), za.ravel()], axis=1)
        d = ((q[:, None, :] - pts[None, :, [0, 2]]) ** 2).sum(axis=-1)
        return np.asarray(pts[d.argmin(axis=1), 1].reshape(xa.shape))

    return nearest


def is_stand_file(path: Path) -> bool:
    """Whether ``path`` is a mixed forest's root layer (False for anything pxr cannot read as a
    layer: the scene reader then names what is wrong)."""
    from forest.usd.stand import is_stand

    if path.suffix.lower() not in (".usd", ".usda", ".usdc") or not path.is_file():
        return False
    try:
        return is_stand(path)
    except READ_ERRORS:
        return False


def _has_forest(path: Path) -> bool:
    """Whether a layer file holds a forest (an empty layer or tile is /World alone)."""
    from pxr import Sdf

    layer = Sdf.Layer.FindOrOpen(str(path))
    return layer is not None and layer.GetPrimAtPath(FOREST) is not None


def _layer_error(name: str, exc: ForestError) -> ForestError:
    """``exc`` naming the layer; a file path in it (the reader's own) is not passed on."""
    where = exc.path if exc.path.startswith("/World") or not Path(exc.path).is_absolute() else ""
    return ForestError(f"layer {name!r}: {exc.message}", path=where or "scene")


def load_stand(path: Path, read: Callable[[Path], SceneArrays]) -> StandScene:
    """The stand whose root layer is ``path``, each layer file read by ``read``; see the
    module's docstring for what is refused."""
    from forest.usd.stand import read_stand

    try:
        files = read_stand(path)
    except ForestError as exc:
        raise ForestError(exc.message, path="scene") from None
    except READ_ERRORS as exc:
        raise _root_error(exc) from None
    layers = [(layer.name, layer.files) for layer in files.layers]
    return _load_files(path, layers, files.terrain_points, files.terrain_quads, read, "layer")


def is_tiled_file(path: Path) -> bool:
    """Whether ``path`` is a tiled forest's root layer (``/World/Tiles`` of payloads,
    :mod:`forest.usd.tiled`)."""
    from pxr import Sdf

    if path.suffix.lower() not in (".usd", ".usda", ".usdc") or not path.is_file():
        return False
    try:
        layer = Sdf.Layer.FindOrOpen(str(path))
        return layer is not None and layer.GetPrimAtPath(TILES) is not None
    except READ_ERRORS:
        return False


def load_tiled(path: Path, read: Callable[[Path], SceneArrays]) -> StandScene:
    """A tiled forest's root layer as a stand: each tile's file (its payload) read by
    ``read`` and drawn as a layer, on level ground over the forest's area (its
    ``forest:tiling`` plan, else the tiles' extents). Refused as :func:`load_stand` refuses:
    a tile file outside the root's folder, or missing (a root uploaded alone)."""
    from pxr import Sdf

    try:
        layer = Sdf.Layer.FindOrOpen(str(path))
        group = layer.GetPrimAtPath(TILES) if layer is not None else None
        if group is None:
            raise ForestError("not a tiled forest's root layer", path="scene")
        tiles = [
            (
                spec.name,
                tuple(
                    path.parent / p.assetPath for p in spec.payloadList.GetAddedOrExplicitItems()
                ),
            )
            for spec in group.nameChildren
        ]
        plan = group.attributes[TILING].default if TILING in group.attributes else None
        hint = [spec.attributes["extentsHint"].default for spec in group.nameChildren
                if "extentsHint" in spec.attributes]  # fmt: skip
    except ForestError:
        raise
    except READ_ERRORS as exc:
        raise _root_error(exc) from None
    if plan is not None:
        w, d = (float(v) for v in json.loads(plan)["area"])
        lo, hi = (-w / 2, -d / 2), (w / 2, d / 2)
    elif hint:
        box = np.array([[tuple(v) for v in h] for h in hint], np.float64).reshape(-1, 3)
        lo, hi = (box[:, 0].min(), box[:, 2].min()), (box[:, 0].max(), box[:, 2].max())
    else:
        lo, hi = (-1.0, -1.0), (1.0, 1.0)
    ground = np.array(
        [[lo[0], 0.0, lo[1]], [hi[0], 0.0, lo[1]], [hi[0], 0.0, hi[1]], [lo[0], 0.0, hi[1]]]
    )
    # (0, 3, 2, 1): counter-clockwise seen from above, as a stand's terrain quads
    return _load_files(path, tiles, ground, np.array([[0, 3, 2, 1]]), read, "tile")


def _root_error(exc: BaseException) -> ForestError:
    lines = str(exc).strip().splitlines()
    why = f"{type(exc).__name__}: {lines[-1][:200]}" if lines else type(exc).__name__
    return ForestError(f"the root layer could not be read ({why})", path="scene")


def _load_files(
    path: Path,
    layers: list[tuple[str, tuple[Path, ...]]],
    terrain_points: F64,
    terrain_quads: np.ndarray,
    read: Callable[[Path], SceneArrays],
    what: str,
) -> StandScene:
    """Every layer's (or tile's) files read (those without trees left out) over the terrain;
    a file outside the root's folder or missing is refused, naming the ``what``."""
    folder = path.parent.resolve()
    names: list[str] = []
    scenes: list[SceneArrays] = []
    for layer_name, layer_files in layers:
        for k, file in enumerate(layer_files):
            name = layer_name if len(layer_files) == 1 else f"{layer_name}[{k}]"
            if not file.resolve().is_relative_to(folder):
                raise ForestError(
                    f"{what} {layer_name!r} references a file outside the root layer's folder "
                    "(a path with '..', an absolute path or a link): refused",
                    path="scene",
                )
            if not file.is_file():
                rel = file.resolve().relative_to(folder).as_posix()
                raise ForestError(
                    f"{what} {layer_name!r}: its scene file {rel} is not beside the root layer: "
                    f"a {'mixed' if what == 'layer' else 'tiled'} forest renders with its "
                    f"{what} files, not from its root layer alone",
                    path="scene",
                )
            try:
                if not _has_forest(file):
                    continue  # a layer (or tile) without trees
                scenes.append(read(file))
            except ForestError as exc:
                raise _layer_error(layer_name, exc) from None
            except READ_ERRORS:
                raise ForestError(
                    f"{what} {layer_name!r}: its scene file could not be read", path="scene"
                ) from None
            names.append(name)
    if not scenes:
        raise ForestError(f"the forest has no trees in any {what}", path="scene")
    try:
        terrain = TerrainMesh.from_quads(terrain_points, terrain_quads)
    except ValueError as exc:
        raise ForestError(f"the terrain mesh is malformed: {exc}", path="scene") from None
    return StandScene(path, tuple(names), tuple(scenes), terrain)


def stand_points(stand: StandScene, frame: int = 0, foliage: bool = True) -> F64:
    """``(m, 3)`` world points enclosing every layer's trees (their leaf clouds too, with
    ``foliage``) at ``frame``, and the terrain."""
    parts = [stand.terrain.points]
    for scene in stand.scenes:
        parts.append(scene_points(scene, frame))
        if foliage and scene.n_foliage:
            parts.append(foliage_points(scene, frame))
    return np.concatenate(parts)


def stand_view(
    stand: StandScene,
    size: tuple[int, int],
    tess_max: float,
    frame: int = 0,
    alpha: float = 0.75,
    lod_half: float | None = None,
    foliage: bool = True,
    spec: CameraSpec | None = None,
    ground: bool = False,
) -> tuple[Camera, TessSettings]:
    """:func:`worker.render.render_file.preview_view` for a stand: the camera ``spec`` asks for
    around every layer and the terrain (an ``eye`` view stands on the terrain), and the
    level-of-detail settings. A close-up of one tree (``spec.tree``) is refused."""
    if spec is not None and spec.tree is not None:
        raise ForestError(
            "a mixed forest has no tree numbers across its layers: render a layer's own file "
            "for a close-up",
            path="tree",
        )
    points = stand_points(stand, frame, foliage)
    lo, hi = points.min(axis=0), points.max(axis=0)
    camera = place_camera(spec or CameraSpec(), points, size[0] / size[1], ground, stand.floor())
    tess = auto_lod(camera, lo, hi, tess_max, alpha)
    if lod_half is not None:
        tess = TessSettings(tess_max, alpha, tess.lod_near, lod_half)
    return camera, tess
