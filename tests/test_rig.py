"""Compact wind (issue 12): a scene stores one float32 quaternion per turning bone per frame
(at most 16 bytes per bone per frame) and the rig once; the palette rebuilt by forward
kinematics equals the generator's within float32 tolerance, and rims still coincide in every
frame. Old scenes (a matrix per bone per frame) are refused with a clear error."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from pxr import Sdf, Usd, Vt

from forest.errors import SceneError
from forest.geometry.tolerances import PALETTE_REBUILT_REL
from forest.geometry.transforms import matrix_to_quat, quat_to_matrix
from forest.growth.generate import Forest, ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.growth.rig import (
    forest_rig,
    hierarchy_levels,
    joint_rotations,
    linear_quaternions,
    quaternion_linear,
)
from forest.usd.contract import (
    BONE_FORMAT,
    BONE_FORMAT_VERSION,
    BONE_SCALES,
    BONE_TRANSLATIONS,
    JOINT_ROTATIONS,
    PIECES,
    ROOT_ROTATIONS,
)
from forest.usd.read import read_scene, select_engine
from forest.usd.scene import write_scene
from tests.test_assembly import check_rims

Windy = tuple[Forest, Path]
# two shapes of tree: a broad crown of many short pieces and a tall one of long limbs
PRESETS = ("almond", "oak")


def assert_rebuilt_palette(got: np.ndarray, want: np.ndarray) -> None:
    """A palette rebuilt from float32 rotations equals ``want`` (the generator's) to
    PALETTE_REBUILT_REL of the forest's size (the box of its bones' origins)."""
    origins = want[:, :3, 3]
    size = float(np.linalg.norm(np.ptp(origins, axis=0)))
    assert size > 0
    err = np.abs(got - want).max()
    assert err <= PALETTE_REBUILT_REL * size, (err, size)


@pytest.fixture(scope="module", params=PRESETS)
def windy(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Windy:
    f = generate_forest(load_preset(request.param), 5, ForestOptions(trees=2, frames=4, fps=6))
    path = write_scene(f, tmp_path_factory.mktemp("rig") / "f.usdc", skinned=False)
    return f, path


def test_forward_kinematics_of_the_rig_is_the_generators_palette(windy: Windy) -> None:
    f = windy[0]
    rig = forest_rig(f)
    for time in (None, 0.0, 0.4, 1.3):
        q = joint_rotations(f, time)
        want = f.palette(time)
        # in float64 the rig is the pose itself: only rounding apart
        np.testing.assert_allclose(rig.palette(q), want, rtol=0, atol=1e-12 * np.abs(want).max())
        assert_rebuilt_palette(rig.palette(q.astype(np.float32)), want)
        transposed = np.swapaxes(rig.palette(q), -1, -2)
        np.testing.assert_array_equal(rig.palette(q, row_vectors=True), transposed)


def test_read_scene_palette_equals_the_uncompressed_one_in_every_frame(windy: Windy) -> None:
    f, path = windy
    scene = read_scene(path)
    assert scene.times == f.frame_times() and scene.n_frames == 4
    assert scene.joint_rotations.dtype == np.float32
    moved = 0.0
    for k, time in enumerate(scene.times):
        want = f.palette(time)
        assert_rebuilt_palette(scene.palette(k), want)
        moved = max(moved, float(np.abs(want - f.palette(scene.times[0])).max()))
    assert moved > 1e-3  # the wind moves the bones: the frames are not one pose repeated
    # the foliage follows the rebuilt palette as it followed the stored one
    np.testing.assert_allclose(
        scene.foliage_at(2), f.foliage_anchors().positions(f.palette(scene.times[2])), atol=1e-5
    )


def test_rims_coincide_in_every_frame_of_the_rebuilt_palette(windy: Windy) -> None:
    f, path = windy
    scene = read_scene(path)
    for k in range(scene.n_frames):
        check_rims(f, scene.palette(k), f"frame {k}")


def test_a_frame_costs_at_most_16_bytes_per_bone(windy: Windy) -> None:
    f, path = windy
    stage = Usd.Stage.Open(str(path))
    attr = stage.GetPrimAtPath(PIECES).GetAttribute(JOINT_ROTATIONS)
    assert attr.GetTypeName() == Sdf.ValueTypeNames.QuatfArray
    samples = attr.GetTimeSamples()
    assert len(samples) == 4
    n_bones = len(f.bones)
    # instance roots never turn: a third of the bones of these trees cost nothing
    for t in samples:
        value = np.array(attr.Get(t), np.float32)  # quatf: 16 bytes each
        assert value.shape == (n_bones - f.n_instances, 4)
        assert value.nbytes <= 16 * n_bones
    # nothing else on the instancer is time-sampled per bone (the old matrix palette is gone)
    prim = stage.GetPrimAtPath(PIECES)
    sampled = [a.GetName() for a in prim.GetAttributes() if a.GetNumTimeSamples()]
    assert "forest:bonePalette" not in [a.GetName() for a in prim.GetAttributes()]
    for name in sampled:
        if name != JOINT_ROTATIONS:  # the posed variant's per-instance transforms
            assert len(prim.GetAttribute(name).Get(samples[0])) in (2, f.n_instances), name


def test_still_scene_stores_the_pose_once(tmp_path: Path) -> None:
    f = generate_forest(load_preset("almond"), 2, ForestOptions(trees=1))
    scene = read_scene(write_scene(f, tmp_path / "still.usdc", skinned=False))
    assert scene.times == [None] and scene.n_frames == 1
    assert_rebuilt_palette(scene.palette(0), f.palette(None))
    stage = Usd.Stage.Open(str(tmp_path / "still.usdc"))
    attr = stage.GetPrimAtPath(PIECES).GetAttribute(JOINT_ROTATIONS)
    assert attr.HasAuthoredValue() and not attr.GetNumTimeSamples()


def edited_copy(path: Path, tmp_path: Path) -> Usd.Stage:
    """A stage on a copy of ``path``: edits must not reach the layer other tests open."""
    copy = tmp_path / f"copy-{len(list(tmp_path.iterdir()))}.usdc"
    shutil.copyfile(path, copy)
    return Usd.Stage.Open(str(copy))


def test_old_matrix_palette_scenes_are_refused_clearly(windy: Windy, tmp_path: Path) -> None:
    f, path = windy
    stage = edited_copy(path, tmp_path)
    prim = stage.GetPrimAtPath(PIECES)
    for name in ("forest:boneFormat", "forest:boneParents", JOINT_ROTATIONS):
        prim.RemoveProperty(name)
    old = prim.CreateAttribute("forest:bonePalette", Sdf.ValueTypeNames.Matrix4dArray)
    old.Set(Vt.Matrix4dArray.FromNumpy(np.swapaxes(f.palette(0.0), -1, -2).copy()), 0)
    stage.GetRootLayer().Export(str(tmp_path / "old.usdc"))
    with pytest.raises(SceneError, match="older version") as err:
        read_scene(tmp_path / "old.usdc")
    assert err.value.path == f"{PIECES}.forest:bonePalette"


def test_broken_rigs_name_their_attribute(windy: Windy, tmp_path: Path) -> None:
    _, path = windy

    def broken(name: str, value: object, time: float | None = None) -> Path:
        stage = edited_copy(path, tmp_path)
        attr = stage.GetPrimAtPath(PIECES).GetAttribute(name)
        attr.Set(value, Usd.TimeCode.Default() if time is None else Usd.TimeCode(time))
        out = tmp_path / f"broken-{name.split(':')[1]}.usdc"
        stage.GetRootLayer().Export(str(out))
        return out

    stage = Usd.Stage.Open(str(path))
    prim = stage.GetPrimAtPath(PIECES)
    parents = np.array(prim.GetAttribute("forest:boneParents").Get(), np.int32)
    parents[0] = 1  # a tree's root under its own hub: a cycle
    with pytest.raises(SceneError, match="cycle") as err:
        read_scene(broken("forest:boneParents", Vt.IntArray.FromNumpy(parents)))
    assert err.value.path == f"{PIECES}.forest:boneParents"
    rot = np.array(prim.GetAttribute(JOINT_ROTATIONS).Get(1), np.float32)
    rot[3] = 0.0  # no rotation at all
    with pytest.raises(SceneError, match="unit quaternions") as err:
        read_scene(broken(JOINT_ROTATIONS, Vt.QuatfArray.FromNumpy(rot), 1))
    assert err.value.path == f"{PIECES}.{JOINT_ROTATIONS}"
    with pytest.raises(SceneError, match="format 4"):
        read_scene(broken("forest:boneFormat", 4))


def test_the_rig_is_stored_in_float32(windy: Windy) -> None:
    """Bone format 3: the rig's translations, scales and root rotations are float32 (half the
    bytes of format 2's doubles; the palette tests above hold it to PALETTE_REBUILT_REL), and
    the engine variant keeps one orientation array, the exact quatf one."""
    _, path = windy
    stage = Usd.Stage.Open(str(path))
    select_engine(stage)
    prim = stage.GetPrimAtPath(PIECES)
    assert prim.GetAttribute(BONE_FORMAT).Get() == BONE_FORMAT_VERSION == 3
    types = Sdf.ValueTypeNames
    for name, want in (
        (BONE_TRANSLATIONS, types.Float3Array),
        (BONE_SCALES, types.FloatArray),
        (ROOT_ROTATIONS, types.QuatfArray),
        (JOINT_ROTATIONS, types.QuatfArray),
    ):
        assert prim.GetAttribute(name).GetTypeName() == want, name
    assert prim.GetAttribute("orientationsf").HasAuthoredValue()
    assert not prim.GetAttribute("orientations").HasAuthoredValue()


def test_format_2_scenes_are_refused_clearly(windy: Windy, tmp_path: Path) -> None:
    """A scene of the previous bone format (the same rig in float64) is refused with one line
    naming the format and how to make the scene again."""
    f, path = windy
    stage = edited_copy(path, tmp_path)
    prim = stage.GetPrimAtPath(PIECES)
    rig = forest_rig(f)
    types = Sdf.ValueTypeNames
    for name, typ, value in (
        (BONE_TRANSLATIONS, types.Double3Array, Vt.Vec3dArray.FromNumpy(rig.translation)),
        (BONE_SCALES, types.DoubleArray, Vt.DoubleArray.FromNumpy(rig.scale)),
        (ROOT_ROTATIONS, types.QuatdArray, Vt.QuatdArray.FromNumpy(rig.root_rotation)),
    ):
        prim.RemoveProperty(name)
        prim.CreateAttribute(name, typ, custom=True).Set(value)
    prim.GetAttribute(BONE_FORMAT).Set(2)
    stage.GetRootLayer().Export(str(tmp_path / "format2.usdc"))
    with pytest.raises(SceneError) as err:
        read_scene(tmp_path / "format2.usdc")
    assert err.value.path == f"{PIECES}.{BONE_FORMAT}"
    message = str(err.value)
    assert "\n" not in message
    assert "bone format 2" in message and "reads format 3" in message
    assert "generate the scene again" in message


def test_hierarchy_levels_put_every_parent_before_its_children() -> None:
    parent = np.array([-1, 0, 1, 1, -1, 4, 2, 6], np.int32)
    order, starts = hierarchy_levels(parent)
    assert sorted(order.tolist()) == list(range(8))
    level = np.empty(8, int)
    for k in range(len(starts) - 1):
        level[order[starts[k] : starts[k + 1]]] = k
    np.testing.assert_array_equal(level, [0, 1, 2, 2, 0, 1, 3, 4])
    with pytest.raises(ValueError, match="cycle"):
        hierarchy_levels(np.array([-1, 2, 1], np.int32))
    with pytest.raises(ValueError, match="parents must lie"):
        hierarchy_levels(np.array([-1, 7], np.int32))


def test_quaternions_of_rotation_rows_match_shepperd_on_matrices() -> None:
    rng = np.random.default_rng(3)
    q = rng.normal(size=(500, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[:4] = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]  # half turns, identity
    m = quat_to_matrix(q)
    got = linear_quaternions(m[:, :3, :3].reshape(-1, 9).T)
    np.testing.assert_allclose(got, matrix_to_quat(m), atol=1e-12)
    np.testing.assert_allclose(quaternion_linear(got).T.reshape(-1, 3, 3), m[:, :3, :3], atol=1e-12)
