"""Render a forest USD scene as Blender imports it (Cycles on the CPU): what an artist sees
after File > Import > USD, lit by a sun and a sky over a grey ground. Run with the Blender
venv's Python (``bash tests/setup_blender_venv.sh`` makes it):

    .venv-blender/bin/python tests/blender_render.py SCENE.usdc OUT.png [--size PX] [--samples N]

The camera frames the imported meshes' evaluated (skinned) geometry at the first frame from
the side, a little above. tests/test_blender.py renders a tree with it and checks the
pixels; the Blender gallery (docs/gallery.md) was made with it.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

try:
    import bpy
    from mathutils import Vector
except ImportError:  # pragma: no cover - depends on the interpreter
    sys.exit("blender_render.py needs Blender's bpy module: run it with .venv-blender/bin/python")

from blender_import_check import usd_import


def world_bounds() -> tuple[Vector, Vector]:
    """Bounds of every evaluated mesh vertex (skinned, at the current frame) in world space."""
    dg = bpy.context.evaluated_depsgraph_get()
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for ob in bpy.context.scene.objects:
        if ob.type != "MESH":
            continue
        ev = ob.evaluated_get(dg)
        mesh = ev.to_mesh()
        co = np.empty(3 * len(mesh.vertices))
        mesh.vertices.foreach_get("co", co)
        m = np.array(ev.matrix_world)
        w = co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]
        ev.to_mesh_clear()
        if len(w):
            lo, hi = np.minimum(lo, w.min(axis=0)), np.maximum(hi, w.max(axis=0))
    return Vector(lo.tolist()), Vector(hi.tolist())


def stage_and_render(out: str, size: int, samples: int) -> None:
    scene = bpy.context.scene
    scene.frame_set(scene.frame_start)
    lo, hi = world_bounds()
    centre, ext = (lo + hi) / 2, hi - lo
    height = max(ext.z, 1e-3)
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(cam)
    cam.data.lens = 50
    # 50 mm on a 36 mm sensor sees about 39.6 degrees: the tree's height (or width) fills 80 %
    span = max(height, ext.x, ext.y) / 0.8
    dist = span / (2 * math.tan(math.radians(39.6) / 2))
    cam.location = centre + Vector((0.8 * dist, -0.6 * dist, 0.1 * height))
    cam.rotation_euler = (centre - cam.location).to_track_quat("-Z", "Y").to_euler()
    scene.camera = cam
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    scene.collection.objects.link(sun)
    sun.data.energy = 4.0
    sun.rotation_euler = (math.radians(40), math.radians(10), math.radians(30))
    world = bpy.data.worlds.new("Sky")
    scene.world = world
    world.use_nodes = True
    bg = world.node_tree.nodes["Background"]
    bg.inputs[0].default_value = (0.55, 0.65, 0.8, 1.0)
    bg.inputs[1].default_value = 0.8
    ground = max(ext.x, ext.y, height) * 8
    bpy.ops.mesh.primitive_plane_add(size=ground, location=(centre.x, centre.y, lo.z))
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_denoising = False
    scene.render.resolution_x = scene.render.resolution_y = size
    scene.render.filepath = out
    bpy.ops.render.render(write_still=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene")
    ap.add_argument("out")
    ap.add_argument("--size", type=int, default=360)
    ap.add_argument("--samples", type=int, default=16)
    args = ap.parse_args(argv)
    usd_import(Path(args.scene))  # the options every check uses; exits on a failed import
    stage_and_render(args.out, args.size, args.samples)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else sys.argv[1:]))
