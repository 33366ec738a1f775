"""Render a .glb (ez-tree's, from to_glb.py) or one of our USD scenes the way
tests/blender_render.py does (Cycles, the same sun, sky and ground), for the side-by-side:

    .venv-blender/bin/python docs/eztree/side.py SCENE OUT.png
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))
import bpy  # noqa: E402
from blender_import_check import usd_import  # noqa: E402
from blender_render import stage_and_render  # noqa: E402

scene, out = sys.argv[1:3]
bpy.ops.wm.read_factory_settings(use_empty=True)
if scene.endswith(".glb"):
    bpy.ops.import_scene.gltf(filepath=scene)
else:
    usd_import(Path(scene))
stage_and_render(out, 480, 32)
