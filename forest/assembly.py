"""Topological transforms (paper 4.2): ``T(child) = T(parent) @ B(rim) @ Twist(k)``, composed
one depth level at a time for every tree at once; ``T(root) = M(tree)``."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from forest import affine, rim
from forest.expand import PieceGraph
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
    """``(n, 4, 4)`` world transforms of every piece instance at rest."""
    table = affine.from_matrices(building_twist_table(pieces).reshape(-1, 4, 4))
    soa = np.empty((12, len(graph)))
    for idx in graph.levels:
        par = graph.parent[idx]
        if par[0] < 0:  # level 0: tree roots
            soa[:, idx] = affine.from_matrices(tree_transforms[graph.tree[idx]])
            continue
        col = (graph.piece[par] * MAX_LEAF_RIMS + graph.parent_rim[idx]) * rim.SIDES + graph.twist[
            idx
        ]
        soa[:, idx] = affine.compose(soa[:, par], table[:, col])
    return affine.to_matrices(soa)
