"""Shared by the glTF tests: a small animated forest, the library's own skinning of its trees
in the order of the GLB's vertices (the pieces' quad corners and the leaf cards, each moved by
the generator's palette), a reader of the GLB's own skinning, and the Node tools."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pygltflib as gl
from helpers_skin import cut_palette, skin_forest

from forest.geometry.transforms import compose_similarity, invert_similarity
from forest.growth.generate import Forest, ForestOptions, foliage_or_none, generate_forest
from forest.growth.joint_budget import GAME_JOINTS
from forest.growth.presets import load_preset
from forest.usd.skinned import dcc_joints, joint_frames, leaves_mesh, tree_slices

ROOT = Path(__file__).resolve().parents[1]
NODE_DIR = ROOT / "tests" / "node"
TREES, FRAMES, FPS = 2, 6, 24.0
CHECK_FRAMES = (0, 3)  # the two frames whose skinned vertices the consumers must reproduce
# the game profile's LOD0 budget for the small forest's files: over its trees' triangles, so
# LOD0 is the whole tree the expectations below are made of
WHOLE_LOD0 = 1_000_000


def small_forest(frames: int = FRAMES) -> Forest:
    return generate_forest(
        load_preset("almond"), 3, ForestOptions(trees=TREES, frames=frames, fps=FPS)
    )


def expected_bark(forest: Forest, time: float | None) -> list[np.ndarray]:
    """Per tree ``(4 q, 3)``: every quad corner of the tree's pieces skinned with the forest's
    palette at ``time`` as the skins' joints (GAME_JOINTS per tree) carry it (world space,
    y up), in the order the GLB's bark mesh holds them."""
    pos, _ = skin_forest(forest, cut_palette(forest, forest.palette(time), GAME_JOINTS))
    out = []
    for inst, _bones in tree_slices(forest):
        points, quads, base = [], [], 0
        for i in range(inst.start, inst.stop):
            piece = forest.pieces[forest.graph.piece[i]]
            points.append(pos[i])
            quads.append(piece.quads + base)
            base += len(piece.positions)
        out.append(np.concatenate(points)[np.concatenate(quads).ravel()])
    return out


_DTYPE: dict[int, type[np.generic]] = {
    gl.FLOAT: np.float32,
    gl.UNSIGNED_INT: np.uint32,
    gl.UNSIGNED_SHORT: np.uint16,
    gl.UNSIGNED_BYTE: np.uint8,
    gl.SHORT: np.int16,
    gl.BYTE: np.int8,
}


def read(doc: gl.GLTF2, accessor: int) -> np.ndarray:
    """An accessor's data ``(n,)`` or ``(n, c)`` as stored (normalised integers as fractions;
    a strided view's rows read at its stride)."""
    acc = doc.accessors[accessor]
    view = doc.bufferViews[acc.bufferView]
    dtype = _DTYPE[acc.componentType]
    width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}[acc.type]
    start = (view.byteOffset or 0) + (acc.byteOffset or 0)
    item = np.dtype(dtype).itemsize
    stride = view.byteStride or item * width  # quantized vec3 rows are padded to 4 bytes
    a = np.ndarray((acc.count, width), dtype, doc.binary_blob(), start, (stride, item)).copy()
    a = a if width > 1 else a.ravel()
    if acc.normalized:
        return a.astype(np.float64) / np.iinfo(dtype).max
    return a


def quad_corners(doc: gl.GLTF2, prim: gl.Primitive) -> np.ndarray:
    """``(q * 4,)`` the vertex of every quad corner of a primitive written as two triangles
    per quad (0 1 2, 0 2 3)."""
    return read(doc, prim.indices).reshape(-1, 6)[:, [0, 1, 2, 5]].ravel().astype(np.intp)


def gl_count(doc: gl.GLTF2, prim: gl.Primitive) -> int:
    """A primitive's vertex count."""
    return int(doc.accessors[prim.attributes.POSITION].count)


def tree_mesh_nodes(doc: gl.GLTF2) -> list[int]:
    """Each tree's most detailed skinned node, in tree order: the scene's skinned roots (the
    film profile's ``Tree_<k>_Mesh``, the game profile's ``Tree_<k>_LOD0``; a game tree's
    lower levels are in no scene)."""
    return [i for i in doc.scenes[0].nodes if doc.nodes[i].skin is not None]


def expected_tree(forest: Forest, doc: gl.GLTF2, time: float | None) -> list[list[np.ndarray]]:
    """Per tree, per primitive of its mesh (bark, then leaves: one primitive, or the game
    profile's runs of :data:`forest.gltf.lod.CARDS_PER_PRIMITIVE` cards): ``(n, 3)`` the
    library's own skinning at ``time`` of each of the GLB's vertices (world space, y up).
    Bark: the pieces' quad corners (:func:`expected_bark`), each at the vertex the file's
    indices give it; leaves: the cards as the USD Leaves mesh stands, moved rigidly with
    their hub bone."""
    bark = expected_bark(forest, time)
    pal = forest.palette(time)
    still = joint_frames(forest).still
    anchors = foliage_or_none(forest)
    dcc = dcc_joints(forest, GAME_JOINTS)
    out = []
    nodes = tree_mesh_nodes(doc)
    for k, (inst, bones) in enumerate(tree_slices(forest, GAME_JOINTS)):
        mesh = doc.meshes[doc.nodes[nodes[k]].mesh]
        corners = quad_corners(doc, mesh.primitives[0])
        want = np.empty((int(corners.max()) + 1, 3))
        want[corners] = bark[k]
        prims = [want]
        if anchors is not None and len(mesh.primitives) > 1:
            to_tree = invert_similarity(forest.tree_transforms[k])
            leaves = leaves_mesh(forest, anchors, inst, bones, to_tree, still, GAME_JOINTS)
            assert leaves is not None
            pts, joint = leaves[0], leaves[4]
            bone = dcc.bone[joint + bones.start]
            # the hub's kept joint's motion from the standing tree (still) to ``time``
            move = pal[bone] @ np.linalg.inv(still[bone]) @ forest.tree_transforms[k]
            cards = np.einsum("vij,vj->vi", move[:, :3, :3], pts) + move[:, :3, 3]
            runs = np.cumsum([gl_count(doc, p) for p in mesh.primitives[1:]])[:-1]
            prims += np.split(cards, runs)
        out.append(prims)
    return out


def glb_skinned(doc: gl.GLTF2, mesh_node: int, frame: int) -> list[np.ndarray]:
    """Per primitive of the node's mesh ``(n, 3)``: its vertices as glTF skins them at key
    ``frame`` of the first animation (each node's own TRS where no channel targets it)."""
    t = {i: np.array(n.translation or [0.0] * 3) for i, n in enumerate(doc.nodes)}
    q = {i: np.array(n.rotation or [0.0, 0.0, 0.0, 1.0]) for i, n in enumerate(doc.nodes)}
    s = {i: np.array(n.scale or [1.0] * 3) for i, n in enumerate(doc.nodes)}
    for anim in doc.animations[:1]:
        for ch in anim.channels:
            keys = read(doc, anim.samplers[ch.sampler].output)
            {"translation": t, "rotation": q, "scale": s}[ch.target.path][ch.target.node] = keys[
                frame
            ]
    parent = {c: i for i, n in enumerate(doc.nodes) for c in (n.children or [])}
    n = len(doc.nodes)
    local = compose_similarity(
        np.array([t[i] for i in range(n)]),
        np.array([q[i] for i in range(n)]),
        np.array([s[i][0] for i in range(n)]),
    )
    done: dict[int, np.ndarray] = {}

    def world(i: int) -> np.ndarray:
        if i not in done:
            done[i] = local[i] if i not in parent else world(parent[i]) @ local[i]
        return done[i]

    node = doc.nodes[mesh_node]
    skin = doc.skins[node.skin]
    ibm = read(doc, skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
    joints = np.array([world(j) for j in skin.joints]) @ ibm
    out = []
    for prim in doc.meshes[node.mesh].primitives:
        p = read(doc, prim.attributes.POSITION).astype(np.float64)
        j = read(doc, prim.attributes.JOINTS_0).astype(np.intp)
        w = read(doc, prim.attributes.WEIGHTS_0).astype(np.float64)
        m = np.einsum("vk,vkab->vab", w, joints[j])
        out.append(np.einsum("vab,vb->va", m[:, :3, :3], p) + m[:, :3, 3])
    return out


def tree_heights(expected: list[np.ndarray]) -> list[float]:
    return [float(p[:, 1].max() - p[:, 1].min()) for p in expected]


def node_tools() -> str | None:
    """Why the Node tools cannot run, or None when they can."""
    if shutil.which("node") is None:
        return "node is not installed (the CI script installs nodejs and npm)"
    if not (NODE_DIR / "node_modules" / "gltf-validator").is_dir():
        return "tests/node/node_modules is missing: run `npm ci` in tests/node (.ci/run does)"
    return None


def run_node(script: str, *args: str) -> dict[str, Any]:
    proc = subprocess.run(
        ["node", str(NODE_DIR / script), *args],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=NODE_DIR,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    result: dict[str, Any] = json.loads(proc.stdout)
    return result
