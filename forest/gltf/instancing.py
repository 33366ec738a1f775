"""The forest's pieces instanced with ``EXT_mesh_gpu_instancing``, in a second scene.

Scene 0 (the default, what every consumer opens) holds the skinned trees; scene 1,
"Pieces (instanced, rest)", holds one node per piece type whose mesh is the piece prototype
and whose extension lists every instance's translation, rotation and scale (the topological
transforms: the rest pose, unposed and still, as the USD PointInstancer's). A consumer that
knows the extension (three.js, Blender, Babylon.js, Godot 4) can open that scene for a cheap
forest; one that does not keeps the skinned default scene, the fallback. The extension is
used, not required, so the file stays valid for every reader. Prototype quads all show the
atlas' first tile: per-instance tiles would need per-instance UVs, which glTF cannot carry.
"""

from __future__ import annotations

import numpy as np
import pygltflib as gl

from forest.bark.atlas import atlas_uv
from forest.geometry.transforms import decompose_similarity
from forest.gltf.buffer import Blob
from forest.growth.generate import Forest
from forest.usd.materials import tile_udim_st

EXTENSION = "EXT_mesh_gpu_instancing"
_QUAD_TRIS = np.array([0, 1, 2, 0, 2, 3], np.uint32)


def add_instanced_scene(
    gltf: gl.GLTF2, blob: Blob, forest: Forest, material: int, n_slices: int, tile_size: int
) -> None:
    """Scene 1: per piece type in use, a node with the prototype mesh instanced at every
    instance of that type."""
    t, q, s = decompose_similarity(forest.transforms)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    nodes = []
    for pid, piece in enumerate(forest.pieces):
        inst = np.flatnonzero(forest.graph.piece == pid)
        if len(inst) == 0:
            continue
        corner = piece.quads.ravel()
        st = tile_udim_st(np.zeros(len(piece.quads), np.int32))
        tris = (np.arange(len(piece.quads), dtype=np.uint32)[:, None] * 4 + _QUAD_TRIS).ravel()
        prim = gl.Primitive(
            attributes=gl.Attributes(
                POSITION=blob.accessor(
                    piece.positions[corner].astype(np.float32), gl.ARRAY_BUFFER, bounds=True
                ),
                NORMAL=blob.accessor(piece.normals[corner].astype(np.float32), gl.ARRAY_BUFFER),
                TEXCOORD_0=blob.accessor(
                    atlas_uv(st, n_slices, tile_size).reshape(-1, 2), gl.ARRAY_BUFFER
                ),
            ),
            indices=blob.accessor(tris.astype(np.uint32), gl.ELEMENT_ARRAY_BUFFER),
            material=material,
        )
        gltf.meshes.append(gl.Mesh(name=f"Piece_{piece.name}", primitives=[prim]))
        scale = np.repeat(s[inst, None], 3, axis=1)
        attributes = {
            "TRANSLATION": blob.accessor(t[inst].astype(np.float32)),
            "ROTATION": blob.accessor(q[inst].astype(np.float32)),
            "SCALE": blob.accessor(scale.astype(np.float32)),
        }
        gltf.nodes.append(
            gl.Node(
                name=f"Pieces_{piece.name}",
                mesh=len(gltf.meshes) - 1,
                extensions={EXTENSION: {"attributes": attributes}},
            )
        )
        nodes.append(len(gltf.nodes) - 1)
    gltf.scenes.append(gl.Scene(name="Pieces (instanced, rest)", nodes=nodes))
    gltf.extensionsUsed = [*gltf.extensionsUsed, EXTENSION]
