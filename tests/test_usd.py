"""USD scenes: contract, validity, round trip, USD's own skinning, determinism."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pxr import Usd, UsdGeom, UsdSkel, UsdValidation
from scipy.spatial import cKDTree

from forest.errors import OutputError, SceneError
from forest.geometry.pieces import PIECE_NAMES
from forest.geometry.tolerances import INSTANCE_TRANSFORM_REL
from forest.growth.foliage import MODELS
from forest.growth.generate import Forest, ForestOptions, generate_forest
from forest.growth.presets import load_preset, preset_names
from forest.usd.contract import PIECES
from forest.usd.read import read_scene, select_engine
from forest.usd.scene import write_scene
from forest.usd.skinned import dcc_joints, tree_slices
from tests.helpers_skin import usd_skinned_points
from tests.test_assembly import forward_kinematics
from tests.test_rig import assert_rebuilt_palette


def validation_errors(stage: Usd.Stage) -> list[str]:
    registry = UsdValidation.ValidationRegistry()
    ctx = UsdValidation.ValidationContext(registry.GetOrLoadAllValidators())
    return [
        f"{e.GetIdentifier()}: {e.GetMessage()}" for e in ctx.Validate(stage) if not e.HasNoError()
    ]


def test_skinned_scene_passes_usd_validation(skinned_scene: Path) -> None:
    stage = Usd.Stage.Open(str(skinned_scene))
    assert validation_errors(stage) == []
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetDefaultPrim().GetPath() == "/World"
    assert stage.GetTimeCodesPerSecond() == 6.0  # the fixture's fps
    for prim in stage.Traverse():
        assert prim.GetTypeName(), f"typeless prim {prim.GetPath()}"
        if prim.IsA(UsdGeom.Boundable):  # no UsdValidation validator checks extents
            extent = UsdGeom.Boundable(prim).GetExtentAttr().Get()
            assert extent is not None and len(extent) == 2, f"no extent on {prim.GetPath()}"


@pytest.mark.parametrize("name", preset_names())
def test_every_mesh_has_valid_topology_and_extent(name: str, tmp_path: Path) -> None:
    forest = generate_forest(load_preset(name), 2, ForestOptions(trees=2))
    stage = Usd.Stage.Open(str(write_scene(forest, tmp_path / "f.usdc", skinned=True)))
    select_engine(stage)  # the pieces and the leaf clouds
    meshes = [UsdGeom.Mesh(p) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    assert len(meshes) == len(PIECE_NAMES) + MODELS
    default = Usd.Stage.Open(str(stage.GetRootLayer().identifier))  # skinned
    skinned = [UsdGeom.Mesh(p) for p in default.Traverse() if p.IsA(UsdGeom.Mesh)]
    # (bark, proxy, leaves, the leaves' proxy) per tree
    assert len(skinned) == 4 * 2
    meshes += skinned
    for mesh in meshes:
        ok, why = UsdGeom.Mesh.ValidateTopology(
            mesh.GetFaceVertexIndicesAttr().Get(),
            mesh.GetFaceVertexCountsAttr().Get(),
            len(mesh.GetPointsAttr().Get()),
        )
        assert ok, f"{mesh.GetPath()}: {why}"
        assert mesh.GetExtentAttr().HasAuthoredValue()
    assert validation_errors(stage) == []
    assert validation_errors(default) == []


def test_point_instancer_reproduces_generator_transforms(
    skinned_scene: Path, windy_forest: Forest
) -> None:
    stage = Usd.Stage.Open(str(skinned_scene))
    select_engine(stage)
    inst = UsdGeom.PointInstancer(stage.GetPrimAtPath(PIECES))
    t = Usd.TimeCode.Default()
    usd = np.swapaxes(np.asarray(inst.ComputeInstanceTransformsAtTime(t, t)), -1, -2)
    ours = windy_forest.transforms
    scale = np.abs(ours).max(axis=(1, 2), keepdims=True)
    assert np.abs(usd - ours).max() / scale.max() < INSTANCE_TRANSFORM_REL
    assert (np.abs(usd - ours) <= INSTANCE_TRANSFORM_REL * scale).all()


@pytest.mark.parametrize("suffix", [".usda", ".usdc"])  # a .usdz holds no pieces
def test_reader_returns_generator_arrays(windy_forest: Forest, tmp_path: Path, suffix: str) -> None:
    f = windy_forest
    scene = read_scene(write_scene(f, tmp_path / f"f{suffix}"))
    g = f.graph
    for ours, theirs in [
        (g.piece, scene.proto_indices),
        (g.tree, scene.tree),
        (f.bones.offset, scene.bone_offset),
        (f.tile_indices, scene.tile_indices),
        (g.parent, scene.parent),
        (g.parent_rim, scene.parent_rim),
        (g.twist, scene.twist),
        (g.depth, scene.depth),
        (g.symbol, scene.symbol),
    ]:
        assert theirs.dtype == np.int32
        np.testing.assert_array_equal(theirs, ours)
    assert scene.seed == 11 and scene.version == f.version
    assert scene.times == f.frame_times()
    for k, time in enumerate(scene.times):
        assert_rebuilt_palette(scene.palette(k), f.palette(time))
    np.testing.assert_array_equal(scene.tree_transforms, f.tree_transforms)
    assert np.abs(scene.transforms - f.transforms).max() < 1e-5 * np.abs(f.transforms).max()
    for ours_p, theirs_p in zip(f.pieces, scene.pieces, strict=True):
        np.testing.assert_array_equal(theirs_p.quads, ours_p.quads)
        np.testing.assert_array_equal(theirs_p.leaf_rims, ours_p.leaf_rims)
        np.testing.assert_array_equal(theirs_p.building, ours_p.building)


def _our_skinned_points(f: Forest, inst: slice, time: float | None) -> np.ndarray:
    pal = f.palette(time)
    out = []
    for i in range(inst.start, inst.stop):
        p = f.pieces[f.graph.piece[i]]
        m = pal[f.bones.offset[i] + p.joint_indices]
        v = np.einsum("kjab,kb->kja", m[..., :3, :3], p.positions) + m[..., :3, 3]
        out.append((p.joint_weights[..., None] * v).sum(axis=1))
    return np.concatenate(out)


def assert_usd_skinning_matches_ours(stage: Usd.Stage, f: Forest, frames: tuple[int, ...]) -> None:
    """USD's own skinning of every tree's welded Bark equals ours at ``frames``: every vertex
    of ours is one of USD's, and back, within 1e-4 of the tree's size. Not closer: USD skins
    from the bind pose (the tree as it stands), ours from the prototypes, and linear blend
    skinning from two bind poses differs at a blended vertex by the wind's turn times the
    distance between where its joints put it when standing (up to 4e-5 of the size: half a
    millimetre on an 11 m willow); at a still frame the two are equal to float32."""
    for k, (inst, _) in enumerate(tree_slices(f)):
        root = stage.GetPrimAtPath(f"/World/Forest/Trees/Tree_{k:05d}")
        for frame in frames:
            usd = usd_skinned_points(root, "Bark", frame)
            ours = _our_skinned_points(f, inst, frame / f.options.fps)
            size = np.ptp(ours, axis=0).max()
            assert cKDTree(usd).query(ours)[0].max() < 1e-4 * size
            assert cKDTree(ours).query(usd)[0].max() < 1e-4 * size


def test_usd_skinning_matches_ours_at_two_frames(skinned_scene: Path, windy_forest: Forest) -> None:
    f = windy_forest
    assert_usd_skinning_matches_ours(Usd.Stage.Open(str(skinned_scene)), f, (0, 2))
    for inst, _ in tree_slices(f):
        size = np.ptp(_our_skinned_points(f, inst, 0.0), axis=0).max()
        # the wind really moves the tree between the two frames (mid-clip: the clip loops, so
        # its last frame is on its way back to the first)
        later = _our_skinned_points(f, inst, 2 / f.options.fps)
        assert np.abs(_our_skinned_points(f, inst, 0.0) - later).max() > 1e-4 * size


@pytest.mark.parametrize("preset", ["pine", "spruce"])
def test_skinned_tree_is_bound_as_it_stands(preset: str, tmp_path: Path) -> None:
    """The skinned form's bind pose is the standing tree: a still frame's joints do not move
    or scale (every animation scale is 1), the Bark's points are ours to float32 precision
    along a whole pine or spruce leader (bound in the generator's rest layout, whose top is
    microns across, they were centimetres off), and the bind pose a DCC shows at rest is the
    tree's own shape and height."""
    f = generate_forest(load_preset(preset), 5, ForestOptions(trees=1))
    stage = Usd.Stage.Open(str(write_scene(f, tmp_path / "tree.usdc", skinned=True)))
    root = stage.GetPrimAtPath("/World/Forest/Trees/Tree_00000")
    anim = UsdSkel.Animation(root.GetPrimAtPath("Skeleton/Wind"))
    np.testing.assert_array_equal(np.asarray(anim.GetScalesAttr().Get(0)), 1.0)
    mesh = UsdGeom.Mesh(root.GetChild("Bark"))
    world = np.asarray(UsdGeom.Xformable(root).ComputeLocalToWorldTransform(0)).T
    rest = np.asarray(mesh.GetPointsAttr().Get(), np.float64) @ world[:3, :3].T + world[:3, 3]
    ((inst, _),) = tree_slices(f)
    ours = _our_skinned_points(f, inst, None)
    size = np.ptp(ours, axis=0).max()
    assert cKDTree(rest).query(ours)[0].max() < 2e-6 * size
    skinned = usd_skinned_points(root, "Bark", 0)
    assert np.abs(skinned - rest).max() < 2e-6 * size


def test_proxy_is_decimated_and_bound(skinned_scene: Path) -> None:
    stage = Usd.Stage.Open(str(skinned_scene))
    root = stage.GetPrimAtPath("/World/Forest/Trees/Tree_00000")
    bark, proxy = UsdGeom.Mesh(root.GetChild("Bark")), UsdGeom.Mesh(root.GetChild("Proxy"))
    assert proxy.GetPurposeAttr().Get() == UsdGeom.Tokens.proxy
    assert bark.GetPurposeAttr().Get() == UsdGeom.Tokens.render
    n_tris_full = 2 * len(bark.GetFaceVertexCountsAttr().Get())
    assert 0 < len(proxy.GetFaceVertexCountsAttr().Get()) < 0.5 * n_tris_full
    assert UsdSkel.BindingAPI(proxy.GetPrim()).GetSkeletonRel().GetTargets()


def test_udim_st_follows_tile_indices(skinned_scene: Path, windy_forest: Forest) -> None:
    stage = Usd.Stage.Open(str(skinned_scene))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Forest/Trees/Tree_00000/Bark"))
    primvar = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
    assert primvar.IsIndexed()
    st = np.asarray(primvar.ComputeFlattened()).reshape(-1, 4, 2)
    inst, _ = tree_slices(windy_forest)[0]
    tiles = np.concatenate(
        [
            windy_forest.tile_indices[
                i, : len(windy_forest.pieces[windy_forest.graph.piece[i]].quads)
            ]
            for i in range(inst.start, inst.stop)
        ]
    )
    udim_u, udim_v = np.floor(st.min(axis=1)).T
    np.testing.assert_array_equal(udim_u + 10 * udim_v, tiles)


_WRITE = """
import sys
from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.usd.scene import write_scene
f = generate_forest(load_preset("uniform"), 5, ForestOptions(trees=2, frames=2))
write_scene(f, sys.argv[1], skinned=True)
"""


@pytest.mark.parametrize("suffix", [".usda", ".usdc", ".usdz"])
def test_same_grammar_and_seed_give_byte_identical_files(tmp_path: Path, suffix: str) -> None:
    paths = []
    for i, tz in enumerate(("UTC", "Asia/Tokyo")):  # usdz zip headers once held local mtimes
        out = tmp_path / f"run{i}" / f"forest{suffix}"
        out.parent.mkdir()
        subprocess.run(
            [sys.executable, "-c", _WRITE, str(out)],
            check=True,
            env={"TZ": tz, "PATH": "/usr/bin:/bin"},
            cwd=Path(__file__).parents[1],
        )
        paths.append(out)
    assert paths[0].read_bytes() == paths[1].read_bytes()
    # and the pictures beside a .usda/.usdc, file for file
    folders = [p.with_name(f"{p.stem}.textures") for p in paths]
    assert folders[0].is_dir() == (suffix != ".usdz")
    if suffix != ".usdz":
        first = sorted(f.name for f in folders[0].iterdir())
        assert first == sorted(f.name for f in folders[1].iterdir()) and first
        for name in first:
            assert (folders[0] / name).read_bytes() == (folders[1] / name).read_bytes()


def test_unwritable_and_unknown_outputs_fail_before_work(
    windy_forest: Forest, tmp_path: Path
) -> None:
    with pytest.raises(OutputError, match="unknown format"):
        write_scene(windy_forest, tmp_path / "x.obj")
    with pytest.raises(OutputError, match="does not exist"):
        write_scene(windy_forest, tmp_path / "missing" / "x.usda")
    with pytest.raises(OutputError, match="not writable"):
        write_scene(windy_forest, "/proc/x.usda")
    assert list(tmp_path.iterdir()) == []  # no temporary files left behind


def test_reader_names_what_is_wrong(tmp_path: Path, skinned_scene: Path) -> None:
    with pytest.raises(SceneError, match="no such file"):
        read_scene(tmp_path / "none.usda")
    junk = tmp_path / "junk.usda"
    junk.write_text("#usda 1.0\n( this is not usd")
    with pytest.raises(SceneError, match="not a readable USD file"):
        read_scene(junk)
    truncated = tmp_path / "cut.usdc"
    data = write_scene(generate_forest(load_preset("hazel"), 1), tmp_path / "ok.usdc").read_bytes()
    truncated.write_bytes(data[: len(data) // 2])
    with pytest.raises(SceneError):
        read_scene(truncated)
    empty = Usd.Stage.CreateNew(str(tmp_path / "empty.usda"))
    UsdGeom.Xform.Define(empty, "/World")
    empty.Save()
    with pytest.raises(SceneError, match="/World/Forest"):
        read_scene(tmp_path / "empty.usda")
    stage = Usd.Stage.Open(str(skinned_scene))
    stage.GetPrimAtPath(PIECES).GetAttribute("forest:jointRotations").Clear()
    broken = tmp_path / "broken.usda"
    stage.GetRootLayer().Export(str(broken))
    with pytest.raises(SceneError, match=r"/World/Forest/Pieces\.forest:jointRotations"):
        read_scene(broken)


@pytest.mark.parametrize("preset", ["almond", "spruce"])
def test_dcc_joints_leave_out_hung_roots_and_pose_every_kept_bone_alike(preset: str) -> None:
    """The skinned forms' joints (DccJoints): every bone but the roots of pieces hung on a
    parent's terminal, and forward kinematics of the joints' locals gives each kept bone's
    global transform in every frame (so its skinning matrix is unchanged), while a left-out
    root's global is its terminal's times a constant twist."""
    f = generate_forest(load_preset(preset), 4, ForestOptions(trees=2, frames=3))
    dcc = dcc_joints(f)
    b, g = f.bones, f.graph
    hung = b.offset[g.parent >= 0]
    assert len(dcc) == len(b) - len(hung)
    assert not np.isin(dcc.bone, hung).any()
    np.testing.assert_array_equal(dcc.of_bone[hung], dcc.of_bone[b.parent[hung]])
    assert (dcc.parent < np.arange(len(dcc))).all()  # parent-first
    still = f.local_bones(None)[hung]
    for time in (None, 0.0, 2 / 24):
        local = f.local_bones(time)
        want = forward_kinematics(b.parent, local)
        got = forward_kinematics(dcc.parent, dcc.locals(local))
        np.testing.assert_allclose(got, want[dcc.bone], rtol=0, atol=1e-9 * np.abs(want).max())
        # a left-out root's own local (its twist from the terminal) is the same every frame
        np.testing.assert_array_equal(local[hung], still)
