"""A forest as one glTF 2.0 binary (.glb): per tree one skinned mesh on its skeleton (a bark
primitive and a leaves primitive), the wind as one animation; written atomically,
byte-identical for the same forest.

Scene layout (y up, metres, as the USD scenes): one scene; for tree k a root node
``Tree_<k>`` (the tree transform) holding the joint hierarchy, and a root node
``Tree_<k>_Mesh`` with the skinned mesh (glTF skins ignore a skinned node's own transform, so
it stays at the root with none). The meshes are those of the USD skinned form
(:mod:`forest.usd.skinned`): the welded bark and the leaf cards, in the bind pose.
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
from forest.geometry.transforms import F64, invert_similarity
from forest.gltf.bark import add_bark_material
from forest.gltf.buffer import Blob
from forest.gltf.compress import DEFAULT_PACKING, Packing, glb, pack
from forest.gltf.leaves import LeafMaterials
from forest.gltf.primitive import SkinnedQuads, skinned_primitive
from forest.gltf.skin import TreeSkin, add_tree_skeleton, add_wind, sample_pose
from forest.growth.foliage import FoliageAnchors
from forest.growth.generate import Forest, foliage_or_none
from forest.growth.joint_budget import GAME_JOINTS
from forest.usd.skinned import joint_frames, leaves_mesh, tree_mesh, tree_slices

Progress = Callable[[str, int, int], None]
MAX_VERTICES = 8_000_000  # baked vertices per file (bark and leaves): about 450 MB of GLB


def baked_vertices(forest: Forest) -> int:
    """Vertices the baked meshes will have, counted before baking: 4 per bark quad (every
    quad maps a whole tile, so no quad shares a corner's UV with its neighbour) and every
    leaf spray's own."""
    quads = np.array([len(p.quads) for p in forest.pieces])
    n = int(4 * quads[forest.graph.piece].sum())
    anchors = foliage_or_none(forest)
    if anchors is not None:
        per_model = np.array([len(c.positions) for c in anchors.models()])
        n += int(per_model[anchors.model].sum())
    return n


def check_size(forest: Forest) -> None:
    n = baked_vertices(forest)
    if n > MAX_VERTICES:
        raise LimitError(
            f"{forest.options.trees} trees bake to {n} vertices, over the glTF cap of "
            f"{MAX_VERTICES}; use fewer trees (or USD, which instances the pieces)",
            path="trees",
            limit=MAX_VERTICES,
        )


def bark_quads(
    forest: Forest,
    inst: slice,
    bones: slice,
    to_tree: F64,
    still: F64,
    n_slices: int,
    size: int,
    budget: int | None = None,
) -> SkinnedQuads:
    """The tree's welded bark as the USD skinned form writes it (tree space, bind pose
    ``still``, skinned to the tree's joints ``bones``), each quad's tile as atlas UVs."""
    pts, nrm, quads, jidx, jw, st = tree_mesh(
        forest, inst, bones, to_tree, still, weld=True, budget=budget
    )
    return SkinnedQuads(pts, nrm, quads, jidx, jw, atlas_uv(st, n_slices, size))


def leaf_quads(
    forest: Forest,
    anchors: FoliageAnchors,
    inst: slice,
    bones: slice,
    to_tree: F64,
    still: F64,
    budget: int | None = None,
) -> tuple[SkinnedQuads, F64] | None:
    """The tree's leaf cards as the USD skinned form's Leaves mesh (each vertex on its
    cloud's hub joint, weight 1) and their mean colour; None for a tree without clouds."""
    leaves = leaves_mesh(forest, anchors, inst, bones, to_tree, still, budget)
    if leaves is None:
        return None
    pts, nrm, quads, st, joint, colour = leaves
    # leaf_texture's row 0 is t = 0, as glTF's v = 0 is the image's top row: st as it is
    uv = st.astype(np.float32)[quads]
    mesh = SkinnedQuads(pts, nrm, quads, joint[:, None], np.ones((len(joint), 1)), uv)
    return mesh, colour.astype(np.float64).mean(axis=0)


def forest_gltf(
    forest: Forest,
    tiles: Path | None = None,
    progress: Progress | None = None,
    joint_budget: int | None = GAME_JOINTS,
) -> gl.GLTF2:
    """The forest as a glTF document with its binary blob set. ``tiles``: a tile-set folder
    whose ``bark.<UDIM>.png`` make the atlas, instead of the shipped set of the grammar's
    ``bark``. ``joint_budget``: joints per tree's skin (:mod:`forest.growth.joint_budget`),
    None for one per bone."""
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
    frames = joint_frames(forest, joint_budget)
    pose = sample_pose(forest, frames)
    anchors = foliage_or_none(forest)
    leaf_materials = LeafMaterials(gltf, blob, anchors.family) if anchors is not None else None
    skins: list[tuple[TreeSkin, slice]] = []
    slices_ = tree_slices(forest, joint_budget)
    if progress:
        progress("glTF trees", 0, len(slices_))
    for k, (inst, bones) in enumerate(slices_):
        skin = add_tree_skeleton(gltf, blob, forest, frames, pose, k, inst, bones, joint_budget)
        skins.append((skin, bones))
        n_joints = bones.stop - bones.start
        to_tree = invert_similarity(forest.tree_transforms[k])
        mesh = bark_quads(
            forest, inst, bones, to_tree, frames.still, len(slices), slices.shape[1], joint_budget
        )
        prims = [skinned_primitive(blob, mesh, n_joints, bark)]
        if anchors is not None and leaf_materials is not None:
            leaves = leaf_quads(forest, anchors, inst, bones, to_tree, frames.still, joint_budget)
            if leaves is not None:
                material = leaf_materials.tree_material(k, leaves[1])
                prims.append(skinned_primitive(blob, leaves[0], n_joints, material))
        gltf.meshes.append(gl.Mesh(name=f"Tree_{k:05d}", primitives=prims))
        gltf.nodes.append(
            gl.Node(name=f"Tree_{k:05d}_Mesh", mesh=len(gltf.meshes) - 1, skin=skin.skin)
        )
        gltf.scenes[0].nodes.append(len(gltf.nodes) - 1)
        if progress:
            progress("glTF trees", k + 1, len(slices_))
    add_wind(gltf, blob, pose, skins)
    blob.finish()
    return gltf


def glb_bytes(gltf: gl.GLTF2) -> bytes:
    return glb(gltf)


def write_glb(
    forest: Forest,
    path: str | Path,
    *,
    tiles: Path | None = None,
    progress: Progress | None = None,
    packing: Packing = DEFAULT_PACKING,
) -> Path:
    """Write ``forest`` to ``path`` (.glb) atomically; returns the path. ``packing``: how
    the binary data is stored (:mod:`forest.gltf.compress`)."""
    out = Path(path)
    gltf = pack(forest_gltf(forest, tiles, progress), packing)
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
