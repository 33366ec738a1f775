"""The prims of a skinned mesh: a Mesh of quads with vertex normals and a purpose, its st as an
indexed primvar, its binding to a Skeleton's joints; and a tree's leaves as such a mesh.
Shared by the skinned trees (:mod:`forest.usd.skinned`) and their levels of detail
(:mod:`forest.usd.lod`)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from pxr import Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt

from forest.geometry.transforms import F64
from forest.lod.select import LeavesMesh
from forest.usd.materials import LeafMaterials


def write_leaves(
    stage: Usd.Stage,
    path: str,
    skel: UsdSkel.Skeleton,
    leaves: LeavesMesh,
    materials: LeafMaterials,
    purpose: str = UsdGeom.Tokens.default_,
) -> UsdGeom.Mesh:
    """``leaves`` as a double-sided Mesh at ``path``, each vertex bound rigidly to its joint
    of ``skel``, with the leaf ``materials``."""
    lm = define_mesh(stage, path, leaves.points, leaves.normals, leaves.quads, purpose)
    lm.CreateDoubleSidedAttr(True)
    indexed_st(lm.GetPrim(), leaves.st, UsdGeom.Tokens.vertex)
    lm.CreateDisplayColorPrimvar(UsdGeom.Tokens.uniform).Set(Vt.Vec3fArray.FromNumpy(leaves.colour))
    bind_skin(lm.GetPrim(), skel, leaves.joint, np.ones(len(leaves.joint)), 1)
    materials.bind(lm.GetPrim())
    return lm


def bind_skin(
    prim: Usd.Prim, skel: UsdSkel.Skeleton, jidx: NDArray[np.int32], jw: F64, size: int
) -> None:
    api = UsdSkel.BindingAPI.Apply(prim)
    api.CreateSkeletonRel().SetTargets([skel.GetPath()])
    api.CreateJointIndicesPrimvar(False, size).Set(Vt.IntArray.FromNumpy(jidx.ravel()))
    api.CreateJointWeightsPrimvar(False, size).Set(
        Vt.FloatArray.FromNumpy(jw.astype(np.float32).ravel())
    )
    api.CreateGeomBindTransformAttr(Gf.Matrix4d(1.0))


def define_mesh(
    stage: Usd.Stage,
    path: str,
    pts: F64,
    normals: F64,
    faces: NDArray[np.int32],
    purpose: str,
) -> UsdGeom.Mesh:
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(pts, np.float32)))
    mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(normals, np.float32)))
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    mesh.CreateFaceVertexCountsAttr(
        Vt.IntArray.FromNumpy(np.full(len(faces), faces.shape[1], np.int32))
    )
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(faces).ravel()))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateExtentAttr(UsdGeom.Mesh.ComputeExtent(mesh.GetPointsAttr().Get()))
    mesh.CreatePurposeAttr(purpose)
    return mesh


def indexed_st(prim: Usd.Prim, st: F64, interp: str) -> None:
    """``st`` as an indexed primvar: the few distinct UVs and an index per element."""
    # distinct as stored (float32 pairs), each pair one uint64: a 1-D unique is ten times
    # faster than np.unique(axis=0), which sorted rows as opaque records
    pairs = np.ascontiguousarray(st.reshape(-1, 2), dtype=np.float32).view(np.uint64).ravel()
    keys, index = np.unique(pairs, return_inverse=True)
    values = keys.view(np.float32).reshape(-1, 2)
    pv = UsdGeom.PrimvarsAPI(prim).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, interp)
    pv.Set(Vt.Vec2fArray.FromNumpy(values))
    pv.SetIndices(Vt.IntArray.FromNumpy(index.ravel().astype(np.int32)))
