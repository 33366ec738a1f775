"""Import a .glb with Blender's glTF importer (run by .venv-blender's python, see
tests/test_gltf_blender.py) and report what Blender made: armatures, skinned meshes, actions
and their frame ranges, images and the materials that read them, the mesh objects, the import's
seconds, and the world-space deformed vertices of every skinned mesh at the frames asked for
(glTF's y-up axes, so they compare with the library's skinning directly).

    python gltf_blender_check.py FOREST.glb --frames 0,3 --points-out PTS.npz --json-out R.json
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import bpy
import numpy as np


def deformed_points(ob: Any) -> np.ndarray:
    """Evaluated vertices of a mesh object in world space, turned back to glTF's y-up axes
    (the importer maps glTF (x, y, z) to Blender (x, -z, y))."""
    dg = bpy.context.evaluated_depsgraph_get()
    ev = ob.evaluated_get(dg)
    me = ev.to_mesh()
    try:
        co = np.empty(len(me.vertices) * 3, np.float32)
        me.vertices.foreach_get("co", co)
        mw = np.array(ev.matrix_world)
    finally:
        ev.to_mesh_clear()
    p = co.reshape(-1, 3).astype(np.float64) @ mw[:3, :3].T + mw[:3, 3]
    return np.stack([p[:, 0], p[:, 2], -p[:, 1]], axis=1)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("glb", type=Path)
    ap.add_argument("--frames", default="0")
    ap.add_argument("--points-out", type=Path, required=True)
    ap.add_argument("--json-out", type=Path, required=True)
    args = ap.parse_args()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    start = time.perf_counter()
    result = bpy.ops.import_scene.gltf(filepath=str(args.glb))
    seconds = time.perf_counter() - start
    scene = bpy.context.scene
    arms = [o for o in scene.objects if o.type == "ARMATURE"]
    skinned = sorted(
        (
            o
            for o in scene.objects
            if o.type == "MESH" and any(m.type == "ARMATURE" for m in o.modifiers)
        ),
        key=lambda o: o.name,
    )
    actions = {}
    for arm in arms:
        ad = arm.animation_data
        act = ad.action if ad is not None else None
        actions[arm.name] = (
            None
            if act is None
            else {
                "name": act.name,
                "frame_range": [float(v) for v in act.frame_range],
            }
        )
    textured = {}
    for mat in bpy.data.materials:
        if mat.node_tree is None:
            continue
        imgs = [n.image.name for n in mat.node_tree.nodes if n.type == "TEX_IMAGE" and n.image]
        textured[mat.name] = {"images": imgs, "blend": getattr(mat, "blend_method", None)}
    images = {
        im.name: {"size": list(im.size), "packed": im.packed_file is not None}
        for im in bpy.data.images
    }
    # the importer draws bones with an icosphere of its own (a bone's custom shape)
    shapes = {pb.custom_shape for a in arms for pb in a.pose.bones if pb.custom_shape}
    meshes = sorted(o.name for o in scene.objects if o.type == "MESH" and o not in shapes)
    points: dict[str, np.ndarray] = {}
    frames = [int(f) for f in args.frames.split(",")]
    for f in frames:
        scene.frame_set(f)
        for ob in skinned:
            points[f"{ob.name}@{f}"] = deformed_points(ob)
    np.savez(args.points_out, **points)
    report: dict[str, Any] = {
        "import": sorted(result),
        "armatures": sorted(a.name for a in arms),
        "bones": {a.name: len(a.data.bones) for a in arms},
        "skinned_meshes": [o.name for o in skinned],
        "mesh_armature": {
            o.name: next(m.object.name for m in o.modifiers if m.type == "ARMATURE" and m.object)
            for o in skinned
        },
        "actions": actions,
        "all_actions": sorted(a.name for a in bpy.data.actions),
        "materials": textured,
        "images": images,
        "mesh_objects": meshes,
        "import_seconds": seconds,
        "fps": scene.render.fps,
        "frames": frames,
    }
    args.json_out.write_text(json.dumps(report, indent=1, sort_keys=True))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
