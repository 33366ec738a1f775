"""The ``representation`` variant set: what a USD consumer that knows nothing of forest:*
composes by default, the posed instances against USD's own skinning, model hierarchy."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pxr import Kind, Usd, UsdGeom, UsdSkel, UsdValidation

from forest.growth.generate import Forest
from forest.usd.contract import ENGINE, FOREST, PIECES, POSED, REPRESENTATION, SKINNED, TREES
from forest.usd.read import select_engine
from forest.usd.scene import write_scene

POSED_MAX_REL = 0.03  # measured worst over the presets: 2.9 % of the height (willow), docs/usd.md


def _selected(path: Path, variant: str | None = None) -> Usd.Stage:
    stage = Usd.Stage.Open(str(path))
    if variant is not None:
        with Usd.EditContext(stage, stage.GetSessionLayer()):
            stage.GetPrimAtPath(FOREST).GetVariantSet(REPRESENTATION).SetVariantSelection(variant)
    return stage


def _visible_gprims(stage: Usd.Stage) -> list[str]:
    out = []
    for prim in stage.Traverse():
        if prim.IsA(UsdGeom.PointInstancer) or (
            prim.IsA(UsdGeom.Mesh)
            and "Prototypes" not in str(prim.GetPath())
            and UsdGeom.Imageable(prim).ComputePurpose() != UsdGeom.Tokens.proxy
        ):
            out.append(str(prim.GetPath()))
    return out


@pytest.mark.parametrize("skinned", [False, True])
def test_default_shows_each_tree_once(windy_forest: Forest, tmp_path: Path, skinned: bool) -> None:
    path = write_scene(windy_forest, tmp_path / "f.usdc", skinned=skinned)
    stage = Usd.Stage.Open(str(path))
    vset = stage.GetPrimAtPath(FOREST).GetVariantSet(REPRESENTATION)
    assert vset.GetVariantSelection() == (SKINNED if skinned else POSED)
    shown = _visible_gprims(stage)
    if skinned:  # bark and leaves per tree, no instancer
        assert sorted(shown) == sorted(
            f"{TREES}/Tree_{k:05d}/{m}" for k in range(3) for m in ("Bark", "Leaves")
        )
    else:  # the pieces once, the leaf clouds once, no skinned tree
        assert sorted(shown) == [f"{FOREST}/Foliage", PIECES]


def test_posed_instances_follow_usd_skinning(skinned_scene: Path, windy_forest: Forest) -> None:
    """Every vertex of every posed piece instance against UsdSkel's skinning of the same
    tree, at the first and last frame, within POSED_MAX_REL of the tree's height."""
    from scipy.spatial import cKDTree

    posed = _selected(skinned_scene, POSED)
    skinned = _selected(skinned_scene, SKINNED)
    inst = UsdGeom.PointInstancer(posed.GetPrimAtPath(PIECES))
    protos = [UsdGeom.Mesh(posed.GetPrimAtPath(t)) for t in inst.GetPrototypesRel().GetTargets()]
    proto_pts = [np.asarray(m.GetPointsAttr().Get(), np.float64) for m in protos]
    idx = np.asarray(inst.GetProtoIndicesAttr().Get())
    tree = np.asarray(posed.GetPrimAtPath(PIECES).GetAttribute("primvars:forest:treeId").Get())
    cache = UsdSkel.Cache()
    for frame in (0, windy_forest.options.frames - 1):
        tc = Usd.TimeCode(frame)
        xf = np.asarray(inst.ComputeInstanceTransformsAtTime(tc, tc))
        for k in range(windy_forest.options.trees):
            root = skinned.GetPrimAtPath(f"{TREES}/Tree_{k:05d}")
            cache.Populate(UsdSkel.Root(root), Usd.PrimDefaultPredicate)
            skel = cache.GetSkelQuery(UsdSkel.Skeleton(root.GetChild("Skeleton")))
            bark = root.GetChild("Bark")
            pts = UsdGeom.Mesh(bark).GetPointsAttr().Get(tc)
            cache.GetSkinningQuery(bark).ComputeSkinnedPoints(
                skel.ComputeSkinningTransforms(tc), pts, tc
            )
            w = np.asarray(UsdGeom.Xformable(root).ComputeLocalToWorldTransform(tc))
            usd = np.c_[np.asarray(pts, np.float64), np.ones(len(pts))] @ w
            ours = np.concatenate(
                [
                    np.c_[proto_pts[idx[i]], np.ones(len(proto_pts[idx[i]]))] @ xf[i]
                    for i in np.flatnonzero(tree == k)
                ]
            )
            height = usd[:, 1].max() - usd[:, 1].min()
            err = cKDTree(usd[:, :3]).query(ours[:, :3])[0]
            assert err.max() < POSED_MAX_REL * height, (frame, k, err.max() / height)
            assert np.median(err) < 0.002 * height


def test_engine_variant_is_what_the_reader_reads(skinned_scene: Path) -> None:
    stage = Usd.Stage.Open(str(skinned_scene))
    select_engine(stage)
    prim = stage.GetPrimAtPath(PIECES)
    assert prim.IsActive()
    assert not prim.GetAttribute("positions").GetTimeSamples()  # the topological transforms
    vset = stage.GetPrimAtPath(FOREST).GetVariantSet(REPRESENTATION)
    assert vset.GetVariantSelection() == ENGINE
    assert set(vset.GetVariantNames()) == {ENGINE, POSED, SKINNED}


def test_model_hierarchy_and_layer_doc(skinned_scene: Path, windy_forest: Forest) -> None:
    stage = Usd.Stage.Open(str(skinned_scene))
    assert Usd.ModelAPI(stage.GetPrimAtPath("/World")).GetKind() == Kind.Tokens.assembly
    assert Usd.ModelAPI(stage.GetPrimAtPath(FOREST)).GetKind() == Kind.Tokens.group
    assert Usd.ModelAPI(stage.GetPrimAtPath(TREES)).GetKind() == Kind.Tokens.group
    for tree in stage.GetPrimAtPath(TREES).GetChildren():
        model = Usd.ModelAPI(tree)
        assert model.GetKind() == Kind.Tokens.component and tree.IsModel()
        assert model.GetAssetName() == tree.GetName()
        assert model.GetAssetVersion() == windy_forest.version
    doc = stage.GetRootLayer().documentation
    assert "interlocking-forest" in doc and windy_forest.grammar.name in doc
    assert f"seed {windy_forest.seed}" in doc


def test_skinned_form_is_welded_indexed_and_bounded_per_frame(skinned_scene: Path) -> None:
    from scipy.spatial import cKDTree

    stage = Usd.Stage.Open(str(skinned_scene))
    root = stage.GetPrimAtPath(f"{TREES}/Tree_00000")
    bark = UsdGeom.Mesh(root.GetChild("Bark"))
    pts = np.asarray(bark.GetPointsAttr().Get(), np.float64)
    assert len(cKDTree(pts).query_pairs(1e-6)) == 0  # no seam left open
    assert UsdGeom.PrimvarsAPI(bark).GetPrimvar("st").IsIndexed()
    proxy = UsdGeom.Mesh(root.GetChild("Proxy"))
    n = np.asarray(proxy.GetNormalsAttr().Get())
    assert len(n) == len(proxy.GetPointsAttr().Get())
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-5)
    for prim in (root, root.GetChild("Skeleton")):
        samples = UsdGeom.Boundable(prim).GetExtentAttr().GetTimeSamples()
        assert len(samples) == stage.GetEndTimeCode() + 1


@pytest.mark.parametrize(
    ("suffix", "variant"),
    [(s, v) for s in (".usda", ".usdc") for v in (ENGINE, POSED, SKINNED)]
    + [(".usdz", SKINNED)],  # a .usdz holds the skinned trees only (ARKit)
)
def test_usd_validation_on_every_form(
    windy_forest: Forest, tmp_path: Path, suffix: str, variant: str
) -> None:
    tiles = None if suffix == ".usdz" else "tiles"  # a usdz packs tiles that exist
    path = write_scene(windy_forest, tmp_path / f"f{suffix}", skinned=True, tiles=tiles)
    stage = _selected(path, variant)
    registry = UsdValidation.ValidationRegistry()
    ctx = UsdValidation.ValidationContext(registry.GetOrLoadAllValidators())
    errors = [f"{e.GetIdentifier()}: {e.GetMessage()}" for e in ctx.Validate(stage)]
    errors = [e for e in errors if "MissingReference" not in e or suffix == ".usdz"]
    assert errors == [], errors


def test_small_forests_are_skinned_by_default(
    windy_forest: Forest, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """No ``skinned`` argument: skinned (exact in any DCC) up to SKINNED_MAX_TREES trees and
    SKINNED_MAX_PIECES pieces, posed above; a .usdz is skinned whatever the size."""
    import forest.usd.scene as scene

    def selection(path: Path) -> str:
        stage = Usd.Stage.Open(str(path))
        return str(stage.GetPrimAtPath(FOREST).GetVariantSet(REPRESENTATION).GetVariantSelection())

    assert windy_forest.options.trees <= scene.SKINNED_MAX_TREES
    assert selection(write_scene(windy_forest, tmp_path / "small.usdc")) == SKINNED
    monkeypatch.setattr(scene, "SKINNED_MAX_TREES", windy_forest.options.trees - 1)
    assert selection(write_scene(windy_forest, tmp_path / "many.usdc")) == POSED
    assert selection(write_scene(windy_forest, tmp_path / "many.usdz")) == SKINNED
    monkeypatch.undo()
    monkeypatch.setattr(scene, "SKINNED_MAX_PIECES", windy_forest.n_instances - 1)
    assert selection(write_scene(windy_forest, tmp_path / "big.usdc")) == POSED
    assert selection(write_scene(windy_forest, tmp_path / "forced.usdc", skinned=True)) == SKINNED


def test_cli_skinned_and_no_skinned(tmp_path: Path) -> None:
    """forest generate: the default for a small forest is skinned, --no-skinned posed, and
    --no-skinned with a .usdz is a one-line error naming the option (exit 2)."""
    from click.testing import CliRunner

    from cli.app import main

    def run(*args: str) -> tuple[int, str]:
        res = CliRunner().invoke(
            main, ["generate", "--preset", "almond", "--seed", "1", "--trees", "1", *args]
        )
        return res.exit_code, res.output

    def selection(path: Path) -> str:
        stage = Usd.Stage.Open(str(path))
        return str(stage.GetPrimAtPath(FOREST).GetVariantSet(REPRESENTATION).GetVariantSelection())

    code, out = run("-o", str(tmp_path / "a.usdc"))
    assert code == 0 and out.strip().endswith("skinned"), out
    assert selection(tmp_path / "a.usdc") == SKINNED
    code, out = run("--no-skinned", "-o", str(tmp_path / "b.usdc"))
    assert code == 0 and out.strip().endswith("posed"), out
    assert selection(tmp_path / "b.usdc") == POSED
    code, out = run("--no-skinned", "-o", str(tmp_path / "c.usdz"))
    assert code == 2 and "skinned" in out and "usdz" in out, out
    assert not (tmp_path / "c.usdz").exists()


def test_posed_fit_moments_equal_one_product_per_instance_and_joint(
    windy_forest: Forest, monkeypatch: pytest.MonkeyPatch
) -> None:
    """fit_posed's moments come from one product per prototype and joint; they are the sums
    of the per-instance products over all MAX_JOINTS joints (its unused ones weighing 0) it
    replaced, bit for bit, so the posed values do not move."""
    from forest.geometry.pieces import MAX_JOINTS
    from forest.usd import posed

    forest = windy_forest
    moments = posed.piece_moments(forest.pieces)
    assert list(moments.joints) == [len(p.joint_rest) for p in forest.pieces]
    palette = forest.palette(0.4)
    proto, offset = forest.graph.piece, forest.bones.offset
    bones = np.minimum(offset[:, None] + np.arange(MAX_JOINTS), len(palette) - 1)
    # the formula before 0.7.0: a (3, 4) @ (4, 4) product per instance and joint, summed
    ref = (palette[:, :3, :][bones] @ moments.w[proto]).sum(axis=1)
    seen: list[np.ndarray] = []
    real = posed.polar_rotation

    def spy(h: np.ndarray, iterations: int = 8) -> np.ndarray:
        seen.append(h)
        return real(h, iterations)

    monkeypatch.setattr(posed, "polar_rotation", spy)
    posed.fit_posed(moments, proto, offset, palette)
    p_mean = moments.mean[proto]
    want = ref[:, :3, :3] - ref[:, :3, 3][:, :, None] * p_mean[:, None, :]
    np.testing.assert_array_equal(np.concatenate(seen), want)
