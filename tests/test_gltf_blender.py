"""The GLB imports into real Blender (bpy from PyPI in .venv-blender, as tests/test_blender.py)
through its glTF importer: one armature and one mesh object (bark and leaves) per tree, with
the Wind action over the wind's frames, the bark and leaf textures packed, and the deformed
vertices at two frames equal the library's skinning within 1e-3 of the tree's height.

The file is the default (quantized) packing. Blender reads its int16 positions less exactly
than three.js (6.5e-4 of the height against 1.3e-4; 1.1e-4 with float positions): its
importer guesses the bind pose by inverting the inverse binds, which carry the positions'
dequantisation scale (about 1e-4 m), in float32."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pygltflib as gl
import pytest
from helpers_gltf import CHECK_FRAMES, FPS, FRAMES, TREES, expected_tree, small_forest

from forest.gltf.document import write_glb
from forest.growth.generate import Forest

pytestmark = pytest.mark.slow  # Blender (bpy) imports in a subprocess

ROOT = Path(__file__).resolve().parents[1]
BLENDER_PY = ROOT / ".venv-blender" / "bin" / "python"
CHECK = ROOT / "tests" / "gltf_blender_check.py"

Run = tuple[Forest, dict[str, Any], Any, gl.GLTF2]


@pytest.fixture(scope="module")
def blender_run(tmp_path_factory: pytest.TempPathFactory) -> Run:
    if not BLENDER_PY.exists():
        pytest.fail(
            f"{BLENDER_PY.relative_to(ROOT)} does not exist: create it with "
            "`bash tests/setup_blender_venv.sh` (the CI script runs it)",
            pytrace=False,
        )
    tmp = tmp_path_factory.mktemp("gltf-blender")
    forest = small_forest()
    glb = write_glb(forest, tmp / "forest.glb")
    out, points = tmp / "report.json", tmp / "points.npz"
    proc = subprocess.run(
        [str(BLENDER_PY), str(CHECK), str(glb), "--frames", ",".join(map(str, CHECK_FRAMES)),
         "--points-out", str(points), "--json-out", str(out)],
        capture_output=True, text=True, timeout=600, cwd=tmp,
    )  # fmt: skip
    if not out.exists():
        pytest.fail(
            f"the Blender glTF check crashed (exit {proc.returncode}):\n{proc.stdout[-3000:]}"
            f"\n{proc.stderr[-3000:]}",
            pytrace=False,
        )
    report = json.loads(out.read_text())
    sys.stdout.write(json.dumps(report, indent=1, sort_keys=True)[:4000] + "\n")
    return forest, report, np.load(points), gl.GLTF2.load(str(glb))


def test_one_armature_per_tree_with_the_wind_action(blender_run: Run) -> None:
    forest, report, _, _ = blender_run
    names = [f"Tree_{k:05d}" for k in range(TREES)]
    assert report["armatures"] == names
    assert report["skinned_meshes"] == [f"{n}_Mesh" for n in names]
    assert report["mesh_objects"] == report["skinned_meshes"]  # nothing else: no second scene
    assert report["mesh_armature"] == {f"{n}_Mesh": n for n in names}
    for n in names:
        action = report["actions"][n]
        assert action is not None and action["name"].startswith("Wind"), action
        # the importer keys seconds at the scene's frame rate (24, as our fps)
        assert action["frame_range"] == [0.0, FRAMES - 1.0]
    assert report["fps"] == FPS
    bones = [b.stop - b.start for _, b in _slices(forest)]
    assert [report["bones"][n] for n in names] == bones


def _slices(forest: Forest) -> list[tuple[slice, slice]]:
    from forest.growth.joint_budget import GAME_JOINTS
    from forest.usd.skinned import tree_slices

    return tree_slices(forest, GAME_JOINTS)


def test_textures_are_packed_and_used(blender_run: Run) -> None:
    forest, report, _, _ = blender_run
    images = report["images"]
    assert set(images) == {f"bark-{forest.grammar.bark}", f"leaf-{forest.grammar.leaves.family}"}
    assert all(im["packed"] and min(im["size"]) > 0 for im in images.values())
    assert report["materials"]["Bark"]["images"] == [f"bark-{forest.grammar.bark}"]
    leaves = [m for n, m in report["materials"].items() if n.startswith("Leaves_")]
    assert len(leaves) == TREES and all(
        m["images"] == [f"leaf-{forest.grammar.leaves.family}"] for m in leaves
    )


def test_deformed_vertices_match_our_skinning(blender_run: Run) -> None:
    """Blender joins a mesh's primitives into one object, bark's vertices first."""
    forest, _, points, doc = blender_run
    for f in CHECK_FRAMES:
        for k, prims in enumerate(expected_tree(forest, doc, f / FPS)):
            want = np.concatenate(prims)
            height = float(np.ptp(prims[0][:, 1]))
            got = points[f"Tree_{k:05d}_Mesh@{f}"]
            assert got.shape == want.shape
            err = float(np.abs(got - want).max())
            assert err <= 1e-3 * height, (f, k, err, height)
