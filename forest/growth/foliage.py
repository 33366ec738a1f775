"""Foliage (paper 6): the leaf-cloud model built in code, its procedural leaf texture, and the
anchors that tie each cloud to the bone of the piece it sits on.

The leaf cloud is one small mesh of leaf cards (rhombus quads, double sided) scattered in a
ball of unit diameter about the origin; every foliage instance shows the same cloud, scaled by
its size (a diameter in metres) and unrotated, so a renderer can draw it as 2.5D impostors: one
picture of the cloud per view direction, on camera-facing billboards.

An anchor is a point in a piece's model space (the hub joint) and the palette entry of that
piece's hub bone; the cloud's centre at any frame is that palette matrix applied to the rest
point, so foliage follows the wind with its branch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from forest.geometry.pieces import HUB
from forest.geometry.transforms import F64

LEAVES = 256
LEAF_LENGTH = 0.2  # of the cloud's diameter
LEAF_WIDTH = 0.12
LEAF_SEED = 6
TEXTURE_SIZE = 128
CLOUD_RADII = 7.0  # a cloud's diameter in radii of the piece it sits on (its scale)
# corners of a leaf card in its own (across, along) frame, and their st: base, right, tip, left
CARD = np.array([[0.0, 0.0], [0.5, 0.4], [0.0, 1.0], [-0.5, 0.4]])
CARD_ST = np.array([[0.5, 0.0], [1.0, 0.4], [0.5, 1.0], [0.0, 0.4]])
LEAF_GREEN = (0.22, 0.42, 0.13)


@dataclass(frozen=True, eq=False)
class LeafCloud:
    """positions, normals : (4 c, 3)   st : (4 c, 2)   quads : (c, 4) int32 (one card each).

    Each card owns its four vertices (flat normal); the ball's radius is ``radius``."""

    positions: F64
    normals: F64
    st: F64
    quads: NDArray[np.int32]

    @property
    def n_cards(self) -> int:
        return len(self.quads)

    @property
    def radius(self) -> float:
        """Largest distance of a vertex from the centre (the billboard's half size)."""
        return float(np.linalg.norm(self.positions, axis=1).max())

    def triangles(self) -> NDArray[np.int32]:
        """``(2 c, 3)`` the cards split along their base-tip diagonal."""
        q = self.quads
        return np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]]).astype(np.int32)


def leaf_cloud(
    leaves: int = LEAVES,
    seed: int = LEAF_SEED,
    length: float = LEAF_LENGTH,
    width: float = LEAF_WIDTH,
) -> LeafCloud:
    """A ball of ``leaves`` cards of unit diameter: stems point roughly outwards (leaves grow
    from the twigs inside towards the light), denser near the surface, so the silhouette reads
    as a clumpy cloud and the inside is mostly hidden."""
    rng = np.random.default_rng(seed)
    outer = 0.5 - length  # card bases stay inside, so tips stay inside the unit ball
    d = rng.normal(size=(leaves, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    r = outer * rng.random(leaves) ** 0.35
    base = d * r[:, None]
    # the stem direction: outwards with a random tilt, the blade turned about it at random
    along = d + 0.6 * rng.normal(size=(leaves, 3))
    along /= np.linalg.norm(along, axis=1, keepdims=True)
    helper = rng.normal(size=(leaves, 3))
    across = np.cross(along, helper)
    across /= np.linalg.norm(across, axis=1, keepdims=True)
    normal = np.cross(across, along)
    pos = (
        base[:, None]
        + CARD[None, :, 0:1] * width * across[:, None]
        + CARD[None, :, 1:2] * length * along[:, None]
    )
    quads = np.arange(4 * leaves, dtype=np.int32).reshape(leaves, 4)
    return LeafCloud(
        positions=pos.reshape(-1, 3),
        normals=np.repeat(normal, 4, axis=0),
        st=np.tile(CARD_ST, (leaves, 1)),
        quads=quads,
    )


def leaf_texture(size: int = TEXTURE_SIZE) -> NDArray[np.uint8]:
    """``(size, size, 4)`` RGBA (row 0 is t = 0, the stem end): a leaf blade with a midrib and
    side veins, in sRGB, with alpha 255 on the blade and 0 around it. Made from code, so
    nothing of unclear origin ships and any worker can rebuild it."""
    t = (np.arange(size) + 0.5) / size
    s, tt = np.meshgrid(t, t)  # s across (column), t along (row)
    x = (s - 0.5) * 2.0  # -1..1 across
    # blade half width along the leaf: zero at the stem and the tip, widest at 40 %
    rise, fall = np.sin(np.pi * 0.5 * tt / 0.4), np.cos(np.pi * 0.5 * (tt - 0.4) / 0.6)
    half = np.where(tt < 0.4, rise, fall)
    half = 0.95 * np.clip(half, 0, 1) ** 0.8 * np.clip((tt - 0.04) / 0.06, 0, 1)
    half *= np.clip((0.985 - tt) / 0.05, 0, 1)  # a pointed tip
    blade = np.abs(x) <= half
    rib = np.abs(x) < 0.045
    vein_phase = (tt - 0.55 * np.abs(x)) * 9.0
    veins = (np.abs(vein_phase - np.round(vein_phase)) < 0.07) & (tt > 0.1)
    shade = 0.85 + 0.3 * (1 - np.abs(x)) * np.clip(tt * 1.5, 0, 1)
    rng = np.random.default_rng(size)
    mottle = 1.0 + 0.06 * rng.standard_normal((size, size))
    base = np.array(LEAF_GREEN)
    rgb = base[None, None] * (shade * mottle)[..., None]
    rgb = np.where((rib | veins)[..., None], rgb * 0.6 + np.array([0.12, 0.16, 0.06]), rgb)
    srgb = np.power(np.clip(rgb, 0, 1), 1 / 2.2)
    out = np.zeros((size, size, 4), np.uint8)
    out[..., :3] = np.round(srgb * 255).astype(np.uint8)
    out[..., 3] = np.where(blade, 255, 0).astype(np.uint8)
    return out


@dataclass(frozen=True, eq=False)
class FoliageAnchors:
    """instance : (k,) int32 piece instance each cloud sits on
    bone : (k,) int32 the palette entry it follows (the instance's bone offset + HUB)
    rest : (k, 3) float64 its point in the piece's model space
    size : (k,) float64 cloud diameter, metres"""

    instance: NDArray[np.int32]
    bone: NDArray[np.int32]
    rest: F64
    size: F64

    def __len__(self) -> int:
        return len(self.instance)

    def positions(self, palette: F64, row_vectors: bool = False) -> F64:
        """``(k, 3)`` cloud centres: each anchor's palette matrix applied to its rest point
        (``palette`` in column-vector form, or USD's row-vector form with ``row_vectors``)."""
        return anchor_positions(palette, self.bone, self.rest, row_vectors)


def anchor_positions(
    palette: F64, bone: NDArray[np.int32], rest: F64, row_vectors: bool = False
) -> F64:
    """``palette[bone]`` applied to the points ``rest`` (see FoliageAnchors.positions)."""
    m = palette[bone]
    if row_vectors:
        return np.einsum("ni,nij->nj", rest, m[:, :3, :3]) + m[:, 3, :3]
    return np.einsum("nij,nj->ni", m[:, :3, :3], rest) + m[:, :3, 3]


def foliage_anchors(
    instance: NDArray[np.int32],
    piece: NDArray[np.int32],
    bone_offset: NDArray[np.int32],
    transforms: F64,
    hub_rest: F64,
) -> FoliageAnchors:
    """Anchors at the hubs of the foliage-bearing ``instance``\\ s; diameter CLOUD_RADII
    piece radii (the piece's scale is the cube root of its topological transform's
    determinant; a piece's root rim has unit radius)."""
    idx = np.asarray(instance, np.int32)
    t = transforms[idx]
    scale = np.cbrt(np.linalg.det(t[:, :3, :3]))
    return FoliageAnchors(
        instance=idx,
        bone=(bone_offset[idx] + HUB).astype(np.int32),
        rest=hub_rest[piece[idx]],
        size=CLOUD_RADII * scale,
    )
