"""Joints cut to a budget per tree (forest.growth.joint_budget) in the skinned forms: the
counts, the kept set's shape, the skin bound to kept joints only, the still tree unchanged
and the wind still moving it, USD's own skinning of the written file against the full rig."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pxr import Usd, UsdSkel

from forest.errors import LimitError
from forest.growth.generate import Forest, ForestOptions, generate_forest
from forest.growth.joint_budget import (
    DCC_JOINTS,
    GAME_JOINTS,
    keep_joints,
    merge_influences,
    nearest_kept,
    reaches,
)
from forest.growth.presets import load_preset
from forest.usd.scene import write_scene
from forest.usd.skinned import dcc_joints, tree_mesh, tree_slices
from tests.helpers_skin import usd_skinned_points

TREE = "/World/Forest/Trees/Tree_00000"


@pytest.fixture(scope="module", params=["oak", "spruce"])
def big(request: pytest.FixtureRequest) -> Forest:
    """Two trees of a species with thousands of joints each, in the wind."""
    return generate_forest(load_preset(request.param), 3, ForestOptions(trees=2, frames=4))


def test_hand_made_hierarchy_keeps_the_longest_reach() -> None:
    #       0 (root)
    #      / \
    #     1   4       1 reaches 3 m further (2, 3 above it), 4 one metre
    #     |
    #     2 - 3
    parent = np.array([-1, 0, 1, 2, 0])
    position = np.array([[0, 0, 0], [0, 1, 0], [0, 2, 0], [0, 4, 0], [1, 0, 0]], float)
    np.testing.assert_allclose(reaches(parent, position), [4, 3, 2, 0, 0])
    tree = np.zeros(5, np.intp)
    assert keep_joints(parent, tree, position, 3).tolist() == [True, True, True, False, False]
    keep = keep_joints(parent, tree, position, 2)
    assert keep.tolist() == [True, True, False, False, False]
    assert nearest_kept(parent, keep).tolist() == [0, 1, 1, 1, 0]
    # two trees: each keeps its own budget
    two = keep_joints(
        np.r_[parent, parent + 5 * (parent >= 0)],
        np.repeat([0, 1], 5),
        np.r_[position, position],
        2,
    )
    assert two.tolist() == [True, True, False, False, False] * 2
    with pytest.raises(LimitError, match="at least one joint"):
        keep_joints(parent, tree, position, 0)


def test_merged_influences_name_each_joint_once() -> None:
    index = np.array([[3, 5, 3, 0], [1, 2, 0, 0], [4, 4, 4, 4]])
    weight = np.array([[0.5, 0.2, 0.3, 0.0], [0.6, 0.4, 0.0, 0.0], [0.25] * 4])
    got_i, got_w = merge_influences(index, weight)
    np.testing.assert_array_equal(got_i, index)  # slots stay, the repeats lose their weight
    np.testing.assert_allclose(got_w, [[0.8, 0.2, 0, 0], [0.6, 0.4, 0, 0], [1, 0, 0, 0]])
    np.testing.assert_array_equal(got_w[1], weight[1])  # no repeat: as it was


@pytest.mark.parametrize("budget", [DCC_JOINTS, GAME_JOINTS])
def test_each_tree_keeps_a_connected_budget(big: Forest, budget: int) -> None:
    full, cut = dcc_joints(big), dcc_joints(big, budget)
    slices = tree_slices(big, budget)
    for (_, joints), (_, all_joints) in zip(slices, tree_slices(big), strict=True):
        assert all_joints.stop - all_joints.start > 2 * budget  # the species needs the cut
        assert joints.stop - joints.start == budget
    # every kept joint but the trees' roots has a kept parent, the one it had in the full set
    index = np.searchsorted(full.bone, cut.bone)
    np.testing.assert_array_equal(full.bone[index], cut.bone)
    roots = cut.parent < 0
    assert roots.sum() == big.options.trees
    np.testing.assert_array_equal(
        cut.bone[cut.parent[~roots]], full.bone[full.parent[index[~roots]]]
    )
    np.testing.assert_array_equal(cut.via, full.via[index])
    # every bone's joint is a kept joint at or above it: walk up from the bone to find it
    b = big.bones
    for bone in np.linspace(0, len(b) - 1, 200).astype(int):
        target, up = cut.bone[cut.of_bone[bone]], int(bone)
        while up != target:
            up = int(b.parent[up])
            assert up >= 0, f"bone {bone}'s joint is not above it"
            assert not np.isin(up, cut.bone) or up == target  # the nearest kept one


def test_skin_names_only_kept_joints_once(big: Forest) -> None:
    ((inst, joints), *_) = tree_slices(big, GAME_JOINTS)
    to_tree = np.linalg.inv(big.tree_transforms[0])
    _, _, _, jidx, jw, _ = tree_mesh(
        big, inst, joints, to_tree, big.palette(), weld=True, budget=GAME_JOINTS
    )
    n = joints.stop - joints.start
    assert jidx.min() >= 0 and jidx.max() < n
    np.testing.assert_allclose(jw.sum(axis=1), 1.0, atol=1e-12)
    # no vertex weighs one joint in two slots
    live = np.where(jw > 0, jidx, -1 - np.arange(jidx.shape[1]))
    assert (np.sort(live, axis=1)[:, 1:] != np.sort(live, axis=1)[:, :-1]).all()


def _stage(forest: Forest, path: Path, budget: int | None) -> Usd.Stage:
    return Usd.Stage.Open(str(write_scene(forest, path, skinned=True, joint_budget=budget)))


def test_usd_skeleton_is_cut_to_the_dcc_budget(big: Forest, tmp_path: Path) -> None:
    stage = Usd.Stage.Open(str(write_scene(big, tmp_path / "f.usdc", skinned=True)))
    for k in range(big.options.trees):
        tree = stage.GetPrimAtPath(f"/World/Forest/Trees/Tree_{k:05d}")
        skel = UsdSkel.Skeleton(tree.GetChild("Skeleton"))
        joints = skel.GetJointsAttr().Get()
        assert len(joints) == DCC_JOINTS
        anim = UsdSkel.Animation(tree.GetChild("Skeleton").GetChild("Wind"))
        assert list(anim.GetJointsAttr().Get()) == list(joints)
        # the animation, and the extents that follow it, on every frame
        for prim in (skel, UsdSkel.Root(tree)):
            assert prim.GetExtentAttr().GetNumTimeSamples() == big.options.frames
        assert anim.GetRotationsAttr().GetNumTimeSamples() == big.options.frames


def test_still_tree_equals_the_full_rig_and_wind_moves_it(tmp_path: Path) -> None:
    """USD's own skinning of the written files: with no wind the cut oak is the full one (to
    float32); in the wind its kept joints move it, and the merged twigs (and the leaves on
    them) stay within a small fraction of the height of where their own joints put them."""
    still = generate_forest(load_preset("oak"), 3, ForestOptions(trees=1))
    windy = generate_forest(load_preset("oak"), 3, ForestOptions(trees=1, frames=6))
    sa, sb = (
        _stage(still, tmp_path / "a.usdc", None),
        _stage(still, tmp_path / "b.usdc", DCC_JOINTS),
    )
    a, b = sa.GetPrimAtPath(TREE), sb.GetPrimAtPath(TREE)
    for mesh in ("Bark", "Leaves"):
        full, cut = usd_skinned_points(a, mesh, 0), usd_skinned_points(b, mesh, 0)
        assert np.abs(cut - full).max() < 2e-6 * np.ptp(full[:, 1]), mesh
    sa, sb = (
        _stage(windy, tmp_path / "wa.usdc", None),
        _stage(windy, tmp_path / "wb.usdc", DCC_JOINTS),
    )
    a, b = sa.GetPrimAtPath(TREE), sb.GetPrimAtPath(TREE)
    for mesh, within in (("Bark", 2e-4), ("Leaves", 3e-3)):
        rest = usd_skinned_points(b, mesh, 0)
        height = float(np.ptp(rest[:, 1]))
        cut, full = usd_skinned_points(b, mesh, 3), usd_skinned_points(a, mesh, 3)
        assert np.linalg.norm(cut - rest, axis=1).max() > 1e-3 * height, f"{mesh} stands still"
        assert np.linalg.norm(cut - full, axis=1).max() < within * height, mesh
