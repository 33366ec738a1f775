"""forest.usd.figures: each measure on scenes whose answer is known — hand-built stages (posed
and skinned layouts, known cards, rims and transforms), the measures' own functions on
synthetic points, and small generated forests checked against the generator's arrays and
between their two written forms; ``forest inspect --figures``."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from pxr import Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt

from cli.app import main
from forest.errors import SceneError
from forest.geometry.pieces import PIECE_NAMES
from forest.growth.generate import Forest, ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.usd.contract import (
    ASSET_TREE,
    BARK_MESH,
    FOLIAGE,
    FOREST,
    INSTANCE,
    LEAF_RIMS,
    LEAVES_MESH,
    PIECES,
    POSED,
    PROXY_MESH,
    REPRESENTATION,
    ROOT_RIM,
    SKINNED,
    TREE_ID,
    TREES,
    tree_name,
)
from forest.usd.figures import (
    TreeFigures,
    card_lengths,
    crown_plan,
    figures_table,
    scene_figures,
)
from forest.usd.scene import write_scene

HEX = np.deg2rad(30.0 + 60.0 * np.arange(6))


def ring(y: float, r: float) -> np.ndarray:
    return np.stack([r * np.cos(HEX), np.full(6, y), r * np.sin(HEX)], axis=1)


def mesh(
    stage: Usd.Stage,
    path: str,
    points: np.ndarray,
    faces: list[list[int]],
    st: np.ndarray | None = None,
    st_interp: str = UsdGeom.Tokens.vertex,
) -> Usd.Prim:
    m = UsdGeom.Mesh.Define(stage, path)
    m.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.asarray(points, np.float32)))
    m.CreateFaceVertexCountsAttr([len(f) for f in faces])
    m.CreateFaceVertexIndicesAttr([i for f in faces for i in f])
    if st is not None:
        pv = UsdGeom.PrimvarsAPI(m).CreatePrimvar(
            "st", Sdf.ValueTypeNames.TexCoord2fArray, st_interp
        )
        pv.Set(Vt.Vec2fArray.FromNumpy(np.asarray(st, np.float32)))
    return m.GetPrim()


def tube(stage: Usd.Stage, path: str) -> Usd.Prim:
    """A hexagonal prism of circumradius 1, height 2: 6 quads, a leaf rim on top."""
    p = mesh(
        stage,
        path,
        np.concatenate([ring(0, 1), ring(2, 1)]),
        [[k, 6 + k, 6 + (k + 1) % 6, (k + 1) % 6] for k in range(6)],
    )
    p.CreateAttribute(ROOT_RIM, Sdf.ValueTypeNames.IntArray).Set(list(range(6)))
    p.CreateAttribute(LEAF_RIMS, Sdf.ValueTypeNames.IntArray).Set(list(range(6, 12)))
    return p


TUBE_TRIANGLES = 12


def cap(stage: Usd.Stage, path: str) -> Usd.Prim:
    """A tip: root rim of circumradius 1, a narrower ring, closed by one hexagon (an n-gon:
    4 triangles); no leaf rims."""
    p = mesh(
        stage,
        path,
        np.concatenate([ring(0, 1), ring(1, 0.4)]),
        [[k, 6 + k, 6 + (k + 1) % 6, (k + 1) % 6] for k in range(6)] + [list(range(11, 5, -1))],
    )
    p.CreateAttribute(ROOT_RIM, Sdf.ValueTypeNames.IntArray).Set(list(range(6)))
    p.CreateAttribute(LEAF_RIMS, Sdf.ValueTypeNames.IntArray).Set([])
    return p


CAP_TRIANGLES = 12 + 4

# two leaf cards of a cloud prototype, in its own space: one standing, 0.4 long (t) by 0.2
# (s); one lying with its picture turned (the leaf along s), 0.4 by 0.1. Both 0.4 long.
CARD_POINTS = np.array(
    [
        [-0.1, 0.0, 0.0], [0.1, 0.0, 0.0], [0.1, 0.4, 0.0], [-0.1, 0.4, 0.0],
        [0.0, 0.0, 0.0], [0.4, 0.0, 0.0], [0.4, 0.0, 0.1], [0.0, 0.0, 0.1],
    ]
)  # fmt: skip
CARD_ST = np.array(
    [[0, 0], [1, 0], [1, 1], [0, 1], [0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64
)
CARD_LENGTH = 0.4


def cloud(stage: Usd.Stage, path: str) -> Usd.Prim:
    return mesh(stage, path, CARD_POINTS, [[0, 1, 2, 3], [4, 5, 6, 7]], CARD_ST)


def instancer(
    stage: Usd.Stage,
    path: str,
    protos: list[Usd.Prim],
    proto: list[int],
    positions: list[tuple[float, float, float]],
    scales: list[float],
    ints: dict[str, list[int]],
) -> UsdGeom.PointInstancer:
    inst = UsdGeom.PointInstancer.Define(stage, path)
    inst.CreatePrototypesRel().SetTargets([p.GetPath() for p in protos])
    inst.CreateProtoIndicesAttr(proto)
    inst.CreatePositionsAttr([Gf.Vec3f(*p) for p in positions])
    inst.CreateScalesAttr([Gf.Vec3f(s, s, s) for s in scales])
    inst.CreateOrientationsAttr([Gf.Quath(1, 0, 0, 0)] * len(proto))
    for name, values in ints.items():
        UsdGeom.PrimvarsAPI(inst).CreatePrimvar(
            name, Sdf.ValueTypeNames.IntArray, UsdGeom.Tokens.vertex
        ).Set(values)
    return inst


def posed_stage(path: Path) -> Path:
    """Two trees in the posed layout, no variant set. Tree 0: a tube of radius 0.2 standing on
    the ground (0 .. 0.4 m), caps of radius 4 and 6 mm; clouds of scale 0.25 on it. Tree 1 at
    x = 10, its tube sunk 5 cm, one cap of radius 2 mm, one cloud of scale 0.5."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.Xform.Define(stage, "/World")
    UsdGeom.Xform.Define(stage, FOREST)
    protos = [tube(stage, f"{PIECES}/Prototypes/Tube"), cap(stage, f"{PIECES}/Prototypes/Cap")]
    instancer(
        stage,
        PIECES,
        protos,
        [0, 1, 1, 0, 1],
        [(0, 0, 0), (0, 0.4, 0), (0.1, 0.3, 0), (10, -0.05, 0), (10, 0.55, 0)],
        [0.2, 0.004, 0.006, 0.3, 0.002],
        {TREE_ID: [0, 0, 0, 1, 1]},
    )
    leaf = [cloud(stage, f"{FOLIAGE}/Prototypes/LeafCloud0")]
    instancer(
        stage,
        FOLIAGE,
        leaf,
        [0, 0, 0],
        [(0, 0.5, 0), (1, 0.6, 0), (10, 1.0, 0)],
        [0.25, 0.25, 0.5],
        {INSTANCE: [0, 2, 3]},
    )
    stage.GetRootLayer().Save()
    return path


def test_posed_layout_every_measure(tmp_path: Path) -> None:
    fig = scene_figures(posed_stage(tmp_path / "posed.usda"))
    assert fig.representation == POSED
    a, b = fig.trees
    assert (a.tree, b.tree) == (0, 1)
    # cards: two per cloud, 0.4 long in the prototype, times the instance scale
    assert (a.cards, b.cards) == (4, 2)
    assert a.card_length == pytest.approx(0.25 * CARD_LENGTH, rel=1e-5)
    assert b.card_length == pytest.approx(0.5 * CARD_LENGTH, rel=1e-5)
    # lowest vertices: tube 0 stands on the ground, tube 1 is sunk 5 cm; the lowest card
    # corner is the cloud's position (corners at y >= 0 in the prototype)
    assert a.bark_low == pytest.approx(0.0, abs=1e-6)
    assert b.bark_low == pytest.approx(-0.05, abs=1e-6)
    assert a.leaf_low == pytest.approx(0.5, abs=1e-6)
    assert b.leaf_low == pytest.approx(1.0, abs=1e-6)
    # height: the highest vertex, bark or leaf (tree 0: the second cloud's card top)
    assert a.height == pytest.approx(0.6 + 0.25 * 0.4, abs=1e-6)
    assert b.height == pytest.approx(max(-0.05 + 0.3 * 2, 0.55 + 0.002, 1.0 + 0.5 * 0.4))
    # tips: twice the cap's root-rim radius (1 in the prototype) times the instance scale
    assert a.tips == 2 and b.tips == 1
    assert a.tip_diameter_median == pytest.approx(0.010, rel=1e-3)
    assert a.tip_diameter_max == pytest.approx(0.012, rel=1e-3)
    assert b.tip_diameter_max == pytest.approx(0.004, rel=1e-3)
    # triangles: quads count 2, the cap's hexagon 4
    assert a.bark_triangles == TUBE_TRIANGLES + 2 * CAP_TRIANGLES
    assert b.bark_triangles == TUBE_TRIANGLES + CAP_TRIANGLES
    assert (a.leaf_triangles, b.leaf_triangles) == (8, 4)
    assert a.triangles == a.bark_triangles + 8
    # crown base: the leaves' 1st percentile of y over the height
    leaf_y = np.concatenate([0.5 + 0.25 * CARD_POINTS[:, 1], 0.6 + 0.25 * CARD_POINTS[:, 1]])
    assert a.crown_base == pytest.approx(np.percentile(leaf_y, 1) / a.height)


def test_a_tree_sees_only_its_own_instances(tmp_path: Path) -> None:
    """Moving tree 1's pieces and cloud changes none of tree 0's figures."""
    before = scene_figures(posed_stage(tmp_path / "a.usda")).trees[0]
    stage = Usd.Stage.Open(str(tmp_path / "a.usda"))
    inst = UsdGeom.PointInstancer(stage.GetPrimAtPath(PIECES))
    pos = list(inst.GetPositionsAttr().Get())
    pos[3], pos[4] = Gf.Vec3f(3, -2, 0), Gf.Vec3f(3, 9, 0)
    inst.GetPositionsAttr().Set(pos)
    stage.GetRootLayer().Save()
    after = scene_figures(tmp_path / "a.usda").trees
    assert after[0] == before
    assert after[1].bark_low == pytest.approx(-2.0)


def test_transforms_above_the_instancers_apply(tmp_path: Path) -> None:
    path = posed_stage(tmp_path / "up.usda")
    before = scene_figures(path).trees
    stage = Usd.Stage.Open(str(path))
    UsdGeom.Xformable(stage.GetPrimAtPath(FOREST)).AddTranslateOp().Set(Gf.Vec3d(7, 2, 0))
    stage.GetRootLayer().Save()
    after = scene_figures(path).trees
    for a, b in zip(before, after, strict=True):
        assert b.bark_low == pytest.approx(a.bark_low + 2, abs=1e-6)
        assert b.leaf_low == pytest.approx(a.leaf_low + 2, abs=1e-6)
        assert b.height == pytest.approx(a.height + 2, abs=1e-6)
        assert b.card_length == pytest.approx(a.card_length)


def test_crown_base_is_the_first_percentile(tmp_path: Path) -> None:
    """Fifty clouds up tree 0 at 1, 2, ... 50 m: the crown base is the 1st percentile of their
    cards' vertex heights over the tree's height."""
    path = posed_stage(tmp_path / "tall.usda")
    stage = Usd.Stage.Open(str(path))
    inst = UsdGeom.PointInstancer(stage.GetPrimAtPath(FOLIAGE))
    ys = np.arange(1.0, 51.0)
    inst.GetProtoIndicesAttr().Set([0] * 50)
    inst.GetPositionsAttr().Set([Gf.Vec3f(0, y, 0) for y in ys])
    inst.GetScalesAttr().Set([Gf.Vec3f(1, 1, 1)] * 50)
    inst.GetOrientationsAttr().Set([Gf.Quath(1, 0, 0, 0)] * 50)
    UsdGeom.PrimvarsAPI(inst).GetPrimvar(INSTANCE).Set([0] * 50)
    stage.GetRootLayer().Save()
    t, bare = scene_figures(path).trees
    assert bare.cards == 0 and math.isnan(bare.crown_base)  # tree 1 has no cloud left
    leaf_y = (ys[:, None] + CARD_POINTS[None, :, 1]).ravel()
    assert t.height == pytest.approx(50.4)
    assert t.crown_base == pytest.approx(np.percentile(leaf_y, 1) / 50.4, rel=1e-6)


def skinned_stage(path: Path) -> Path:
    """The skinned layout: a variant set whose ``skinned`` variant holds one SkelRoot (named
    Tree_00000 but tree 1 by its assetInfo) moved up 1 m, with Bark, a Proxy that sinks 10 m
    (a proxy: not measured) and Leaves with faceVarying, indexed st; ``Pieces`` with the tips
    in the ``posed`` variant only, as the writer does."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.Xform.Define(stage, "/World")
    forest = UsdGeom.Xform.Define(stage, FOREST).GetPrim()
    vset = forest.GetVariantSets().AddVariantSet(REPRESENTATION)
    # outside the variants: the instancer's prototypes and its per-instance primvars
    protos = [tube(stage, f"{PIECES}/Prototypes/Tube"), cap(stage, f"{PIECES}/Prototypes/Cap")]
    inst = UsdGeom.PointInstancer.Define(stage, PIECES)
    inst.CreatePrototypesRel().SetTargets([p.GetPath() for p in protos])
    inst.CreateProtoIndicesAttr([0, 1])
    UsdGeom.PrimvarsAPI(inst).CreatePrimvar(
        TREE_ID, Sdf.ValueTypeNames.IntArray, UsdGeom.Tokens.vertex
    ).Set([1, 1])
    vset.AddVariant(POSED)
    vset.SetVariantSelection(POSED)
    with vset.GetVariantEditContext():
        inst.CreatePositionsAttr([Gf.Vec3f(0, 1, 0), Gf.Vec3f(0, 1.4, 0)])
        inst.CreateScalesAttr([Gf.Vec3f(0.2, 0.2, 0.2), Gf.Vec3f(0.003, 0.003, 0.003)])
    vset.AddVariant(SKINNED)
    vset.SetVariantSelection(SKINNED)
    with vset.GetVariantEditContext():
        stage.GetPrimAtPath(PIECES).SetActive(False)
        UsdGeom.Xform.Define(stage, TREES)
        root = UsdSkel.Root.Define(stage, f"{TREES}/{tree_name(0)}")
        root.AddTranslateOp().Set(Gf.Vec3d(5, 1, 0))
        root.GetPrim().SetAssetInfoByKey(ASSET_TREE, 1)
        base = f"{TREES}/{tree_name(0)}"
        mesh(
            stage,
            f"{base}/{BARK_MESH}",
            np.concatenate([ring(0, 0.2), ring(3, 0.1)]),
            [[k, 6 + k, 6 + (k + 1) % 6, (k + 1) % 6] for k in range(6)] + [[6, 7, 8]],
        )
        proxy = mesh(stage, f"{base}/{PROXY_MESH}", np.array([[0, -10, 0], [1, 0, 0], [0, 1, 0]]),
                     [[0, 1, 2]])  # fmt: skip
        UsdGeom.Imageable(proxy).CreatePurposeAttr(UsdGeom.Tokens.proxy)
        # two cards, the second twice the first; st faceVarying, indexed
        pts = np.concatenate(
            [0.1 * CARD_POINTS[:4] + [0, 2, 0], 0.2 * CARD_POINTS[:4] + [0, 2.5, 0]]
        )
        leaves = mesh(stage, f"{base}/{LEAVES_MESH}", pts, [[0, 1, 2, 3], [4, 5, 6, 7]])
        pv = UsdGeom.PrimvarsAPI(leaves).CreatePrimvar(
            "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying
        )
        pv.Set(Vt.Vec2fArray.FromNumpy(CARD_ST[:4].astype(np.float32)))
        pv.SetIndices(Vt.IntArray([0, 1, 2, 3, 0, 1, 2, 3]))
    stage.GetRootLayer().Save()
    return path


def test_skinned_layout(tmp_path: Path) -> None:
    path = skinned_stage(tmp_path / "skinned.usda")
    fig = scene_figures(path)
    assert fig.representation == SKINNED
    (t,) = fig.trees
    assert t.tree == 1  # from the assetInfo, not the prim's name
    assert t.bark_low == pytest.approx(1.0)  # the SkelRoot's transform applied; proxy ignored
    assert t.height == pytest.approx(max(1 + 3, 1 + 2.5 + 0.2 * 0.4))
    assert t.bark_triangles == 12 + 1
    assert (t.cards, t.leaf_triangles) == (2, 4)
    assert t.card_length == pytest.approx(np.median([0.1 * 0.4, 0.2 * 0.4]), rel=1e-5)
    assert t.leaf_low == pytest.approx(3.0)
    # the tips come from the posed variant though the file composes the skinned trees
    assert t.tips == 1 and t.tip_diameter_max == pytest.approx(0.006, rel=1e-3)
    # and the file's own selection is left as it was
    stage = Usd.Stage.Open(str(path))
    sel = stage.GetPrimAtPath(FOREST).GetVariantSets().GetVariantSet(REPRESENTATION)
    assert sel.GetVariantSelection() == SKINNED


def test_up_axis_must_be_y(tmp_path: Path) -> None:
    path = posed_stage(tmp_path / "z.usda")
    stage = Usd.Stage.Open(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    stage.GetRootLayer().Save()
    with pytest.raises(SceneError, match="up axis Z"):
        scene_figures(path)


def test_a_broken_tree_index_is_named(tmp_path: Path) -> None:
    path = posed_stage(tmp_path / "bad.usda")
    stage = Usd.Stage.Open(str(path))
    UsdGeom.PrimvarsAPI(stage.GetPrimAtPath(FOLIAGE)).GetPrimvar(INSTANCE).Set([0, 2, 9])
    stage.GetRootLayer().Save()
    with pytest.raises(SceneError, match=r"values outside \[0, 5\)") as err:
        scene_figures(path)
    assert err.value.path == f"{FOLIAGE}.primvars:{INSTANCE}"


# -- the measures on their own --------------------------------------------------------------


def test_card_length_is_the_long_side_in_the_picture() -> None:
    rng = np.random.default_rng(1)
    # rhombus leaf cards (the broadleaf card: base, right, tip, left), length 1, width 0.6,
    # turned and moved at random: the length is base to tip, whatever the pose
    shape = np.array([[0.0, 0.0], [0.3, 0.4], [0.0, 1.0], [-0.3, 0.4]])
    st = np.array([[0.5, 0.0], [1.0, 0.4], [0.5, 1.0], [0.0, 0.4]])
    q, _ = np.linalg.qr(rng.normal(size=(50, 3, 3)))
    size = rng.uniform(0.01, 0.3, 50)
    corners = size[:, None, None] * np.einsum("kj,cij->cki", np.c_[shape, np.zeros(4)], q)
    corners += rng.normal(size=(50, 1, 3))
    sts = np.broadcast_to(st, (50, 4, 2))
    np.testing.assert_allclose(card_lengths(corners, sts), size, rtol=1e-9)
    # a picture turned a quarter (the leaf along s) and an atlas cell (st over half the
    # picture) measure the same card
    turned = sts[:, :, ::-1]
    np.testing.assert_allclose(card_lengths(corners, turned), size, rtol=1e-9)
    np.testing.assert_allclose(card_lengths(corners, 0.25 + 0.5 * sts), size, rtol=1e-9)
    # no st, or st on a line: the longest corner-to-corner distance (here base to tip too)
    np.testing.assert_allclose(card_lengths(corners, None), size, rtol=1e-9)
    flat = sts.copy()
    flat[..., 0] = 0.5
    np.testing.assert_allclose(card_lengths(corners, flat), size, rtol=1e-9)
    # a wide card is as long as it is wide
    wide = np.array([[[0, 0, 0], [0.3, 0, 0], [0.3, 0.1, 0], [0, 0.1, 0]]], float)
    unit = np.array([[[0, 0], [1, 0], [1, 1], [0, 1]]], float)
    assert card_lengths(wide, unit)[0] == pytest.approx(0.3)


def test_crown_plan_of_a_turned_ellipse() -> None:
    """A filled ellipse of half axes 4 and 2 turned 30 degrees: narrow/wide is 0.5 (the 5-95 %
    extents of an affine image of a disc keep its axes' ratio), the width 8 (full extent)."""
    rng = np.random.default_rng(2)
    r = np.sqrt(rng.random(200_000))
    phi = rng.uniform(0, 2 * np.pi, 200_000)
    pts = np.stack([4 * r * np.cos(phi), 2 * r * np.sin(phi)], axis=1)
    turn = np.deg2rad(30)
    rot = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
    ratio, width = crown_plan(pts @ rot.T + [5.0, -3.0])
    assert ratio == pytest.approx(0.5, abs=0.01)
    assert width == pytest.approx(8.0, abs=0.02)
    # a round crown; a line of points is as narrow as it gets
    assert crown_plan(np.stack([r * np.cos(phi), r * np.sin(phi)], axis=1))[0] == pytest.approx(
        1.0, abs=0.01
    )
    line = np.stack([np.linspace(0, 1, 100), np.linspace(0, 2, 100)], axis=1)
    assert crown_plan(line)[0] == pytest.approx(0.0, abs=1e-9)
    assert all(math.isnan(v) for v in crown_plan(np.zeros((2, 2))))


def test_table_reads() -> None:
    t = TreeFigures(
        tree=0, height=12.3456, bark_low=0.0, leaf_low=math.nan, cards=1234, card_length=0.0876,
        tips=3, tip_diameter_median=0.0071, tip_diameter_max=0.0123, crown_narrow_wide=0.81,
        crown_width=9.0, crown_base=0.25, bark_triangles=1000, leaf_triangles=2468,
    )  # fmt: skip
    head, row = figures_table([t], ["oak 3"], "tree").splitlines()
    assert head.split()[:3] == ["tree", "tree", "height"]
    cells = row.split()
    assert cells[:4] == ["oak", "3", "0", "12.35"]
    assert "8.8" in cells and "-" in cells and "1.23" in cells and "3,468" in cells
    assert len(head) == len(row)


# -- generated forests ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def hazel() -> Forest:
    return generate_forest(load_preset("hazel"), 3, ForestOptions(trees=2))


@pytest.fixture(scope="module")
def hazel_files(hazel: Forest, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    folder = tmp_path_factory.mktemp("hazel")
    return (
        write_scene(hazel, folder / "skinned.usdc", skinned=True),
        write_scene(hazel, folder / "posed.usdc", skinned=False),
    )


def test_generated_tree_against_the_generator(
    hazel: Forest, hazel_files: tuple[Path, Path]
) -> None:
    """Counts and card sizes as the generator made them: triangles from the pieces' quads and
    the sprays' cards, the caps, each card's long side times its spray's scale."""
    fig = scene_figures(hazel_files[0])
    anchors = hazel.foliage_anchors()
    models = anchors.models()
    g = hazel.graph
    tree_of_cloud = g.tree[anchors.instance]
    quads = np.array([len(p.quads) for p in hazel.pieces])
    for t in fig.trees:
        mine = g.tree == t.tree
        assert t.bark_triangles == 2 * quads[g.piece[mine]].sum()
        assert t.tips == int((g.piece[mine] == PIECE_NAMES.index("Cap")).sum())
        clouds = np.flatnonzero(tree_of_cloud == t.tree)

        # a card is a rectangle (corners base-left, base-right, tip-right, tip-left): its
        # long side, whether it runs along the leaf or across it
        def long_sides(m: int) -> np.ndarray:
            p = models[m].positions[models[m].quads]
            return np.maximum(
                np.linalg.norm(p[:, 1] - p[:, 0], axis=1), np.linalg.norm(p[:, 3] - p[:, 0], axis=1)
            )

        lengths = np.concatenate([anchors.size[a] * long_sides(anchors.model[a]) for a in clouds])
        assert t.cards == len(lengths) and t.leaf_triangles == 2 * len(lengths)
        assert t.card_length == pytest.approx(np.median(lengths), rel=1e-4)
        # the tips are thinner than the trunk and not nothing
        assert 0 < t.tip_diameter_median <= t.tip_diameter_max < 0.1


def test_skinned_and_posed_forms_agree(hazel_files: tuple[Path, Path]) -> None:
    skinned, posed = (scene_figures(p) for p in hazel_files)
    assert (skinned.representation, posed.representation) == (SKINNED, POSED)
    assert len(skinned.trees) == len(posed.trees) == 2
    for a, b in zip(skinned.trees, posed.trees, strict=True):
        assert a.tree == b.tree
        assert (a.cards, a.tips, a.bark_triangles, a.leaf_triangles) == (
            b.cards, b.tips, b.bark_triangles, b.leaf_triangles,
        )  # fmt: skip
        assert a.tip_diameter_max == b.tip_diameter_max  # both from the posed variant
        # the posed pieces are rigid fits of the skinned ones: a few millimetres apart
        assert a.card_length == pytest.approx(b.card_length, rel=1e-3)
        assert a.height == pytest.approx(b.height, abs=0.02)
        # the lowest bark differs at the stool: its piece is stretched past its own length
        # (root_min_length) and a rigid fit of it sinks ~0.1 m into the ground (known gap of
        # the posed form); the skinned form, the one consumers open, stays on the ground
        assert a.bark_low == pytest.approx(0.0, abs=0.001)
        assert -0.15 <= b.bark_low <= a.bark_low + 0.02
        assert a.leaf_low == pytest.approx(b.leaf_low, abs=0.02)
        assert a.crown_narrow_wide == pytest.approx(b.crown_narrow_wide, abs=0.01)
        assert a.crown_base == pytest.approx(b.crown_base, abs=0.01)


def test_inspect_prints_the_figures(hazel_files: tuple[Path, Path], tmp_path: Path) -> None:
    res = CliRunner().invoke(main, ["inspect", str(hazel_files[0]), "--figures"])
    assert res.exit_code == 0, res.output
    lines = res.output.splitlines()
    assert lines[0] == f"{hazel_files[0]}: 2 tree(s), measured on the skinned form"
    assert lines[1].split()[:3] == ["tree", "height", "m"]
    assert [line.split()[0] for line in lines[2:]] == ["0", "1"]
    res = CliRunner().invoke(main, ["inspect", str(hazel_files[0])])
    assert res.exit_code == 2
    assert "give -o SHEET.png for the contact sheet, --figures" in res.output
