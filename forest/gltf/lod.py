"""The game profile's levels of detail in glTF: per tree one node per level, each a skinned
mesh on the tree's one skin, chained with the ``MSFT_lod`` extension.

* ``Tree_<k>_LOD0``: in the scene, the most detailed level (:data:`forest.lod.select.GAME_LOD0`:
  the full tree, or without its thinnest pieces where that is over a game's budget), with
  ``extensions.MSFT_lod.ids`` naming the other levels' nodes and
  ``extras.MSFT_screencoverage`` the screen fraction down to which each level shows.
* ``Tree_<k>_LOD1``, ``_LOD2``: :func:`forest.lod.levels.tree_levels`' levels (fewer pieces,
  fewer or crown cards), every kept bark vertex LOD0's with LOD0's joints and weights: their
  bark primitives read LOD0's bark accessors through index buffers of their own.
* ``Tree_<k>_LOD3``: the impostor's crossed card pair (:mod:`forest.lod.impostor`, baked with
  the render extra's GL; left out where there is none), bound to the root joint.

As ``MSFT_lod`` asks, the lower levels' nodes are in no scene: a reader without the extension
shows LOD0 only, and each level's node and mesh (named alike) stays usable on its own.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import pygltflib as gl
from numpy.typing import NDArray

from forest.geometry.transforms import F64
from forest.gltf.bark import png_bytes
from forest.gltf.buffer import Blob
from forest.gltf.primitive import SkinnedQuads, VertexSet, skinned_primitive
from forest.lod.select import BarkMesh, LeavesMesh

if TYPE_CHECKING:
    from forest.lod.impostor import Impostor

MSFT_LOD = "MSFT_lod"
SCREEN_COVERAGE = "MSFT_screencoverage"
# the screen fraction (of the viewport's height the tree's bounds cover) down to which each
# level shows; below the last, nothing. A level's triangles drop about 4-5x per step, so it
# takes over when the tree is about half as tall on screen
COVERAGE = (0.4, 0.15, 0.04, 0.004)
IMPOSTOR_ROUGHNESS = 0.8
IMPOSTOR_LEVEL = 3  # the card pair: after the levels made of pieces
# a card's four vertices: 16,383 cards are the most whose vertices a 16-bit index reaches
# (65,535 is the primitive restart value)
CARDS_PER_PRIMITIVE = 65535 // 4


def lod_name(tree: int, level: int) -> str:
    """A level's node and mesh name."""
    return f"Tree_{tree:05d}_LOD{level}"


def bark_quads(bark: BarkMesh, uv: NDArray[np.float32], colour: F64 | None = None) -> SkinnedQuads:
    """A level's bark with its corners' glTF ``uv`` (q, 4, 2): atlas UVs of its UDIM st
    (:func:`forest.bark.atlas.atlas_uv`, film) or its lattice on the repeating bark picture
    (:func:`forest.bark.lattice.lattice_uv`, game); ``colour`` (v, 3): each vertex's tint."""
    return SkinnedQuads(
        bark.points, bark.normals, bark.quads, bark.joints, bark.weights, uv, colour
    )


def leaf_quads(leaves: LeavesMesh, *, flat: bool = False) -> SkinnedQuads:
    """A level's leaf cards, each vertex on its joint with weight 1 (the leaf picture's row 0
    is t = 0, as glTF's v = 0 is the image's top row: st as it is). ``flat``: without
    normals (a card is flat, so a reader's own face normal is the card's)."""
    uv = leaves.st.astype(np.float32)[leaves.quads]
    one = np.ones((len(leaves.joint), 1))
    normals = None if flat else leaves.normals
    return SkinnedQuads(leaves.points, normals, leaves.quads, leaves.joint[:, None], one, uv)


def leaf_chunks(leaves: LeavesMesh, *, flat: bool = False) -> list[SkinnedQuads]:
    """:func:`leaf_quads` in runs of at most :data:`CARDS_PER_PRIMITIVE` cards, so every
    primitive indexes its vertices with 16 bits (half the index bytes of one big one)."""
    whole = leaf_quads(leaves, flat=flat)
    out = []
    for start in range(0, len(leaves.quads), CARDS_PER_PRIMITIVE):
        quads = leaves.quads[start : start + CARDS_PER_PRIMITIVE]
        used = np.unique(quads)
        index = np.full(len(leaves.points), -1, np.int64)
        index[used] = np.arange(len(used))
        out.append(
            SkinnedQuads(
                whole.points[used],
                None if whole.normals is None else whole.normals[used],
                index[quads],
                whole.joints[used],
                whole.weights[used],
                whole.uv[start : start + CARDS_PER_PRIMITIVE],
            )
        )
    return out


@dataclass(frozen=True)
class ImpostorSheet:
    """Every tree's impostor card picture in one grid (``columns`` wide), so one material
    serves them all: cell ``k`` holds tree k's pair of views."""

    columns: int
    rows: int

    @classmethod
    def of(cls, trees: int) -> ImpostorSheet:
        columns = max(1, int(np.ceil(np.sqrt(trees))))
        return cls(columns, max(1, -(-trees // columns)))

    def picture(self, cards: list[NDArray[np.uint8]]) -> NDArray[np.uint8]:
        h, w = cards[0].shape[:2]
        sheet = np.zeros((self.rows * h, self.columns * w, 4), np.uint8)
        for k, c in enumerate(cards):
            r, col = divmod(k, self.columns)
            sheet[r * h : (r + 1) * h, col * w : (col + 1) * w] = c
        return sheet

    def uv(self, tree: int, st: F64) -> F64:
        """Card st (s across the pair's picture, t up from its bottom) as glTF UVs in the
        sheet (v = 0 its top row)."""
        r, col = divmod(tree, self.columns)
        return np.stack([(col + st[:, 0]) / self.columns, (r + 1.0 - st[:, 1]) / self.rows], 1)


def add_impostor_material(gltf: gl.GLTF2, blob: Blob, sheet: NDArray[np.uint8]) -> int:
    """The impostors' material: the card sheet as base colour, cut by its alpha."""
    texture = blob.texture(png_bytes(sheet), "impostor-cards")
    gltf.materials.append(
        gl.Material(
            name="Impostor",
            pbrMetallicRoughness=gl.PbrMetallicRoughness(
                baseColorTexture=gl.TextureInfo(index=texture),
                metallicFactor=0.0,
                roughnessFactor=IMPOSTOR_ROUGHNESS,
            ),
            alphaMode=gl.MASK,
            alphaCutoff=0.5,
            doubleSided=True,
        )
    )
    return len(gltf.materials) - 1


def impostor_quads(imp: Impostor, sheet: ImpostorSheet, tree: int) -> SkinnedQuads:
    """The tree's card pair on its root joint (joint 0, weight 1: the cards stand still)."""
    from forest.lod.impostor import card_pair

    pts, nrm, quads, st = card_pair(imp)
    uv = sheet.uv(tree, st).astype(np.float32)[quads]
    zero = np.zeros((len(pts), 1), np.int64)
    return SkinnedQuads(pts, nrm, quads, zero, np.ones((len(pts), 1)), uv)


def add_levels(
    gltf: gl.GLTF2,
    blob: Blob,
    tree: int,
    first: int,
    skin: int,
    n_joints: int,
    levels: list[list[tuple[SkinnedQuads, int]]],
) -> list[int]:
    """Tree ``tree``'s level nodes and meshes from level ``first`` on (``levels``: per level
    its (quads, material) primitives, most detailed first) on ``skin``; LOD0's node joins
    the default scene. Returns the nodes."""
    nodes = []
    # the bark of a lower level is some of the first level's vertices: their accessors are
    # shared (a reader uploads them once; Blender keeps only the vertices a level draws)
    shared: dict[int, VertexSet] = {}
    for level, prims in enumerate(levels, first):
        primitives = []
        for n, (q, m) in enumerate(prims):
            base = shared.get(m) if n == 0 else None
            prim, vertices = skinned_primitive(
                blob, q, n_joints, m, base=base, share=level == first and n == 0
            )
            if vertices is not None:
                shared.setdefault(m, vertices)
            primitives.append(prim)
        gltf.meshes.append(gl.Mesh(name=lod_name(tree, level), primitives=primitives))
        gltf.nodes.append(gl.Node(name=lod_name(tree, level), mesh=len(gltf.meshes) - 1, skin=skin))
        nodes.append(len(gltf.nodes) - 1)
        if level == 0:
            gltf.scenes[0].nodes.append(nodes[-1])
    return nodes


def chain_levels(gltf: gl.GLTF2, nodes: list[int]) -> None:
    """LOD0's node ``nodes[0]`` names the lower levels' ``nodes[1:]`` with ``MSFT_lod`` and
    the screen coverage down to which each shows (``extras``, as the extension's own
    examples); the extension is used, not required (a reader without it shows LOD0)."""
    if len(nodes) < 2:
        return
    lod0 = gltf.nodes[nodes[0]]
    lod0.extensions = {MSFT_LOD: {"ids": nodes[1:]}}
    lod0.extras = {SCREEN_COVERAGE: list(COVERAGE[: len(nodes)])}
    if MSFT_LOD not in gltf.extensionsUsed:
        gltf.extensionsUsed.append(MSFT_LOD)
