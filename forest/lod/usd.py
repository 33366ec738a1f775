"""A skinned tree's levels of detail in USD: the variant set :data:`LOD` on its SkelRoot.

``lod0`` authors nothing: the tree's own Bark, Proxy and Leaves (written outside the variant
set) are LOD0, so a stage that selects it composes exactly the tree without levels. Each
higher level deactivates those three (``active`` is authored nowhere else, so the variant's
opinion holds) and defines its own :func:`lod_mesh` Bark and Leaves, skinned to the same
Skeleton: a consumer switches with ``GetVariantSet('lod').SetVariantSelection('lod2')``.

The skinned trees are themselves written inside the forest's ``representation`` variant, so
the level's edit target nests: the current target's spec path of the tree plus the level's
variant selection.
"""

from __future__ import annotations

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdShade, UsdSkel, Vt

from forest.geometry.pieces import MAX_INFLUENCES
from forest.geometry.transforms import F64
from forest.growth.foliage import FoliageAnchors
from forest.growth.generate import Forest
from forest.lod.levels import Level, tree_levels
from forest.lod.select import BarkMesh, LeavesMesh
from forest.usd.contract import BARK_MESH, LEAVES_MESH, LOD, PROXY_MESH, lod_mesh, lod_variant
from forest.usd.materials import LeafMaterials
from forest.usd.skinned import _bind, _indexed_st, _mesh


def write_tree_lods(
    stage: Usd.Stage,
    root: Usd.Prim,
    skel: UsdSkel.Skeleton,
    forest: Forest,
    anchors: FoliageAnchors | None,
    tree: tuple[slice, slice, F64, F64],
    bark: BarkMesh,
    leaves: LeavesMesh | None,
    bark_material: UsdShade.Material,
    leaf_materials: LeafMaterials | None,
) -> list[Level]:
    """The levels of the tree ``root`` (``tree``: its instances, joints, world-to-tree
    transform and still palette, as :func:`forest.usd.skinned.tree_mesh` takes them; ``bark``
    and ``leaves`` its LOD0 meshes) as its :data:`LOD` variant set; returns the levels."""
    inst, bones, to_tree, still = tree
    levels = tree_levels(forest, anchors, inst, bones, to_tree, still, bark, leaves)
    write_lod_variants(stage, root, skel, levels, bark_material, leaf_materials)
    return levels


def write_lod_variants(
    stage: Usd.Stage,
    root: Usd.Prim,
    skel: UsdSkel.Skeleton,
    levels: list[Level],
    bark_material: UsdShade.Material,
    leaf_materials: LeafMaterials | None,
) -> None:
    """The variant set :data:`LOD` on the tree ``root`` (a SkelRoot whose LOD0 meshes are
    written): one variant per level of ``levels``, ``lod0`` selected."""
    outer = stage.GetEditTarget()
    vset = root.GetVariantSets().AddVariantSet(LOD)
    for level in levels:
        vset.AddVariant(lod_variant(level.level))
    path = root.GetPath()
    for level in levels[1:]:
        name = lod_variant(level.level)
        vset.SetVariantSelection(name)  # a level's prims compose (and define) only when selected
        spec = outer.MapToSpecPath(path).AppendVariantSelection(LOD, name)
        target = Usd.EditTarget.ForLocalDirectVariant(outer.GetLayer(), spec)
        with Usd.EditContext(stage, target):
            for full in (BARK_MESH, PROXY_MESH, LEAVES_MESH):
                if root.GetChild(full):
                    stage.OverridePrim(path.AppendChild(full)).SetActive(False)
            _write_level(stage, path, skel, level, bark_material, leaf_materials)
    vset.SetVariantSelection(lod_variant(0))


def _write_level(
    stage: Usd.Stage,
    path: Sdf.Path,
    skel: UsdSkel.Skeleton,
    level: Level,
    bark_material: UsdShade.Material,
    leaf_materials: LeafMaterials | None,
) -> None:
    b = level.bark
    mesh = _mesh(
        stage,
        str(path.AppendChild(lod_mesh(BARK_MESH, level.level))),
        b.points,
        b.normals,
        b.quads,
        UsdGeom.Tokens.default_,
    )
    _indexed_st(mesh.GetPrim(), b.st, UsdGeom.Tokens.faceVarying)
    _bind(mesh.GetPrim(), skel, b.joints, b.weights, MAX_INFLUENCES)
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(bark_material)
    leaves = level.leaves
    if leaves is None or leaf_materials is None:
        return
    lm = _mesh(
        stage,
        str(path.AppendChild(lod_mesh(LEAVES_MESH, level.level))),
        leaves.points,
        leaves.normals,
        leaves.quads,
        UsdGeom.Tokens.default_,
    )
    lm.CreateDoubleSidedAttr(True)
    _indexed_st(lm.GetPrim(), leaves.st, UsdGeom.Tokens.vertex)
    lm.CreateDisplayColorPrimvar(UsdGeom.Tokens.uniform).Set(Vt.Vec3fArray.FromNumpy(leaves.colour))
    _bind(lm.GetPrim(), skel, leaves.joint, np.ones(len(leaves.joint)), 1)
    leaf_materials.bind(lm.GetPrim())
