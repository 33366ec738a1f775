"""A mixed forest (a recipe's stand) as USD: one scene file per species layer (per layer and
tile when tiled), each the ordinary forest scene of :mod:`forest.usd.scene`, and a root layer
that references them all over the terrain, so a DCC opens the whole stand as one scene.

Root layer::

    /World                         Xform, assembly, default prim; forest:recipe (JSON)
    /World/Terrain                 Mesh (quads, normals, primvars:st 0-1 over the area),
                                   bound to /World/Looks/Ground (UsdPreviewSurface)
    /World/Layers                  Xform, group
    /World/Layers/<layer>          Xform, assembly; forest:species, forest:role, forest:trees;
                                   a reference to @./<OUT>_layers/<layer>.usdc@ (untiled), or
    /World/Layers/<layer>/T_<i>_<j>  one reference per tile with trees (tiled)

Every reference carries ``extentsHint``. Layer files keep their own textures (bark tile set
and leaf picture, in ``<layer>.textures/`` beside them) unless tiled (flat colours, as a tiled
forest's tiles).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from pxr import Gf, Kind, Sdf, Usd, UsdGeom, UsdShade, Vt

from forest.atomic import replaced_when_written
from forest.errors import ForestError
from forest.growth.generate import ForestOptions
from forest.stand.generate import Stand
from forest.usd.contract import (
    LAYER_ROLE,
    LAYER_SPECIES,
    RECIPE,
    STAND_LAYERS,
    TERRAIN,
    TERRAIN_MATERIAL,
    TILE_INDEX,
    TILE_TREES,
    tile_name,
)
from forest.usd.files import check_output_path
from forest.usd.prims import define_world, set_frames
from forest.usd.tiled import tile_extent, write_empty_tile
from schemas.tiles import tile_grid

GROUND_COLOR = (0.20, 0.17, 0.11)  # linear: dark loam under leaf litter
Note = Callable[[str, int, int], None]


@dataclass(frozen=True)
class LayerFile:
    """A written layer (or layer tile): the recipe's layer index, the tile (None untiled),
    its file relative to the root's folder, extent and tree count."""

    layer: int
    tile: tuple[int, int] | None
    asset: str
    extent: tuple[tuple[float, float, float], tuple[float, float, float]]
    trees: int
    pieces: int = 0

    def to_json(self) -> dict[str, object]:
        return {
            "layer": self.layer,
            "tile": None if self.tile is None else list(self.tile),
            "asset": self.asset,
            "extent": [list(self.extent[0]), list(self.extent[1])],
            "trees": self.trees,
            "pieces": self.pieces,
        }

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> LayerFile:
        (x0, y0, z0), (x1, y1, z1) = d["extent"]
        tile = None if d["tile"] is None else (int(d["tile"][0]), int(d["tile"][1]))
        extent = ((float(x0), float(y0), float(z0)), (float(x1), float(y1), float(z1)))
        return cls(
            int(d["layer"]), tile, str(d["asset"]), extent, int(d["trees"]), int(d.get("pieces", 0))
        )


def layers_folder(root: Path) -> Path:
    """Where a stand's layer files live: ``<stem>_layers`` beside the root layer."""
    return root.with_name(f"{root.stem}_layers")


def layer_file(root: Path, name: str, beside: bool) -> Path:
    """A layer's (or a layer tile's) file: in :func:`layers_folder`, or with ``beside``
    ``<stem>_<name>.usdc`` in the root's own folder (one folder of plain names, as a job's
    artifacts are)."""
    if beside:
        return root.with_name(f"{root.stem}_{name}.usdc")
    return layers_folder(root) / f"{name}.usdc"


def write_stand(
    stand: Stand,
    path: str | Path,
    options: ForestOptions,
    *,
    skinned: bool | None = None,
    textures: bool = True,
    tile_size: float | None = None,
    progress: Note | None = None,
    beside: bool = False,
) -> Path:
    """Grow and write every layer of ``stand`` (one at a time), then the root layer; the
    layer files where :func:`layer_file` puts them (``beside``: next to the root)."""

    out = check_output_path(path, (".usda", ".usdc"))
    if not beside:
        layers_folder(out).mkdir(parents=True, exist_ok=True)
    note = progress or (lambda stage, done, total: None)
    tiles = [None] if tile_size is None else _tiles(stand.area, tile_size)
    jobs = [(k, t) for k in range(len(stand.recipe.layers)) for t in tiles]
    files: list[LayerFile] = []
    for n, (k, tile) in enumerate(jobs):
        note("layers", n, len(jobs))
        name = stand.recipe.layers[k].name
        file = layer_file(out, name if tile is None else f"{name}_{tile[0]}_{tile[1]}", beside)
        made = write_layer_file(stand, k, file, options, tile, tile_size, skinned, textures)
        if made is not None:
            files.append(replace(made, asset=f"./{file.relative_to(out.parent)}"))
    note("layers", len(jobs), len(jobs))
    return write_stand_root(out, stand, files, frames=options.frames, fps=options.fps)


def write_layer_file(
    stand: Stand,
    k: int,
    file: Path,
    options: ForestOptions,
    tile: tuple[int, int] | None = None,
    tile_size: float | None = None,
    skinned: bool | None = None,
    textures: bool = False,
) -> LayerFile | None:
    """Grow layer ``k`` (its trees in ``tile`` of ``tile_size`` metres, or all of them) and
    write it to ``file``; its entry (asset: the file's name), or None for a tile without the
    layer's trees (no file). An untiled layer without trees is an empty scene."""
    from forest.usd.scene import write_scene

    trees = stand.placement.layers[k]
    if tile is not None:
        assert tile_size is not None
        rect = _rect(stand.area, tile_size, *tile)
        trees = trees.within(rect, _closed(stand.area, tile_size, *tile), stand.area)
    forest = stand.grow_layer(k, options, trees, tile)
    pieces = 0
    if forest is None:
        if tile is not None:
            return None
        write_empty_tile(file)
    else:
        write_scene(forest, file, skinned=skinned, textures=textures and tile is None)
        pieces = forest.n_instances
    del forest
    return LayerFile(k, tile, f"./{file.name}", tile_extent(file), len(trees), pieces)


def _tiles(area: tuple[float, float], tile_size: float) -> list[tuple[int, int] | None]:
    nx, nz = tile_grid(area, tile_size)
    return [(i, j) for j in range(nz) for i in range(nx)]


def largest_tile_counts(stand: Stand, tile_size: float) -> list[int]:
    """Each layer's most trees in one tile of ``tile_size`` metres (as
    :meth:`forest.stand.place.LayerTrees.within` cuts them: half-open tiles, the last row and
    column closed), the counts its caps are checked on before any tile grows."""
    nx, nz = tile_grid(stand.area, tile_size)
    out = []
    for t in stand.placement.layers:
        if not len(t):
            out.append(0)
            continue
        x = t.positions[:, 0] + stand.area[0] / 2
        z = t.positions[:, 2] + stand.area[1] / 2
        i = np.clip(np.floor(x / tile_size).astype(np.int64), 0, nx - 1)
        j = np.clip(np.floor(z / tile_size).astype(np.int64), 0, nz - 1)
        out.append(int(np.bincount(j * nx + i).max()))
    return out


def _rect(area: tuple[float, float], s: float, i: int, j: int) -> tuple[float, float, float, float]:
    return i * s, min((i + 1) * s, area[0]), j * s, min((j + 1) * s, area[1])


def _closed(area: tuple[float, float], s: float, i: int, j: int) -> tuple[bool, bool]:
    nx, nz = tile_grid(area, s)
    return i == nx - 1, j == nz - 1


def write_stand_root(
    path: Path, stand: Stand, files: list[LayerFile], *, frames: int = 0, fps: float = 24.0
) -> Path:
    """The root layer over written layer files (see the module's docstring)."""
    root = Sdf.Layer.CreateAnonymous("stand.usda")  # held here: it outlives the stage
    stage = Usd.Stage.Open(root)
    try:
        world, _ = define_world(stage, STAND_LAYERS)
        stage.GetRootLayer().documentation = (
            f"interlocking-forest mixed forest: recipe {stand.recipe.name}, "
            f"{stand.trees} trees in {len(stand.recipe.layers)} layers over terrain"
        )
        world.GetPrim().CreateAttribute(RECIPE, Sdf.ValueTypeNames.String, custom=True).Set(
            stand.recipe.model_dump_json(exclude_none=True)
        )
        if frames > 0:
            set_frames(stage, frames, fps)
        ground = _terrain(stage, stand)
        refs: list[tuple[Sdf.Path, str]] = []
        whole = Gf.Range3d()
        lo_g, hi_g = ground.min(axis=0), ground.max(axis=0)
        whole.UnionWith(Gf.Range3d(Gf.Vec3d(*lo_g.tolist()), Gf.Vec3d(*hi_g.tolist())))
        for k, layer in enumerate(stand.recipe.layers):
            xf = UsdGeom.Xform.Define(stage, f"{STAND_LAYERS}/{layer.name}")
            prim = xf.GetPrim()
            Usd.ModelAPI(prim).SetKind(Kind.Tokens.assembly)
            prim.CreateAttribute(LAYER_SPECIES, Sdf.ValueTypeNames.String, custom=True).Set(
                layer.species
            )
            prim.CreateAttribute(LAYER_ROLE, Sdf.ValueTypeNames.String, custom=True).Set(layer.role)
            mine = [f for f in files if f.layer == k]
            prim.CreateAttribute(TILE_TREES, Sdf.ValueTypeNames.Int, custom=True).Set(
                sum(f.trees for f in mine)
            )
            for f in mine:
                target = prim
                if f.tile is not None:
                    target = UsdGeom.Xform.Define(
                        stage, f"{STAND_LAYERS}/{layer.name}/{tile_name(*f.tile)}"
                    ).GetPrim()
                    Usd.ModelAPI(target).SetKind(Kind.Tokens.assembly)
                    target.CreateAttribute(TILE_INDEX, Sdf.ValueTypeNames.Int2, custom=True).Set(
                        Gf.Vec2i(*f.tile)
                    )
                    target.CreateAttribute(TILE_TREES, Sdf.ValueTypeNames.Int, custom=True).Set(
                        f.trees
                    )
                refs.append((target.GetPath(), f.asset))
                lo, hi = f.extent
                UsdGeom.ModelAPI.Apply(target).SetExtentsHint(
                    Vt.Vec3fArray([Gf.Vec3f(*lo), Gf.Vec3f(*hi)])
                )
                if f.trees:
                    whole.UnionWith(Gf.Range3d(Gf.Vec3d(*lo), Gf.Vec3d(*hi)))
        lo3, hi3 = whole.GetMin(), whole.GetMax()
        UsdGeom.ModelAPI.Apply(world.GetPrim()).SetExtentsHint(
            Vt.Vec3fArray([Gf.Vec3f(*lo3), Gf.Vec3f(*hi3)])
        )
    finally:
        del stage
    # referenced once the stage is gone: writing the root never opens a layer file
    for prim_path, asset in refs:
        root.GetPrimAtPath(prim_path).referenceList.Prepend(Sdf.Reference(asset))
    with replaced_when_written(path) as tmp:
        if not root.Export(str(tmp)):
            raise ForestError("cannot write the root layer", path=str(path))
    return path


def stand_file(root: str | Path, path: str | Path) -> Path:
    """A written stand (its root layer and layer files) as one file: ``.usda``/``.usdc``
    flattened (every layer composed into one; no texture folder travels with it, so the
    layers are best written without textures), or a ``.usdz`` package of the root, its layer
    files and every picture they name."""
    out = check_output_path(path)
    root = Path(root)
    if out.suffix.lower() == ".usdz":
        from pxr import UsdUtils

        with replaced_when_written(out) as tmp:
            if not UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(root)), str(tmp)):
                raise ForestError("cannot package the stand as a .usdz", path=out.name)
        return out
    stage = Usd.Stage.Open(str(root))
    if stage is None:
        raise ForestError("cannot open the stand's root layer", path=root.name)
    flat = stage.Flatten()
    del stage
    with replaced_when_written(out) as tmp:
        if not flat.Export(str(tmp)):
            raise ForestError("cannot write the flattened stand", path=out.name)
    return out


def _terrain(stage: Usd.Stage, stand: Stand) -> np.ndarray:
    """The terrain's Mesh and its Ground material; its points (for the root's extent)."""
    points, quads, st, normals = stand.ground.mesh()
    mesh = UsdGeom.Mesh.Define(stage, TERRAIN)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points.astype(np.float32)))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(quads), 4, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(quads.reshape(-1).astype(np.int32)))
    mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(normals.astype(np.float32)))
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    lo, hi = points.min(axis=0), points.max(axis=0)
    mesh.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*lo.tolist()), Gf.Vec3f(*hi.tolist())]))
    api = UsdGeom.PrimvarsAPI(mesh)
    api.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex).Set(
        Vt.Vec2fArray.FromNumpy(st.astype(np.float32))
    )
    mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(
        Vt.Vec3fArray([Gf.Vec3f(*GROUND_COLOR)])
    )
    mat = UsdShade.Material.Define(stage, TERRAIN_MATERIAL)
    pbr = UsdShade.Shader.Define(stage, f"{TERRAIN_MATERIAL}/Surface")
    pbr.CreateIdAttr("UsdPreviewSurface")
    pbr.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*GROUND_COLOR))
    pbr.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.95)
    mat.CreateSurfaceOutput().ConnectToSource(pbr.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
    return points


@dataclass(frozen=True)
class StandLayerFiles:
    """A written stand's layer as its root layer names it: the layer's name, species, role
    and its scene files (one, or one per tile with trees), absolute."""

    name: str
    species: str
    role: str
    files: tuple[Path, ...]


@dataclass(frozen=True)
class StandFiles:
    """What a stand's root layer holds: the recipe (JSON), the terrain mesh (points ``(p,
    3)``, quads ``(q, 4)``) and the layers."""

    recipe: dict[str, object]
    terrain_points: np.ndarray
    terrain_quads: np.ndarray
    layers: tuple[StandLayerFiles, ...]


def is_stand(path: str | Path) -> bool:
    """True when ``path`` is a USD layer whose ``/World`` carries a recipe (read without
    composing: references are not opened)."""
    layer = Sdf.Layer.FindOrOpen(str(path))
    if layer is None:
        return False
    spec = layer.GetPrimAtPath("/World")
    return spec is not None and RECIPE in spec.attributes


def read_stand(path: str | Path) -> StandFiles:
    """A stand's root layer, read without composing it (each layer file is opened by its
    reader on its own)."""
    root = Path(path)
    layer = Sdf.Layer.FindOrOpen(str(root))
    world = layer.GetPrimAtPath("/World") if layer is not None else None
    if world is None or RECIPE not in world.attributes:
        raise ForestError("not a mixed forest's root layer (no forest:recipe)", path=str(root))
    recipe = json.loads(world.attributes[RECIPE].default)
    terrain = layer.GetPrimAtPath(TERRAIN)
    if terrain is None:
        raise ForestError(f"missing prim {TERRAIN}", path=str(root))
    points = np.array(terrain.attributes["points"].default, np.float64).reshape(-1, 3)
    quads = np.array(terrain.attributes["faceVertexIndices"].default, np.int64).reshape(-1, 4)
    group = layer.GetPrimAtPath(STAND_LAYERS)
    layers = []
    for spec in group.nameChildren if group is not None else ():
        targets = [spec, *spec.nameChildren]
        files = tuple(
            (root.parent / ref.assetPath).resolve()
            for t in targets
            for ref in t.referenceList.GetAddedOrExplicitItems()
        )
        attrs = spec.attributes
        layers.append(
            StandLayerFiles(
                spec.name,
                str(attrs[LAYER_SPECIES].default) if LAYER_SPECIES in attrs else "",
                str(attrs[LAYER_ROLE].default) if LAYER_ROLE in attrs else "",
                files,
            )
        )
    return StandFiles(recipe, points, quads, tuple(layers))
