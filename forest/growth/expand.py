"""Stochastic grammar expansion into a piece graph, one depth level at a time for all trees."""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from forest.errors import GrammarError, LimitError
from forest.geometry import rim
from forest.geometry.pieces import MAX_LEAF_RIMS
from forest.growth.grammar import CompiledGrammar
from forest.settings import ForestSettings

I32 = NDArray[np.int32]
# instances per block of whole trees that later stages process together: big enough to
# amortise numpy's per-call cost, small enough that a level's temporaries stay in cache
BLOCK_PIECES = 16384


@dataclass(frozen=True, eq=False)
class PieceGraph:
    """Piece instances of a forest, tree-major, parents before children within a tree.

    tree, parent (-1 for a tree's root piece), parent_rim, depth, piece, symbol, alt, twist :
    (n,) int32. length : (n,) float64, the instance's length scale. radius : (n,) float64, the
    scale its parent's terminal joint takes for it (1 for roots).
    """

    tree: I32
    parent: I32
    parent_rim: I32
    depth: I32
    piece: I32
    symbol: I32
    alt: I32
    twist: I32
    length: NDArray[np.float64]
    radius: NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.tree)

    @cached_property
    def building_twist_column(self) -> NDArray[np.intp]:
        """``(n,)`` index of ``B[parent piece, parent rim] @ Twist[twist]`` in the flattened
        ``(p, MAX_LEAF_RIMS, 6)`` building-twist table (``forest.growth.assembly``); 0 for roots."""
        par = np.maximum(self.parent, 0)
        col = (self.piece[par].astype(np.intp) * MAX_LEAF_RIMS + self.parent_rim) * rim.SIDES
        col += self.twist
        col[self.parent < 0] = 0
        return col

    @cached_property
    def blocks(self) -> tuple[LevelBlock, ...]:
        """Blocks of whole trees, about ``BLOCK_PIECES`` instances each, in depth order."""
        starts = np.flatnonzero(np.diff(self.tree, prepend=-1))
        # each block starts at the first tree starting at or after a multiple of the size;
        # a multiple inside the last tree starts none (a tree is never split)
        at = np.searchsorted(starts, np.arange(0, len(self), BLOCK_PIECES))
        cuts = np.unique(starts[at[at < len(starts)]])
        bounds = [*cuts.tolist(), len(self)]
        return tuple(LevelBlock.of(self.depth, a, b) for a, b in itertools.pairwise(bounds))


@dataclass(frozen=True, eq=False)
class LevelBlock:
    """Instances ``[start, stop)`` (whole trees) in depth order, for the level-by-level passes.

    order : (m,) intp  instance indices sorted by depth (stable), level ``d`` being
    ``order[bounds[d]:bounds[d + 1]]``; rank : (m,) intp  where instance ``start + i`` sits in
    ``order``. Passes compute a level into contiguous columns of the block and put the results
    in instance order once, with ``rank``: cheaper than scattering every level.
    """

    start: int
    stop: int
    order: NDArray[np.intp]
    bounds: NDArray[np.intp]
    rank: NDArray[np.intp]

    @classmethod
    def of(cls, depth: I32, start: int, stop: int) -> LevelBlock:
        d = depth[start:stop].astype(np.int16)  # stable sorts of 16-bit keys are radix sorts
        order = np.argsort(d, kind="stable")
        bounds = np.searchsorted(d[order], np.arange(int(d.max()) + 2))
        rank = np.empty(stop - start, np.intp)
        rank[order] = np.arange(stop - start)
        return cls(start, stop, order + start, bounds, rank)

    def levels(self) -> Iterator[tuple[int, NDArray[np.intp]]]:
        """``(first position in order, instance indices)`` of each depth level."""
        for lo, hi in itertools.pairwise(self.bounds.tolist()):
            yield lo, self.order[lo:hi]


def _uniform(rng: np.random.Generator, lo_hi: NDArray[np.float64]) -> NDArray[np.float64]:
    u = rng.random(lo_hi.shape[:-1])
    return lo_hi[..., 0] + u * (lo_hi[..., 1] - lo_hi[..., 0])


def expand(
    cg: CompiledGrammar, n_trees: int, rng: np.random.Generator, settings: ForestSettings
) -> PieceGraph:
    """Grow ``n_trees`` trees from the axiom; every draw is batched over one depth level."""
    # the open rims of the current level
    f_tree = np.arange(n_trees, dtype=np.int32)
    f_parent = np.full(n_trees, -1, np.int32)
    f_rim = np.zeros(n_trees, np.int32)
    f_sym = np.full(n_trees, cg.axiom, np.int32)
    f_len = np.ones(n_trees)
    f_rad = np.ones(n_trees)
    out: list[tuple[NDArray, ...]] = []
    count = 0
    per_tree = np.zeros(n_trees, np.int64)
    for depth in range(cg.max_depth + 1):
        # np.take: several times faster than fancy indexing for these row gathers
        cum = np.take(cg.choice_table(depth), f_sym, axis=0)
        total = cum[:, -1]
        u = rng.random(len(f_sym)) * total
        alt = (u[:, None] >= cum).sum(axis=1).astype(np.int32)
        keep = total > 0  # no eligible alternative at this depth: the rim stays a tip
        if not keep.all():
            alt, f_tree, f_parent, f_rim, f_sym = (
                alt[keep],
                f_tree[keep],
                f_parent[keep],
                f_rim[keep],
                f_sym[keep],
            )
            f_len, f_rad = f_len[keep], f_rad[keep]
        m = len(alt)
        if m == 0:
            break
        twist = np.take(cg.alt_twist, alt)
        twist = np.where(twist < 0, rng.integers(0, 6, m, dtype=np.int32), twist).astype(np.int32)
        ids = np.arange(count, count + m, dtype=np.int32)
        out.append(
            (
                f_tree,
                f_parent,
                f_rim,
                np.full(m, depth, np.int32),
                np.take(cg.alt_piece, alt),
                f_sym,
                alt,
                twist,
                f_len,
                f_rad,
            )
        )
        count += m
        per_tree += np.bincount(f_tree, minlength=n_trees)
        if count > settings.max_pieces_per_forest:
            raise LimitError(
                f"the forest grew past {settings.max_pieces_per_forest} pieces; "
                "use fewer trees or a smaller grammar",
                path="max_pieces_per_forest",
                limit=settings.max_pieces_per_forest,
            )
        if per_tree.max() > settings.max_pieces_per_tree:
            raise LimitError(
                f"a tree grew past {settings.max_pieces_per_tree} pieces; "
                "lower max_depth or the branching",
                path="max_pieces_per_tree",
                limit=settings.max_pieces_per_tree,
            )
        succ = np.take(cg.alt_succ, alt, axis=0)
        if depth == cg.max_depth:
            if cg.grammar.max_depth is None and (succ >= 0).any():
                raise GrammarError(
                    f"the rules did not terminate within {cg.max_depth} levels; set max_depth",
                    path="max_depth",
                )
            break
        grow = np.flatnonzero(succ >= 0)  # (instance, rim) pairs, flattened
        grow_i = grow // MAX_LEAF_RIMS
        f_tree = f_tree[grow_i]
        f_parent = ids[grow_i]
        f_rim = (grow % MAX_LEAF_RIMS).astype(np.int32)
        f_sym = np.take(succ, grow)
        alt_rim = np.take(alt, grow_i) * MAX_LEAF_RIMS + f_rim  # into (A * R, 2) ranges
        f_len = _uniform(rng, np.take(cg.alt_length.reshape(-1, 2), alt_rim, axis=0))
        f_rad = _uniform(rng, np.take(cg.alt_radius.reshape(-1, 2), alt_rim, axis=0))
    cols = [np.concatenate(c) for c in zip(*out, strict=True)]
    tree, parent, rim, depth_a, piece, sym, alt_a, twist_a, length, radius = cols
    # level order -> tree-major order; a stable sort keeps parents before children
    order = np.argsort(tree, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    parent = parent[order]
    parent = np.where(parent >= 0, rank[np.maximum(parent, 0)], -1).astype(np.int32)
    return PieceGraph(
        tree=tree[order].astype(np.int32),
        parent=parent,
        parent_rim=rim[order],
        depth=depth_a[order],
        piece=piece[order],
        symbol=sym[order],
        alt=alt_a[order],
        twist=twist_a[order],
        length=length[order],
        radius=radius[order],
    )


def children_radius(graph: PieceGraph, radius: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(n, MAX_LEAF_RIMS)`` scale of each terminal joint: its child's ``radius`` (per
    instance, e.g. ``graph.radius`` rounded), else 1."""
    out = np.ones((len(graph), MAX_LEAF_RIMS))
    has = np.flatnonzero(graph.parent >= 0)
    out.ravel()[np.take(graph.parent, has) * MAX_LEAF_RIMS + np.take(graph.parent_rim, has)] = (
        np.take(radius, has)
    )
    return out
