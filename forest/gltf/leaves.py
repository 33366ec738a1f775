"""Leaves: a tree's leaf clouds as one alpha-tested (``alphaMode: MASK``, double sided)
primitive of the tree's skinned mesh, every card skinned rigidly (weight 1) to its cloud's hub
joint, exactly as the USD skinned form's ``Leaves`` mesh
(:func:`forest.usd.skinned.leaves_mesh`): the wind moves each card with its branch.

The leaf texture is stored once; in the film profile every tree gets a material tinted by its
clouds' mean colour (a material per cloud colour would split the primitive, and ``COLOR_0`` is
not multiplied in by every importer), in the game profile all trees share one, tinted by the
forest's mean.
"""

from __future__ import annotations

import pygltflib as gl

from forest.geometry.transforms import F64
from forest.gltf.bark import png_bytes
from forest.gltf.buffer import Blob
from forest.growth.foliage import Family, leaf_texture

ALPHA_CUTOFF = 0.5
ROUGHNESS = 0.7


class LeafMaterials:
    """The family's leaf texture, added to the document once, and a tinted material per
    tree reading it."""

    def __init__(self, gltf: gl.GLTF2, blob: Blob, family: Family) -> None:
        self.gltf = gltf
        self.texture = blob.texture(png_bytes(leaf_texture(family)), f"leaf-{family}")

    def tree_material(self, tree: int | None, colour: F64) -> int:
        """A material tinted ``colour`` (linear RGB) for tree ``tree`` (None: one for every
        tree, "Leaves"); its index."""
        self.gltf.materials.append(
            gl.Material(
                name="Leaves" if tree is None else f"Leaves_{tree:05d}",
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
        return len(self.gltf.materials) - 1
