"""Import a textured forest scene (.usda/.usdc with its ``<stem>.textures/`` folder, or a
.usdz) into real Blender and report the pictures it loaded; optionally render it. Run with the
Blender venv's Python, from another folder than the scene's:

    .venv-blender/bin/python tests/blender_texture_check.py SCENE [--render OUT.png]

Checks (each failure is listed under "failures" and makes the exit status 1): every image
texture node of the bark and leaf materials holds an image whose pixels Blender read (every
tile of a UDIM image); the bark's Base Color and the leaves' Alpha are fed by an image
(leaf cards cut by the picture's alpha). The JSON report is the last line of stdout.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

try:
    import bpy
except ImportError:  # pragma: no cover - depends on the interpreter
    sys.exit("blender_texture_check.py needs Blender's bpy module: run it with .venv-blender")

sys.path.insert(0, str(Path(__file__).parent))
from blender_import_check import usd_import
from blender_render import stage_and_render


def image_report(im: bpy.types.Image) -> dict[str, Any]:
    """What Blender made of one image: its source, path, and whether its pixels were read
    (each tile of a UDIM image decoded to a size)."""
    n_pixels = len(im.pixels)  # reading the pixels loads the image buffer
    tiles = [t for t in im.tiles] if im.source == "TILED" else []
    unread = [t.number for t in tiles if t.size[0] <= 0 or t.channels <= 0]
    return {
        "name": im.name,
        "source": im.source,
        "filepath": im.filepath,
        "packed": im.packed_file is not None,
        "size": list(im.size),
        "tiles": len(tiles),
        "loaded": bool(im.has_data) and n_pixels > 0 and not unread,
    }


def fed_by_image(socket: Any) -> bool:
    """Whether an image texture node feeds ``socket`` (through any nodes between)."""
    seen = set()
    stack = [link.from_node for link in socket.links]
    while stack:
        node = stack.pop()
        if node.name in seen:
            continue
        seen.add(node.name)
        if node.bl_idname == "ShaderNodeTexImage":
            return True
        stack += [link.from_node for inp in node.inputs for link in inp.links]
    return False


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene")
    ap.add_argument("--render", help="also render a small Cycles picture here")
    ap.add_argument("--size", type=int, default=240)
    ap.add_argument("--samples", type=int, default=8)
    ap.add_argument(
        "--impostor",
        action="store_true",
        help="the scene selects lod3: expect the impostor's material (colour and alpha from "
        "its picture) instead of bark and leaves",
    )
    args = ap.parse_args(argv)
    _used, _missing, took = usd_import(Path(args.scene))  # exits on a failed import
    failures: list[str] = []
    materials: dict[str, Any] = {}
    used = {s.material.name for ob in bpy.data.objects for s in ob.material_slots if s.material}
    for mat in bpy.data.materials:
        if mat.name not in used or not mat.node_tree:
            continue
        nodes = mat.node_tree.nodes
        images = [
            image_report(n.image) for n in nodes if n.bl_idname == "ShaderNodeTexImage" and n.image
        ]
        empty = [n.name for n in nodes if n.bl_idname == "ShaderNodeTexImage" and not n.image]
        bsdf = next((n for n in nodes if n.bl_idname == "ShaderNodeBsdfPrincipled"), None)
        entry = {
            "images": images,
            "empty_image_nodes": empty,
            "base_color_textured": bool(bsdf) and fed_by_image(bsdf.inputs["Base Color"]),
            "alpha_textured": bool(bsdf) and fed_by_image(bsdf.inputs["Alpha"]),
            "blend_method": getattr(mat, "blend_method", None),
        }
        materials[mat.name] = entry
        if empty:
            failures.append(f"{mat.name}: image nodes without an image {empty}")
        failures += [f"{mat.name}: {im['name']} not loaded" for im in images if not im["loaded"]]
        if mat.name.startswith("Bark") and not entry["base_color_textured"]:
            failures.append(f"{mat.name}: Base Color not from a picture")
        if mat.name.startswith("Leaf") and not entry["alpha_textured"]:
            failures.append(f"{mat.name}: Alpha not from the leaf picture (square cards)")
    kinds = ("ImpostorLook",) if args.impostor else ("Bark", "Leaf")
    for kind in kinds:
        if not any(m.startswith(kind) for m in materials):
            failures.append(f"no {kind} material among {sorted(materials)}")
    for name, entry in materials.items():
        if name.startswith("ImpostorLook") and not (
            entry["base_color_textured"] and entry["alpha_textured"]
        ):
            failures.append(f"{name}: Base Color and Alpha not from the cards' picture")
    report = {
        "blender": bpy.app.version_string,
        "scene": args.scene,
        "import_s": round(took, 2),
        "objects": len(bpy.data.objects),
        "materials": materials,
        "failures": failures,
    }
    if args.render:
        stage_and_render(args.render, args.size, args.samples)
        report["render"] = args.render
    print(json.dumps(report))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else sys.argv[1:]))
