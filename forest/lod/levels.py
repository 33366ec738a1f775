"""One tree's levels of detail from its full meshes (LOD0): which pieces and sprays each keeps
(:mod:`forest.lod.select`), made into meshes skinned to the same joints."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from forest.geometry.transforms import F64
from forest.growth.foliage import LEAF, STEM, FoliageAnchors
from forest.growth.generate import Forest
from forest.lod.cards import crown_cards
from forest.lod.select import (
    BarkMesh,
    LeavesMesh,
    hang_joints,
    kept_by_radius,
    local_parents,
    quad_instances,
    radius_for,
    select_bark,
    spread_pick,
    tree_anchors,
)
from forest.lod.targets import BARK_SHARE, TARGETS, LodTarget

# LOD1's cards grow by this over 1 / sqrt(kept fraction): sprays whose cards overlapped less
# once fewer cover more. Measured on oak seed 3 (alpha coverage at 1024 px, side and top):
# 1.0 covered 20 % more than LOD0, 0.9 matches it within a few per cent
CARD_GROWTH = 0.85
# a capped LOD0 (forest.lod.select.GAME_LOD0) keeps most sprays, which overlap as much as
# before: its cards grow by the area they stand for. Oak seed 3 at 150 k triangles, alpha
# coverage at 512 px (front, side, top): 12.2, 12.7, 22.9 % full; 12.2, 12.7, 23.2 % at 1.0
# (11.3, 11.8, 21.4 % at 0.85)
LOD0_CARD_GROWTH = 1.0


@dataclass(frozen=True, eq=False)
class Level:
    """One level of detail of a tree: its bark (LOD0's vertices it keeps), its leaves (None
    where the tree bears none) and the root radius of the thinnest piece it keeps (metres)."""

    level: int
    bark: BarkMesh
    leaves: LeavesMesh | None
    min_radius: float

    @property
    def triangles(self) -> tuple[int, int]:
        """(bark, leaves) triangles."""
        return 2 * len(self.bark.quads), 0 if self.leaves is None else self.leaves.triangles


def tree_levels(
    forest: Forest,
    anchors: FoliageAnchors | None,
    inst: slice,
    bones: slice,
    to_tree: F64,
    still: F64,
    bark: BarkMesh,
    leaves: LeavesMesh | None,
    joint_budget: int | None = None,
    lod0: LodTarget | None = None,
) -> list[Level]:
    """LOD0 (``bark``, ``leaves``: the tree's full meshes as :mod:`forest.usd.skinned` makes
    them from ``inst``, ``bones``, ``to_tree`` and ``still``), LOD1 and LOD2, each within its
    :data:`forest.lod.select.TARGETS` of LOD0's triangles; ``joint_budget``: the skeleton's
    joints per tree, as ``bones`` counts them (:mod:`forest.growth.joint_budget`). ``lod0``:
    a cap on LOD0 itself (:data:`forest.lod.select.GAME_LOD0`): over it, LOD0 drops the
    thinnest pieces and thins the leaf cards as LOD1 does, bark and leaves each keeping
    their share; LOD1 and LOD2 are still made from the full tree (they keep thicker pieces
    than any such LOD0, so every level's bark stays a part of LOD0's)."""
    total = 2 * len(bark.quads) + (0 if leaves is None else leaves.triangles)
    out = [Level(0, bark, leaves, float(forest.graph.scale[inst].min()))]
    if lod0 is not None and lod0.triangles(total) < total:
        share = 2 * len(bark.quads) / total
        out[0] = _reduced(
            forest,
            anchors,
            inst,
            bones,
            bark,
            leaves,
            0,
            lod0.triangles(total),
            share,
            joint_budget,
        )
    for level in (1, 2):
        target = TARGETS[level].triangles(total)
        out.append(
            _reduced(
                forest,
                anchors,
                inst,
                bones,
                bark,
                leaves,
                level,
                target,
                BARK_SHARE,
                joint_budget,
            )
        )
    return out


def _reduced(
    forest: Forest,
    anchors: FoliageAnchors | None,
    inst: slice,
    bones: slice,
    bark: BarkMesh,
    leaves: LeavesMesh | None,
    level: int,
    target: int,
    bark_share: float,
    joint_budget: int | None,
) -> Level:
    """The tree's ``level`` within ``target`` triangles, ``bark_share`` of them bark: the
    pieces of at least the root radius that fits, fewer leaf cards (LOD0, LOD1) or crown
    cards (LOD2) in the rest."""
    scale = forest.graph.scale[inst]
    parent = local_parents(forest, inst)
    of_quad = quad_instances(forest, inst)
    quads = np.bincount(of_quad, minlength=len(scale))
    bark_quads = int(bark_share * target) // 2 if leaves is not None else target // 2
    radius = radius_for(scale, parent, quads, bark_quads)
    kept = kept_by_radius(scale, parent, radius)
    lod_bark = select_bark(bark, kept[of_quad])
    lod_leaves = None
    sel = None if anchors is None or leaves is None else tree_anchors(anchors, inst)
    if anchors is not None and leaves is not None and sel is not None and len(sel):
        budget = max(target - 2 * len(lod_bark.quads), 0)
        tree = anchors.select(sel)
        if level == 2:
            lod_leaves = _cards(forest, tree, inst, bones, kept, leaves, budget, joint_budget)
        else:
            growth = LOD0_CARD_GROWTH if level == 0 else CARD_GROWTH
            lod_leaves = _fewer_cards(
                forest, tree, inst, bones, kept, leaves, budget, joint_budget, growth
            )
    return Level(level, lod_bark, lod_leaves, radius)


def _fewer_cards(
    forest: Forest,
    tree: FoliageAnchors,
    inst: slice,
    bones: slice,
    kept: NDArray[np.bool_],
    leaves: LeavesMesh,
    budget: int,
    joint_budget: int | None = None,
    growth: float = CARD_GROWTH,
) -> LeavesMesh | None:
    """LOD0's ``leaves`` with an evenly spread subset of their leaf cards within ``budget``
    triangles, every spray keeping its share: each kept card grows about its middle by
    ``growth / sqrt(kept fraction)`` (the crown's coverage stays, its outline barely moves), stem
    cards go (a spray's stalk is thinner than a pixel where this level shows), and every
    card is bound to the nearest kept joint (:func:`hang_joints`)."""
    models = tree.models()
    kinds = [np.full(len(m.quads), LEAF, np.int8) if m.kind is None else m.kind for m in models]
    kind = np.concatenate([kinds[m] for m in tree.model])
    spray = np.repeat(np.arange(len(tree)), [len(models[m].quads) for m in tree.model])
    cards = np.flatnonzero(kind != STEM)
    if budget < 2 or not len(cards):
        return None
    fraction = min(1.0, budget / (2 * len(cards)))
    pick = cards[spread_pick(len(cards), fraction)]
    fraction = len(pick) / len(cards)
    quads = leaves.quads[pick]
    mid = leaves.points[quads].mean(axis=1)
    grow = growth / np.sqrt(fraction)
    points = mid[:, None] + (leaves.points[quads] - mid[:, None]) * grow
    joint = hang_joints(forest, inst, bones, kept, tree, joint_budget)[spray[pick]]
    return LeavesMesh(
        points.reshape(-1, 3),
        leaves.normals[quads].reshape(-1, 3),
        np.arange(4 * len(pick), dtype=np.int32).reshape(-1, 4),
        leaves.st[quads].reshape(-1, 2),
        np.repeat(joint, 4).astype(np.int32),
        leaves.colour[pick],
    )


def _cards(
    forest: Forest,
    tree: FoliageAnchors,
    inst: slice,
    bones: slice,
    kept: NDArray[np.bool_],
    leaves: LeavesMesh,
    budget: int,
    joint_budget: int | None = None,
) -> LeavesMesh | None:
    """Crown cards over every spray of LOD0's ``leaves`` within ``budget`` triangles."""
    if budget < 2:
        return None
    verts = np.array([len(m.positions) for m in tree.models()])[tree.model]
    start = np.concatenate([[0], np.cumsum(verts)[:-1]])
    centre = np.add.reduceat(leaves.points, start, axis=0) / verts[:, None]
    spray = np.repeat(np.arange(len(tree)), verts)
    dist = np.linalg.norm(leaves.points - centre[spray], axis=1)
    radius = np.zeros(len(tree))
    np.maximum.at(radius, spray, dist)
    joint = hang_joints(forest, inst, bones, kept, tree, joint_budget)
    bounds = (leaves.points.min(axis=0), leaves.points.max(axis=0))
    return crown_cards(centre, radius, joint, tree.color, budget // 2, bounds)
