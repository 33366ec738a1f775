"""Each tree's skeleton as glTF joint nodes, a skin (inverse bind matrices) and the wind as
animation channels (translation, rotation and scale of every joint whose keys change, time in
seconds).

The joints are those of the USD skinned form (:func:`forest.usd.skinned.joint_frames`): no
scale in their frames, parent-first, the tree's root joint at identity under the tree's node,
which carries the tree transform.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pygltflib as gl
from numpy.typing import NDArray

from forest.geometry.transforms import F64, decompose_similarity, invert_similarity
from forest.gltf.buffer import Blob
from forest.growth.generate import Forest
from forest.usd.skinned import JointFrames, JointTQS, joint_paths


@dataclass(frozen=True)
class Pose:
    """Unscaled joint locals of every bone at each sample: translations ``(f, b, 3)``,
    xyzw rotations ``(f, b, 4)`` (signs continuous along f, so linear keys never take the
    long way), scales ``(f, b, 3)``, all float32; ``times`` ``(f,)`` float32 seconds, or
    None for a still forest (one posed sample, no animation)."""

    t: NDArray[np.float32]
    q: NDArray[np.float32]
    s: NDArray[np.float32]
    times: NDArray[np.float32] | None


def sample_pose(forest: Forest, frames: JointFrames) -> Pose:
    samples: list[JointTQS] = [
        frames.unscaled(frames.locals(forest, t)) for t in forest.frame_times()
    ]
    t = np.stack([x[0] for x in samples]).astype(np.float32)
    q = np.stack([x[1] for x in samples]).astype(np.float64)
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    # flip each key onto the hemisphere of the one before it (q and -q are one rotation)
    flip = np.ones(q.shape[:2])
    flip[1:] = np.where(np.einsum("fbi,fbi->fb", q[1:], q[:-1]) < 0, -1.0, 1.0)
    q *= np.cumprod(flip, axis=0)[..., None]
    s = np.stack([x[2] for x in samples]).astype(np.float32)
    times = None
    if forest.animated:
        times = (np.arange(forest.options.frames) / forest.options.fps).astype(np.float32)
    return Pose(t, q.astype(np.float32), s, times)


def similarity_trs(m: F64) -> list[dict[str, list[float]]]:
    """Similarities ``(n, 4, 4)`` as nodes' translation / rotation / scale (identity parts
    left out, as glTF's defaults), decomposed in one call (a forest's trees at once)."""
    t, q, s = decompose_similarity(m)
    # each row normalised by its own norm call: the batched norm sums in another order, and
    # the written floats stay those of before
    q = q / np.array([np.linalg.norm(r) for r in q])[:, None]
    has_t = np.any(t != 0, axis=1)
    has_r = ~np.all(np.isclose(q, (0, 0, 0, 1), rtol=0, atol=1e-12), axis=1)
    has_s = np.abs(s - 1.0) > 1e-12
    return _parts(t, q, np.repeat(s[:, None], 3, axis=1), has_t, has_r, has_s)


def _parts(
    t: NDArray[np.floating],
    q: NDArray[np.floating],
    s: NDArray[np.floating],
    has_t: NDArray[np.bool_],
    has_r: NDArray[np.bool_],
    has_s: NDArray[np.bool_],
) -> list[dict[str, list[float]]]:
    """Per row, the TRS parts flagged (as Python floats: ``tolist`` gives each float32 or
    float64 value exactly, as ``float`` did one at a time)."""
    out: list[dict[str, list[float]]] = []
    columns = (t, q, s, has_t, has_r, has_s)
    rows = zip(*(c.tolist() for c in columns), strict=True)
    for tv, qv, sv, ht, hr, hs in rows:
        node: dict[str, list[float]] = {}
        if ht:
            node["translation"] = tv
        if hr:
            node["rotation"] = qv
        if hs:
            node["scale"] = sv
        out.append(node)
    return out


def rest_trs(pose: Pose) -> list[dict[str, list[float]]]:
    """Every bone's joint node TRS at the pose's first sample (the rest of a still forest),
    without the identity parts: one vectorised pass per forest, not a numpy test per joint."""
    t, q, s = pose.t[0], pose.q[0], pose.s[0]
    has_t = np.any(t != 0, axis=1)
    has_r = np.any(q[:, :3] != 0, axis=1) | (q[:, 3] != 1)
    has_s = np.any(s != 1, axis=1)
    return _parts(t, q, s, has_t, has_r, has_s)


@dataclass(frozen=True)
class TreeSkin:
    """One tree's skin: ``nodes`` the joint node indices (parent-first, in the tree's bone
    order), ``skin`` its index in ``skins``, ``inverse_binds`` ``(j, 4, 4)`` float64."""

    nodes: list[int]
    skin: int
    inverse_binds: F64


def add_tree_skeleton(
    gltf: gl.GLTF2,
    blob: Blob,
    forest: Forest,
    frames: JointFrames,
    tree: int,
    inst: slice,
    bones: slice,
    budget: int | None = None,
    *,
    tree_trs: dict[str, list[float]],
    joint_trs: list[dict[str, list[float]]],
) -> TreeSkin:
    """The tree's node (tree transform) with its joint hierarchy under it, posed at the first
    sample, and its skin (``frames`` and ``bones`` of the joint ``budget``). Appends the tree
    node to the default scene. ``tree_trs`` (the tree's :func:`similarity_trs`) and
    ``joint_trs`` (:func:`rest_trs` of the pose): made once per forest, in one call each."""
    names = [p.rsplit("/", 1)[-1] for p in joint_paths(forest, inst, bones, budget)]
    parent = (frames.joints.parent[bones] - bones.start).tolist()
    first = len(gltf.nodes)
    tree_node = gl.Node(name=f"Tree_{tree:05d}", **tree_trs)
    nodes = list(range(first + 1, first + 1 + len(names)))
    joint_nodes = [gl.Node(name=name, **joint_trs[bones.start + j]) for j, name in enumerate(names)]
    for j, p in enumerate(parent):  # parent-first: a joint's host is made before it
        (tree_node if p < 0 else joint_nodes[p]).children.append(nodes[j])
    gltf.nodes.append(tree_node)
    gltf.nodes.extend(joint_nodes)
    gltf.scenes[0].nodes.append(first)
    inverse = invert_similarity(frames.binds[bones])
    ibm = blob.accessor(inverse.astype(np.float32))
    gltf.skins.append(
        gl.Skin(name=f"Tree_{tree:05d}", inverseBindMatrices=ibm, joints=nodes, skeleton=nodes[0])
    )
    return TreeSkin(nodes, len(gltf.skins) - 1, inverse)


# a joint's path is constant when no key leaves frame 0's by more than this (metres, unit
# quaternion components, scale factors): below float32's step at a tree's size (about 1e-6
# at 10 m), so the node's own TRS (frame 0) stands for every key
CONSTANT_TOL = 1e-6


def varying(keys: NDArray[np.float32]) -> NDArray[np.bool_]:
    """``(b,)`` which joints' keys ``(f, b, c)`` change over the clip (beyond
    :data:`CONSTANT_TOL`)."""
    return np.abs(keys - keys[:1]).max(axis=(0, 2)) > CONSTANT_TOL


def add_wind(gltf: gl.GLTF2, blob: Blob, pose: Pose, skins: list[tuple[TreeSkin, slice]]) -> None:
    """One animation "Wind": a LINEAR sampler per joint and path whose keys change, all
    reading one time accessor; a constant path gets no channel (its node keeps frame 0's
    value, which is every frame's). Each path's kept keys lie in one buffer view
    (joint-major)."""
    if pose.times is None:
        return
    times = blob.accessor(pose.times, bounds=True)
    # one "Wind" for a whole file: a mixed forest's layers add their channels to it
    found = [a for a in gltf.animations if a.name == "Wind"]
    anim = found[0] if found else gl.Animation(name="Wind")
    f = len(pose.times)
    # (global bone, its node) of every joint of every tree, in file order
    bone = np.concatenate([np.arange(b.start, b.stop) for _, b in skins]).astype(np.intp)
    node = [n for s, _ in skins for n in s.nodes]
    for path, keys in (("translation", pose.t), ("rotation", pose.q), ("scale", pose.s)):
        kept = np.flatnonzero(varying(keys[:, bone]))
        if not len(kept):
            continue
        joint_major = np.ascontiguousarray(np.swapaxes(keys[:, bone[kept]], 0, 1))  # (k, f, c)
        view = blob.view(joint_major.tobytes())
        per_joint = f * keys.shape[2] * 4
        for i, j in enumerate(kept):
            out = blob.accessor(joint_major[i], view=view, offset=i * per_joint)
            anim.samplers.append(gl.AnimationSampler(input=times, output=out))
            anim.channels.append(
                gl.AnimationChannel(
                    sampler=len(anim.samplers) - 1,
                    target=gl.AnimationChannelTarget(node=node[int(j)], path=path),
                )
            )
    if anim.channels and not found:  # glTF asks for at least one channel
        gltf.animations.append(anim)
