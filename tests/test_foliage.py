"""Foliage data (paper 6): the leaf-cloud model and its texture, the anchors that tie clouds to
their pieces' hub bones, and /World/Forest/Foliage as a PointInstancer of the leaf-cloud Mesh
that follows the wind."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom

from forest.geometry.pieces import HUB
from forest.growth.foliage import CLOUD_RADII, leaf_cloud, leaf_texture
from forest.growth.generate import Forest
from forest.usd.read import read_scene
from forest.usd.scene import FOLIAGE, FOLIAGE_CLOUD, write_scene
from tests.test_usd import validation_errors


@pytest.fixture(scope="module")
def windy_scene(windy_forest: Forest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_scene(windy_forest, tmp_path_factory.mktemp("foliage") / "f.usda")


def test_leaf_cloud_is_cards_in_a_unit_ball() -> None:
    c = leaf_cloud()
    assert c.n_cards == 256 and c.quads.shape == (256, 4)
    assert c.radius <= 0.5 + 1e-12
    assert c.triangles().shape == (512, 3)
    # flat cards: every corner lies in the plane of its card's normal
    p = c.positions.reshape(-1, 4, 3)
    n = c.normals.reshape(-1, 4, 3)
    np.testing.assert_allclose(np.linalg.norm(n, axis=2), 1.0, atol=1e-12)
    assert np.abs(np.einsum("cka,ca->ck", p - p[:, :1], n[:, 0])).max() < 1e-12
    # the same code gives the same cloud
    np.testing.assert_array_equal(leaf_cloud().positions, c.positions)


def test_leaf_texture_is_a_blade_with_empty_surroundings() -> None:
    t = leaf_texture(64)
    assert t.shape == (64, 64, 4) and t.dtype == np.uint8
    blade = t[..., 3] == 255
    assert set(np.unique(t[..., 3])) == {0, 255}
    assert 0.25 < blade.mean() < 0.75
    assert not blade[0].any() and not blade[-1].any()  # stem end and tip are narrow
    assert blade[:, 32].sum() > 50  # the midrib column runs the leaf's length
    g = t[..., 1][blade].astype(float)
    assert g.mean() > t[..., 0][blade].mean() and g.mean() > t[..., 2][blade].mean()  # green
    np.testing.assert_array_equal(leaf_texture(64), t)


def test_anchors_sit_on_hub_bones_of_foliage_pieces(windy_forest: Forest) -> None:
    f = windy_forest
    a = f.foliage_anchors()
    assert len(a) == len(f.foliage_instance) > 0
    np.testing.assert_array_equal(a.bone, f.bones.offset[a.instance] + HUB)
    assert (f.bones.joint[a.bone] == HUB).all()
    assert (f.bones.instance[a.bone] == a.instance).all()
    scale = np.cbrt(np.linalg.det(f.transforms[a.instance, :3, :3]))
    np.testing.assert_allclose(a.size, CLOUD_RADII * scale)
    # unposed, the hub bone's palette entry is the topological transform: the cloud sits at
    # the piece's hub in the assembled tree
    rest = a.positions(f.rest_palette())
    t = f.transforms[a.instance]
    np.testing.assert_allclose(
        rest, np.einsum("nij,nj->ni", t[:, :3, :3], a.rest) + t[:, :3, 3], atol=1e-9
    )


def test_foliage_is_a_point_instancer_of_the_leaf_cloud(windy_scene: Path) -> None:
    stage = Usd.Stage.Open(str(windy_scene))
    assert validation_errors(stage) == []
    prim = stage.GetPrimAtPath(FOLIAGE)
    assert prim.IsA(UsdGeom.PointInstancer)
    inst = UsdGeom.PointInstancer(prim)
    assert [str(p) for p in inst.GetPrototypesRel().GetTargets()] == [FOLIAGE_CLOUD]
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath(FOLIAGE_CLOUD))
    assert mesh.GetDoubleSidedAttr().Get() is True
    assert len(mesh.GetFaceVertexCountsAttr().Get()) == leaf_cloud().n_cards
    assert mesh.GetExtentAttr().HasAuthoredValue() and inst.GetExtentAttr().HasAuthoredValue()
    # DCC tools see instances of the real mesh, scaled by the cloud's diameter, at every frame
    for frame in (0, 3):
        xf = inst.ComputeInstanceTransformsAtTime(Usd.TimeCode(frame), Usd.TimeCode(frame))
        assert len(xf) == len(inst.GetProtoIndicesAttr().Get()) > 0
    pv = UsdGeom.PrimvarsAPI(prim)
    for name in ("instance", "boneOffset", "joint", "restPosition"):
        assert pv.GetPrimvar(f"forest:{name}").GetInterpolation() == UsdGeom.Tokens.vertex


def test_positions_follow_the_wind_with_their_bones(
    windy_scene: Path, windy_forest: Forest
) -> None:
    f = windy_forest
    scene = read_scene(windy_scene)
    stage = Usd.Stage.Open(str(windy_scene))
    positions = UsdGeom.PointInstancer(stage.GetPrimAtPath(FOLIAGE)).GetPositionsAttr()
    assert positions.GetTimeSamples() == [0.0, 1.0, 2.0, 3.0]
    np.testing.assert_array_equal(scene.foliage_instance, f.foliage_instance)
    np.testing.assert_array_equal(scene.foliage_bone, f.foliage_anchors().bone)
    np.testing.assert_allclose(scene.foliage_sizes, f.foliage_anchors().size, rtol=1e-6)
    moved = 0.0
    for frame, time in enumerate(f.frame_times()):
        pal = f.palette(time)
        # a cloud's centre at frame F: its piece's hub bone at F applied to its rest point
        want = np.einsum("nij,nj->ni", pal[scene.foliage_bone, :3, :3], scene.foliage_rest)
        want += pal[scene.foliage_bone, :3, 3]
        np.testing.assert_allclose(scene.foliage_at(frame), want, atol=1e-5)
        usd = np.asarray(positions.Get(Usd.TimeCode(frame)), dtype=np.float64)
        np.testing.assert_allclose(usd, want, atol=1e-5)
        moved = max(moved, float(np.abs(want - scene.foliage_at(0)).max()))
    assert moved > 1e-3  # the wind really moves them


def test_old_points_foliage_still_reads(tmp_path: Path, windy_scene: Path) -> None:
    stage = Usd.Stage.Open(str(windy_scene))
    stage.RemovePrim(FOLIAGE)
    pts = UsdGeom.Points.Define(stage, FOLIAGE)
    pts.CreatePointsAttr([(0.0, 1.0, 2.0), (3.0, 4.0, 5.0)])
    pts.CreateWidthsAttr([0.5, 0.7])
    UsdGeom.PrimvarsAPI(pts.GetPrim()).CreatePrimvar(
        "forest:instance", _int_array(), UsdGeom.Tokens.vertex
    ).Set([1, 2])
    out = tmp_path / "old.usda"
    stage.GetRootLayer().Export(str(out))
    scene = read_scene(out)
    assert scene.n_foliage == 2 and scene.foliage_cloud is None
    np.testing.assert_array_equal(scene.foliage_bone, [-1, -1])
    np.testing.assert_allclose(scene.foliage_at(2), [[0, 1, 2], [3, 4, 5]])
    np.testing.assert_allclose(scene.foliage_sizes, [0.5, 0.7])


def _int_array() -> Any:
    return Sdf.ValueTypeNames.IntArray
