"""Leaf clouds as alpha-tested cards (``alphaMode: MASK``, double sided) that follow their hub
joints: each cloud is a child node of the joint its piece's hub bone became, so the wind
moves it with its branch.

The cloud models of the forest's leaf family (:func:`forest.growth.foliage.cloud_models`) are
stored once; every tree gets a material tinted by its clouds' mean colour (glTF has no
per-instance colour in core) and one mesh per model it uses, sharing the model's accessors.
At rest a cloud stands where the USD instancer puts it (the hub's rest point on the piece),
turned by its yaw about the world's vertical, scaled to its diameter; posed and in the wind
it turns with its joint.
"""

from __future__ import annotations

import numpy as np
import pygltflib as gl
from numpy.typing import NDArray

from forest.geometry.transforms import F64, compose_similarity
from forest.gltf.bark import png_bytes
from forest.gltf.buffer import Blob
from forest.gltf.skin import Pose, TreeSkin, trs
from forest.growth.foliage import FoliageAnchors, leaf_texture, yaw_quaternions
from forest.growth.generate import Forest
from forest.usd.skinned import dcc_joints

ALPHA_CUTOFF = 0.5
ROUGHNESS = 0.7


class LeafLibrary:
    """The family's cloud models (accessors) and leaf texture, added to ``gltf`` once."""

    def __init__(self, gltf: gl.GLTF2, blob: Blob, anchors: FoliageAnchors) -> None:
        self.gltf = gltf
        models = anchors.models()
        self.texture = blob.texture(
            png_bytes(leaf_texture(anchors.family)), f"leaf-{anchors.family}"
        )
        self.attributes: list[gl.Attributes] = []
        self.indices: list[int] = []
        for cloud in models:
            self.attributes.append(
                gl.Attributes(
                    POSITION=blob.accessor(
                        cloud.positions.astype(np.float32), gl.ARRAY_BUFFER, bounds=True
                    ),
                    NORMAL=blob.accessor(cloud.normals.astype(np.float32), gl.ARRAY_BUFFER),
                    # leaf_texture's row 0 is t = 0, as glTF's v = 0 is the image's top row
                    TEXCOORD_0=blob.accessor(cloud.st.astype(np.float32), gl.ARRAY_BUFFER),
                )
            )
            tris = cloud.triangles().astype(
                np.uint16 if len(cloud.positions) < 65536 else np.uint32
            )
            self.indices.append(blob.accessor(tris.ravel(), gl.ELEMENT_ARRAY_BUFFER))

    def tree_meshes(self, tree: int, colour: F64, models: set[int]) -> dict[int, int]:
        """A material tinted ``colour`` (linear RGB) and one mesh per model in ``models``;
        model -> mesh index."""
        self.gltf.materials.append(
            gl.Material(
                name=f"Leaves_{tree:05d}",
                pbrMetallicRoughness=gl.PbrMetallicRoughness(
                    baseColorFactor=[*(float(c) for c in colour), 1.0],
                    baseColorTexture=gl.TextureInfo(index=self.texture),
                    metallicFactor=0.0,
                    roughnessFactor=ROUGHNESS,
                ),
                alphaMode=gl.MASK,
                alphaCutoff=ALPHA_CUTOFF,
                doubleSided=True,
            )
        )
        material = len(self.gltf.materials) - 1
        out = {}
        for m in sorted(models):
            prim = gl.Primitive(
                attributes=self.attributes[m], indices=self.indices[m], material=material
            )
            self.gltf.meshes.append(gl.Mesh(name=f"LeafCloud{m}_{tree:05d}", primitives=[prim]))
            out[m] = len(self.gltf.meshes) - 1
        return out


def cloud_locals(forest: Forest, anchors: FoliageAnchors, joint_world: F64, time: float) -> F64:
    """``(k, 4, 4)`` each cloud's transform relative to its joint, whose world frame at the
    first sample (as the file's node hierarchy states it) is ``joint_world`` ``(k, 4, 4)``:
    there the cloud sits at its posed centre, turned by its yaw, at its diameter; later it
    moves rigidly with the joint."""
    centre = anchors.positions(forest.palette(time if forest.animated else None))
    q = yaw_quaternions(anchors.yaw)
    world = compose_similarity(centre, q, anchors.size)
    return np.linalg.inv(joint_world) @ world


def joint_worlds(tree_transform: F64, parent: NDArray[np.intp], pose: F64) -> F64:
    """``(j, 4, 4)`` world frames of a tree's joints from their local frames ``pose``
    ``(j, 4, 4)`` (parent-first; ``parent`` -1 for the root, under the tree's node)."""
    out = np.empty_like(pose)
    for j in range(len(pose)):  # parent-first: each parent is done before its children
        out[j] = (tree_transform if parent[j] < 0 else out[parent[j]]) @ pose[j]
    return out


def add_tree_clouds(
    gltf: gl.GLTF2,
    library: LeafLibrary,
    forest: Forest,
    anchors: FoliageAnchors,
    pick: np.ndarray,
    tree: int,
    skin: TreeSkin,
    bones: slice,
    pose: Pose,
    budget: int | None = None,
) -> None:
    """The clouds ``pick`` (indices into ``anchors``) of one tree as child nodes of their
    hubs' joints (of the joint ``budget``, as ``skin``)."""
    if len(pick) == 0:
        return
    colour = anchors.color[pick].astype(np.float64).mean(axis=0)
    meshes = library.tree_meshes(tree, colour, {int(m) for m in anchors.model[pick]})
    dcc = dcc_joints(forest, budget)
    joint = dcc.of_bone[anchors.bone[pick]] - bones.start
    # the joints' world frames at the first sample: the nodes' own TRS composed down the tree
    s = pose.s[0, bones]
    s = s[:, 0] if s.ndim == 2 else s  # a uniform scale stored as glTF's three
    local = compose_similarity(pose.t[0, bones], pose.q[0, bones], s)
    parent = (dcc.parent[bones] - bones.start).astype(np.intp)
    world = joint_worlds(forest.tree_transforms[tree], parent, local)[joint]
    sub = anchors.select(pick)
    time = float(pose.times[0]) if pose.times is not None else 0.0
    local = cloud_locals(forest, sub, world, time)
    for c in range(len(pick)):
        node = gl.Node(
            name=f"Leaves_{int(pick[c])}", mesh=meshes[int(sub.model[c])], **trs(local[c])
        )
        gltf.nodes.append(node)
        gltf.nodes[skin.nodes[int(joint[c])]].children.append(len(gltf.nodes) - 1)
