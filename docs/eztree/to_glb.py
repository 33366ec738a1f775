"""An ez-tree preset's meshes (``dump.mjs``) as a .glb with ez-tree's own bark and leaf
pictures and tints, scaled to ``HEIGHT`` metres (ez-tree's units are arbitrary: its "Oak
Large" is 97 units tall):

    python docs/eztree/to_glb.py oak_large.json oak_large.glb 22

Run it in this folder after ``npm install`` (the pictures come from the installed package).
"""

import json
import sys

import numpy as np
import trimesh
from PIL import Image

ASSETS = "node_modules/@dgreenheck/ez-tree/src/lib/assets"


def linear(rgb: int) -> list[float]:
    """A three.js hex colour as a glTF base colour factor (linear RGBA)."""
    c = np.array([(rgb >> 16) & 255, (rgb >> 8) & 255, rgb & 255]) / 255.0
    return [*(c**2.2), 1.0]


def main(src: str, out: str, height: float) -> None:
    d = json.load(open(src))
    o = d["options"]
    bark_top = np.array(d["meshes"]["bark"]["position"]).reshape(-1, 3)[:, 1].max()
    scene = trimesh.Scene()
    for name in ("bark", "leaves"):
        m = d["meshes"][name]
        uv = np.array(m["uv"]).reshape(-1, 2)
        if name == "bark":  # ez-tree repeats its bark picture by textureScale
            scale = o["bark"]["textureScale"]
            uv = uv * np.array([scale["x"], scale["y"]])
            picture = Image.open(f"{ASSETS}/bark/{o['bark']['type']}_color_1k.jpg")
            material = trimesh.visual.material.PBRMaterial(
                baseColorTexture=picture, baseColorFactor=linear(o["bark"]["tint"]),
                roughnessFactor=1.0, metallicFactor=0.0,
            )  # fmt: skip
        else:
            picture = Image.open(f"{ASSETS}/leaves/{o['leaves']['type']}_color.png")
            material = trimesh.visual.material.PBRMaterial(
                baseColorTexture=picture, baseColorFactor=linear(o["leaves"]["tint"]),
                alphaMode="MASK", alphaCutoff=o["leaves"]["alphaTest"], doubleSided=True,
                roughnessFactor=1.0, metallicFactor=0.0,
            )  # fmt: skip
        mesh = trimesh.Trimesh(
            np.array(m["position"]).reshape(-1, 3) * (height / bark_top),
            np.array(m["index"]).reshape(-1, 3),
            vertex_normals=np.array(m["normal"]).reshape(-1, 3),
            visual=trimesh.visual.TextureVisuals(uv=uv, material=material),
            process=False,
        )
        scene.add_geometry(mesh, node_name=name, geom_name=name)
    scene.export(out)
    print(f"{out}: {height} m, {sum(len(g.faces) for g in scene.geometry.values())} triangles")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], float(sys.argv[3]))
