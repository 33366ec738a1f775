"""Small pieces every USD writer here uses: the stage's world and frame range, custom
attributes and primvars, quad meshes, time codes and matrices in Gf's row-vector form."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from pxr import Kind, Sdf, Usd, UsdGeom, Vt

from forest.geometry.transforms import F64
from forest.usd.contract import WORLD


def define_world(stage: Usd.Stage, group_path: str) -> tuple[UsdGeom.Xform, UsdGeom.Xform]:
    """Y up, metres, ``/World`` (an assembly, the default prim) and the group under it."""
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    world = UsdGeom.Xform.Define(stage, WORLD)
    Usd.ModelAPI(world).SetKind(Kind.Tokens.assembly)
    stage.SetDefaultPrim(world.GetPrim())
    group = UsdGeom.Xform.Define(stage, group_path)
    Usd.ModelAPI(group).SetKind(Kind.Tokens.group)
    return world, group


def set_frames(stage: Usd.Stage, frames: int, fps: float) -> None:
    """Time codes are frames at ``fps``: ``frames`` of them from 0."""
    stage.SetTimeCodesPerSecond(fps)
    stage.SetFramesPerSecond(fps)
    stage.SetStartTimeCode(0)
    stage.SetEndTimeCode(frames - 1)


def time_code(t: float | None, fps: float) -> Usd.TimeCode:
    """The time code of ``t`` seconds (None: the default time)."""
    return Usd.TimeCode.Default() if t is None else Usd.TimeCode(round(t * fps, 9))


def row_major(m: F64) -> Vt.Matrix4dArray:
    """Column-vector ``(n, 4, 4)`` matrices -> Gf row-vector array."""
    return Vt.Matrix4dArray.FromNumpy(np.ascontiguousarray(np.swapaxes(m, -1, -2)))


def set_attr(
    prim: Usd.Prim,
    name: str,
    type_: Sdf.ValueTypeName,
    value: object,
    time: Usd.TimeCode | None = None,
) -> Usd.Attribute:
    """Set the custom attribute ``name`` (made if missing) at ``time`` (None: the default)."""
    attr = prim.GetAttribute(name) or prim.CreateAttribute(name, type_, custom=True)
    attr.Set(value, time if time is not None else Usd.TimeCode.Default())
    return attr


def set_primvar(
    prim: Usd.Prim,
    name: str,
    type_: Sdf.ValueTypeName,
    interp: str,
    value: object,
    element_size: int = 1,
) -> None:
    """Author primvar ``name`` with its interpolation and element size."""
    pv = UsdGeom.PrimvarsAPI(prim).CreatePrimvar(name, type_, interp, element_size)
    pv.Set(value)


def quad_mesh(
    stage: Usd.Stage,
    path: str,
    points: F64,
    normals: F64,
    quads: NDArray[np.int32],
    double_sided: bool = False,
) -> UsdGeom.Mesh:
    """A quad Mesh (no subdivision) of ``(v, 3)`` points, ``(v, 3)`` per-vertex normals and
    ``(q, 4)`` quads, with its extent."""
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
