"""A mixed forest (a recipe's stand) as one .glb: the terrain as a plain mesh, then every
layer's trees as :func:`forest.gltf.document.add_forest` writes a forest's (each layer its own
bark and leaf materials), their names prefixed with the layer's (``oak_Tree_00003``), the wind
of every layer in one "Wind" animation. Layers are grown one at a time and dropped once
written, so memory follows the largest layer plus the document.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pygltflib as gl

from forest import __version__
from forest.caps import MAX_VERTICES
from forest.errors import ForestError, LimitError
from forest.gltf.buffer import Blob
from forest.gltf.compress import DEFAULT_PACKING, Packing
from forest.gltf.document import (
    DEFAULT_PROFILE,
    PROFILES,
    Profile,
    Progress,
    add_forest,
    baked_vertices,
    document,
    game_lod0,
    profile_joints,
    save_glb,
)
from forest.growth.generate import ForestOptions
from forest.lod.targets import GAME_LOD0
from forest.stand.generate import Stand
from forest.stand.terrain import Heightfield
from forest.usd.stand import GROUND_COLOR

_NAMED = ("nodes", "meshes", "skins", "materials", "textures", "images")


def add_terrain(gltf: gl.GLTF2, blob: Blob, ground: Heightfield) -> int:
    """The ground as one mesh node in the scene (positions, normals, 0-1 UVs over the area, a
    rough ground-coloured material); the node's index."""
    points, quads, st, normals = ground.mesh()
    tris = quads[:, [0, 1, 2, 0, 2, 3]].reshape(-1).astype(np.uint32)
    attrs = gl.Attributes(
        POSITION=blob.accessor(points.astype(np.float32), gl.ARRAY_BUFFER, bounds=True),
        NORMAL=blob.accessor(normals.astype(np.float32), gl.ARRAY_BUFFER),
        TEXCOORD_0=blob.accessor(
            np.stack([st[:, 0], 1.0 - st[:, 1]], axis=1).astype(np.float32), gl.ARRAY_BUFFER
        ),
    )
    gltf.materials.append(
        gl.Material(
            name="Ground",
            pbrMetallicRoughness=gl.PbrMetallicRoughness(
                baseColorFactor=[*GROUND_COLOR, 1.0], metallicFactor=0.0, roughnessFactor=0.95
            ),
        )
    )
    prim = gl.Primitive(
        attributes=attrs,
        indices=blob.accessor(tris, gl.ELEMENT_ARRAY_BUFFER),
        material=len(gltf.materials) - 1,
    )
    gltf.meshes.append(gl.Mesh(name="Terrain", primitives=[prim]))
    gltf.nodes.append(gl.Node(name="Terrain", mesh=len(gltf.meshes) - 1))
    gltf.scenes[0].nodes.append(len(gltf.nodes) - 1)
    return len(gltf.nodes) - 1


def stand_gltf(
    stand: Stand,
    options: ForestOptions,
    progress: Progress | None = None,
    *,
    profile: Profile = DEFAULT_PROFILE,
    impostor: bool | None = None,
    lod0_triangles: int | None = None,
) -> gl.GLTF2:
    """The stand as one glTF document with its binary blob set (``profile``, ``impostor``,
    ``lod0_triangles`` as :func:`forest.gltf.document.forest_gltf`'s)."""
    if profile not in PROFILES:
        raise ForestError(
            f"unknown glTF profile {profile!r}; one of {', '.join(PROFILES)}", path="profile"
        )
    lod0 = GAME_LOD0 if lod0_triangles is None else game_lod0(lod0_triangles, profile)
    game = profile == "game"
    if game and impostor is None:
        from forest.lod.impostor import gl_missing

        impostor = gl_missing() is None
    gltf = document(
        __version__,
        {
            "recipe": stand.recipe.model_dump_json(exclude_none=True),
            "seed": int(stand.seed),
            "trees": stand.trees,
            "area": list(stand.area),
            "frames": options.frames,
            "fps": options.fps,
            "profile": profile,
        },
    )
    blob = Blob(gltf)
    add_terrain(gltf, blob, stand.ground)
    vertices = 0
    for k, layer in enumerate(stand.recipe.layers):
        forest = stand.grow_layer(k, options)
        if forest is None:
            continue
        vertices += baked_vertices(forest, profile, lod0.budget)
        if vertices > MAX_VERTICES:
            raise LimitError(
                f"the stand's trees bake to over {MAX_VERTICES} vertices (the glTF cap) by "
                f"layer {layer.name!r}; use fewer trees (or USD, which instances the pieces)",
                path="trees",
                limit=MAX_VERTICES,
            )
        first = {name: len(getattr(gltf, name)) for name in _NAMED}
        add_forest(
            gltf,
            blob,
            forest,
            None,
            progress,
            profile_joints(profile),
            game,
            bool(impostor),
            lod0,
        )
        del forest
        for name in _NAMED:  # what this layer added is named after it
            for item in getattr(gltf, name)[first[name] :]:
                item.name = f"{layer.name}_{item.name}" if item.name else layer.name
    blob.finish()
    return gltf


def write_stand_glb(
    stand: Stand,
    path: str | Path,
    options: ForestOptions,
    *,
    progress: Progress | None = None,
    packing: Packing = DEFAULT_PACKING,
    profile: Profile = DEFAULT_PROFILE,
    impostor: bool | None = None,
    lod0_triangles: int | None = None,
) -> Path:
    """Write the stand to ``path`` (.glb) atomically; returns the path."""
    doc = stand_gltf(
        stand, options, progress, profile=profile, impostor=impostor, lod0_triangles=lod0_triangles
    )
    return save_glb(doc, path, packing, progress)
