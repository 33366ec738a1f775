"""A forest's leaf clouds as a PointInstancer (``/World/Forest/Foliage``, see
:mod:`forest.usd.contract`) of the leaf family's cloud models, following the pieces' bones."""

from __future__ import annotations

import numpy as np
from pxr import Sdf, Usd, UsdGeom, Vt

from forest.geometry.pieces import HUB
from forest.geometry.transforms import F64
from forest.growth.foliage import FoliageAnchors, LeafCloud, yaw_quaternions
from forest.growth.generate import Forest
from forest.growth.rig import F32
from forest.usd.contract import (
    BONE_OFFSET,
    FOLIAGE,
    FOLIAGE_CLOUD,
    FOLIAGE_PROTOTYPES,
    INSTANCE,
    JOINT,
    LEAF_FAMILY,
    REST_POSITION,
    YAW,
)
from forest.usd.materials import LeafMaterials, leaf_material
from forest.usd.prims import quad_mesh, set_attr, set_primvar, time_code


def write_leaf_cloud(
    stage: Usd.Stage, path: str, cloud: LeafCloud, material: LeafMaterials
) -> UsdGeom.Mesh:
    """A leaf-cloud model as a double-sided Mesh of leaf cards (unit diameter), its leaf family
    in ``forest:leafFamily`` (which texture its st index). No displayColor of its own, so the
    instancer's per-instance displayColor reaches it."""
    mesh = quad_mesh(stage, path, cloud.positions, cloud.normals, cloud.quads, double_sided=True)
    set_primvar(
        mesh.GetPrim(),
        "st",
        Sdf.ValueTypeNames.TexCoord2fArray,
        UsdGeom.Tokens.vertex,
        Vt.Vec2fArray.FromNumpy(cloud.st.astype(np.float32)),
    )
    set_attr(mesh.GetPrim(), LEAF_FAMILY, Sdf.ValueTypeNames.Token, cloud.family)
    material.bind(mesh.GetPrim())
    return mesh


def write_foliage(
    stage: Usd.Stage,
    forest: Forest,
    anchors: FoliageAnchors,
    samples: list[tuple[float | None, F32]],
    extent: F64,
    leaf_file: str | None = None,
) -> UsdGeom.PointInstancer:
    """Leaf clouds as a PointInstancer of the leaf family's cloud models (one Mesh prototype
    per model, ``protoIndices`` the model): one instance per anchor, turned about +y by its
    yaw (``orientations``/``orientationsf``; the exact radians in ``forest:yaw``), scaled by
    its diameter, at its centre on the posed forest (``samples``: time and ``(k, 3)`` float32
    centres per palette sample, time-sampled with wind; ``extent`` ``(2, 3)`` the bound of
    every cloud's ball over the samples, :func:`clouds_bound`), tinted by
    ``primvars:displayColor`` (linear RGB, vertex interpolation: one per instance). Per
    instance also: the piece it sits on (``forest:instance``), that piece's
    ``forest:boneOffset`` and the joint it follows
    (``forest:joint``), and the rest point in the piece's model space
    (``forest:restPosition``): the centre at any frame is ``palette[boneOffset + joint]``
    applied to the rest point."""
    inst = UsdGeom.PointInstancer.Define(stage, FOLIAGE)
    prim = inst.GetPrim()
    UsdGeom.Scope.Define(stage, FOLIAGE_PROTOTYPES)
    material = leaf_material(stage, anchors.color, leaf_file)
    models = anchors.models()
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
    for i, (time, pos) in enumerate(samples):
        value = Vt.Vec3fArray.FromNumpy(pos)
        # the default is the first sample, so tools that read no time still see the clouds
        if i == 0:
            positions.Set(value)
        if time is not None:
            positions.Set(value, time_code(time, forest.options.fps))
    vertex = UsdGeom.Tokens.vertex
    ints = Sdf.ValueTypeNames.IntArray
    set_primvar(
        prim,
        "displayColor",
        Sdf.ValueTypeNames.Color3fArray,
        vertex,
        Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(anchors.color, np.float32)),
    )
    set_primvar(
        prim,
        YAW,
        Sdf.ValueTypeNames.DoubleArray,
        vertex,
        Vt.DoubleArray.FromNumpy(np.ascontiguousarray(anchors.yaw, np.float64)),
    )
    set_primvar(prim, INSTANCE, ints, vertex, Vt.IntArray.FromNumpy(anchors.instance))
    set_primvar(
        prim,
        BONE_OFFSET,
        ints,
        vertex,
        Vt.IntArray.FromNumpy(forest.bones.offset[anchors.instance]),
    )
    set_primvar(prim, JOINT, ints, vertex, Vt.IntArray.FromNumpy(np.full(k, HUB, np.int32)))
    set_primvar(
        prim,
        REST_POSITION,
        Sdf.ValueTypeNames.Float3Array,
        vertex,
        Vt.Vec3fArray.FromNumpy(anchors.rest.astype(np.float32)),
    )
    inst.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(extent.astype(np.float32)))
    return inst


def clouds_bound(anchors: FoliageAnchors, positions: F64, bound: F64 | None = None) -> F64:
    """``(2, 3)`` min and max of every cloud's bounding ball (any yaw) centred on
    ``positions`` ``(k, 3)``, joined with ``bound`` (that of other samples): the extent over
    every frame, without a ``(frames, k, 3)`` stack of them (min and max are exact in any
    order)."""
    r = anchors.size[:, None] * max(c.radius for c in anchors.models())
    out = np.stack([(positions - r).min(axis=0), (positions + r).max(axis=0)])
    if bound is not None:
        out = np.stack([np.minimum(bound[0], out[0]), np.maximum(bound[1], out[1])])
    return out
