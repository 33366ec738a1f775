"""A tiled forest as USD: one scene file per tile and a root layer holding each tile as a
payload with its extent, so a DCC opens the whole forest at once (payloads unloaded, boxes
from ``extentsHint``) and loads tiles on demand.

Root layer::

    /World                       Xform, assembly, default prim
    /World/Tiles                 Xform, group
    /World/Tiles/T_<i>_<j>       Xform, assembly; payload @./<OUT>_tiles/<i>_<j>.usdc@,
                                 extentsHint (min, max) over every frame; forest:tile (i, j)
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pxr import Gf, Kind, Sdf, Usd, UsdGeom, Vt

from forest.atomic import replaced_when_written
from forest.errors import ForestError
from forest.growth.generate import Forest
from forest.usd.contract import TILE_INDEX, TILE_TREES, TILES, TILING, WORLD, tile_name
from forest.usd.files import check_output_path, discard, finish, new_stage_layer
from forest.usd.prims import define_world, set_frames

TILE_SUFFIX = ".usdc"


@dataclass(frozen=True)
class TileEntry:
    """A written tile: its index, its file relative to the root layer's folder (posix), its
    extent ``((x, y, z) min, (x, y, z) max)`` in metres and its tree count."""

    i: int
    j: int
    asset: str
    extent: tuple[tuple[float, float, float], tuple[float, float, float]]
    trees: int

    def to_json(self) -> dict[str, object]:
        return {
            "i": self.i,
            "j": self.j,
            "asset": self.asset,
            "extent": self.extent,
            "trees": self.trees,
        }

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> TileEntry:
        (x0, y0, z0), (x1, y1, z1) = d["extent"]
        extent = ((float(x0), float(y0), float(z0)), (float(x1), float(y1), float(z1)))
        return cls(int(d["i"]), int(d["j"]), str(d["asset"]), extent, int(d["trees"]))


def tiles_folder(root: Path) -> Path:
    """Where the tiles of root layer ``root`` live: ``<stem>_tiles`` beside it."""
    return root.with_name(f"{root.stem}_tiles")


def tile_extent(path: Path) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """The world extent of a written tile's default prim over its default time and every
    authored frame (wind moves the crowns)."""
    stage = Usd.Stage.Open(str(path))
    prim = stage.GetDefaultPrim()
    start, end = stage.GetStartTimeCode(), stage.GetEndTimeCode()
    times = [Usd.TimeCode.Default()]
    if stage.HasAuthoredTimeCodeRange():
        times += [Usd.TimeCode(t) for t in np.arange(start, end + 1)]
    box = Gf.Range3d()
    purposes = [UsdGeom.Tokens.default_, UsdGeom.Tokens.render]
    for t in times:
        box.UnionWith(UsdGeom.BBoxCache(t, purposes).ComputeWorldBound(prim).ComputeAlignedRange())
    if box.IsEmpty():
        return (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    lo, hi = box.GetMin(), box.GetMax()
    return (lo[0], lo[1], lo[2]), (hi[0], hi[1], hi[2])


def write_empty_tile(path: Path) -> Path:
    """A tile no tree stands in: ``/World`` only (the root's payload still resolves)."""
    stage, tmp = new_stage_layer(path)
    try:
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
        world = UsdGeom.Xform.Define(stage, WORLD)
        stage.SetDefaultPrim(world.GetPrim())
        finish(stage, tmp, path)
    finally:
        del stage
        discard(tmp)
    return path


def write_tile(
    forest: Forest | None, root: Path, i: int, j: int, *, skinned: bool = False
) -> TileEntry:
    """Write tile ``(i, j)`` (a forest, or None for an empty tile) beside the root layer
    ``root``, in ``<root stem>_tiles/<i>_<j>.usdc``."""
    folder = tiles_folder(root)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{i}_{j}{TILE_SUFFIX}"
    return write_tile_file(forest, path, f"./{folder.name}/{path.name}", i, j, skinned=skinned)


def write_tile_file(
    forest: Forest | None, path: Path, asset: str, i: int, j: int, *, skinned: bool = False
) -> TileEntry:
    """Write tile ``(i, j)`` to ``path``; its entry names it ``asset`` (relative to the root
    layer's folder)."""
    from forest.usd.scene import write_scene

    if forest is None:
        write_empty_tile(path)
    else:
        # flat colours: a texture folder per tile would copy the tile set into every tile
        write_scene(forest, path, skinned=skinned, textures=False)
    trees = 0 if forest is None else forest.options.trees
    return TileEntry(i, j, asset, tile_extent(path), trees)


def write_root(
    path: str | Path,
    tiles: Sequence[TileEntry],
    *,
    doc: str = "",
    frames: int = 0,
    fps: float = 24.0,
    meta: dict[str, object] | None = None,
) -> Path:
    """Write the root layer of a tiled forest (.usda or .usdc): every tile a payload with
    its ``extentsHint``, ordered by ``(j, i)`` whatever order ``tiles`` come in."""
    out = check_output_path(path, (".usda", ".usdc"))
    # authored with payloads unloaded: writing the root never opens a tile
    stage = Usd.Stage.CreateInMemory(load=Usd.Stage.LoadNone)
    try:
        world, group = define_world(stage, TILES)
        stage.GetRootLayer().documentation = doc or (
            f"interlocking-forest tiled forest: {len(tiles)} tile payloads under {TILES}"
        )
        if meta is not None:
            group.GetPrim().CreateAttribute(TILING, Sdf.ValueTypeNames.String, custom=True).Set(
                json.dumps(meta, sort_keys=True)
            )
        if frames > 0:
            set_frames(stage, frames, fps)
        whole = Gf.Range3d()
        for t in sorted(tiles, key=lambda e: (e.j, e.i)):
            xf = UsdGeom.Xform.Define(stage, f"{TILES}/{tile_name(t.i, t.j)}")
            prim = xf.GetPrim()
            Usd.ModelAPI(prim).SetKind(Kind.Tokens.assembly)
            prim.GetPayloads().AddPayload(t.asset)
            lo, hi = t.extent
            UsdGeom.ModelAPI.Apply(prim).SetExtentsHint(
                Vt.Vec3fArray([Gf.Vec3f(*lo), Gf.Vec3f(*hi)])
            )
            prim.CreateAttribute(TILE_INDEX, Sdf.ValueTypeNames.Int2, custom=True).Set(
                Gf.Vec2i(t.i, t.j)
            )
            prim.CreateAttribute(TILE_TREES, Sdf.ValueTypeNames.Int, custom=True).Set(t.trees)
            if t.trees:
                whole.UnionWith(Gf.Range3d(Gf.Vec3d(*lo), Gf.Vec3d(*hi)))
        if not whole.IsEmpty():
            lo3, hi3 = whole.GetMin(), whole.GetMax()
            UsdGeom.ModelAPI.Apply(world.GetPrim()).SetExtentsHint(
                Vt.Vec3fArray([Gf.Vec3f(*lo3), Gf.Vec3f(*hi3)])
            )
        # in a private folder, then renamed: a half-written root never shows
        with replaced_when_written(out) as tmp:
            if not stage.GetRootLayer().Export(str(tmp)):
                raise ForestError("cannot write the root layer", path=str(out))
    finally:
        del stage
    return out
