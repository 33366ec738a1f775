"""Crown cards: a far level's leaves as a few large cards, each showing the family's leaf
cluster (``ROSETTE_ST`` of the leaf picture) where a group of sprays grows.

The sprays are grouped by a grid over the crown, its cell as small as the card budget allows;
each group becomes three crossed cards (two upright, one level, turned by a golden-angle yaw
per group so the crossings do not line up), big enough to cover its sprays, bound rigidly to
the joint of the group's spray nearest its centre and coloured with its sprays' mean colour.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from forest.geometry.transforms import F64
from forest.growth.foliage import ROSETTE_ST
from forest.lod.select import I32, LeavesMesh

CARD_QUADS = 3  # two upright cards and a level one per group
GOLDEN = np.deg2rad(137.5)
# a card's half side over its group's radius: the cluster picture is opaque over much of its
# square, so cards smaller than the group's disc cover what its sprays did. Oak seed 3, alpha
# coverage (forest.lod.views, 1024 px, side and top): LOD0 12.8 %, 23.4 %; LOD2 with cards
# at 0.88: about twice LOD0's; at 0.4, the level card 1.4 times larger: 13.2 %, 20.4 %
CARD_GROWTH = 0.4
LEVEL_CARD = 1.4  # the level card over the upright ones: a crown seen from above is denser
BISECTIONS = 24


def group_sprays(centre: F64, max_groups: int) -> NDArray[np.intp]:
    """``(k,)`` a group per spray centre: grid cells as small as keeps the groups at most
    ``max_groups`` (at least one group)."""
    lo_corner = centre.min(axis=0)
    size = float(np.ptp(centre, axis=0).max()) + 1e-9

    def cells(cell: float) -> tuple[int, NDArray[np.intp]]:
        key = np.floor((centre - lo_corner) / cell).astype(np.int64)
        _, group = np.unique(key, axis=0, return_inverse=True)
        return int(group.max()) + 1, group.ravel()

    lo, hi = size / 1e4, size * 1.01  # cell sizes: too many groups .. one group
    best = cells(hi)[1]
    for _ in range(BISECTIONS):
        mid = np.sqrt(lo * hi)
        n, group = cells(mid)
        if n <= max_groups:
            hi, best = mid, group
        else:
            lo = mid
    return best


def crown_cards(
    centre: F64,
    radius: F64,
    joint: I32,
    colour: NDArray[np.float32],
    max_cards: int,
    bounds: tuple[F64, F64],
) -> LeavesMesh:
    """Crown cards over sprays at ``centre`` (k, 3) of ``radius`` (k,), each bound to
    ``joint`` (k,) and tinted ``colour`` (k, 3); at most ``max_cards`` quads, inside
    ``bounds`` (the full leaves' box, low and high corner: a card at the crown's rim moves
    inwards rather than past the tree's extent)."""
    group = group_sprays(centre, max(1, max_cards // CARD_QUADS))
    n = int(group.max()) + 1
    count = np.bincount(group, minlength=n).astype(np.float64)
    mid = np.stack([np.bincount(group, centre[:, c], n) for c in range(3)], axis=1) / count[:, None]
    # half size: the group's spread about its middle plus its sprays' own size
    far = np.linalg.norm(centre - mid[group], axis=1) + radius
    half = np.zeros(n)
    np.maximum.at(half, group, far)
    half *= CARD_GROWTH
    # a card's corners reach h sqrt 2 across (any yaw) and h up and down
    reach = half[:, None] * np.array([np.sqrt(2.0) * LEVEL_CARD, 1.0, np.sqrt(2.0) * LEVEL_CARD])
    lo, hi = bounds
    mid = np.clip(mid, np.minimum(lo + reach, (lo + hi) / 2), np.maximum(hi - reach, (lo + hi) / 2))
    near = np.full(n, np.inf)
    dist = np.linalg.norm(centre - mid[group], axis=1)
    np.minimum.at(near, group, dist)
    nearest = np.flatnonzero(dist == near[group])
    card_joint = np.zeros(n, np.int32)
    card_joint[group[nearest[::-1]]] = joint[nearest[::-1]]  # the first nearest wins
    tint = np.stack([np.bincount(group, colour[:, c], n) for c in range(3)], axis=1)
    tint = (tint / count[:, None]).astype(np.float32)

    yaw = GOLDEN * np.arange(n)
    across = np.stack([np.cos(yaw), np.zeros(n), np.sin(yaw)], axis=1)
    side = np.stack([-np.sin(yaw), np.zeros(n), np.cos(yaw)], axis=1)
    up = np.broadcast_to([0.0, 1.0, 0.0], (n, 3))
    # per card (u, v) axes, normal and size: two upright crossed cards, one level
    axes = [(across, up, side, 1.0), (side, up, -across, 1.0), (across, side, -up, LEVEL_CARD)]
    corner = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    s0, s1, t0, t1 = ROSETTE_ST
    corner_st = np.array([[s0, t0], [s1, t0], [s1, t1], [s0, t1]])
    pts, nrm = [], []
    for u, v, w, grow in axes:
        h = grow * half[:, None, None]
        pts.append(
            mid[:, None] + h * (corner[None, :, :1] * u[:, None] + corner[None, :, 1:] * v[:, None])
        )
        nrm.append(np.repeat(w[:, None], 4, axis=1))
    points = np.stack(pts, axis=1).reshape(-1, 3)  # group-major: a group's cards together
    normals = np.stack(nrm, axis=1).reshape(-1, 3)
    quads = np.arange(len(points), dtype=np.int32).reshape(-1, 4)
    return LeavesMesh(
        points,
        normals,
        quads,
        np.tile(corner_st, (n * CARD_QUADS, 1)),
        np.repeat(card_joint, 4 * CARD_QUADS).astype(np.int32),
        np.repeat(tint, CARD_QUADS, axis=0),
    )
