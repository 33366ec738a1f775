"""Foliage data (paper 6): the leaf-cloud models of each family and their textures, the anchors
that tie clouds to their pieces' hub bones (with model, heading and colour), and
/World/Forest/Foliage as a PointInstancer of the family's cloud Meshes that follows the wind."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom

from forest.geometry.pieces import HUB, piece_library
from forest.growth.foliage import (
    CLUSTER,
    FAMILIES,
    LEAF,
    MODELS,
    ROSETTE,
    SPRAY,
    SPRAY_LEAVES,
    SPRIG_NEEDLE_ANGLE,
    SPRIG_RATIO,
    STEM_S,
    STEM_T,
    YAW_STEPS,
    cloud_colors,
    cloud_models,
    hex_to_linear,
    leaf_cloud,
    leaf_texture,
    spray_anchors,
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


# what the issue asks of each species' leaves: card length range (metres, stalk included)
REAL_LENGTH = {
    "oak": (0.07, 0.15), "birch": (0.035, 0.09), "hazel": (0.06, 0.13), "willow": (0.07, 0.16),
    "almond": (0.07, 0.13), "poplar": (0.05, 0.12), "pine": (0.035, 0.075),
}  # fmt: skip


@pytest.mark.parametrize("family", FAMILIES)
def test_sprays_are_flat_cards_in_metres(family: str) -> None:
    models = cloud_models(family)  # type: ignore[arg-type]
    assert len(models) == MODELS
    for m, c in enumerate(models):
        assert c.family == family
        assert c.quads.shape == (c.n_cards, 4) and c.triangles().shape == (2 * c.n_cards, 3)
        assert c.kind is not None and c.kind.shape == (c.n_cards,)
        assert c.leaf is not None and c.leaf.any() and c.n_leaves >= c.leaf.sum()
        # a branchlet: its shoot starts at the origin (a card's half width away at most), no
        # more than 2 m long
        assert np.linalg.norm(c.positions, axis=1).min() < 0.05 and 0.1 < c.radius < 2.0
        # flat cards: every corner lies in the plane of its card's normal
        p = c.positions.reshape(-1, 4, 3)
        n = c.normals.reshape(-1, 4, 3)
        np.testing.assert_allclose(np.linalg.norm(n, axis=2), 1.0, atol=1e-9)
        assert np.abs(np.einsum("cka,ca->ck", p - p[:, :1], n[:, 0])).max() < 1e-9
        # the same code gives the same spray
        np.testing.assert_array_equal(leaf_cloud(family, m).positions, c.positions)  # type: ignore[arg-type]
        if family in REAL_LENGTH:
            lo, hi = REAL_LENGTH[family]
            lengths = c.leaf_lengths()  # the youngest leaves at a shoot's tip are smaller
            assert 0.7 * lo <= lengths.min() and lengths.max() <= hi, (lengths.min(), lengths.max())
            assert lo <= np.median(lengths) <= hi
    # the models of a family differ (no two clumps alike)
    ext = [np.ptp(c.positions, axis=0) for c in models]
    assert min(np.abs(ext[i] - ext[j]).max() for i in range(MODELS) for j in range(i)) > 1e-3
    assert len({c.n_cards for c in models}) > 1


def test_spray_leaves_follow_the_phyllotaxis_and_face_the_light() -> None:
    oak = cloud_models("oak")
    for c in oak:
        assert c.leaf is not None and c.kind is not None
        n = c.normals[::4][c.leaf]
        assert np.median(np.abs(n[:, 1])) > 0.7  # blades mostly level, facing up or down
        # the main shoot and its spurs end in cluster cards of ROSETTE leaves, every side
        # shoot is a card of SPRAY_LEAVES (flat_sides): all of them facing up, the sprays
        # leaning out over their heading by 24-48 degrees (so a crown seen from the side
        # shows their leaves, not their edges)
        cluster, spray = c.kind == CLUSTER, c.kind == SPRAY
        assert cluster.sum() >= 2 and spray.sum() >= 4
        assert (c.normals[::4][cluster][:, 1] > 0.6).all()
        assert (c.normals[::4][spray][:, 1] > 0.45).all()
        assert c.n_leaves == c.leaf.sum() + ROSETTE * cluster.sum() + SPRAY_LEAVES * spray.sum()
        # most cards still show one leaf (so the median card is a leaf): a side shoot takes
        # two cards (its spray and the leaf below it) where it took about nine
        assert c.leaf.mean() > 0.55
    # a grammar's length and phyllotaxis reach the models
    small = cloud_models("hazel", (0.02, 0.03), "opposite")
    assert all(c.leaf_lengths().min() >= 0.014 and c.leaf_lengths().max() <= 0.03 for c in small)
    assert small[0].n_cards != cloud_models("hazel")[0].n_cards or not np.array_equal(
        small[0].positions, cloud_models("hazel")[0].positions
    )


@pytest.mark.parametrize("family", ["willow", "birch", "strands"])
def test_hanging_shoots_hang_their_leaves(family: str) -> None:
    for c in cloud_models(family):  # type: ignore[arg-type]
        p = c.positions.reshape(-1, 4, 3)[c.leaf]
        base, tip = 0.5 * (p[:, 0] + p[:, 1]), 0.5 * (p[:, 2] + p[:, 3])
        assert (tip[:, 1] < base[:, 1]).all()  # every leaf points down
        assert c.positions[:, 1].min() < -0.25  # the shoot falls a long way


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
    leaf, cluster, spray = shape[:, :32], shape[32:, 32:], shape[:32, 32:]
    assert 0.1 < leaf.mean() < 0.75 and 0.1 < cluster.mean() < 0.9
    assert 0.1 < spray.mean() < 0.75
    fine = leaf_texture(family, 128)[:64, 64:, 3] == 255  # type: ignore[arg-type]
    assert fine[2:40, 31:33].any(axis=1).all()  # a twig up the middle (a few mm: 1 texel here)
    assert not shape[:, 0].any() and not shape[:, 31].any()  # room round the leaf
    assert not spray[:, 0].any() and not spray[:, 31].any()
    assert leaf[:, 16].sum() > 40  # the stalk and midrib (or the twig) run the card's length
    # the stalk stem cards show: opaque over STEM_S x STEM_T
    assert t[int(STEM_T[0] * 64) : int(STEM_T[1] * 64) + 1, int(STEM_S[0] * 64), 3].min() == 255
    assert cluster[12:20, 12:20].any()  # the cluster's leaves meet in its middle
    rgb = t[..., :3][shape].astype(float)
    # neutral: the spray's colour tints it, so no channel dominates
    assert np.abs(rgb[:, 0] - rgb[:, 1]).max() <= 1 and rgb[:, 2].mean() < rgb[:, 1].mean()
    np.testing.assert_array_equal(leaf_texture(family, 64), t)  # type: ignore[arg-type]


def test_every_species_has_its_own_leaf_picture() -> None:
    species = ["oak", "birch", "hazel", "willow", "almond", "poplar", "pine", "spruce"]
    alphas = [leaf_texture(f, 64)[:, :32, 3] for f in species]  # type: ignore[arg-type]
    for i in range(len(alphas)):
        for j in range(i):
            assert (alphas[i] != alphas[j]).mean() > 0.02, (species[i], species[j])
    # the oak's blade is lobed: across its upper half the width swings in and out
    a = leaf_texture("oak", 256)[:, :128, 3] > 0
    width = a[100:240].sum(axis=1).astype(float)
    swings = np.sum(np.abs(np.diff(np.sign(np.diff(width)))) > 0)
    assert swings >= 4


def test_spruce_needles_are_drawn_at_their_size() -> None:
    """A spruce sprig card is about SPRIG_RATIO times as long as wide, the ratio its picture is
    drawn for, so the needles show at 1-2.5 cm (SPECIES.md), not as streaks along the card."""
    for model in range(MODELS):
        cloud = leaf_cloud("spruce", model)
        corners = cloud.positions[cloud.quads[cloud.kind == LEAF]]  # (c, 4, 3)
        width = np.linalg.norm(corners[:, 1] - corners[:, 0], axis=1)
        length = np.linalg.norm(corners[:, 3] - corners[:, 0], axis=1)
        ratio = np.median(length / width)
        assert 0.6 * SPRIG_RATIO < ratio < 1.4 * SPRIG_RATIO, (model, ratio)
        # a needle reaches 75-95 % of the half width at SPRIG_NEEDLE_ANGLE to its twig
        needle = 0.85 * (width / 2) / np.sin(np.radians(SPRIG_NEEDLE_ANGLE))
        assert needle.min() >= 0.01 and needle.max() <= 0.025, (model, needle.min(), needle.max())
    # on such a card, lines leaving the twig at SPRIG_NEEDLE_ANGLE run along needles in the
    # picture (left half of the texture: x across -1..1, t along 0..1), one every 1/64
    size = 1024
    alpha = leaf_texture("spruce", size)[:, : size // 2, 3] > 0
    x = np.linspace(0.12, 0.7, 40)
    rise = 0.5 / np.tan(np.radians(SPRIG_NEEDLE_ANGLE)) / SPRIG_RATIO  # t per unit of x
    on = []
    for k in range(8, 56):
        for side in (-1, 1):
            t0 = (k + (0.5 if side > 0 else 0.0)) / 64
            col = np.clip(((side * x + 1) / 2 * (size // 2)).astype(int), 0, size // 2 - 1)
            row = np.clip(((t0 + rise * x) * size).astype(int), 0, size - 1)
            on.append(alpha[row, col].mean())
    assert np.median(on) > 0.95, np.median(on)


def test_anchors_follow_hub_bones_of_foliage_pieces(windy_forest: Forest) -> None:
    f = windy_forest
    a = f.foliage_anchors()
    assert len(a) > len(np.unique(a.instance)) > 0  # several sprays per piece
    assert set(np.unique(a.instance).tolist()) <= set(f.foliage_instance.tolist())
    np.testing.assert_array_equal(a.bone, f.bones.offset[a.instance] + HUB)
    assert (f.bones.joint[a.bone] == HUB).all()
    assert (f.bones.instance[a.bone] == a.instance).all()
    lo, hi = f.grammar.leaves.scale
    assert (a.size >= 0.59 * lo).all() and (a.size <= hi).all()
    # on the piece's axis between its hub and a terminal
    for i in range(0, len(a), 37):
        j = f.pieces[f.graph.piece[a.instance[i]]].joint_rest[:, :3, 3]
        hub, tips = j[HUB], j[HUB + 1 :]
        d = a.rest[i] - hub
        assert min(np.linalg.norm(np.cross(d, t - hub)) for t in tips) < 1e-9
    # unposed, the hub bone's palette entry is the topological transform
    rest = a.positions(f.rest_palette())
    t = f.transforms[a.instance]
    np.testing.assert_allclose(
        rest, np.einsum("nij,nj->ni", t[:, :3, :3], a.rest) + t[:, :3, 3], atol=1e-9
    )


def test_anchors_draw_models_headings_and_colours_per_spray(windy_forest: Forest) -> None:
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
    for name in ("model", "yaw", "color", "rest", "size"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


@pytest.mark.parametrize("preset", ["willow", "hazel", "spruce", "birch"])
def test_no_leaf_below_the_ground(preset: str) -> None:
    f = generate_forest(load_preset(preset), 3, ForestOptions(trees=2))
    a = f.foliage_anchors()
    models = a.models()
    pos = a.positions(f.palette())
    ground = f.tree_transforms[f.graph.tree[a.instance], 1, 3]
    low = np.array([c.positions[:, 1].min() for c in models])[a.model]
    assert (pos[:, 1] + a.size * low - ground >= 0.3 - 1e-9).all()
    assert (pos[:, 1] - ground >= f.grammar.leaves.min_height).all()


def test_shell_and_triangle_budget_thin_the_inside() -> None:
    g = load_preset("oak")
    full = g.model_copy(update={"leaves": g.leaves.model_copy(
        update={"shell": 0.0, "max_triangles": None})})  # fmt: skip
    f = generate_forest(full, 2, ForestOptions(trees=1))
    a = f.foliage_anchors()
    tris = np.array([2 * c.n_cards for c in a.models()])
    shell = generate_forest(full.model_copy(update={"leaves": full.leaves.model_copy(
        update={"shell": 0.5})}), 2, ForestOptions(trees=1)).foliage_anchors()  # fmt: skip
    assert 0 < len(shell) < len(a)
    budget = int(tris[a.model].sum() // 2)
    capped_leaves = full.leaves.model_copy(update={"max_triangles": budget})
    capped_grammar = full.model_copy(update={"leaves": capped_leaves})
    capped = generate_forest(capped_grammar, 2, ForestOptions(trees=1)).foliage_anchors()
    assert budget - tris.max() <= tris[capped.model].sum() <= budget


def test_every_tree_has_a_base_colour_and_its_sprays_vary_around_it() -> None:
    palette = ["#38691f", "#8a9a20", "#2f5a3a"]
    tree = np.repeat(np.arange(40, dtype=np.int32), 30)
    c = cloud_colors(palette, tree, np.random.default_rng(3)).astype(np.float64)
    base = hex_to_linear(palette)
    per_tree = c.reshape(40, 30, 3)
    mean = per_tree.mean(axis=1)
    nearest = np.linalg.norm(mean[:, None] - base[None], axis=2).argmin(axis=1)
    assert len(set(nearest.tolist())) == 3  # every palette entry is drawn by some tree
    # a spray stays near its tree's colour (value within about 40 %), but not identical
    ratio = per_tree.sum(axis=2) / base[nearest].sum(axis=1)[:, None]
    assert ratio.min() > 0.6 and ratio.max() < 1.6 and ratio.std() > 0.03
    assert (c.argmax(axis=1) == 1).all()  # the greens stay green


def test_autumn_takes_the_autumn_palette_and_a_bad_season_names_the_field() -> None:
    leaves = Leaves(colors=["#38691f"], autumn_colors=["#c0501a"])
    pieces = piece_library(1)
    k = 4
    frames = np.repeat(np.eye(4)[None], k, axis=0)
    frames[:, 1, 3] = 5.0
    args = (
        np.arange(k, dtype=np.int32), np.zeros(k, np.int32), np.zeros(k, np.int32),
        [p.joint_rest for p in pieces], frames, np.zeros(k, np.int32), np.zeros(k), leaves,
    )  # fmt: skip
    summer = spray_anchors(*args, np.random.default_rng(1))
    autumn = spray_anchors(*args, np.random.default_rng(1), season="autumn")
    assert len(summer) >= 2 * k
    assert (summer.color[:, 1] > summer.color[:, 0]).all()
    assert (autumn.color[:, 0] > autumn.color[:, 1]).all()
    with pytest.raises(ValueError, match="season"):
        spray_anchors(*args, np.random.default_rng(1), season="winter")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="ground"):
        spray_anchors(*args[:6], np.zeros(3), *args[7:], np.random.default_rng(1))
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
    for path, cloud in zip(want, windy_forest.foliage_anchors().models(), strict=True):
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
    for got, want in zip(scene.foliage_clouds, a.models(), strict=True):
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
    np.testing.assert_array_equal(scene.foliage_instance, f.foliage_anchors().instance)
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
    models = a.models()
    counts = np.array([len(m.positions) for m in models])[a.model]
    centre = np.repeat(a.positions(f.palette()), counts, axis=0)
    reach = np.repeat(a.size * np.array([m.radius for m in models])[a.model], counts)
    dist = np.linalg.norm(world - centre, axis=1)
    assert len(world) == counts.sum()
    assert (dist <= reach * 1.001 + 1e-4).all(), f"{dist.max():.3g} m from a cloud centre"
    # and the clouds keep their size: the farthest leaf of each cloud reaches its edge
    far = np.maximum.reduceat(dist / reach, np.r_[0, np.cumsum(counts)[:-1]])
    assert far.min() > 0.5


# -- the anchors' selection, grouped by tree: the per-tree loops it replaced, bit for bit ----


def _outer_loop(pos: np.ndarray, tree: np.ndarray, bands: int = 10) -> np.ndarray:
    """The per-tree loop ``_outer`` was until 0.7.0 (a mask and np.percentile per tree and
    band), kept as the reference the grouped one must equal."""
    out = np.zeros(len(pos))
    for t in np.unique(tree):
        sel = np.flatnonzero(tree == t)
        p = pos[sel]
        lo, hi = np.percentile(p[:, 1], [2, 98])
        h = max(0.5 * float(hi - lo), 1e-6)
        across = np.hypot(p[:, 0] - p[:, 0].mean(), p[:, 2] - p[:, 2].mean())
        band = np.clip(((p[:, 1] - lo) / (2 * h) * bands).astype(np.int64), 0, bands - 1)
        radius = np.ones(bands)
        for b in np.unique(band):
            radius[b] = max(float(np.percentile(across[band == b], 95)), 1e-6)
        out[sel] = np.maximum(across / radius[band], np.abs(p[:, 1] - lo - h) / h)
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_outer_grouped_equals_the_per_tree_loop(seed: int) -> None:
    from forest.growth.foliage import _outer, group_by, sorted_quantile

    rng = np.random.default_rng(seed)
    k = 5000
    tree = rng.integers(0, 40, k).astype(np.int32)
    tree[:3] = 77  # a tree of three sprays, and one of a single spray
    tree[3] = 90
    pos = rng.normal(size=(k, 3)) * [3.0, 5.0, 3.0] + tree[:, None] * [10.0, 0.0, 0.0]
    pos[rng.random(k) < 0.05, 1] = 2.0  # ties
    assert np.array_equal(_outer(pos, tree), _outer_loop(pos, tree))
    big = tree + 40_000  # keys past 16 bits: the other sort
    assert np.array_equal(_outer(pos, big), _outer_loop(pos, big))
    order, bounds = group_by(big)
    assert np.array_equal(order, np.argsort(big, kind="stable")) and len(bounds) == 43
    for n in (1, 2, 3, 7, 100, 1001):
        values = np.sort(rng.normal(size=n))
        for q in (0.0, 0.02, 0.5, 0.95, 0.98, 1.0):
            assert sorted_quantile(values, q) == np.percentile(values, 100 * q), (n, q)


def test_low_sprays_and_triangle_caps_equal_their_loops() -> None:
    from forest.growth.foliage import _cap_triangles, _fit_low

    rng = np.random.default_rng(5)
    m = 4000
    drop = np.array([0.4, 0.9, 0.2, 0.9, 1.3, 0.6, 0.0, 0.5])
    model = rng.integers(0, 8, m).astype(np.int32)
    size = rng.uniform(0.8, 1.2, m)
    room = rng.uniform(-0.5, 1.5, m)
    keep = rng.random(m) < 0.9
    low = keep & (size * drop[model] > room)
    for d in (drop, drop + 0.1):  # with and without a model that never drops
        want_model, want_size, want_keep = model.copy(), size.copy(), keep.copy()
        order = np.argsort(d)
        for i in np.flatnonzero(low):  # the loop _fit_low replaced
            fits = order[want_size[i] * d[order] <= room[i]]
            if len(fits):
                want_model[i] = fits[-1]
            elif room[i] > 0 and room[i] / d[order[0]] >= 0.6 * 0.8:
                want_model[i], want_size[i] = order[0], room[i] / d[order[0]]
            else:
                want_keep[i] = False
        got_model, got_size, got_keep = model.copy(), size.copy(), keep.copy()
        _fit_low(got_model, got_size, got_keep, low, room, d, 0.6 * 0.8)
        assert np.array_equal(got_model, want_model)
        assert np.array_equal(got_size, want_size)
        assert np.array_equal(got_keep, want_keep)
        assert (got_size != size).any() or d is drop  # the shrinking branch is reached
        assert not (got_keep & low & (got_size * d[got_model] > room)).any()
    tree = rng.integers(0, 25, m).astype(np.int32)
    score = np.round(rng.random(m), 2)  # ties, broken by index
    tris = rng.integers(10, 60, m)
    want = keep.copy()
    for t in np.unique(tree):  # the loop _cap_triangles replaced
        sel = np.flatnonzero(want & (tree == t))
        sel = sel[np.argsort(-score[sel], kind="stable")]
        want[sel[np.cumsum(tris[sel]) > 2000]] = False
    got = keep.copy()
    _cap_triangles(got, score, tree, tris, 2000)
    assert np.array_equal(got, want) and got.sum() < keep.sum()
    got = keep.copy()
    _cap_triangles(got, score, tree + 40_000, tris, 2000)
    assert np.array_equal(got, want) and got.sum() < keep.sum()
    none = np.zeros(m, bool)
    _cap_triangles(none, score, tree, tris, 2000)
    assert not none.any()
