"""Foliage data (paper 6): the leaf-cloud models of each family and their textures, the anchors
that tie clouds to their pieces' hub bones (with model, heading and colour), and
/World/Forest/Foliage as a PointInstancer of the family's cloud Meshes that follows the wind."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom

from forest.geometry.pieces import HUB
from forest.growth.foliage import (
    CARDS,
    FAMILIES,
    MODELS,
    YAW_STEPS,
    cloud_colors,
    cloud_models,
    foliage_anchors,
    hex_to_linear,
    leaf_cloud,
    leaf_texture,
)
from forest.growth.generate import Forest, ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.usd.contract import FOLIAGE, FOLIAGE_CLOUD
from forest.usd.read import read_scene
from forest.usd.scene import write_scene
from schemas.grammar import Leaves
from tests.helpers_skin import usd_skinned_points
from tests.test_usd import validation_errors


@pytest.fixture(scope="module")
def windy_scene(windy_forest: Forest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    # the instanced foliage (a small forest is otherwise skinned, its Foliage inactive)
    return write_scene(windy_forest, tmp_path_factory.mktemp("foliage") / "f.usda", skinned=False)


@pytest.mark.parametrize("family", FAMILIES)
def test_leaf_clouds_are_cards_in_a_unit_ball(family: str) -> None:
    models = cloud_models(family)
    assert len(models) == MODELS
    for m, c in enumerate(models):
        assert c.family == family
        assert c.n_cards == CARDS and c.quads.shape == (CARDS, 4)
        assert abs(c.radius - 0.5) < 1e-12
        assert c.triangles().shape == (2 * CARDS, 3)
        # flat cards: every corner lies in the plane of its card's normal
        p = c.positions.reshape(-1, 4, 3)
        n = c.normals.reshape(-1, 4, 3)
        np.testing.assert_allclose(np.linalg.norm(n, axis=2), 1.0, atol=1e-12)
        assert np.abs(np.einsum("cka,ca->ck", p - p[:, :1], n[:, 0])).max() < 1e-12
        # the same code gives the same cloud
        np.testing.assert_array_equal(leaf_cloud(family, m).positions, c.positions)
    # the models of a family differ in shape
    ext = [np.ptp(c.positions, axis=0) for c in models]
    assert max(np.abs(ext[i] - ext[j]).max() for i in range(3) for j in range(i)) > 0.05


def test_strands_hang_down_from_the_top() -> None:
    for c in cloud_models("strands"):
        p = c.positions.reshape(-1, 4, 3)
        base, tip = p[:, 0], p[:, 2]
        assert (tip[:, 1] < base[:, 1]).all()  # every leaf points down
        assert base[:, 1].max() > 0.25 and p[..., 1].min() < -0.2  # from the top, a long way


def test_bad_family_or_model_names_the_field() -> None:
    with pytest.raises(ValueError, match=r"leaves\.family"):
        leaf_cloud("palm")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="model"):
        leaf_cloud("needles", MODELS)
    with pytest.raises(ValueError, match=r"leaves\.family"):
        leaf_texture("palm")  # type: ignore[arg-type]


@pytest.mark.parametrize("family", FAMILIES)
def test_leaf_textures_are_neutral_leaves_with_empty_surroundings(family: str) -> None:
    t = leaf_texture(family, 64)  # type: ignore[arg-type]
    assert t.shape == (64, 64, 4) and t.dtype == np.uint8
    shape = t[..., 3] == 255
    assert set(np.unique(t[..., 3])) == {0, 255}
    assert 0.15 < shape.mean() < 0.75
    assert not shape[0].any()  # the stem end is empty
    assert shape[:, 32].sum() > 50  # the midrib (or the twig) runs the leaf's length
    rgb = t[..., :3][shape].astype(float)
    # neutral: the cloud's colour tints it, so no channel dominates
    assert np.abs(rgb[:, 0] - rgb[:, 1]).max() <= 1 and rgb[:, 2].mean() < rgb[:, 1].mean()
    np.testing.assert_array_equal(leaf_texture(family, 64), t)  # type: ignore[arg-type]
    assert not np.array_equal(
        leaf_texture("broadleaf", 64)[..., 3], leaf_texture("needles", 64)[..., 3]
    )


def test_anchors_sit_on_hub_bones_of_foliage_pieces(windy_forest: Forest) -> None:
    f = windy_forest
    a = f.foliage_anchors()
    assert len(a) == len(f.foliage_instance) > 0
    np.testing.assert_array_equal(a.bone, f.bones.offset[a.instance] + HUB)
    assert (f.bones.joint[a.bone] == HUB).all()
    assert (f.bones.instance[a.bone] == a.instance).all()
    # the branch's radius: its rest scale with every rim scale and radius factor above it
    np.testing.assert_allclose(a.size, f.grammar.leaves.size * f.graph.scale[a.instance])
    # unposed, the hub bone's palette entry is the topological transform: the cloud sits at
    # the piece's hub in the assembled tree
    rest = a.positions(f.rest_palette())
    t = f.transforms[a.instance]
    np.testing.assert_allclose(
        rest, np.einsum("nij,nj->ni", t[:, :3, :3], a.rest) + t[:, :3, 3], atol=1e-9
    )


def test_anchors_draw_models_headings_and_colours_per_cloud(windy_forest: Forest) -> None:
    a = windy_forest.foliage_anchors()
    k = len(a)
    assert a.model.dtype == np.int32 and a.yaw.dtype == np.float64
    assert a.color.dtype == np.float32 and a.color.shape == (k, 3)
    assert set(a.model.tolist()) == set(range(MODELS))
    steps = a.yaw / (2 * np.pi / YAW_STEPS)
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-12)
    assert len(set(np.round(steps).tolist())) > YAW_STEPS // 2
    # deterministic for the seed
    b = windy_forest.foliage_anchors()
    for name in ("model", "yaw", "color"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def test_every_tree_has_a_base_colour_and_its_clouds_vary_around_it() -> None:
    palette = ["#38691f", "#8a9a20", "#2f5a3a"]
    tree = np.repeat(np.arange(40, dtype=np.int32), 30)
    c = cloud_colors(palette, tree, np.random.default_rng(3)).astype(np.float64)
    base = hex_to_linear(palette)
    per_tree = c.reshape(40, 30, 3)
    mean = per_tree.mean(axis=1)
    nearest = np.linalg.norm(mean[:, None] - base[None], axis=2).argmin(axis=1)
    assert len(set(nearest.tolist())) == 3  # every palette entry is drawn by some tree
    # a cloud stays near its tree's colour (value within about 40 %), but not identical
    ratio = per_tree.sum(axis=2) / base[nearest].sum(axis=1)[:, None]
    assert ratio.min() > 0.6 and ratio.max() < 1.6 and ratio.std() > 0.03
    assert (c.argmax(axis=1) == 1).all()  # the greens stay green


def test_autumn_takes_the_autumn_palette_and_a_bad_season_names_the_field() -> None:
    leaves = Leaves(colors=["#38691f"], autumn_colors=["#c0501a"])
    args = (
        np.arange(4, dtype=np.int32), np.zeros(4, np.int32), np.zeros(4, np.int32),
        np.zeros((1, 3)), np.full(4, 0.1), np.zeros(4, np.int32), leaves,
    )  # fmt: skip
    summer = foliage_anchors(*args, np.random.default_rng(1))
    autumn = foliage_anchors(*args, np.random.default_rng(1), season="autumn")
    assert (summer.color[:, 1] > summer.color[:, 0]).all()
    assert (autumn.color[:, 0] > autumn.color[:, 1]).all()
    np.testing.assert_allclose(summer.size, 0.1 * leaves.size)
    with pytest.raises(ValueError, match="season"):
        foliage_anchors(*args, np.random.default_rng(1), season="winter")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="radius"):
        foliage_anchors(*args[:4], np.full(3, 0.1), *args[5:], np.random.default_rng(1))
    f = generate_forest(
        load_preset("almond"), 2, ForestOptions(season="autumn")
    )  # the option reaches the anchors
    g = f.grammar.leaves
    want = hex_to_linear(g.autumn_colors or g.colors)
    got = f.foliage_anchors().color.astype(np.float64)
    assert np.linalg.norm(got.mean(axis=0) - want.mean(axis=0)) < 0.2


def test_foliage_is_a_point_instancer_of_the_cloud_models(
    windy_scene: Path, windy_forest: Forest
) -> None:
    stage = Usd.Stage.Open(str(windy_scene))
    assert validation_errors(stage) == []
    prim = stage.GetPrimAtPath(FOLIAGE)
    assert prim.IsA(UsdGeom.PointInstancer)
    inst = UsdGeom.PointInstancer(prim)
    want = [f"{FOLIAGE_CLOUD}{m}" for m in range(MODELS)]
    assert [str(p) for p in inst.GetPrototypesRel().GetTargets()] == want
    family = windy_forest.grammar.leaves.family
    for path, cloud in zip(want, cloud_models(family), strict=True):
        mesh = UsdGeom.Mesh(stage.GetPrimAtPath(path))
        assert mesh.GetDoubleSidedAttr().Get() is True
        assert len(mesh.GetFaceVertexCountsAttr().Get()) == cloud.n_cards
        assert mesh.GetPrim().GetAttribute("forest:leafFamily").Get() == family
        assert not mesh.GetDisplayColorAttr().HasAuthoredValue()  # the instancer's reaches it
        assert mesh.GetExtentAttr().HasAuthoredValue()
    assert inst.GetExtentAttr().HasAuthoredValue()
    a = windy_forest.foliage_anchors()
    np.testing.assert_array_equal(np.asarray(inst.GetProtoIndicesAttr().Get()), a.model)
    # DCC tools see instances of the real meshes, turned, scaled, at every frame
    for frame in (0, 3):
        xf = np.asarray(
            inst.ComputeInstanceTransformsAtTime(Usd.TimeCode(frame), Usd.TimeCode(frame))
        )
        assert len(xf) == len(a) > 0
        # row vectors: the first row is the turned, scaled x axis
        want_x = a.size[:, None] * np.stack([np.cos(a.yaw), 0 * a.yaw, -np.sin(a.yaw)], axis=1)
        np.testing.assert_allclose(xf[:, 0, :3], want_x, atol=1e-3 * a.size.max())
    pv = UsdGeom.PrimvarsAPI(prim)
    for name in ("forest:instance", "forest:boneOffset", "forest:joint", "forest:restPosition",
                 "forest:yaw", "displayColor"):  # fmt: skip
        assert pv.GetPrimvar(name).GetInterpolation() == UsdGeom.Tokens.vertex
    color = np.asarray(pv.GetPrimvar("displayColor").Get(), np.float32)
    np.testing.assert_array_equal(color, a.color)


def test_the_reader_returns_models_headings_and_colours_exactly(
    windy_scene: Path, windy_forest: Forest
) -> None:
    scene = read_scene(windy_scene)
    a = windy_forest.foliage_anchors()
    np.testing.assert_array_equal(scene.foliage_model, a.model)
    np.testing.assert_array_equal(scene.foliage_yaw, a.yaw)
    np.testing.assert_array_equal(scene.foliage_color, a.color)
    for got, want in zip(scene.foliage_clouds, cloud_models(a.family), strict=True):
        assert got.family == want.family
        np.testing.assert_allclose(got.positions, want.positions, atol=1e-7)
        np.testing.assert_allclose(got.st, want.st, atol=1e-7)
        np.testing.assert_array_equal(got.quads, want.quads)


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
    assert scene.n_foliage == 2 and scene.foliage_clouds == ()
    np.testing.assert_array_equal(scene.foliage_model, [0, 0])
    np.testing.assert_array_equal(scene.foliage_bone, [-1, -1])
    np.testing.assert_allclose(scene.foliage_at(2), [[0, 1, 2], [3, 4, 5]])
    np.testing.assert_allclose(scene.foliage_sizes, [0.5, 0.7])


def _int_array() -> Any:
    return Sdf.ValueTypeNames.IntArray


@pytest.mark.parametrize("preset", ["pine", "spruce", "poplar", "oak", "almond", "willow"])
def test_skinned_leaves_stay_on_their_clouds(preset: str, tmp_path: Path) -> None:
    """USD's own skinning (what every DCC draws) puts each cloud's leaves around its posed
    centre, no farther than the cloud's size: a pine's leader is far thinner at rest than
    posed, and leaves laid out at posed size around the rest centre were skinned to
    kilometres (Blender drew them there)."""
    f = generate_forest(load_preset(preset), 4, ForestOptions(trees=1))
    stage = Usd.Stage.Open(str(write_scene(f, tmp_path / "tree.usdc", skinned=True)))
    world = usd_skinned_points(stage.GetPrimAtPath("/World/Forest/Trees/Tree_00000"), "Leaves", 0)
    a = f.foliage_anchors()
    models = cloud_models(a.family)
    counts = np.array([len(m.positions) for m in models])[a.model]
    centre = np.repeat(a.positions(f.palette()), counts, axis=0)
    reach = np.repeat(a.size * np.array([m.radius for m in models])[a.model], counts)
    dist = np.linalg.norm(world - centre, axis=1)
    assert len(world) == counts.sum()
    assert (dist <= reach * 1.001 + 1e-4).all(), f"{dist.max():.3g} m from a cloud centre"
    # and the clouds keep their size: the farthest leaf of each cloud reaches its edge
    far = np.maximum.reduceat(dist / reach, np.r_[0, np.cumsum(counts)[:-1]])
    assert far.min() > 0.5
