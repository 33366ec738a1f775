"""``forest inspect``: the numpy skinning behind the contact sheet, and the sheet itself
(pyvista offscreen through VTK's EGL window)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from cli import main
from cli.sheets.inspect import skin_forest
from forest.bark.tile_folder import read_image_subimages
from forest.geometry.tolerances import TEST_RIM_POSITION_REL
from forest.usd.read import SceneArrays

ROOT = Path(__file__).parents[2]


def test_skinned_sheet_mesh_has_every_quad_rim_and_joint(mixed_scene: SceneArrays) -> None:
    sk = skin_forest(mixed_scene, frame=1)
    n_quads = np.array([len(p.quads) for p in mixed_scene.pieces])[mixed_scene.proto_indices]
    assert len(sk.quads) == n_quads.sum()
    np.testing.assert_array_equal(sk.tile, mixed_scene.tile_indices[sk.instance, sk.quad])
    n_rims = np.array([1 + p.n_leaf_rims for p in mixed_scene.pieces])[mixed_scene.proto_indices]
    assert len(sk.rims) == n_rims.sum()
    assert len(sk.joints) == mixed_scene.n_bones


def test_sheet_skeleton_joins_child_roots_to_parent_tips(mixed_scene: SceneArrays) -> None:
    """A child's root joint sits on its parent's terminal joint (paper 4.3)."""
    sk = skin_forest(mixed_scene, frame=2)
    s = mixed_scene
    # joints come out per piece type in instance order, like the palette they are read from
    first = np.zeros(s.n_instances, np.int64)
    k = 0
    for t, piece in enumerate(s.pieces):
        idx = np.nonzero(s.proto_indices == t)[0]
        first[idx] = k + piece.n_joints * np.arange(len(idx))
        k += piece.n_joints * len(idx)
    child = np.nonzero(s.parent >= 0)[0]
    root = sk.joints[first[child]]
    tip = sk.joints[first[s.parent[child]] + 2 + s.parent_rim[child]]
    scale = float(np.ptp(sk.points, axis=0).max())
    np.testing.assert_allclose(root, tip, atol=TEST_RIM_POSITION_REL * scale)


@pytest.mark.slow  # a VTK render in a process of its own; 16 s on llvmpipe
def test_contact_sheet_png(mixed_scene_path: Path, tmp_path: Path) -> None:
    """Drawn by ``forest inspect`` in a process of its own, as users run it: VTK terminates
    the process's EGL display when its window goes, which kills every other EGL context of
    the process (the GL tests' session context, a render worker's)."""
    out = tmp_path / "sheet.png"
    args = [str(mixed_scene_path), "-o", str(out), "--frame", "1", "--width", "480"]
    res = subprocess.run(
        [sys.executable, "-m", "cli", "inspect", *args, "--height", "360"],
        capture_output=True,
        text=True,
        timeout=300,
        env={
            **os.environ,
            "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
        },
    )
    if res.returncode != 0 and "offscreen window" in res.stderr + res.stdout:
        if os.environ.get("FOREST_REQUIRE_GL") == "1":
            pytest.fail(res.stderr + res.stdout)
        pytest.skip(res.stderr + res.stdout)
    assert res.returncode == 0, res.stderr + res.stdout
    assert res.stdout.startswith(f"wrote {out}: ")
    img = read_image_subimages(out)[0]
    assert img.shape == (360, 480, 4)
    rgb = img[..., :3].astype(int)
    background = rgb[-1, -1]
    assert (np.abs(rgb - background).max(axis=-1) > 30).mean() > 0.02  # trees drawn
    quadrant = [rgb[:180, :240], rgb[:180, 240:], rgb[180:, :240], rgb[180:, 240:]]
    drawn = [(np.abs(q - background).max(axis=-1) > 30).mean() for q in quadrant]
    assert min(drawn) > 0.01  # every panel shows the forest
    red = (rgb[..., 0] > 180) & (rgb[..., 1] < 80) & (rgb[..., 2] < 90)
    assert red[:180, 240:].sum() > 20  # rims highlighted in the tile-class panel


def test_inspect_cli_refuses_other_formats(mixed_scene_path: Path, tmp_path: Path) -> None:
    res = CliRunner().invoke(
        main, ["inspect", str(mixed_scene_path), "-o", str(tmp_path / "a.jpg")]
    )
    assert res.exit_code == 2
    assert res.output == f"error: {tmp_path / 'a.jpg'}: the contact sheet is a PNG: name it *.png\n"
