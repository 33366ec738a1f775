"""What each level of detail keeps of a tree, chosen from its pieces (the paper's method: the
tree is made of instanced low-poly pieces, so a level is the pieces it keeps, not a decimated
surface).

* LOD0: the full tree.
* LOD1: the pieces of at least a root radius (``PieceGraph.scale``) and all their ancestors;
  the leaf sprays of the dropped twigs stay where they are, bound to the joint of the nearest
  kept piece (the terminal the dropped branch hung on), and a spread subset of the sprays,
  scaled by ``1 / sqrt(kept fraction)`` to keep the crown's coverage, meets the budget.
* LOD2: the trunk and main limbs (a larger radius) and crown cards
  (:mod:`forest.lod.cards`).

Every kept bark vertex is LOD0's vertex with LOD0's skin, so a level's surface is LOD0's
where it keeps it, at every wind frame.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from forest.errors import ForestError
from forest.geometry.transforms import F64
from forest.growth.foliage import FoliageAnchors
from forest.growth.generate import Forest
from forest.growth.joints import dcc_joints

I32 = NDArray[np.int32]


class BarkMesh(NamedTuple):
    """One tree's bark as :func:`forest.usd.skinned.tree_mesh` makes it: points (v, 3),
    normals (v, 3), quads (q, 4), joint indices and weights (v, MAX_INFLUENCES) into the
    tree's joints, faceVarying UDIM st (q, 4, 2)."""

    points: F64
    normals: F64
    quads: I32
    joints: I32
    weights: F64
    st: F64


class LeavesMesh(NamedTuple):
    """One tree's leaves as :func:`forest.usd.skinned.leaves_mesh` makes them: points (v, 3),
    normals (v, 3), quads (q, 4), vertex st (v, 2), the joint of each vertex (v,) (rigid,
    weight 1) and a colour per quad (q, 3) float32."""

    points: F64
    normals: F64
    quads: I32
    st: F64
    joint: I32
    colour: NDArray[np.float32]

    @property
    def triangles(self) -> int:
        return 2 * len(self.quads)


def quad_instances(forest: Forest, inst: slice) -> NDArray[np.intp]:
    """``(q,)`` the tree-local instance (0 = ``inst.start``) of every bark quad, in the order
    :func:`forest.usd.skinned.tree_mesh` writes them (welding keeps the quads' order)."""
    per_piece = np.array([len(p.quads) for p in forest.pieces], np.intp)
    n = inst.stop - inst.start
    return np.repeat(np.arange(n), per_piece[forest.graph.piece[inst]])


def local_parents(forest: Forest, inst: slice) -> NDArray[np.intp]:
    """``(n,)`` each instance's parent, tree-local; the root is its own parent."""
    parent = forest.graph.parent[inst].astype(np.intp) - inst.start
    return np.where(parent >= 0, parent, np.arange(len(parent)))


def with_ancestors(keep: NDArray[np.bool_], parent: NDArray[np.intp]) -> NDArray[np.bool_]:
    """``keep`` less every instance with a dropped ancestor (one pass per depth level), so the
    kept pieces stay one connected tree from the root."""
    keep = keep.copy()
    keep[parent == np.arange(len(parent))] = True  # the root always stays
    while True:
        closed = keep & keep[parent]
        if np.array_equal(closed, keep):
            return keep
        keep = closed


def kept_by_radius(scale: F64, parent: NDArray[np.intp], min_radius: float) -> NDArray[np.bool_]:
    """``(n,)`` the instances of a root radius of at least ``min_radius`` metres whose
    ancestors are all kept."""
    return with_ancestors(np.asarray(scale) >= min_radius, parent)


def radius_for(
    scale: F64, parent: NDArray[np.intp], quads: NDArray[np.intp], max_quads: int
) -> float:
    """The smallest root radius (one of ``scale``) whose kept pieces have at most
    ``max_quads`` quads (``quads`` per instance); the largest radius (the root alone) where
    none does. Fewer pieces are kept as the radius grows, so a bisection finds it."""
    radii = np.unique(scale)
    lo, hi = 0, len(radii) - 1
    while lo < hi:
        mid = (lo + hi) // 2
        if quads[kept_by_radius(scale, parent, radii[mid])].sum() <= max_quads:
            hi = mid
        else:
            lo = mid + 1
    return float(radii[lo])


def hang_joints(
    forest: Forest,
    inst: slice,
    bones: slice,
    kept: NDArray[np.bool_],
    anchors: FoliageAnchors,
    budget: int | None = None,
) -> I32:
    """``(k,)`` the tree-local joint each spray of ``anchors`` (all of this tree) is bound to
    at a level keeping the instances ``kept``: its own hub's on a kept piece; on a dropped
    one, the joint the dropped branch hangs on (the terminal of the nearest kept ancestor,
    where :func:`forest.growth.joints.dcc_joints` with ``budget`` binds the branch's root)."""
    of_bone = dcc_joints(forest, budget).of_bone
    parent = local_parents(forest, inst)
    on = anchors.instance.astype(np.intp) - inst.start
    cur, child = on.copy(), on.copy()
    while True:
        up = ~kept[cur]
        if not up.any():
            break
        child[up] = cur[up]
        cur[up] = parent[cur[up]]
    own = of_bone[anchors.bone]
    hung = of_bone[forest.bones.offset[child + inst.start]]
    return (np.where(kept[on], own, hung) - bones.start).astype(np.int32)


def spread_pick(n: int, fraction: float) -> NDArray[np.intp]:
    """About ``fraction * n`` of ``range(n)``, evenly spread (the sprays come branch by
    branch, so every branch keeps its share)."""
    if not 0.0 < fraction <= 1.0:
        raise ForestError(f"LOD spray fraction must be in (0, 1], got {fraction}")
    i = np.arange(n)
    return np.flatnonzero(np.floor((i + 1) * fraction) > np.floor(i * fraction))


def cap_holes(quads: I32, st: F64) -> tuple[I32, F64]:
    """``quads`` (q, 4) and their corners' st (q, 4, 2) with every hole closed: where a
    dropped piece leaves a loop of edges that one quad alone holds (a cut branch's end, the
    rim a dropped twig stood on), a fan of quads over the loop's own vertices, wound as the
    surface around it. A corner of a cap reads the st its vertex has in the quad beside it,
    so a cap adds no vertex (a level's bark stays LOD0's vertices). Loops of an odd length
    or that touch another loop stay open (they do not occur on tube rims)."""
    a = np.asarray(quads, np.int64)
    b = np.roll(a, -1, axis=1)
    lo, hi = np.minimum(a, b).ravel(), np.maximum(a, b).ravel()
    key = lo * (int(a.max(initial=0)) + 1) + hi
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    lone = np.flatnonzero(counts[inverse.ravel()] == 1)
    if not len(lone):
        return quads, st
    start, end = a.ravel()[lone], b.ravel()[lone]
    corner_st = st.reshape(-1, 2)[lone]  # the st each loop vertex has beside the hole
    # a cap runs each lone edge the other way, from its end to its start; a vertex of one
    # loop is one edge's start and another's end: more, and it joins two loops (left open)
    vertex, n = np.unique(np.concatenate([start, end]), return_counts=True)
    shared = vertex[n > 2]
    ok = ~(np.isin(start, shared) | np.isin(end, shared))
    start, end, corner_st = start[ok], end[ok], corner_st[ok]
    step = dict(zip(end.tolist(), start.tolist(), strict=True))
    st_of = dict(zip(start.tolist(), corner_st, strict=True))
    new_quads, new_st = [], []
    seen: set[int] = set()
    for v0 in sorted(step):
        if v0 in seen:
            continue
        loop = [v0]
        while (nxt := step.get(loop[-1])) is not None and nxt != v0 and len(loop) <= len(step):
            loop.append(nxt)
        seen.update(loop)
        if nxt != v0 or len(loop) % 2 or len(loop) < 4:
            continue
        for i in range(1, len(loop) - 2, 2):
            q = (loop[0], loop[i], loop[i + 1], loop[i + 2])
            new_quads.append(q)
            new_st.append([st_of[v] for v in q])
    if not new_quads:
        return quads, st
    return (
        np.concatenate([quads, np.array(new_quads, quads.dtype)]),
        np.concatenate([st, np.array(new_st, st.dtype)]),
    )


def select_bark(bark: BarkMesh, keep_quad: NDArray[np.bool_]) -> BarkMesh:
    """The quads ``keep_quad`` of ``bark`` and the vertices they use (LOD0's, same skin),
    with the holes the dropped pieces leave capped (:func:`cap_holes`)."""
    quads, st = cap_holes(bark.quads[keep_quad], bark.st[keep_quad])
    used = np.zeros(len(bark.points), bool)
    used[quads.ravel()] = True
    index = np.cumsum(used) - 1
    return BarkMesh(
        bark.points[used],
        bark.normals[used],
        index[quads].astype(np.int32),
        bark.joints[used],
        bark.weights[used],
        st,
    )


def tree_anchors(anchors: FoliageAnchors, inst: slice) -> NDArray[np.intp]:
    """The sprays of one tree (in :func:`forest.usd.skinned.leaves_mesh`'s order)."""
    return np.flatnonzero((anchors.instance >= inst.start) & (anchors.instance < inst.stop))
