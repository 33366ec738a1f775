"""Topological transforms (paper 4.2): ``T(child) = T(parent) @ B(rim) @ Twist(k)``, composed
one depth level at a time for every tree at once; ``T(root) = M(tree)``."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from forest import affine, rim
from forest.expand import BLOCK_PIECES, PieceGraph
from forest.pieces import MAX_LEAF_RIMS, PieceArrays
from forest.transforms import F64


def building_twist_table(pieces: tuple[PieceArrays, ...]) -> F64:
    """``(p, MAX_LEAF_RIMS, 6, 4, 4)``: ``B[p, r] @ Twist[k]``, identity where no rim ``r``."""
    out = np.broadcast_to(np.eye(4), (len(pieces), MAX_LEAF_RIMS, rim.SIDES, 4, 4)).copy()
    tw = rim.twists()
    for i, p in enumerate(pieces):
        out[i, : p.n_leaf_rims] = p.building[:, None] @ tw[None]
    return out


def building_twist_column(
    piece: NDArray[np.int32], rim_: NDArray[np.int32], twist: NDArray[np.int32]
) -> NDArray[np.int64]:
    """Index of ``B[piece, rim] @ Twist[twist]`` in the flattened building-twist table."""
    return (piece.astype(np.int64) * MAX_LEAF_RIMS + rim_) * rim.SIDES + twist


def topological_transforms(
    graph: PieceGraph, tree_transforms: F64, pieces: tuple[PieceArrays, ...]
) -> F64:
    """``(n, 4, 4)`` world transforms of every piece instance at rest, composed block by
    block of whole trees, one depth level at a time (SoA, see :mod:`forest.affine`)."""
    table = affine.from_matrices(building_twist_table(pieces).reshape(-1, 4, 4))
    out = np.empty((len(graph), 4, 4))
    for start, stop in graph.tree_blocks(BLOCK_PIECES):
        soa = np.empty((12, stop - start))
        for idx in graph.levels_in(start, stop):
            par = graph.parent[idx]
            if par[0] < 0:  # level 0: tree roots
                soa[:, idx - start] = affine.from_matrices(tree_transforms[graph.tree[idx]])
                continue
            col = building_twist_column(graph.piece[par], graph.parent_rim[idx], graph.twist[idx])
            soa[:, idx - start] = affine.compose(soa[:, par - start], table[:, col])
        affine.to_matrices(soa, out[start:stop])
    return out
