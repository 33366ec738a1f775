"""The pieces of a forest as one PointInstancer (``/World/Forest/Pieces``, see
:mod:`forest.usd.contract`): the piece meshes are its prototypes. Per instance it carries the
topological transform (positions, orientations as quatf ``orientationsf``, scales), ids, and
primvars ``forest:treeId``, ``forest:boneOffset``, ``forest:tileIndices`` and the piece
graph. The forest's bone palette (skinning matrices, prototype space -> world) is stored
compactly (:mod:`forest.growth.rig`): the bones' parents, translations, scales and root
rotations once (float32: a palette rebuilt from them agrees with the generator's to about
5e-8 of the forest's size, within ``PALETTE_REBUILT_REL``), and ``forest:jointRotations``
(one quatf per turning bone) time-sampled with wind. Gf matrices use row vectors, so every
matrix is transposed on its way out.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdShade, Vt

from forest.geometry.pieces import QUAD_ST, PieceArrays
from forest.geometry.transforms import BLOCK, F64, compose_similarity, decompose_similarity
from forest.growth.generate import Forest
from forest.growth.rig import BoneRig, forest_rig, joint_rotations
from forest.usd.contract import (
    BONE_FORMAT,
    BONE_FORMAT_VERSION,
    BONE_OFFSET,
    BONE_PARENTS,
    BONE_SCALES,
    BONE_TRANSLATIONS,
    BUILDING,
    DEPTH,
    ENGINE,
    JOINT_INDICES,
    JOINT_NAMES,
    JOINT_PARENTS,
    JOINT_REST,
    JOINT_ROTATIONS,
    JOINT_WEIGHTS,
    LEAF_RIMS,
    PARENT,
    PARENT_RIM,
    PIECE_PROTOTYPES,
    PIECES,
    POSED,
    ROOT_RIM,
    ROOT_ROTATIONS,
    SYMBOL,
    SYMBOLS,
    TILE_CLASS,
    TILE_INDICES,
    TREE_ID,
    TWIST,
)
from forest.usd.posed import fit_posed, piece_moments
from forest.usd.prims import quad_mesh, row_major, set_attr, set_primvar, time_code

Progress = Callable[[str, int, int], None]


def write_prototype(
    stage: Usd.Stage, path: str, piece: PieceArrays, material: UsdShade.Material
) -> UsdGeom.Mesh:
    """A piece as a quad Mesh with normals, faceVarying st, skin weights and rim metadata."""
    mesh = quad_mesh(stage, path, piece.positions, piece.normals, piece.quads)
    prim = mesh.GetPrim()
    st = np.broadcast_to(QUAD_ST, (len(piece.quads), 4, 2)).reshape(-1, 2).astype(np.float32)
    set_primvar(
        prim,
        "st",
        Sdf.ValueTypeNames.TexCoord2fArray,
        UsdGeom.Tokens.faceVarying,
        Vt.Vec2fArray.FromNumpy(st),
    )
    set_primvar(
        prim,
        TILE_CLASS,
        Sdf.ValueTypeNames.IntArray,
        UsdGeom.Tokens.uniform,
        Vt.IntArray.FromNumpy(piece.tile_class),
    )
    set_primvar(
        prim,
        JOINT_INDICES,
        Sdf.ValueTypeNames.IntArray,
        UsdGeom.Tokens.vertex,
        Vt.IntArray.FromNumpy(piece.joint_indices.ravel()),
        4,
    )
    set_primvar(
        prim,
        JOINT_WEIGHTS,
        Sdf.ValueTypeNames.FloatArray,
        UsdGeom.Tokens.vertex,
        Vt.FloatArray.FromNumpy(piece.joint_weights.astype(np.float32).ravel()),
        4,
    )
    set_attr(prim, ROOT_RIM, Sdf.ValueTypeNames.IntArray, Vt.IntArray.FromNumpy(piece.root_rim))
    set_attr(
        prim,
        LEAF_RIMS,
        Sdf.ValueTypeNames.IntArray,
        Vt.IntArray.FromNumpy(piece.leaf_rims.ravel()),
    )
    set_attr(prim, BUILDING, Sdf.ValueTypeNames.Matrix4dArray, row_major(piece.building))
    set_attr(prim, JOINT_REST, Sdf.ValueTypeNames.Matrix4dArray, row_major(piece.joint_rest))
    set_attr(
        prim,
        JOINT_PARENTS,
        Sdf.ValueTypeNames.IntArray,
        Vt.IntArray.FromNumpy(piece.joint_parents),
    )
    set_attr(prim, JOINT_NAMES, Sdf.ValueTypeNames.TokenArray, list(piece.joint_names))
    UsdShade.MaterialBindingAPI.Apply(prim).Bind(material)
    return mesh


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
    times = forest.frame_times()
    if progress:  # the instance arrays before the first sample take a while on big forests
        progress("palette", 0, len(times))
    inst = UsdGeom.PointInstancer.Define(stage, PIECES)
    prim = inst.GetPrim()
    protos = UsdGeom.Scope.Define(stage, PIECE_PROTOTYPES)
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
    # exact topological transforms: quatf orientationsf alone (USD prefers it to the quath
    # orientations, whose half floats turn a piece by up to 1e-3 rad: a second copy was bytes
    # no reader looked at)
    with Usd.EditContext(stage, targets[ENGINE]):
        inst.CreatePositionsAttr(Vt.Vec3fArray.FromNumpy(t.astype(np.float32)))
        inst.CreateOrientationsfAttr(Vt.QuatfArray.FromNumpy(q.astype(np.float32)))
        inst.CreateScalesAttr(
            Vt.Vec3fArray.FromNumpy(np.repeat(s.astype(np.float32)[:, None], 3, axis=1))
        )
        inst.CreateExtentAttr(instances_extent(boxes, forest.transforms))
    moments = piece_moments(forest.pieces)
    inst.CreateIdsAttr(Vt.Int64Array.FromNumpy(np.arange(len(g), dtype=np.int64)))
    q_max = forest.tile_indices.shape[1]
    vertex = UsdGeom.Tokens.vertex
    ints = Sdf.ValueTypeNames.IntArray
    for name, arr, size in (
        (TREE_ID, g.tree, 1),
        (BONE_OFFSET, forest.bones.offset, 1),
        # int16 straight into int[]: Vt widens it without an int32 copy of the largest array
        (TILE_INDICES, forest.tile_indices.ravel(), q_max),
        (PARENT, g.parent, 1),
        (PARENT_RIM, g.parent_rim, 1),
        (TWIST, g.twist, 1),
        (DEPTH, g.depth, 1),
        (SYMBOL, g.symbol, 1),
    ):
        set_primvar(
            prim, name, ints, vertex, Vt.IntArray.FromNumpy(np.ascontiguousarray(arr)), size
        )
    set_attr(prim, SYMBOLS, Sdf.ValueTypeNames.TokenArray, list(forest.grammar.rules))
    write_rig(prim, forest_rig(forest))  # the rig's arrays go as soon as they are in the layer
    for i, time in enumerate(times):
        palette = _row_palette(forest, time)
        code = time_code(time, forest.options.fps)
        rotations = joint_rotations(forest, time, np.float32)
        quats = Vt.QuatfArray.FromNumpy(rotations)
        set_attr(prim, JOINT_ROTATIONS, Sdf.ValueTypeNames.QuatfArray, quats, code)
        t, q, s = fit_posed(moments, g.piece, forest.bones.offset, np.swapaxes(palette, -1, -2))
        positions = Vt.Vec3fArray.FromNumpy(t.astype(np.float32))
        orientations = Vt.QuathArray.FromNumpy(q.astype(np.float16))
        scales = Vt.Vec3fArray.FromNumpy(np.repeat(s.astype(np.float32)[:, None], 3, axis=1))
        extent = _posed_extent(boxes, t, q, s)
        # the first sample is also the default, so tools that read no time see the pose; a
        # still forest's only sample is the default itself: each value is authored once
        codes = [code]
        if i == 0 and not code.IsDefault():
            codes.insert(0, Usd.TimeCode.Default())
        with Usd.EditContext(stage, targets[POSED]):
            for c in codes:
                inst.CreatePositionsAttr().Set(positions, c)
                inst.CreateOrientationsAttr().Set(orientations, c)
                inst.CreateScalesAttr().Set(scales, c)
                inst.CreateExtentAttr().Set(extent, c)
        if on_palette is not None:
            on_palette(time, palette)
        del palette, rotations, quats, t, q, s, positions, orientations, scales, extent
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


def write_rig(prim: Usd.Prim, rig: BoneRig) -> None:
    """The time-independent part of the bones (:class:`forest.growth.rig.BoneRig`; the rest
    joint frames are the prototypes' ``forest:jointRest``) and the format marker. Stored as
    float32 (bone format 3): translations are local to the parent bone and scales mostly
    short binary fractions, so rounding stays at float32's own spacing."""
    set_attr(prim, BONE_FORMAT, Sdf.ValueTypeNames.Int, BONE_FORMAT_VERSION)
    parents = Vt.IntArray.FromNumpy(np.ascontiguousarray(rig.parent, np.int32))
    set_attr(prim, BONE_PARENTS, Sdf.ValueTypeNames.IntArray, parents)
    set_attr(
        prim,
        BONE_TRANSLATIONS,
        Sdf.ValueTypeNames.Float3Array,
        Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(rig.translation, np.float32)),
    )
    set_attr(
        prim,
        BONE_SCALES,
        Sdf.ValueTypeNames.FloatArray,
        Vt.FloatArray.FromNumpy(np.ascontiguousarray(rig.scale, np.float32)),
    )
    set_attr(
        prim,
        ROOT_ROTATIONS,
        Sdf.ValueTypeNames.QuatfArray,
        Vt.QuatfArray.FromNumpy(np.ascontiguousarray(rig.root_rotation, np.float32)),
    )


def instances_extent(boxes: F64, m: F64) -> Vt.Vec3fArray:
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


def _posed_extent(boxes: F64, t: F64, q: F64, s: F64) -> Vt.Vec3fArray:
    """:func:`instances_extent` of the similarities ``(t, q, s)``, composed a block of
    instances at a time (min and max are exact in any order: the same extent as one pass)."""
    if not len(t):
        return instances_extent(boxes, np.zeros((0, 4, 4)))
    lo, hi = np.full(3, np.inf, np.float32), np.full(3, -np.inf, np.float32)
    for a in range(0, len(t), BLOCK):
        z = a + BLOCK
        ext = np.asarray(instances_extent(boxes[a:z], compose_similarity(t[a:z], q[a:z], s[a:z])))
        lo, hi = np.minimum(lo, ext[0]), np.maximum(hi, ext[1])
    return Vt.Vec3fArray.FromNumpy(np.stack([lo, hi]))
