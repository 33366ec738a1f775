"""A piece with no leaf rims (Cap) and a ground piece (Flare) through the whole pipeline:
growth, bones, tile indices, USD files (.usda/.usdc) read back exactly, USD validation,
the skinned export, and rims that coincide in every pose."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from forest.geometry.pieces import PIECE_NAMES, piece_library
from forest.growth.generate import Forest, ForestOptions, generate_forest
from forest.usd.read import read_scene
from forest.usd.scene import write_scene
from schemas.grammar import Grammar
from tests.test_assembly import check_rims, check_welded_boundary, open_tips, palettes
from tests.test_rig import assert_rebuilt_palette
from tests.test_usd import validation_errors

# a Flare trunk base, a fork, and every branch closed by a Cap
CAPPED = {
    "axiom": "A",
    "rules": {
        "A": [{"piece": "Flare", "successors": [{"symbol": "B"}]}],
        "B": [{"piece": "Y", "successors": [{"symbol": "C"}, {"symbol": "D"}]}],
        "C": [{"piece": "I", "successors": [{"symbol": "E"}], "pose": {"bend": [5, 15]}}],
        "D": [{"piece": "T", "successors": [{"symbol": "E"}, {"symbol": "E"}]}],
        "E": [{"piece": "Cap", "successors": []}],
    },
}
# the brief's smallest case: one stem and its cap
I_CAP = {
    "axiom": "A",
    "rules": {
        "A": [{"piece": "I", "successors": [{"symbol": "B"}]}],
        "B": [{"piece": "Cap", "successors": []}],
    },
}
GRAMMARS = {"capped": CAPPED, "i-cap": I_CAP}


def make(name: str, seed: int = 5, segments: int = 1) -> Forest:
    g = Grammar.model_validate(GRAMMARS[name])
    return generate_forest(g, seed, ForestOptions(trees=2, frames=3, segments=segments))


def test_cap_has_no_leaf_rims_and_two_joints() -> None:
    cap = piece_library(1)[PIECE_NAMES.index("Cap")]
    assert cap.n_leaf_rims == 0 and cap.n_joints == 2
    assert cap.leaf_rims.shape == (0, 6) and cap.building.shape == (0, 4, 4)
    assert cap.joint_names == ("root", "hub")
    # it ends in a point: the highest vertex is alone on the axis
    top = int(np.argmax(cap.positions[:, 1]))
    np.testing.assert_allclose(cap.positions[top, [0, 2]], 0.0, atol=1e-12)
    assert 2.0 <= cap.positions[top, 1] <= 3.5


@pytest.mark.parametrize("name", sorted(GRAMMARS))
@pytest.mark.parametrize("segments", [1, 2])
def test_capped_tree_grows_and_rims_coincide(name: str, segments: int) -> None:
    f = make(name, segments=segments)
    caps = f.graph.piece == PIECE_NAMES.index("Cap")
    assert caps.any()
    assert not open_tips(f)  # every leaf rim carries a child: branches end in caps
    n_joints = np.array([f.pieces[p].n_joints for p in f.graph.piece])
    np.testing.assert_array_equal(np.diff(f.bones.offset), n_joints[:-1])
    assert len(f.bones) == n_joints.sum()
    n_quads = np.array([len(f.pieces[p].quads) for p in f.graph.piece])
    assert ((f.tile_indices >= 0).sum(axis=1) == n_quads).all()
    for label, pal in palettes(f, (0.3, 1.1)):
        check_rims(f, pal, f"{name} {label}")
        check_welded_boundary(f, pal, f"{name} {label}")


@pytest.mark.parametrize("suffix", [".usda", ".usdc"])  # a .usdz holds no pieces
def test_capped_scene_round_trips_and_validates(tmp_path: Path, suffix: str) -> None:
    f = make("capped")
    path = write_scene(f, tmp_path / f"capped{suffix}", skinned=True)
    scene = read_scene(path)
    g = f.graph
    for ours, theirs in [
        (g.piece, scene.proto_indices),
        (g.parent, scene.parent),
        (g.parent_rim, scene.parent_rim),
        (g.twist, scene.twist),
        (f.bones.offset, scene.bone_offset),
        (f.tile_indices, scene.tile_indices),
    ]:
        np.testing.assert_array_equal(theirs, ours)
    for k, time in enumerate(scene.times):
        assert_rebuilt_palette(scene.palette(k), f.palette(time))
    assert [p.name for p in scene.pieces] == list(PIECE_NAMES)
    for ours_p, theirs_p in zip(f.pieces, scene.pieces, strict=True):
        for field in ("quads", "tile_class", "leaf_rims", "root_rim", "joint_parents"):
            np.testing.assert_array_equal(getattr(theirs_p, field), getattr(ours_p, field))
        np.testing.assert_array_equal(theirs_p.building, ours_p.building)
        np.testing.assert_array_equal(theirs_p.joint_rest, ours_p.joint_rest)
        assert theirs_p.building.shape == ours_p.building.shape
    stage = Usd.Stage.Open(str(path))
    assert validation_errors(stage) == []
    for prim in stage.Traverse():
        if prim.IsA(UsdGeom.Mesh):
            mesh = UsdGeom.Mesh(prim)
            ok, why = UsdGeom.Mesh.ValidateTopology(
                mesh.GetFaceVertexIndicesAttr().Get(),
                mesh.GetFaceVertexCountsAttr().Get(),
                len(mesh.GetPointsAttr().Get()),
            )
            assert ok, f"{prim.GetPath()}: {why}"


def test_capped_skinned_export_matches_our_skinning(tmp_path: Path) -> None:
    from tests.test_usd import assert_usd_skinning_matches_ours

    f = make("capped")
    stage = Usd.Stage.Open(str(write_scene(f, tmp_path / "capped.usda", skinned=True)))
    assert_usd_skinning_matches_ours(stage, f, (2,))
