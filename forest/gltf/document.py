"""A forest as one glTF 2.0 binary (.glb): per tree a skinned bark mesh on its skeleton, the
wind as an animation, leaf clouds on the hub joints; written atomically, byte-identical for
the same forest.

Scene layout (y up, metres, as the USD scenes): for tree k a root node ``Tree_<k>`` (the
tree transform) holding the joint hierarchy (leaf-cloud nodes under the hub joints), and a
root node ``Tree_<k>_Bark`` with the skinned mesh (glTF skins ignore a skinned node's own
transform, so it stays at the root with none).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pygltflib as gl

from forest.atomic import replaced_when_written
from forest.bark.atlas import atlas_uv, make_atlas, read_slices, tile_folder
from forest.errors import LimitError, OutputError
from forest.geometry.transforms import F64
from forest.gltf.bark import add_bark_material
from forest.gltf.buffer import Blob
from forest.gltf.instancing import add_instanced_scene
from forest.gltf.leaves import LeafLibrary, add_tree_clouds
from forest.gltf.skin import TreeSkin, add_tree_skeleton, add_wind, sample_pose
from forest.growth.generate import Forest, foliage_or_none
from forest.usd.skinned import joint_frames, tree_mesh, tree_slices

Progress = Callable[[str, int, int], None]
MAX_VERTICES = 8_000_000  # baked bark vertices per file (4 per quad): about 450 MB of GLB
_QUAD_TRIS = np.array([0, 1, 2, 0, 2, 3], np.uint32)


def bark_vertices(forest: Forest) -> int:
    """Vertices the baked bark meshes will have (4 per quad), counted before baking."""
    quads = np.array([len(p.quads) for p in forest.pieces])
    return int(4 * quads[forest.graph.piece].sum())


def check_size(forest: Forest) -> None:
    n = bark_vertices(forest)
    if n > MAX_VERTICES:
        raise LimitError(
            f"{forest.options.trees} trees bake to {n} bark vertices, over the glTF cap of "
            f"{MAX_VERTICES}; use fewer trees (or USD, which instances the pieces)",
            path="trees",
            limit=MAX_VERTICES,
        )


def _bark_primitive(
    blob: Blob,
    forest: Forest,
    inst: slice,
    bones: slice,
    tree: int,
    material: int,
    n_slices: int,
    tile_size: int,
    still: F64,
) -> gl.Primitive:
    """The tree's bark in tree space as it stands (skinned with ``still``, the skins' bind
    pose), one vertex per quad corner (each quad has its own tile UVs), two triangles per
    quad."""
    from forest.geometry.transforms import invert_similarity

    to_tree = invert_similarity(forest.tree_transforms[tree])
    pts, nrm, quads, jidx, jw, st = tree_mesh(forest, inst, bones, to_tree, still)
    corner = quads.ravel()
    w = jw[corner]
    w = w / w.sum(axis=1, keepdims=True)
    j = np.where(w > 0, jidx[corner], 0)  # unused influences name joint 0
    jtype = np.uint8 if bones.stop - bones.start <= 256 else np.uint16
    tris = (np.arange(len(quads), dtype=np.uint32)[:, None] * 4 + _QUAD_TRIS).ravel()
    attrs = gl.Attributes(
        POSITION=blob.accessor(pts[corner].astype(np.float32), gl.ARRAY_BUFFER, bounds=True),
        NORMAL=blob.accessor(nrm[corner].astype(np.float32), gl.ARRAY_BUFFER),
        TEXCOORD_0=blob.accessor(atlas_uv(st, n_slices, tile_size).reshape(-1, 2), gl.ARRAY_BUFFER),
        JOINTS_0=blob.accessor(j.astype(jtype), gl.ARRAY_BUFFER),
        WEIGHTS_0=blob.accessor(w.astype(np.float32), gl.ARRAY_BUFFER),
    )
    index = tris.astype(np.uint16) if 4 * len(quads) <= 65536 else tris
    return gl.Primitive(
        attributes=attrs,
        indices=blob.accessor(index, gl.ELEMENT_ARRAY_BUFFER),
        material=material,
    )


def forest_gltf(
    forest: Forest, tiles: Path | None = None, progress: Progress | None = None
) -> gl.GLTF2:
    """The forest as a glTF document with its binary blob set. ``tiles``: a tile-set folder
    whose ``bark.<UDIM>.png`` make the atlas, instead of the shipped set of the grammar's
    ``bark``."""
    check_size(forest)
    opts = forest.options
    gltf = gl.GLTF2(
        asset=gl.Asset(
            version="2.0",
            generator=f"interlocking-forest {forest.version}",
            extras={
                "forest": {
                    "grammar": json.dumps(forest.grammar.model_dump(mode="json"), sort_keys=True),
                    "seed": int(forest.seed),
                    "version": forest.version,
                    "trees": opts.trees,
                    "frames": opts.frames,
                    "fps": opts.fps,
                }
            },
        ),
        scene=0,
        scenes=[gl.Scene(name="Forest", nodes=[])],
    )
    blob = Blob(gltf)
    slices = read_slices(tile_folder(forest.grammar.bark, tiles), forest.manifest.n_slices)
    bark = add_bark_material(gltf, blob, make_atlas(slices), forest.grammar.bark)
    frames = joint_frames(forest)
    pose = sample_pose(forest, frames)
    anchors = foliage_or_none(forest)
    library = LeafLibrary(gltf, blob, anchors) if anchors is not None else None
    anchor_tree = forest.graph.tree[anchors.instance] if anchors is not None else None
    skins: list[tuple[TreeSkin, slice]] = []
    slices_ = tree_slices(forest)
    if progress:
        progress("glTF trees", 0, len(slices_))
    for k, (inst, bones) in enumerate(slices_):
        skin = add_tree_skeleton(gltf, blob, forest, frames, pose, k, inst, bones)
        skins.append((skin, bones))
        prim = _bark_primitive(
            blob, forest, inst, bones, k, bark, len(slices), slices.shape[1], frames.still
        )
        gltf.meshes.append(gl.Mesh(name=f"Bark_{k:05d}", primitives=[prim]))
        gltf.nodes.append(
            gl.Node(name=f"Tree_{k:05d}_Bark", mesh=len(gltf.meshes) - 1, skin=skin.skin)
        )
        gltf.scenes[0].nodes.append(len(gltf.nodes) - 1)
        if anchors is not None and library is not None and anchor_tree is not None:
            pick = np.flatnonzero(anchor_tree == k)
            add_tree_clouds(gltf, library, forest, anchors, pick, k, skin, bones, pose)
        if progress:
            progress("glTF trees", k + 1, len(slices_))
    add_wind(gltf, blob, pose, skins)
    add_instanced_scene(gltf, blob, forest, bark, len(slices), slices.shape[1])
    blob.finish()
    return gltf


def glb_bytes(gltf: gl.GLTF2) -> bytes:
    return b"".join(gltf.save_to_bytes())


def write_glb(
    forest: Forest,
    path: str | Path,
    *,
    tiles: Path | None = None,
    progress: Progress | None = None,
) -> Path:
    """Write ``forest`` to ``path`` (.glb) atomically; returns the path."""
    out = Path(path)
    gltf = forest_gltf(forest, tiles, progress)
    # one step: pygltflib encodes the whole document in one call
    if progress:
        progress("save", 0, 1)
    data = glb_bytes(gltf)
    try:
        with replaced_when_written(out) as tmp:
            tmp.write_bytes(data)
    except OSError as exc:
        raise OutputError(f"cannot write: {exc.strerror}", path=str(out)) from None
    if progress:
        progress("save", 1, 1)
    return out
