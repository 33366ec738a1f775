"""Topological transforms (paper 4.2): ``T(child) = T(parent) @ B(rim) @ Twist(k)``, composed
one depth level at a time for every tree at once; ``T(root) = M(tree)``."""

from __future__ import annotations

from collections.abc import Sequence
from functools import cache

import numpy as np

from forest.geometry import affine, rim
from forest.geometry.pieces import MAX_LEAF_RIMS, PieceArrays
from forest.geometry.transforms import F64
from forest.growth.expand import LevelBlock, PieceGraph
from forest.growth.parallel import for_block_groups


@cache
def building_twist_table(pieces: tuple[PieceArrays, ...]) -> F64:
    """``(12, p * MAX_LEAF_RIMS * 6)`` affine batch (:mod:`forest.geometry.affine`) of
    ``B[p, r] @ Twist[k]``, flattened ``(p, r, k)``; identity where no rim ``r``."""
    out = np.broadcast_to(np.eye(4), (len(pieces), MAX_LEAF_RIMS, rim.SIDES, 4, 4)).copy()
    tw = rim.twists()
    for i, p in enumerate(pieces):
        out[i, : p.n_leaf_rims] = p.building[:, None] @ tw[None]
    return affine.from_matrices(out.reshape(-1, 4, 4))


def topological_transforms(
    graph: PieceGraph, tree_transforms: F64, pieces: tuple[PieceArrays, ...]
) -> F64:
    """``(n, 4, 4)`` world transforms of every piece instance at rest, composed block by
    block of whole trees, one depth level at a time (SoA, see :mod:`forest.geometry.affine`)."""
    table = building_twist_table(pieces)
    out = np.empty((len(graph), 4, 4))

    def run(blocks: Sequence[LevelBlock]) -> None:
        # work arrays shared by a thread's blocks (fresh ones would be page-faulted anew)
        most = max((blk.stop - blk.start for blk in blocks), default=0)
        soa_all, mats_all = np.empty(12 * most), np.empty((most, 4, 4))
        for blk in blocks:
            # columns in the block's depth order; C-contiguous (np.take copies a strided
            # source whole)
            soa = soa_all[: 12 * (blk.stop - blk.start)].reshape(12, -1)
            for lo, idx in blk.levels():
                level = soa[:, lo : lo + len(idx)]
                par = graph.parent[idx]
                if lo == 0:  # tree roots
                    level[:] = affine.from_matrices(tree_transforms[graph.tree[idx]])
                    continue
                parent = np.take(soa, blk.rank[par - blk.start], axis=1)
                col = np.take(graph.building_twist_column, idx)
                affine.compose(parent, np.take(table, col, axis=1), out=level)
            mats = affine.to_matrices(soa, out=mats_all[: blk.stop - blk.start])
            np.take(mats, blk.rank, axis=0, out=out[blk.start : blk.stop], mode="clip")

    for_block_groups(run, graph.blocks)
    return out
