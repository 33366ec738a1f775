"""The bone palette rebuilt on the GPU (shaders/palette.comp) equals the numpy one of
``read_scene`` in every frame, read back from the very storage buffer the piece and foliage
shaders read; the static bone table is checked without GL."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from forest.geometry.tolerances import PALETTE_GPU_REL
from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.usd.read import SceneArrays, read_scene
from forest.usd.scene import write_scene
from worker.render import bone_kinematics
from worker.render.bone_kinematics import bone_records
from worker.render.scene_buffers import SceneBuffers


def gpu_palette(buffers: SceneBuffers) -> NDArray[np.float64]:
    """The palette buffer as ``(b, 4, 4)`` column-vector matrices (GLSL stores columns)."""
    raw = np.frombuffer(buffers.palette.read(), np.float32).reshape(-1, 4, 4)
    return np.swapaxes(raw, -1, -2).astype(np.float64)


def assert_gpu_palette(got: NDArray[np.float64], want: NDArray[np.float64]) -> None:
    """Translations to PALETTE_GPU_REL of the largest coordinate, linear parts to it of the
    largest entry (float32 forward kinematics over every level)."""
    t_scale = float(np.abs(want[:, :3, 3]).max())
    l_scale = float(np.abs(want[:, :3, :3]).max())
    np.testing.assert_allclose(
        got[:, :3, 3], want[:, :3, 3], rtol=0, atol=PALETTE_GPU_REL * t_scale
    )
    np.testing.assert_allclose(
        got[:, :3, :3], want[:, :3, :3], rtol=0, atol=PALETTE_GPU_REL * l_scale
    )
    np.testing.assert_array_equal(got[:, 3], np.broadcast_to([0.0, 0.0, 0.0, 1.0], got[:, 3].shape))


def test_bone_records_list_parents_before_children(mixed_scene: SceneArrays) -> None:
    rec = bone_records(mixed_scene.rig)
    assert rec.dtype.itemsize == 48  # std430 struct Bone: two vec4 and four ints
    pos = np.arange(len(rec))
    has = rec["parent"] >= 0
    assert (rec["parent"][has] < pos[has]).all()
    # each bone once; its parent's palette entry is its parent in the scene
    np.testing.assert_array_equal(np.sort(rec["palette"]), np.arange(mixed_scene.n_bones))
    np.testing.assert_array_equal(
        rec["palette"][rec["parent"][has]], mixed_scene.rig.parent[rec["palette"][has]]
    )
    # roots keep their fixed rotation; every other bone reads a row of the frame's rotations
    rows = rec["rotation"][rec["rotation"] >= 0]
    np.testing.assert_array_equal(np.sort(rows), np.arange(len(mixed_scene.rig.animated)))
    assert (rec["rotation"] < 0).sum() == mixed_scene.n_instances


def test_gpu_palette_equals_the_numpy_one_in_every_frame(
    gl43: Any, mixed_scene: SceneArrays
) -> None:
    buffers = SceneBuffers(gl43, mixed_scene)
    try:
        assert mixed_scene.n_frames == 3
        for frame in (0, 1, 2, 1):  # and back: each use rebuilds the frame asked
            buffers.use(frame)
            assert_gpu_palette(gpu_palette(buffers), mixed_scene.palette(frame))
        # a frame already on the GPU is not rebuilt: the buffer keeps what was written
        buffers.palette.write(np.zeros(16, np.float32).tobytes())
        buffers.use(1)
        assert not gpu_palette(buffers)[0].any()
    finally:
        buffers.release()


def test_gpu_palette_far_from_the_origin(gl43: Any, tmp_path: Path) -> None:
    """Trees 200 m out: world-space rounding grows with the coordinates, the bound with it."""
    forest = generate_forest(
        load_preset("almond"), 4, ForestOptions(trees=3, frames=2, area=(400.0, 400.0))
    )
    scene = read_scene(write_scene(forest, tmp_path / "far.usdc", skinned=False))
    assert np.abs(scene.palette(0)[:, :3, 3]).max() > 50.0
    buffers = SceneBuffers(gl43, scene)
    try:
        for frame in range(scene.n_frames):
            buffers.use(frame)
            assert_gpu_palette(gpu_palette(buffers), scene.palette(frame))
    finally:
        buffers.release()


def test_wide_levels_are_dispatched_in_slices(
    gl43: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A level wider than the work groups one dispatch may hold runs in slices: here one
    group of 64 bones per dispatch gives the same palette."""
    forest = generate_forest(load_preset("almond"), 6, ForestOptions(trees=2, frames=2))
    scene = read_scene(write_scene(forest, tmp_path / "wide.usdc", skinned=False))
    monkeypatch.setattr(bone_kinematics, "MAX_GROUPS", 1)
    buffers = SceneBuffers(gl43, scene)
    try:
        assert max(n for _, n in buffers.kinematics.levels) > 3 * bone_kinematics.LOCAL_SIZE
        buffers.use(1)
        assert_gpu_palette(gpu_palette(buffers), scene.palette(1))
    finally:
        buffers.release()
