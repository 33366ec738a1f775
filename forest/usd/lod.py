"""A skinned tree's levels of detail in USD: the variant set :data:`LOD` on its SkelRoot.

``lod0`` authors nothing: the tree's own Bark, Proxy, Leaves and LeavesProxy (written outside
the variant set) are LOD0, so a stage that selects it composes the tree as it stands. Each
higher level deactivates those four (``active`` is authored nowhere else, so the variant's
opinion holds) and defines its own :func:`lod_mesh` Bark and Leaves, skinned to the same
Skeleton: a consumer switches with ``GetVariantSet('lod').SetVariantSelection('lod2')``.
With :class:`LodOptions` ``impostors``, ``lod3`` is the impostor (:mod:`forest.lod.impostor`,
baked with the render extra's GL): its crossed card pair bound to the root joint, a material
reading the cards' picture (cut by alpha) and, on the mesh, the octahedral atlases' paths.

The skinned trees are themselves written inside the forest's ``representation`` variant, so
the level's edit target nests: the current target's spec path of the tree plus the level's
variant selection.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, UsdSkel

from forest.geometry.pieces import MAX_INFLUENCES
from forest.growth.foliage import FoliageAnchors
from forest.growth.generate import Forest
from forest.lod.levels import Level
from forest.lod.select import BarkMesh, LeavesMesh
from forest.usd.contract import (
    BARK_MESH,
    IMPOSTOR_ATLAS,
    IMPOSTOR_FRAMES,
    IMPOSTOR_MAPS,
    IMPOSTOR_MATERIAL,
    IMPOSTOR_MESH,
    IMPOSTOR_SPHERE,
    LEAVES_MESH,
    LEAVES_PROXY_MESH,
    LOD,
    PROXY_MESH,
    SURFACE,
    lod_mesh,
    lod_variant,
)
from forest.usd.materials import LeafMaterials, st_texture
from forest.usd.prims import set_attr
from forest.usd.skin_prims import bind_skin, define_mesh, indexed_st, write_leaves

if TYPE_CHECKING:
    from forest.lod.impostor import Impostor


IMPOSTOR_LEVEL = 3


@dataclass(frozen=True)
class ImpostorFiles:
    """Where a scene's impostor pictures are written (``folder``, in the layer's private
    folder) and the folder its layer names them in (``asset_folder``, relative to the layer:
    the scene's texture folder, :mod:`forest.usd.textures`, which the pictures join);
    ``packed``: a .usdz's, which names the cards' picture only."""

    folder: Path
    asset_folder: str
    packed: bool = False

    def asset(self, path: Path) -> str:
        return f"{self.asset_folder}/{path.name}"

    def written(self) -> list[Path]:
        """The pictures written so far, by name."""
        if not self.folder.is_dir():
            return []
        return sorted(p for p in self.folder.iterdir() if p.is_file())


@dataclass(frozen=True)
class LodOptions:
    """What :func:`forest.usd.skinned.write_skinned_trees` writes of each tree's levels:
    LOD0-LOD2 always, LOD3 (the impostor) where ``impostors`` says where its pictures go."""

    impostors: ImpostorFiles | None = None


def write_tree_lods(
    stage: Usd.Stage,
    root: Usd.Prim,
    skel: UsdSkel.Skeleton,
    forest: Forest,
    anchors: FoliageAnchors | None,
    levels: list[Level],
    bark: BarkMesh,
    leaves: LeavesMesh | None,
    bark_material: UsdShade.Material,
    leaf_materials: LeafMaterials | None,
    options: LodOptions,
) -> None:
    """The levels of the tree ``root`` (``levels``: :func:`forest.lod.levels.tree_levels` of
    its LOD0 meshes ``bark`` and ``leaves``) as its :data:`LOD` variant set, the impostor
    too where ``options`` asks."""
    impostor = None
    if options.impostors is not None:
        from forest.lod.impostor import bake_tree_impostor

        impostor = (bake_tree_impostor(forest, anchors, bark, leaves), options.impostors)
    write_lod_variants(stage, root, skel, levels, bark_material, leaf_materials, impostor)


def write_lod_variants(
    stage: Usd.Stage,
    root: Usd.Prim,
    skel: UsdSkel.Skeleton,
    levels: list[Level],
    bark_material: UsdShade.Material,
    leaf_materials: LeafMaterials | None,
    impostor: tuple[Impostor, ImpostorFiles] | None = None,
) -> None:
    """The variant set :data:`LOD` on the tree ``root`` (a SkelRoot whose LOD0 meshes are
    written): one variant per level of ``levels`` and ``lod3`` for the ``impostor`` (with
    where its pictures go), ``lod0`` selected."""
    outer = stage.GetEditTarget()
    vset = root.GetVariantSets().AddVariantSet(LOD)
    steps: list[Level | None] = [*levels[1:], *([None] if impostor is not None else [])]
    for k in range(len(levels) + (impostor is not None)):
        vset.AddVariant(lod_variant(k))
    path = root.GetPath()
    for level in steps:
        name = lod_variant(IMPOSTOR_LEVEL if level is None else level.level)
        vset.SetVariantSelection(name)  # a level's prims compose (and define) only when selected
        spec = outer.MapToSpecPath(path).AppendVariantSelection(LOD, name)
        target = Usd.EditTarget.ForLocalDirectVariant(outer.GetLayer(), spec)
        with Usd.EditContext(stage, target):
            for full in (BARK_MESH, PROXY_MESH, LEAVES_MESH, LEAVES_PROXY_MESH):
                if root.GetChild(full):
                    stage.OverridePrim(path.AppendChild(full)).SetActive(False)
            if level is not None:
                _write_level(stage, path, skel, level, bark_material, leaf_materials)
            elif impostor is not None:
                _write_impostor(stage, path, skel, *impostor)
    _level_extents(stage, root, outer, vset)
    vset.SetVariantSelection(lod_variant(0))


def _level_extents(
    stage: Usd.Stage, root: Usd.Prim, outer: Usd.EditTarget, vset: Usd.VariantSet
) -> None:
    """The tree's extent (authored per frame outside the variant set, where it would
    outweigh any variant's) moved into ``lod0`` and computed for every other level inside
    its own variant, so each level's composed extent bounds what it shows."""
    attr = UsdGeom.Boundable(root).GetExtentAttr()
    codes = [Usd.TimeCode(t) for t in attr.GetTimeSamples()] or [Usd.TimeCode.Default()]
    lod0 = [attr.Get(tc) for tc in codes]
    default = attr.Get(Usd.TimeCode.Default())
    spec = outer.GetLayer().GetPrimAtPath(outer.MapToSpecPath(root.GetPath()))
    spec.RemoveProperty(spec.properties[attr.GetName()])
    for name in vset.GetVariantNames():
        vset.SetVariantSelection(name)
        path = outer.MapToSpecPath(root.GetPath()).AppendVariantSelection(LOD, name)
        target = Usd.EditTarget.ForLocalDirectVariant(outer.GetLayer(), path)
        boundable = UsdGeom.Boundable(root)
        if name == lod_variant(0):
            values, first = lod0, default
        else:
            values = [UsdGeom.Boundable.ComputeExtentFromPlugins(boundable, tc) for tc in codes]
            first = values[0]
        with Usd.EditContext(stage, target):
            out = boundable.CreateExtentAttr()
            for tc, value in zip(codes, values, strict=True):
                out.Set(value, tc)
            out.Set(first)


def _write_level(
    stage: Usd.Stage,
    path: Sdf.Path,
    skel: UsdSkel.Skeleton,
    level: Level,
    bark_material: UsdShade.Material,
    leaf_materials: LeafMaterials | None,
) -> None:
    b = level.bark
    mesh = define_mesh(
        stage,
        str(path.AppendChild(lod_mesh(BARK_MESH, level.level))),
        b.points,
        b.normals,
        b.quads,
        UsdGeom.Tokens.default_,
    )
    indexed_st(mesh.GetPrim(), b.st, UsdGeom.Tokens.faceVarying)
    bind_skin(mesh.GetPrim(), skel, b.joints, b.weights, MAX_INFLUENCES)
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(bark_material)
    if level.leaves is not None and leaf_materials is not None:
        name = lod_mesh(LEAVES_MESH, level.level)
        write_leaves(stage, str(path.AppendChild(name)), skel, level.leaves, leaf_materials)


def _write_impostor(
    stage: Usd.Stage, path: Sdf.Path, skel: UsdSkel.Skeleton, imp: Impostor, files: ImpostorFiles
) -> None:
    """lod3: the card pair, bound to the root joint (the cards stand still in the wind), its
    material and the atlases' asset paths."""
    from forest.lod.impostor import card_pair, write_impostor

    written = write_impostor(imp, files.folder, path.name)
    pts, nrm, quads, st = card_pair(imp)
    mesh = define_mesh(
        stage,
        str(path.AppendChild(IMPOSTOR_MESH)),
        pts,
        nrm,
        quads,
        UsdGeom.Tokens.default_,
    )
    mesh.CreateDoubleSidedAttr(True)
    indexed_st(mesh.GetPrim(), st, UsdGeom.Tokens.vertex)
    bind_skin(mesh.GetPrim(), skel, np.zeros(len(pts), np.int32), np.ones(len(pts)), 1)
    prim = mesh.GetPrim()
    # a .usdz carries the cards' picture only: usdz packaging warns on (but packs) assets
    # outside shaders, and Quick Look has no octahedral impostor to feed
    for kind in IMPOSTOR_MAPS if not files.packed else ():
        asset = Sdf.AssetPath(files.asset(written[kind]))
        set_attr(prim, f"{IMPOSTOR_ATLAS}:{kind}", Sdf.ValueTypeNames.Asset, asset)
    set_attr(prim, IMPOSTOR_FRAMES, Sdf.ValueTypeNames.Int, imp.frames)
    set_attr(prim, IMPOSTOR_SPHERE, Sdf.ValueTypeNames.Float4, Gf.Vec4f(*imp.centre, imp.radius))
    look = str(path.AppendChild(IMPOSTOR_MATERIAL))
    mat = UsdShade.Material.Define(stage, look)
    pbr = UsdShade.Shader.Define(stage, f"{look}/{SURFACE}")
    pbr.CreateIdAttr("UsdPreviewSurface")
    pbr.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.8)
    tex = st_texture(
        stage, f"{look}/Cards", files.asset(written["cards"]), "sRGB", (0.3, 0.4, 0.2, 1.0), "clamp"
    )
    rgb = tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    alpha = tex.CreateOutput("a", Sdf.ValueTypeNames.Float)
    pbr.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(rgb)
    pbr.CreateInput("opacity", Sdf.ValueTypeNames.Float).ConnectToSource(alpha)
    pbr.CreateInput("opacityThreshold", Sdf.ValueTypeNames.Float).Set(0.5)
    mat.CreateSurfaceOutput().ConnectToSource(pbr.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(prim).Bind(mat)
