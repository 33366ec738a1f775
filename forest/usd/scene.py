"""Writing a forest as a USD scene (DESIGN.md, "USD scene contract").

``/World/Forest/Pieces`` is one PointInstancer holding every piece of every tree; the piece
meshes are its prototypes. Per instance it carries the topological transform (positions,
orientations as quath *and* quatf, scales), ids, and primvars ``forest:treeId``,
``forest:boneOffset``, ``forest:tileIndices`` and the piece graph. The forest's bone palette
(skinning matrices, prototype space -> world) is stored compactly (:mod:`forest.growth.rig`):
the bones' parents, translations, scales and root rotations once, and ``forest:jointRotations``
(one quatf per turning bone) time-sampled with wind. Gf matrices use row vectors, so every
matrix is transposed on its way out.
"""

from __future__ import annotations

import json
import posixpath
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from pxr import Gf, Kind, Sdf, Usd, UsdGeom, UsdShade, Vt

from forest.bark.tilesets import DEFAULT_SET, mean_colour
from forest.geometry.pieces import HUB, QUAD_ST, PieceArrays
from forest.geometry.transforms import BLOCK, F64, compose_similarity, decompose_similarity
from forest.growth.foliage import (
    LEAF_GREEN,
    Family,
    FoliageAnchors,
    LeafCloud,
    cloud_models,
    leaf_texture,
    yaw_quaternions,
)
from forest.growth.generate import Forest
from forest.growth.rig import BoneRig, forest_rig, joint_rotations
from forest.usd.files import check_output_path, discard, finish, new_stage_layer
from forest.usd.posed import fit_posed, piece_moments
from schemas.tileset import UDIM_PATTERN

FOREST = "/World/Forest"
PIECES = "/World/Forest/Pieces"
FOLIAGE = "/World/Forest/Foliage"
FOLIAGE_PROTOTYPES = "/World/Forest/Foliage/Prototypes"
FOLIAGE_CLOUD = f"{FOLIAGE_PROTOTYPES}/LeafCloud"  # + the model index: LeafCloud0, ...
LOOKS = "/World/Looks"
BARK_TILES = f"{LOOKS}/Bark/Tiles"  # the UsdUVTexture reading the UDIM tiles
BARK_TILE_SET_ATTR = "forest:barkTileSet"  # on the bark material: the shipped set's name
# The variant set on /World/Forest choosing what a consumer that knows nothing of forest:*
# composes: ENGINE the pieces at their topological transforms (rest; the renderer skins them
# with their bone rig), POSED the pieces at best-fit posed transforms, time-sampled,
# SKINNED one UsdSkel mesh per tree (written with --skinned, then the default).
REPRESENTATION = "representation"
ENGINE, POSED, SKINNED = "engine", "posed", "skinned"
# Forests of up to this many trees and pieces get the skinned representation (exact: USD's
# own skinning) unless the caller asks otherwise; larger ones are posed only (rigid best fit
# per piece, README "Representations"): a skinned tree costs 2.5x the file and 9-19x the
# write time of its instanced pieces (4 oaks, 14k pieces, 24 frames: 374 MB, 64 s).
SKINNED_MAX_TREES = 64
SKINNED_MAX_PIECES = 20_000
Progress = Callable[[str, int, int], None]
# How the Pieces instancer stores its bones (``forest:boneFormat``): 2 is the compact rig of
# forest.growth.rig; 1 (no attribute) was one matrix4d per bone per frame, forest:bonePalette.
BONE_FORMAT = 2
JOINT_ROTATIONS = "forest:jointRotations"


def row_major(m: F64) -> Vt.Matrix4dArray:
    """Column-vector ``(n, 4, 4)`` matrices -> Gf row-vector array."""
    return Vt.Matrix4dArray.FromNumpy(np.ascontiguousarray(np.swapaxes(m, -1, -2)))


def _attr(
    prim: Usd.Prim,
    name: str,
    type_: Sdf.ValueTypeName,
    value: object,
    time: Usd.TimeCode | None = None,
) -> Usd.Attribute:
    attr = prim.GetAttribute(name) or prim.CreateAttribute(name, type_, custom=True)
    attr.Set(value, time if time is not None else Usd.TimeCode.Default())
    return attr


def _primvar(
    prim: Usd.Prim,
    name: str,
    type_: Sdf.ValueTypeName,
    interp: str,
    value: object,
    element_size: int = 1,
) -> None:
    pv = UsdGeom.PrimvarsAPI(prim).CreatePrimvar(name, type_, interp, element_size)
    pv.Set(value)


def _quad_mesh(
    stage: Usd.Stage,
    path: str,
    points: F64,
    normals: F64,
    quads: NDArray[np.int32],
    double_sided: bool = False,
) -> UsdGeom.Mesh:
    """A quad Mesh (no subdivision) with per-vertex normals and its extent."""
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points.astype(np.float32)))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(quads), 4, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(quads.ravel()))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    if double_sided:
        mesh.CreateDoubleSidedAttr(True)
    mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(normals.astype(np.float32)))
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    mesh.CreateExtentAttr(UsdGeom.Mesh.ComputeExtent(mesh.GetPointsAttr().Get()))
    return mesh


def write_prototype(
    stage: Usd.Stage, path: str, piece: PieceArrays, material: UsdShade.Material
) -> UsdGeom.Mesh:
    """A piece as a quad Mesh with normals, faceVarying st, skin weights and rim metadata."""
    mesh = _quad_mesh(stage, path, piece.positions, piece.normals, piece.quads)
    prim = mesh.GetPrim()
    st = np.broadcast_to(QUAD_ST, (len(piece.quads), 4, 2)).reshape(-1, 2).astype(np.float32)
    _primvar(
        prim,
        "st",
        Sdf.ValueTypeNames.TexCoord2fArray,
        UsdGeom.Tokens.faceVarying,
        Vt.Vec2fArray.FromNumpy(st),
    )
    _primvar(
        prim,
        "forest:tileClass",
        Sdf.ValueTypeNames.IntArray,
        UsdGeom.Tokens.uniform,
        Vt.IntArray.FromNumpy(piece.tile_class),
    )
    _primvar(
        prim,
        "forest:jointIndices",
        Sdf.ValueTypeNames.IntArray,
        UsdGeom.Tokens.vertex,
        Vt.IntArray.FromNumpy(piece.joint_indices.ravel()),
        4,
    )
    _primvar(
        prim,
        "forest:jointWeights",
        Sdf.ValueTypeNames.FloatArray,
        UsdGeom.Tokens.vertex,
        Vt.FloatArray.FromNumpy(piece.joint_weights.astype(np.float32).ravel()),
        4,
    )
    _attr(
        prim, "forest:rootRim", Sdf.ValueTypeNames.IntArray, Vt.IntArray.FromNumpy(piece.root_rim)
    )
    _attr(
        prim,
        "forest:leafRims",
        Sdf.ValueTypeNames.IntArray,
        Vt.IntArray.FromNumpy(piece.leaf_rims.ravel()),
    )
    _attr(prim, "forest:building", Sdf.ValueTypeNames.Matrix4dArray, row_major(piece.building))
    _attr(prim, "forest:jointRest", Sdf.ValueTypeNames.Matrix4dArray, row_major(piece.joint_rest))
    _attr(
        prim,
        "forest:jointParents",
        Sdf.ValueTypeNames.IntArray,
        Vt.IntArray.FromNumpy(piece.joint_parents),
    )
    _attr(prim, "forest:jointNames", Sdf.ValueTypeNames.TokenArray, list(piece.joint_names))
    UsdShade.MaterialBindingAPI.Apply(prim).Bind(material)
    return mesh


def tile_asset_path(tiles: str) -> str:
    """The UDIM asset path of the tile folder ``tiles`` (given relative to the scene):
    ``./tiles/bark.<UDIM>.png``. The ``./`` anchors it to the layer, which USD resolves
    against the layer's folder, where a bare ``tiles/...`` is a search path that Blender's
    importer resolves against the working directory. Absolute and ``../`` paths are kept."""
    folder = tiles.rstrip("/") or "/"
    if not (posixpath.isabs(folder) or folder in (".", "..") or folder.startswith(("./", "../"))):
        folder = f"./{folder}"
    return posixpath.join(folder, UDIM_PATTERN)


def _st_texture(
    stage: Usd.Stage,
    path: str,
    asset: str,
    color_space: str,
    fallback: tuple[float, ...],
    wrap: str | None = None,
) -> UsdShade.Shader:
    """A UsdUVTexture at ``path`` reading ``asset`` through an ``st`` primvar reader beside it
    (``StReader``, in the same material); the caller adds the outputs it uses."""
    reader = UsdShade.Shader.Define(stage, f"{posixpath.dirname(path)}/StReader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    tex = UsdShade.Shader.Define(stage, path)
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(asset))
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set(color_space)
    if wrap is not None:
        tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set(wrap)
        tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set(wrap)
    tex.CreateInput("fallback", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(*fallback))
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(
        reader.ConnectableAPI(), "result"
    )
    return tex


def bark_material(
    stage: Usd.Stage, tiles: str | None = None, bark: str = DEFAULT_SET
) -> UsdShade.Material:
    """UsdPreviewSurface bark. ``forest:barkTileSet`` names the shipped tile set ``bark``
    (``forest.bark.tilesets``), which the renderer uses when no tile folder is given. With
    ``tiles`` (a folder of ``bark.<UDIM>.png``, relative to the scene) the colour comes from
    the UDIM tiles through ``st``; without, a flat colour, the mean of the set's tiles, so no
    scene references textures that do not exist and a DCC shows the species' colour."""
    UsdGeom.Scope.Define(stage, LOOKS)
    mat = UsdShade.Material.Define(stage, f"{LOOKS}/Bark")
    _attr(mat.GetPrim(), BARK_TILE_SET_ATTR, Sdf.ValueTypeNames.String, bark)
    colour = mean_colour(bark)
    pbr = UsdShade.Shader.Define(stage, f"{LOOKS}/Bark/Surface")
    pbr.CreateIdAttr("UsdPreviewSurface")
    pbr.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.9)
    if tiles is None:
        pbr.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*colour))
    else:
        tex = _st_texture(stage, BARK_TILES, tile_asset_path(tiles), "sRGB", (*colour, 1.0))
        tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
        pbr.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
            tex.ConnectableAPI(), "rgb"
        )
    mat.CreateSurfaceOutput().ConnectToSource(pbr.ConnectableAPI(), "surface")
    return mat


def _time_code(t: float | None, fps: float) -> Usd.TimeCode:
    return Usd.TimeCode.Default() if t is None else Usd.TimeCode(round(t * fps, 9))


def write_instancer(
    stage: Usd.Stage,
    forest: Forest,
    material: UsdShade.Material,
    targets: dict[str, Usd.EditTarget],
    progress: Progress | None = None,
    on_palette: Callable[[float | None, F64], None] | None = None,
) -> UsdGeom.PointInstancer:
    """The pieces' PointInstancer; ``on_palette(time, row_vector_palette)`` sees every
    palette sample as it is written (the foliage writer takes its cloud centres from it).
    Everything but the instance transforms is authored outside the ``representation``
    variants; ``targets[ENGINE]`` gets the exact topological transforms (rest), and
    ``targets[POSED]`` the best-fit posed similarities per palette sample
    (:mod:`forest.usd.posed`)."""
    g = forest.graph
    inst = UsdGeom.PointInstancer.Define(stage, PIECES)
    prim = inst.GetPrim()
    protos = UsdGeom.Scope.Define(stage, f"{PIECES}/Prototypes")
    paths = [
        write_prototype(stage, f"{protos.GetPath()}/{p.name}", p, material).GetPath()
        for p in forest.pieces
    ]
    inst.CreatePrototypesRel().SetTargets(paths)
    inst.CreateProtoIndicesAttr(Vt.IntArray.FromNumpy(g.piece))
    boxes = np.stack(
        [np.stack([p.positions.min(axis=0), p.positions.max(axis=0)]) for p in forest.pieces]
    )[g.piece]
    t, q, s = decompose_similarity(forest.transforms)
    with Usd.EditContext(stage, targets[ENGINE]):  # exact topological transforms
        inst.CreatePositionsAttr(Vt.Vec3fArray.FromNumpy(t.astype(np.float32)))
        inst.CreateOrientationsAttr(Vt.QuathArray.FromNumpy(q.astype(np.float16)))
        inst.CreateOrientationsfAttr(Vt.QuatfArray.FromNumpy(q.astype(np.float32)))
        inst.CreateScalesAttr(
            Vt.Vec3fArray.FromNumpy(np.repeat(s[:, None], 3, axis=1).astype(np.float32))
        )
        inst.CreateExtentAttr(_instances_extent(boxes, forest.transforms))
    moments = piece_moments(forest.pieces)
    inst.CreateIdsAttr(Vt.Int64Array.FromNumpy(np.arange(len(g), dtype=np.int64)))
    q_max = forest.tile_indices.shape[1]
    vertex = UsdGeom.Tokens.vertex
    ints = Sdf.ValueTypeNames.IntArray
    for name, arr, size in (
        ("forest:treeId", g.tree, 1),
        ("forest:boneOffset", forest.bones.offset, 1),
        # int16 straight into int[]: Vt widens it without an int32 copy of the largest array
        ("forest:tileIndices", forest.tile_indices.ravel(), q_max),
        ("forest:parent", g.parent, 1),
        ("forest:parentRim", g.parent_rim, 1),
        ("forest:twist", g.twist, 1),
        ("forest:depth", g.depth, 1),
        ("forest:symbol", g.symbol, 1),
    ):
        _primvar(prim, name, ints, vertex, Vt.IntArray.FromNumpy(np.ascontiguousarray(arr)), size)
    _attr(prim, "forest:symbols", Sdf.ValueTypeNames.TokenArray, list(forest.grammar.rules))
    write_rig(prim, forest_rig(forest))  # the rig's arrays go as soon as they are in the layer
    times = forest.frame_times()
    for i, time in enumerate(times):
        palette = _row_palette(forest, time)
        code = _time_code(time, forest.options.fps)
        rotations = joint_rotations(forest, time, np.float32)
        quats = Vt.QuatfArray.FromNumpy(rotations)
        _attr(prim, JOINT_ROTATIONS, Sdf.ValueTypeNames.QuatfArray, quats, code)
        t, q, s = fit_posed(moments, g.piece, forest.bones.offset, np.swapaxes(palette, -1, -2))
        with Usd.EditContext(stage, targets[POSED]):
            # the first sample is also the default, so tools that read no time see the pose
            for c in (Usd.TimeCode.Default(), code) if i == 0 else (code,):
                inst.CreatePositionsAttr().Set(Vt.Vec3fArray.FromNumpy(t.astype(np.float32)), c)
                inst.CreateOrientationsAttr().Set(Vt.QuathArray.FromNumpy(q.astype(np.float16)), c)
                inst.CreateScalesAttr().Set(
                    Vt.Vec3fArray.FromNumpy(np.repeat(s[:, None], 3, axis=1).astype(np.float32)),
                    c,
                )
                inst.CreateExtentAttr().Set(_posed_extent(boxes, t, q, s), c)
        if on_palette is not None:
            on_palette(time, palette)
        del palette, rotations, quats, t, q, s
        if progress:
            progress("palette", i + 1, len(times))
    return inst


def _row_palette(forest: Forest, time: float | None) -> F64:
    """The palette at ``time`` in USD's row-vector form. A still forest whose generation kept
    its posed palette gives that one transposed (a view, equal to a fresh row-vector palette
    bit for bit) instead of posing every bone again into a second copy."""
    if time is None and forest.still_palette is not None:
        return np.swapaxes(forest.still_palette, -1, -2)
    return forest.palette(time, row_vectors=True)


def _posed_extent(boxes: F64, t: F64, q: F64, s: F64) -> Vt.Vec3fArray:
    """:func:`_instances_extent` of the similarities ``(t, q, s)``, composed a block of
    instances at a time (min and max are exact in any order: the same extent as one pass)."""
    if not len(t):
        return _instances_extent(boxes, np.zeros((0, 4, 4)))
    lo, hi = np.full(3, np.inf, np.float32), np.full(3, -np.inf, np.float32)
    for a in range(0, len(t), BLOCK):
        z = a + BLOCK
        ext = np.asarray(_instances_extent(boxes[a:z], compose_similarity(t[a:z], q[a:z], s[a:z])))
        lo, hi = np.minimum(lo, ext[0]), np.maximum(hi, ext[1])
    return Vt.Vec3fArray.FromNumpy(np.stack([lo, hi]))


def write_rig(prim: Usd.Prim, rig: BoneRig) -> None:
    """The time-independent part of the bones (:class:`forest.growth.rig.BoneRig`; the rest
    joint frames are the prototypes' ``forest:jointRest``) and the format marker."""
    _attr(prim, "forest:boneFormat", Sdf.ValueTypeNames.Int, BONE_FORMAT)
    parents = Vt.IntArray.FromNumpy(np.ascontiguousarray(rig.parent, np.int32))
    _attr(prim, "forest:boneParents", Sdf.ValueTypeNames.IntArray, parents)
    _attr(
        prim,
        "forest:boneTranslations",
        Sdf.ValueTypeNames.Double3Array,
        Vt.Vec3dArray.FromNumpy(np.ascontiguousarray(rig.translation)),
    )
    _attr(
        prim,
        "forest:boneScales",
        Sdf.ValueTypeNames.DoubleArray,
        Vt.DoubleArray.FromNumpy(np.ascontiguousarray(rig.scale)),
    )
    _attr(
        prim,
        "forest:rootRotations",
        Sdf.ValueTypeNames.QuatdArray,
        Vt.QuatdArray.FromNumpy(np.ascontiguousarray(rig.root_rotation)),
    )


def _instances_extent(boxes: F64, m: F64) -> Vt.Vec3fArray:
    """The extent of boxes ``(n, 2, 3)`` (min, max) under ``(n, 4, 4)`` transforms, as
    PointInstancer.ComputeExtent takes it: the bound of every transformed box corner,
    found without corners (a box's half size along axis i is ``sum_j |A_ij| h_j``)."""
    if not len(boxes):
        return Vt.Vec3fArray.FromNumpy(np.zeros((2, 3), np.float32))
    out = np.stack([np.full(3, np.inf), np.full(3, -np.inf)])
    for a in range(0, len(boxes), BLOCK):  # a block at a time: min and max are exact
        b, lin = boxes[a : a + BLOCK], m[a : a + BLOCK, :3, :3]
        centre = (b[:, 0] + b[:, 1]) / 2
        half = (b[:, 1] - b[:, 0]) / 2
        c = np.einsum("nij,nj->ni", lin, centre) + m[a : a + BLOCK, :3, 3]
        h = np.einsum("nij,nj->ni", np.abs(lin), half)
        out[0] = np.minimum(out[0], (c - h).min(axis=0))
        out[1] = np.maximum(out[1], (c + h).max(axis=0))
    return Vt.Vec3fArray.FromNumpy(out.astype(np.float32))


@dataclass(frozen=True)
class LeafMaterials:
    """The leaves' two materials. ``flat``, bound for all purposes, is one colour: what every
    DCC shows (Blender 4.2 and Maya's importers turn a ``UsdPrimvarReader_float3`` into
    nothing, which rendered the leaves white). ``tinted``, bound for the ``preview`` purpose,
    reads ``displayColor`` per cloud: what Hydra Storm (usdview, Houdini's viewport) shows."""

    flat: UsdShade.Material
    tinted: UsdShade.Material

    def bind(self, prim: Usd.Prim) -> None:
        api = UsdShade.MaterialBindingAPI.Apply(prim)
        api.Bind(self.flat)
        api.Bind(self.tinted, materialPurpose=UsdShade.Tokens.preview)


def write_leaf_texture(folder: Path, family: Family) -> Path:
    """The leaf family's picture (:func:`forest.growth.foliage.leaf_texture`) as
    ``folder/leaf-<family>.png``, its rows turned so that USD's ``st`` (t up from the image's
    bottom row) reads it as the leaf cards do: the stem end at t = 0."""
    from forest.bark.images import write_png

    path = folder / f"leaf-{family}.png"
    write_png(path, np.ascontiguousarray(leaf_texture(family)[::-1]))
    return path


def leaf_material(
    stage: Usd.Stage, colors: NDArray[np.floating] | None = None, texture: str | None = None
) -> LeafMaterials:
    """UsdPreviewSurface leaves: the flat one in the mean of the clouds' linear RGB ``colors``
    (leaf green where there are none), the tinted one reading the ``displayColor`` primvar
    (the instancer's per-instance colour, the skinned leaves' per-face one) with that mean as
    its fallback. With ``texture`` (an asset path to :func:`write_leaf_texture`'s picture,
    as a .usdz carries it) both cut each card to its leaf: ``opacity`` from the picture's
    alpha through ``st``, ``opacityThreshold`` 0.5, so a DCC shows leaves, not square cards;
    without, no scene points at a texture file it does not carry."""
    mean = (
        tuple(float(c) for c in np.asarray(colors, np.float64).mean(axis=0))
        if colors is not None and len(colors)
        else LEAF_GREEN
    )
    UsdGeom.Scope.Define(stage, LOOKS)

    def surface(name: str) -> tuple[UsdShade.Material, UsdShade.Shader]:
        mat = UsdShade.Material.Define(stage, f"{LOOKS}/{name}")
        pbr = UsdShade.Shader.Define(stage, f"{LOOKS}/{name}/Surface")
        pbr.CreateIdAttr("UsdPreviewSurface")
        pbr.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.7)
        if texture is not None:
            path = f"{LOOKS}/{name}/Cutout"
            cutout = _st_texture(stage, path, texture, "raw", (1.0, 1.0, 1.0, 1.0), "clamp")
            cutout.CreateOutput("a", Sdf.ValueTypeNames.Float)
            pbr.CreateInput("opacity", Sdf.ValueTypeNames.Float).ConnectToSource(
                cutout.ConnectableAPI(), "a"
            )
            pbr.CreateInput("opacityThreshold", Sdf.ValueTypeNames.Float).Set(0.5)
        mat.CreateSurfaceOutput().ConnectToSource(pbr.ConnectableAPI(), "surface")
        return mat, pbr

    flat, pbr = surface("Leaf")
    pbr.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*mean))
    tinted, pbr = surface("LeafTinted")
    color = UsdShade.Shader.Define(stage, f"{LOOKS}/LeafTinted/DisplayColor")
    color.CreateIdAttr("UsdPrimvarReader_float3")
    color.CreateInput("varname", Sdf.ValueTypeNames.String).Set("displayColor")
    color.CreateInput("fallback", Sdf.ValueTypeNames.Float3).Set(Gf.Vec3f(*mean))
    out = color.CreateOutput("result", Sdf.ValueTypeNames.Float3)
    pbr.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(out)
    return LeafMaterials(flat, tinted)


def write_leaf_cloud(
    stage: Usd.Stage, path: str, cloud: LeafCloud, material: LeafMaterials
) -> UsdGeom.Mesh:
    """A leaf-cloud model as a double-sided Mesh of leaf cards (unit diameter), its leaf family
    in ``forest:leafFamily`` (which texture its st index). No displayColor of its own, so the
    instancer's per-instance displayColor reaches it."""
    mesh = _quad_mesh(stage, path, cloud.positions, cloud.normals, cloud.quads, double_sided=True)
    _primvar(
        mesh.GetPrim(),
        "st",
        Sdf.ValueTypeNames.TexCoord2fArray,
        UsdGeom.Tokens.vertex,
        Vt.Vec2fArray.FromNumpy(cloud.st.astype(np.float32)),
    )
    _attr(mesh.GetPrim(), "forest:leafFamily", Sdf.ValueTypeNames.Token, cloud.family)
    material.bind(mesh.GetPrim())
    return mesh


def write_foliage(
    stage: Usd.Stage,
    forest: Forest,
    anchors: FoliageAnchors,
    samples: list[tuple[float | None, F64]],
    leaf_file: str | None = None,
) -> UsdGeom.PointInstancer:
    """Leaf clouds as a PointInstancer of the leaf family's cloud models (one Mesh prototype
    per model, ``protoIndices`` the model): one instance per anchor, turned about +y by its
    yaw (``orientations``/``orientationsf``; the exact radians in ``forest:yaw``), scaled by
    its diameter, at its centre on the posed forest (``samples``: time and ``(k, 3)`` centres
    per palette sample, time-sampled with wind), tinted by ``primvars:displayColor`` (linear
    RGB, vertex interpolation: one per instance). Per instance also: the piece it sits on
    (``forest:instance``), that piece's ``forest:boneOffset`` and the joint it follows
    (``forest:joint``), and the rest point in the piece's model space
    (``forest:restPosition``): the centre at any frame is ``palette[boneOffset + joint]``
    applied to the rest point."""
    inst = UsdGeom.PointInstancer.Define(stage, FOLIAGE)
    prim = inst.GetPrim()
    UsdGeom.Scope.Define(stage, FOLIAGE_PROTOTYPES)
    material = leaf_material(stage, anchors.color, leaf_file)
    models = cloud_models(anchors.family)
    meshes = [
        write_leaf_cloud(stage, f"{FOLIAGE_CLOUD}{m}", cloud, material)
        for m, cloud in enumerate(models)
    ]
    inst.CreatePrototypesRel().SetTargets([mesh.GetPath() for mesh in meshes])
    k = len(anchors)
    inst.CreateProtoIndicesAttr(Vt.IntArray.FromNumpy(anchors.model.astype(np.int32)))
    q = yaw_quaternions(anchors.yaw)
    inst.CreateOrientationsAttr(Vt.QuathArray.FromNumpy(q.astype(np.float16)))
    inst.CreateOrientationsfAttr(Vt.QuatfArray.FromNumpy(q.astype(np.float32)))
    inst.CreateScalesAttr(
        Vt.Vec3fArray.FromNumpy(np.repeat(anchors.size[:, None], 3, axis=1).astype(np.float32))
    )
    inst.CreateIdsAttr(Vt.Int64Array.FromNumpy(np.arange(k, dtype=np.int64)))
    positions = inst.CreatePositionsAttr()
    # the default is the first sample, so tools that read no time still see the clouds
    positions.Set(Vt.Vec3fArray.FromNumpy(samples[0][1].astype(np.float32)))
    for time, pos in samples:
        if time is not None:
            positions.Set(
                Vt.Vec3fArray.FromNumpy(pos.astype(np.float32)),
                _time_code(time, forest.options.fps),
            )
    vertex = UsdGeom.Tokens.vertex
    ints = Sdf.ValueTypeNames.IntArray
    _primvar(
        prim,
        "displayColor",
        Sdf.ValueTypeNames.Color3fArray,
        vertex,
        Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(anchors.color, np.float32)),
    )
    _primvar(
        prim,
        "forest:yaw",
        Sdf.ValueTypeNames.DoubleArray,
        vertex,
        Vt.DoubleArray.FromNumpy(np.ascontiguousarray(anchors.yaw, np.float64)),
    )
    _primvar(prim, "forest:instance", ints, vertex, Vt.IntArray.FromNumpy(anchors.instance))
    _primvar(
        prim,
        "forest:boneOffset",
        ints,
        vertex,
        Vt.IntArray.FromNumpy(forest.bones.offset[anchors.instance]),
    )
    _primvar(prim, "forest:joint", ints, vertex, Vt.IntArray.FromNumpy(np.full(k, HUB, np.int32)))
    _primvar(
        prim,
        "forest:restPosition",
        Sdf.ValueTypeNames.Float3Array,
        vertex,
        Vt.Vec3fArray.FromNumpy(anchors.rest.astype(np.float32)),
    )
    # extent over every sample: every cloud's bounding ball (any yaw) at every frame
    pos_all = np.stack([p for _, p in samples])
    r = anchors.size[None, :, None] * max(c.radius for c in models)
    lo = (pos_all - r).min(axis=(0, 1))
    hi = (pos_all + r).max(axis=(0, 1))
    inst.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([lo, hi]).astype(np.float32)))
    return inst


def define_world(stage: Usd.Stage, group_path: str) -> tuple[UsdGeom.Xform, UsdGeom.Xform]:
    """Y up, metres, ``/World`` (an assembly, the default prim) and the group under it."""
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    world = UsdGeom.Xform.Define(stage, "/World")
    Usd.ModelAPI(world).SetKind(Kind.Tokens.assembly)
    stage.SetDefaultPrim(world.GetPrim())
    group = UsdGeom.Xform.Define(stage, group_path)
    Usd.ModelAPI(group).SetKind(Kind.Tokens.group)
    return world, group


def setup_stage(stage: Usd.Stage, forest: Forest) -> None:
    _, group = define_world(stage, FOREST)
    prim = group.GetPrim()
    stage.GetRootLayer().documentation = (
        f"interlocking-forest {forest.version}: {forest.options.trees} trees from grammar "
        f"{forest.grammar.name or '(unnamed)'} (axiom {forest.grammar.axiom}), seed "
        f"{int(forest.seed)}; /World/Forest.forest:grammar holds the grammar, "
        "forest:options the options. Variant set 'representation' on /World/Forest: "
        "engine (pieces at rest + the bone rig, forest:jointRotations), posed (pieces at "
        "posed transforms), "
        "skinned (UsdSkel trees, when written)."
    )
    # everything needed to make the scene again
    grammar_json = json.dumps(forest.grammar.model_dump(mode="json"), sort_keys=True)
    _attr(prim, "forest:grammar", Sdf.ValueTypeNames.String, grammar_json)
    _attr(prim, "forest:seed", Sdf.ValueTypeNames.Int64, int(forest.seed))
    _attr(prim, "forest:version", Sdf.ValueTypeNames.String, forest.version)
    opts = forest.options
    _attr(
        prim,
        "forest:options",
        Sdf.ValueTypeNames.String,
        json.dumps(
            {
                "trees": opts.trees,
                "area": list(opts.area),
                "frames": opts.frames,
                "fps": opts.fps,
                "placement": opts.placement,
                "segments": opts.segments,
                "wind": vars(opts.wind),
                "season": opts.season,
            },
            sort_keys=True,
        ),
    )
    _attr(prim, "forest:tileManifest", Sdf.ValueTypeNames.String, forest.manifest.model_dump_json())
    _attr(
        prim,
        "forest:treeTransforms",
        Sdf.ValueTypeNames.Matrix4dArray,
        row_major(forest.tree_transforms),
    )
    if forest.animated:
        stage.SetTimeCodesPerSecond(opts.fps)
        stage.SetFramesPerSecond(opts.fps)
        stage.SetStartTimeCode(0)
        stage.SetEndTimeCode(opts.frames - 1)


def write_scene(
    forest: Forest,
    path: str | Path,
    *,
    skinned: bool | None = None,
    tiles: str | None = None,
    progress: Progress | None = None,
) -> Path:
    """Write ``forest`` to ``path`` (.usda, .usdc or .usdz); returns the path.

    ``skinned``: True writes the skinned trees (then the composed default), False only the
    posed and engine representations, None (default) decides by size: skinned for up to
    :data:`SKINNED_MAX_TREES` trees and :data:`SKINNED_MAX_PIECES` pieces. A .usdz always
    carries the skinned trees and composes them by default (ARKit allows no PointInstancer),
    so ``skinned`` is implied there."""
    out = check_output_path(path)
    skinned = wants_skinned(forest, out, skinned)
    stage, tmp = new_stage_layer(out)
    try:
        setup_stage(stage, forest)
        vset, targets = representation_variants(stage, skinned)
        anchors = forest.foliage_anchors() if len(forest.foliage_instance) else None
        leaf_file = None
        if out.suffix.lower() == ".usdz" and anchors is not None:
            # the leaf picture goes inside: written beside the layer (an absolute path: the
            # packager embeds it under a name of its own). Bark tiles only from a given
            # folder: Blender 4.2 finds no UDIM tile inside a package (magenta bark)
            leaf_file = write_leaf_texture(tmp.parent, anchors.family).resolve().as_posix()
        material = bark_material(stage, tiles, forest.grammar.bark)
        samples: list[tuple[float | None, F64]] = []

        def foliage_sample(time: float | None, palette: F64) -> None:
            if anchors is not None:
                samples.append((time, anchors.positions(palette, row_vectors=True)))

        write_instancer(stage, forest, material, targets, progress, foliage_sample)
        if anchors is not None:
            write_foliage(stage, forest, anchors, samples, leaf_file)
        if skinned:
            from forest.usd.skinned import write_skinned_trees

            vset.SetVariantSelection(SKINNED)  # its extents are computed on the composed trees
            with Usd.EditContext(stage, targets[SKINNED]):
                write_skinned_trees(stage, forest, material, anchors, progress, leaf_file)
                # the skinned trees carry the leaves: each tree is shown once
                for where in (PIECES, FOLIAGE):
                    if stage.GetPrimAtPath(where):
                        stage.GetPrimAtPath(where).SetActive(False)
        vset.SetVariantSelection(SKINNED if skinned else POSED)
        finish(stage, tmp, out)
    finally:
        del stage
        discard(tmp)  # the private folder, with whatever a failed write left in it
    return out


def wants_skinned(forest: Forest, path: Path, skinned: bool | None = None) -> bool:
    """Whether :func:`write_scene` writes (and composes) the skinned trees: always in a
    .usdz, else ``skinned`` when given, else for forests of at most
    :data:`SKINNED_MAX_TREES` trees and :data:`SKINNED_MAX_PIECES` pieces."""
    if path.suffix.lower() == ".usdz":
        return True
    if skinned is not None:
        return skinned
    return (
        len(forest.tree_transforms) <= SKINNED_MAX_TREES
        and forest.n_instances <= SKINNED_MAX_PIECES
    )


def representation_variants(
    stage: Usd.Stage, skinned: bool
) -> tuple[Usd.VariantSet, dict[str, Usd.EditTarget]]:
    """The ``representation`` variant set on /World/Forest and an edit target per variant."""
    vset = stage.GetPrimAtPath(FOREST).GetVariantSets().AddVariantSet(REPRESENTATION)
    targets = {}
    for name in (ENGINE, POSED, SKINNED) if skinned else (ENGINE, POSED):
        vset.AddVariant(name)
        vset.SetVariantSelection(name)
        targets[name] = vset.GetVariantEditTarget()
    return vset, targets


def tile_udim_st(tile_indices: NDArray[np.integer]) -> F64:
    """``(q, 4, 2)`` faceVarying st placing each quad's corners in the UDIM tile of its
    slice: tile ``1001 + k`` spans u in [k % 10, k % 10 + 1], v in [k // 10, k // 10 + 1]."""
    k = np.maximum(tile_indices, 0)
    offset = np.stack([k % 10, k // 10], axis=-1).astype(np.float64)
    return QUAD_ST[None] + offset[:, None]
