"""The exports in Blender 5.2 (bpy 5.2.3 on CPython 3.13, ``.venv-blender52``, made by
``bash tests/setup_blender_venv.sh 5.2``; tests/test_blender.py and test_gltf_blender.py run
4.2 in depth): one oak with wind as .usdc (pictures in its ``.textures/`` folder), .usdz and
game-profile .glb, each imported from another folder by the same check scripts. Each tree
once (the .glb's LOD1-LOD3 in Blender's excluded "Orphan Nodes" collection), its pictures
loaded, its wind moving. A missing venv fails under CI and skips elsewhere."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path
from typing import Any

import pytest

from forest.export import write_forest
from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset

pytestmark = pytest.mark.slow  # real Blender 5.2, about a minute

ROOT = Path(__file__).resolve().parents[1]
PYTHON = ROOT / ".venv-blender52" / "bin" / "python"
TESTS = ROOT / "tests"


def _blender() -> Path:
    if not PYTHON.exists():
        why = f"{PYTHON} is missing: run `bash tests/setup_blender_venv.sh 5.2`"
        if os.environ.get("CI") == "true":
            pytest.fail(why, pytrace=False)
        pytest.skip(why)
    return PYTHON


def _run(script: str, *args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(_blender()), str(TESTS / script), *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=600,
    )


def _last_json(out: str) -> dict[str, Any]:
    line = [x for x in out.splitlines() if x.startswith("{")][-1]
    result: dict[str, Any] = json.loads(line)
    return result


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    _blender()
    forest = generate_forest(load_preset("oak"), 3, ForestOptions(trees=1, frames=12))
    folder = tmp_path_factory.mktemp("scenes")
    return {s: write_forest(forest, folder / f"oak.{s}") for s in ("usdc", "usdz", "glb")}


@pytest.mark.parametrize("suffix", ["usdc", "usdz"])
def test_usd_imports_textured_and_moving(
    files: dict[str, Path], suffix: str, tmp_path: Path
) -> None:
    scene = str(files[suffix])
    done = _run(
        "blender_import_check.py",
        scene,
        "--instances",
        "0",
        "--trees",
        "1",
        "--frames",
        "12",
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    report = _last_json(done.stdout)
    assert report["blender"].startswith("5.2"), report["blender"]
    assert report["failures"] == [] and report["armatures"] == 1
    (tree,) = report["trees"].values()
    assert tree["bones"] <= 1024 and tree["vertex_motion"] > 0
    done = _run("blender_texture_check.py", scene, cwd=tmp_path)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    pictures = _last_json(done.stdout)
    assert pictures["failures"] == []
    bark, leaf = pictures["materials"]["Bark"], pictures["materials"]["Leaf"]
    assert bark["base_color_textured"] and all(i["loaded"] for i in bark["images"])
    assert leaf["alpha_textured"] and all(i["loaded"] for i in leaf["images"])


def test_glb_imports_each_tree_once(files: dict[str, Path], tmp_path: Path) -> None:
    report_file = tmp_path / "glb.json"
    done = _run(
        "gltf_blender_check.py",
        str(files["glb"]),
        "--frames",
        "0,6",
        "--points-out",
        str(tmp_path / "p.npz"),
        "--json-out",
        str(report_file),
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    report = json.loads(report_file.read_text())
    assert report["armatures"] == ["Tree_00000"] and report["bones"]["Tree_00000"] <= 256
    assert all(i["packed"] for i in report["images"].values()) and len(report["images"]) >= 2
    # the levels below LOD0 are in no glTF scene: Blender 5.2 keeps them out of view
    script = (
        "import sys, bpy\n"
        "bpy.ops.wm.read_factory_settings(use_empty=True)\n"
        "bpy.ops.import_scene.gltf(filepath=sys.argv[-1])\n"
        "print([o.name for o in bpy.context.view_layer.objects if o.type == 'MESH' "
        "and o.visible_get()])\n"
    )
    shown = subprocess.run(
        [str(_blender()), "-c", script, str(files["glb"])],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert shown.returncode == 0, shown.stderr[-2000:]
    assert shown.stdout.strip().splitlines()[-1] == "['Tree_00000_LOD0']", shown.stdout[-500:]
