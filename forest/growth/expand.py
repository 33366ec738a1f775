"""Stochastic grammar expansion into a piece graph, one depth level at a time for all trees."""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cache, cached_property

import numpy as np
from numpy.typing import NDArray

from forest.errors import GrammarError, LimitError
from forest.geometry import rim
from forest.geometry.pieces import (
    CAP_APEX,
    CAP_TOP,
    HUB,
    MAX_LEAF_RIMS,
    PIECE_NAMES,
    piece_library,
)
from forest.geometry.transforms import similarity_scale
from forest.growth import keyed
from forest.growth.grammar import CompiledGrammar
from forest.settings import ForestSettings

I32 = NDArray[np.int32]
# instances per block of whole trees that later stages process together: big enough to
# amortise numpy's per-call cost, small enough that a level's temporaries stay in cache
BLOCK_PIECES = 16384
LEVELS_PER_BLOCK = 8
# SPECIES.md: twigs end 0.5-1 cm across whatever the tree. A branch that stops thicker (the
# leader at the crown's top, max_depth, a grammar with no eligible alternative) goes on as a
# short chain of straight pieces, each narrowing to at most FINISH_TAPER of its root (strong
# taper the pieces' skinning takes, like the trunk's cone), until its cap closes a rim no
# wider than this radius (metres)
TIP_RADIUS_M = 0.0048
FINISH_TAPER = 0.4
MAX_FINISH = 8  # pieces: 0.4 ** 8 takes a 7 m radius to a twig's


@dataclass(frozen=True, eq=False)
class PieceGraph:
    """Piece instances of a forest, tree-major, parents before children within a tree.

    tree, parent (-1 for a tree's root piece), parent_rim, depth, piece, symbol, alt, twist :
    (n,) int32. length : (n,) float64, the instance's length scale. radius : (n,) float64, the
    scale its parent's terminal joint takes for it (1 for roots). scale : (n,) float64, the
    radius of the instance's root rim in metres, at rest (tree scale times every rim scale
    and ``radius`` above it). order : (n,) int32 branch order: 0 on the trunk's axis, one more
    on each lateral rim (rims after the first). height : (n,) float64 metres along the
    trunk's axis where the instance starts (first-order branches: where they leave it).
    taper : (n,) float64 the radius where the instance's children leave, over ``scale``
    (the pipe model holds against ``taper * scale``). key : (n,) uint64 the instance's random
    key (:mod:`forest.growth.keyed`): its tree's and its path from the root, nothing else.
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
    scale: NDArray[np.float64]
    order: I32
    height: NDArray[np.float64]
    taper: NDArray[np.float64]
    key: NDArray[np.uint64]

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
        """Blocks of whole trees, about ``BLOCK_PIECES`` instances per 8 depth levels each,
        in depth order (deep trees get bigger blocks, so a level still holds thousands of
        instances and numpy's per-call cost stays small)."""
        starts = np.flatnonzero(np.diff(self.tree, prepend=-1))
        size = BLOCK_PIECES * max(1, (int(self.depth.max(initial=0)) + 1) // LEVELS_PER_BLOCK)
        # each block starts at the first tree starting at or after a multiple of the size;
        # a multiple inside the last tree starts none (a tree is never split)
        at = np.searchsorted(starts, np.arange(0, len(self), size))
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


def _uniform(u: NDArray[np.float64], lo_hi: NDArray[np.float64]) -> NDArray[np.float64]:
    return lo_hi[..., 0] + u * (lo_hi[..., 1] - lo_hi[..., 0])


# Each piece draws from its own key (forest.growth.keyed: the tree's key at the root, a hash
# of the parent's key and rim below), so a tree grows the same whichever trees are expanded
# beside it. Streams of a key (forest.growth.pose's draws take 16 and up): one hash for
# the piece (lanes: alternative, taper, twist), one per rim (lanes: radius, length; the whole
# hash is the key of the child on that rim, whose draws hash it again), and the tree's height
# on the root's key
_PIECE, _RIM, _TREE_HEIGHT = 0, 1, 1 + MAX_LEAF_RIMS


@dataclass(frozen=True, eq=False)
class RimTables:
    """Per piece type ``p`` and leaf rim ``r`` (building transforms do not depend on the
    resolution). sigma : (p, R) rest rim scale, 1 where no rim; rim_y : (p, R) leaf-rim
    height; hub_y : (p,) hub height; rims : (p,) leaf rims (float, for arithmetic);
    tilt : (p, R) rest angle of the rim's axis from the piece's axis (radians); tilt_az :
    (p, R) azimuth of the horizontal axis a positive rotation about which tilts that rim
    further out."""

    sigma: NDArray[np.float64]
    rim_y: NDArray[np.float64]
    hub_y: NDArray[np.float64]
    rims: NDArray[np.float64]
    tilt: NDArray[np.float64]
    tilt_az: NDArray[np.float64]


@cache
def rim_tables() -> RimTables:
    pieces = piece_library()
    shape = (len(pieces), MAX_LEAF_RIMS)
    sigma, rim_y, tilt, tilt_az = np.ones(shape), np.zeros(shape), np.zeros(shape), np.zeros(shape)
    for i, p in enumerate(pieces):
        k = p.n_leaf_rims
        if k:
            lin = p.building[:, :3, :3]
            sigma[i, :k] = similarity_scale(p.building)
            rim_y[i, :k] = p.building[:, 1, 3]
            axis = lin[:, :, 1] / np.linalg.norm(lin[:, :, 1], axis=1, keepdims=True)
            tilt[i, :k] = np.arccos(np.clip(axis[:, 1], -1.0, 1.0))
            tilt_az[i, :k] = np.arctan2(-axis[:, 0], axis[:, 2])  # of +Y x axis
    return RimTables(
        sigma=sigma,
        rim_y=rim_y,
        hub_y=np.array([p.joint_rest[HUB, 1, 3] for p in pieces]),
        rims=np.array([p.n_leaf_rims for p in pieces], np.float64),
        tilt=tilt,
        tilt_az=tilt_az,
    )


def crown_shape(shape: str, t: NDArray[np.float64]) -> NDArray[np.float64]:
    """Weber and Penn's shape ratio: the relative size of a first-order branch leaving the
    trunk at ``t`` (0 at the crown's base, 1 at the top of the tree)."""
    below = 1.0 - np.clip(t, 0.0, 1.0)  # W&P's ratio: 1 at the crown base, 0 at the top
    if shape == "cone":
        return 0.2 + 0.8 * below
    if shape == "ellipsoid":
        return 0.2 + 0.8 * np.sin(np.pi * np.clip(0.1 + 0.9 * below, 0, 1))
    if shape == "dome":
        return 0.2 + 0.8 * np.sin(0.5 * np.pi * below)
    if shape == "column":
        return 0.5 + 0.5 * below
    if shape == "vase":
        return 1.0 - 0.6 * below
    # umbrella: W&P's flame, longest a third of the way down from the top
    return 0.2 + 0.8 * np.where(below <= 0.35, below / 0.35, (1.0 - below) / 0.65)


I_PIECE = PIECE_NAMES.index("I")
GROUND_MARGIN = 0.05  # model units (root radii) a root piece's skin keeps above its root


@cache
def root_min_length() -> NDArray[np.float64]:
    """``(p,)`` the shortest length scale of each piece as a tree's root that keeps its skin
    above its root rim's plane. A length scale moves each joint to that multiple of its rest
    place, while a vertex keeps its rest offset from the joints it follows: unposed, a vertex
    at rest height ``y`` following joints of weighted rest height ``m`` lands at
    ``y + (length - 1) * m``, under the root where the piece is squashed (a stool)."""
    out = np.zeros(len(piece_library()))
    for i, p in enumerate(piece_library()):
        joint_y = p.joint_rest[:, 1, 3]
        m = (p.joint_weights * joint_y[p.joint_indices]).sum(axis=1)
        y = p.positions[:, 1] - GROUND_MARGIN
        up = m > 1e-9
        out[i] = max(0.0, float(np.max(1.0 - y[up] / m[up], initial=0.0)))
    return out


class _Open:
    """The open rims of one level, each about to grow one piece (arrays of equal length)."""

    def __init__(self, **cols: NDArray) -> None:
        self.cols = cols

    def __getattr__(self, name: str) -> NDArray:
        return self.__dict__["cols"][name]

    def __len__(self) -> int:
        return len(self.cols["tree"])

    def take(self, keep: NDArray) -> _Open:
        return _Open(**{k: v[keep] for k, v in self.cols.items()})


def expand(
    cg: CompiledGrammar,
    keys: NDArray[np.uint64],
    settings: ForestSettings,
    tree_radius: NDArray[np.float64] | None = None,
    tree_size: NDArray[np.float64] | None = None,
) -> PieceGraph:
    """Grow one tree per key ``(n_trees,)`` (:func:`forest.growth.keyed.tree_keys`) from the
    axiom; every draw is batched over one depth level, and keyed on the tree and the piece's
    place in it.

    ``tree_radius`` ``(n_trees,)`` is each tree's root-rim radius in metres (its model scale;
    1 if not given). ``tree_size`` ``(n_trees,)`` scales each tree's crown height (a young
    tree of a mixed stand: :mod:`forest.stand`); 1 if not given. Botanical rules of the
    grammar apply per level, all vectorised: the pipe model at forks, the trunk's taper to
    the crown height, the crown envelope on first-order branches, phyllotaxis rolls, and the
    end of every branch thinner than ``twig_radius``; every rim left open gets a cap piece
    (``close_tips``).
    """
    g = cg.grammar
    n_trees = len(keys)
    tab = rim_tables()
    sigma_t, rim_y_t, hub_y_t, rims_t = tab.sigma, tab.rim_y, tab.hub_y, tab.rims
    radius0 = np.ones(n_trees) if tree_radius is None else np.asarray(tree_radius, np.float64)
    crown = g.crown
    if crown:
        u = keyed.draw(keys, _TREE_HEIGHT)
        tree_h = crown.height[0] + u * (crown.height[1] - crown.height[0])
        if tree_size is not None:
            tree_h = tree_h * np.asarray(tree_size, np.float64)
    else:
        tree_h = np.full(n_trees, np.inf)
    f = _Open(
        tree=np.arange(n_trees, dtype=np.int32),
        parent=np.full(n_trees, -1, np.int32),
        rim=np.zeros(n_trees, np.int32),
        sym=np.full(n_trees, cg.axiom, np.int32),
        len=np.full(n_trees, g.axiom_length),
        rad=np.ones(n_trees),
        scale=radius0.copy(),
        order=np.zeros(n_trees, np.int32),
        h=np.zeros(n_trees),
        roll=np.zeros(n_trees),
        cap=np.zeros(n_trees, bool),
        key=np.asarray(keys, np.uint64),
    )
    close = g.close_tips and cg.cap_alt >= 0
    thick = cg.alt_thickness if cg.by_thickness else None
    out: list[tuple[NDArray, ...]] = []
    count = 0
    per_tree = np.zeros(n_trees, np.int64)
    finishing = close and cg.finish_alt >= 0
    last = cg.max_depth + 1 + (MAX_FINISH if finishing else 0)
    for depth in range(last + 1):  # the last level holds only caps
        # np.take: several times faster than fancy indexing for these row gathers
        cum = np.take(cg.choice_table(depth), f.sym, axis=0)
        if thick is not None:  # thickness conditions: each piece's own eligible weights
            fits = (f.scale[:, None] >= thick[:, 0]) & (f.scale[:, None] < thick[:, 1])
            cum = np.cumsum(np.diff(cum, axis=1, prepend=0.0) * fits, axis=1)
        total = cum[:, -1]
        h_piece = keyed.hashes(f.key, _PIECE)
        u = keyed.lane(h_piece, 0) * total
        alt = (u[:, None] >= cum).sum(axis=1).astype(np.int32)
        ends = f.cap | (total <= 0)  # no eligible alternative at this depth: a tip
        finish = np.zeros(len(alt), bool)
        if close:
            alt[ends] = cg.cap_alt
            if finishing and depth < last:
                finish = ends & (f.scale > TIP_RADIUS_M)
                alt[finish] = cg.finish_alt
        elif ends.any():
            f, alt, h_piece = f.take(~ends), alt[~ends], h_piece[~ends]
        m = len(alt)
        if m == 0:
            break
        twist = np.take(cg.alt_twist, alt)
        if (twist < 0).any():
            free = (keyed.lane(h_piece, 2) * 6).astype(np.int32)
            twist = np.where(twist < 0, free, twist).astype(np.int32)
        # phyllotaxis: the axis keeps its exact roll; each piece takes the twist that brings
        # the rounded roll along, so rounding errors never add up
        div = np.take(cg.alt_roll, alt)
        rolled = ~np.isnan(div)
        roll = f.roll + np.where(rolled, div, 60.0 * twist)
        if rolled.any():
            turn = np.round(roll / 60.0) - np.round(f.roll / 60.0)
            twist = np.where(rolled, np.mod(turn, 6), twist).astype(np.int32)
        piece = np.take(cg.alt_piece, alt)
        if crown:
            # below the crown's base the trunk shed its branches long ago: it grows straight
            # pieces there (a clear bole), not forks whose arms would end in horn-like stubs
            leaves_at = f.h + np.take(hub_y_t, piece) * f.scale * f.len
            shed = (f.order == 0) & (np.take(rims_t, piece) > 1)
            shed &= leaves_at < crown.base * np.take(tree_h, f.tree)
            piece = np.where(shed, I_PIECE, piece).astype(np.int32)
        if depth == 0:  # a tree's root piece, squashed too short, folds its skin underground
            f.cols["len"] = np.maximum(f.len, np.take(root_min_length(), piece))
        ids = np.arange(count, count + m, dtype=np.int32)
        count += m
        per_tree += np.bincount(f.tree, minlength=n_trees)
        _check_limits(count, per_tree, settings)
        # what the children get: radii (pipe model, taper), heights, lengths
        succ = np.take(cg.alt_succ, alt, axis=0)
        has_rim = np.arange(MAX_LEAF_RIMS) < np.take(rims_t, piece)[:, None]
        sigma = np.take(sigma_t, piece, axis=0)
        span = f.scale * f.len  # metres per model unit along this piece
        alt_rim = alt[:, None] * MAX_LEAF_RIMS + np.arange(MAX_LEAF_RIMS)  # into (A * R, 2)
        h_rim = keyed.hashes(f.key, _RIM, MAX_LEAF_RIMS)
        w = _uniform(keyed.lane(h_rim, 0), np.take(cg.alt_radius.reshape(-1, 2), alt_rim, axis=0))
        c_len = _uniform(
            keyed.lane(h_rim, 1), np.take(cg.alt_length.reshape(-1, 2), alt_rim, axis=0)
        )
        lateral = np.arange(MAX_LEAF_RIMS) > 0
        c_h = (
            f.h[:, None]
            + np.where(lateral, np.take(hub_y_t, piece)[:, None], np.take(rim_y_t, piece, axis=0))
            * span[:, None]
        )
        first_order = (f.order == 0)[:, None] & lateral & has_rim
        pruned = np.zeros_like(has_rim)
        if crown:
            # crown envelope: a first-order branch's share of the trunk by where it leaves
            rel = c_h / np.take(tree_h, f.tree)[:, None]
            t = (rel - crown.base) / (1.0 - crown.base)
            w = np.where(first_order, w * crown_shape(crown.shape, t), w)
        if cg.pipe_exponent is not None:
            e = cg.pipe_exponent
            share = np.where(has_rim, w, 0.0) ** e
            norm = np.maximum(share.sum(axis=1), 1e-300) ** (1.0 / e)
            s = w / norm[:, None]  # one child: its radius is the parent's (times taper)
        else:
            s = sigma * w
        taper = _uniform(keyed.lane(h_piece, 1), np.take(cg.alt_taper, alt, axis=0))
        if finish.any():  # exactly down to a twig's end, or by FINISH_TAPER on the way
            want = np.maximum(TIP_RADIUS_M / f.scale, FINISH_TAPER)
            taper = np.where(finish, want / s[:, 0], taper)
        s *= taper[:, None]
        if crown:
            # the trunk's axis narrows like a cone to the crown's top (apical control)
            top = np.take(tree_h, f.tree)
            want = np.take(radius0, f.tree) * np.maximum(1.0 - c_h[:, 0] / top, 0.02)
            trunk = (f.order == 0) & ~finish
            cone = np.ones(m)
            cone[trunk] = np.clip(want[trunk] / (s[trunk, 0] * f.scale[trunk]), 0.3, 1.0)
            s *= cone[:, None]
            taper *= cone
        c_scale = f.scale[:, None] * s
        c_order = f.order[:, None] + lateral
        if g.twig_radius is not None:
            pruned |= c_scale < g.twig_radius
        if crown:
            pruned |= (c_order == 0) & (c_h >= np.take(tree_h, f.tree)[:, None])
        out.append(
            (
                f.tree,
                f.parent,
                f.rim,
                np.full(m, depth, np.int32),
                piece,
                f.sym,
                alt,
                twist,
                f.len,
                f.rad,
                f.scale,
                f.order,
                f.h,
                taper,
                f.key,
            )
        )
        if depth >= cg.max_depth:
            if cg.grammar.max_depth is None and (succ >= 0).any():
                raise GrammarError(
                    f"the rules did not terminate within {cg.max_depth} levels; set max_depth",
                    path="max_depth",
                )
            pruned |= has_rim
        grows = has_rim & (succ >= 0) & ~pruned
        opens = grows | (has_rim & ~grows) if close else grows
        flat = np.flatnonzero(opens)  # (instance, rim) pairs, flattened
        i = flat // MAX_LEAF_RIMS
        r = (flat % MAX_LEAF_RIMS).astype(np.int32)
        f = _Open(
            tree=f.tree[i],
            parent=ids[i],
            rim=r,
            sym=np.where(grows.ravel()[flat], succ.ravel()[flat], f.sym[i]).astype(np.int32),
            # a cap at length 1, as end_branches makes them: a stretched one reads (and its
            # best-fit similarity measures) as a thicker end than its rim
            len=np.where(grows.ravel()[flat], c_len.ravel()[flat], 1.0),
            rad=(s / sigma).ravel()[flat],
            scale=c_scale.ravel()[flat],
            order=c_order.ravel()[flat].astype(np.int32),
            h=c_h.ravel()[flat],
            roll=np.where(r == 0, roll[i], 0.0),
            cap=~grows.ravel()[flat],
            key=h_rim.ravel()[flat],
        )
    cols = [np.concatenate(c) for c in zip(*out, strict=True)]
    tree, parent, rim, depth_a, piece_a, sym, alt_a, twist_a = cols[:8]
    length, radius, scale, order, height, taper_a, key = cols[8:]
    # level order -> tree-major order; a stable sort keeps parents before children
    order_ix = np.argsort(tree, kind="stable")
    rank = np.empty_like(order_ix)
    rank[order_ix] = np.arange(len(order_ix))
    parent = parent[order_ix]
    parent = np.where(parent >= 0, rank[np.maximum(parent, 0)], -1).astype(np.int32)
    return PieceGraph(
        tree=tree[order_ix].astype(np.int32),
        parent=parent,
        parent_rim=rim[order_ix],
        depth=depth_a[order_ix],
        piece=piece_a[order_ix],
        symbol=sym[order_ix],
        alt=alt_a[order_ix],
        twist=twist_a[order_ix],
        length=length[order_ix],
        radius=radius[order_ix],
        scale=scale[order_ix],
        order=order[order_ix].astype(np.int32),
        height=height[order_ix],
        taper=taper_a[order_ix],
        key=key[order_ix],
    )


def check_forest_pieces(count: int, settings: ForestSettings) -> None:
    """A :class:`LimitError` when a forest has grown past its piece cap."""
    if count > settings.max_pieces_per_forest:
        raise LimitError(
            f"the forest grew past {settings.max_pieces_per_forest} pieces; "
            "use fewer trees or a smaller grammar",
            path="max_pieces_per_forest",
            limit=settings.max_pieces_per_forest,
        )


def _check_limits(count: int, per_tree: NDArray[np.int64], settings: ForestSettings) -> None:
    check_forest_pieces(count, settings)
    if per_tree.max() > settings.max_pieces_per_tree:
        raise LimitError(
            f"a tree grew past {settings.max_pieces_per_tree} pieces; "
            "lower max_depth or the branching",
            path="max_pieces_per_tree",
            limit=settings.max_pieces_per_tree,
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


def end_branches(
    graph: PieceGraph,
    at: NDArray[np.bool_],
    cg: CompiledGrammar,
    bare: NDArray[np.bool_] | None = None,
) -> PieceGraph:
    """``graph`` with each instance marked in ``at`` (and below no other marked one)
    replaced by a cap piece of length scale 1 and everything above it dropped: the branch
    ends where it would have grown that piece. An end thicker than a twig's
    (:data:`TIP_RADIUS_M`) is finished as in :func:`expand`: short straight pieces (length
    scale 0.5, to stay where the branch stopped) tapering by :data:`FINISH_TAPER` at most,
    then the cap; unless marked in ``bare`` (where a chain would reach too far: a cap alone).
    What stays keeps its keys, so its draws, pose and place are unchanged."""
    cap = PIECE_NAMES.index("Cap")
    gone = np.zeros(len(graph), bool)
    by_depth = LevelBlock.of(graph.depth, 0, len(graph))
    for _, idx in by_depth.levels():
        par = np.take(graph.parent, idx)
        has = par >= 0
        p = np.maximum(par, 0)
        gone[idx] = has & (np.take(gone, p) | np.take(at, p))
    cut = at & ~gone
    keep = np.flatnonzero(~gone)
    new_index = np.cumsum(~gone) - 1
    parent = graph.parent[keep]
    parent = np.where(parent >= 0, new_index[np.maximum(parent, 0)], -1).astype(np.int32)
    cut_k = cut[keep]
    cols = {
        "tree": graph.tree[keep],
        "parent": parent,
        "parent_rim": graph.parent_rim[keep],
        "depth": graph.depth[keep],
        "piece": np.where(cut_k, cap, graph.piece[keep]).astype(np.int32),
        "symbol": graph.symbol[keep],
        "alt": np.where(cut_k, cg.cap_alt, graph.alt[keep]).astype(np.int32),
        "twist": graph.twist[keep],
        "length": np.where(cut_k, 1.0, graph.length[keep]),
        "radius": graph.radius[keep],
        "scale": graph.scale[keep],
        "order": graph.order[keep],
        "height": graph.height[keep],
        "taper": np.where(cut_k, 1.0, graph.taper[keep]),
        "key": graph.key[keep],
    }
    if cg.finish_alt >= 0:
        ends = cut_k if bare is None else cut_k & ~bare[keep]
        _finish_cuts(cols, np.flatnonzero(ends), cg)
    order = np.argsort(cols["tree"], kind="stable")  # appended chains: after their parents
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    par = cols["parent"][order]
    cols = {k: v[order] for k, v in cols.items()}
    cols["parent"] = np.where(par >= 0, rank[np.maximum(par, 0)], -1).astype(np.int32)
    return PieceGraph(**cols)


def finish_reach(scale: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(n,)`` metres from the root rim to the apex of what :func:`end_branches` grows in
    place of pieces whose root rims have radius ``scale`` (metres): its finishing chain, if
    any, and the cap; straight pieces, so along the cut piece's root axis."""
    sc = np.asarray(scale, np.float64).copy()
    reach = np.zeros_like(sc)
    rim_y = rim_tables().rim_y[I_PIECE, 0]
    for _ in range(MAX_FINISH):
        thick = sc > TIP_RADIUS_M
        if not thick.any():
            break
        reach[thick] += rim_y * 0.5 * sc[thick]
        sc[thick] *= np.maximum(TIP_RADIUS_M / sc[thick], FINISH_TAPER)
    return reach + (CAP_TOP + CAP_APEX) * sc


def _finish_cuts(cols: dict[str, NDArray], ends: NDArray[np.intp], cg: CompiledGrammar) -> None:
    """Turn the caps ``ends`` of ``cols`` thicker than a twig into finishing pieces, appending
    the chain each grows (more finishing pieces, then its cap) to ``cols``, in place."""
    cap = PIECE_NAMES.index("Cap")
    sigma = rim_tables().sigma[I_PIECE, 0]
    rim_y = rim_tables().rim_y[I_PIECE, 0]
    for _ in range(MAX_FINISH):
        ends = ends[cols["scale"][ends] > TIP_RADIUS_M]
        if not len(ends):
            return
        sc = cols["scale"][ends]
        want = np.maximum(TIP_RADIUS_M / sc, FINISH_TAPER)
        s_pre = 1.0 if cg.pipe_exponent is not None else sigma
        cols["piece"][ends] = I_PIECE
        cols["alt"][ends] = cg.finish_alt
        cols["length"][ends] = 0.5
        cols["taper"][ends] = want / s_pre
        n = len(cols["tree"])
        child = {
            "tree": cols["tree"][ends],
            "parent": ends.astype(np.int32),
            "parent_rim": np.zeros(len(ends), np.int32),
            "depth": cols["depth"][ends] + 1,
            "piece": np.full(len(ends), cap, np.int32),
            "symbol": cols["symbol"][ends],
            "alt": np.full(len(ends), cg.cap_alt, np.int32),
            "twist": np.zeros(len(ends), np.int32),
            "length": np.ones(len(ends)),
            "radius": want / sigma,
            "scale": sc * want,
            "order": cols["order"][ends],
            "height": cols["height"][ends] + rim_y * sc * 0.5,
            "taper": np.ones(len(ends)),
            "key": keyed.hashes(cols["key"][ends], _RIM, MAX_LEAF_RIMS)[:, 0].copy(),
        }
        for k, v in child.items():
            cols[k] = np.concatenate([cols[k], v.astype(cols[k].dtype)])
        ends = np.arange(n, n + len(ends))
