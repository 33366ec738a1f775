"""What a forester would measure on each generated tree, computed from the posed arrays:
height, trunk diameter at breast height, crown width and base, how round the crown is seen from
above, pieces and bark triangles, how thin the twigs end and the lowest point of the bark.

Used by the species tests (figures against ``shared/SPECIES.md``), the gallery's captions and
``forest presets --figures``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from forest.geometry.pieces import HUB, MAX_LEAF_RIMS, TIP0
from forest.geometry.transforms import F64, similarity_scale
from forest.growth.generate import Forest

BREAST_HEIGHT = 1.3  # metres: where foresters measure a trunk's diameter (DBH)
# A hexagonal rim of circumradius r has the area of a circle of diameter 2 r * this
HEX_AREA_DIAMETER = float(np.sqrt(3.0 * np.sqrt(3.0) / (2.0 * np.pi)))


@dataclass(frozen=True)
class TreeFigures:
    """Per tree ``(t,)`` float64 in metres unless said: height (ground to the highest
    branch point or leaf cloud top), dbh (area-equivalent trunk diameter at 1.3 m), crown_width
    (mean of the x and z extents of branches and clouds), crown_base (lowest leaf cloud's
    bottom), pieces ``(t,)`` int64, tip_radius (largest radius of a rim that ends its branch),
    trunk_radius (root rim radius), tip_diameter (twig ends: the 95th percentile of the
    diameters, corner to corner, of the rims that end branches; the few thicker ends are knots
    of shed branches and the leader's top), crown_roundness (seen from above: the leaf clouds'
    extent across the crown over their extent along it, on the principal axes of their
    positions; 1 for a round crown, small for a flat fan), lowest (the lowest root, hub or
    leaf-rim centre of any piece but the tree's root piece, above the tree's base; < 0 is
    under the ground), bark_triangles ``(t,)`` int64 (two per quad of every piece: full
    detail before tessellation)."""

    height: F64
    dbh: F64
    crown_width: F64
    crown_base: F64
    pieces: NDArray[np.int64]
    tip_radius: F64
    trunk_radius: F64
    tip_diameter: F64
    crown_roundness: F64
    lowest: F64
    bark_triangles: NDArray[np.int64]

    @property
    def slenderness(self) -> F64:
        """Height over DBH (both in metres)."""
        return self.height / self.dbh

    @property
    def crown_ratio(self) -> F64:
        """Crown width over height."""
        return self.crown_width / self.height

    @property
    def crown_base_fraction(self) -> F64:
        """Crown base over height (the bare bole's share of the tree)."""
        return self.crown_base / self.height


def piece_points(forest: Forest, palette: F64 | None = None) -> tuple[F64, F64]:
    """``(n, 3)`` world root-rim centre and ``(n, 3)`` hub of every piece, posed (no wind)."""
    pal = forest.palette() if palette is None else palette
    off = forest.bones.offset
    roots = pal[off, :3, 3]
    hub_rest = np.stack([p.joint_rest[HUB, :3, 3] for p in forest.pieces])[forest.graph.piece]
    hub_m = pal[off + HUB]
    hubs = np.einsum("nij,nj->ni", hub_m[:, :3, :3], hub_rest) + hub_m[:, :3, 3]
    return roots, hubs


def rim_radius(forest: Forest, palette: F64 | None = None) -> F64:
    """``(n,)`` posed root-rim radius of every piece in metres."""
    pal = forest.palette() if palette is None else palette
    return similarity_scale(pal[forest.bones.offset])


def tree_figures(forest: Forest) -> TreeFigures:
    g = forest.graph
    n_trees = forest.options.trees
    pal = forest.palette()
    roots, hubs = piece_points(forest, pal)
    radius = rim_radius(forest, pal)
    base = forest.tree_transforms[:, :3, 3]
    rel_roots = roots - base[g.tree]
    rel_hubs = hubs - base[g.tree]
    anchors = forest.foliage_anchors()
    cloud = anchors.positions(pal) - base[g.tree[anchors.instance]]
    half = anchors.size / 2
    top = np.zeros(n_trees)
    np.maximum.at(top, g.tree, np.maximum(rel_roots[:, 1], rel_hubs[:, 1]))
    np.maximum.at(top, g.tree[anchors.instance], cloud[:, 1] + half)
    lo = np.full((n_trees, 2), np.inf)
    hi = np.full((n_trees, 2), -np.inf)
    for pts, tree, pad in (
        (rel_hubs[:, [0, 2]], g.tree, 0.0),
        (cloud[:, [0, 2]], g.tree[anchors.instance], half),
    ):
        np.minimum.at(lo, tree, pts - np.asarray(pad)[..., None])
        np.maximum.at(hi, tree, pts + np.asarray(pad)[..., None])
    crown_base = np.full(n_trees, np.inf)
    np.minimum.at(crown_base, g.tree[anchors.instance], cloud[:, 1] - half)
    # DBH: the trunk-axis piece that holds breast height (the highest starting below it)
    trunk = np.flatnonzero((g.order == 0) & (rel_roots[:, 1] <= BREAST_HEIGHT))
    best = np.full(n_trees, -1)
    key = rel_roots[trunk, 1]
    by_height = trunk[np.lexsort((key, g.tree[trunk]))]
    best[g.tree[by_height]] = by_height  # the last write per tree is its highest
    dbh = 2 * HEX_AREA_DIAMETER * np.where(best >= 0, radius[np.maximum(best, 0)], np.nan)
    ends = _ending_rims(forest, radius)
    tip = np.zeros(n_trees)
    np.maximum.at(tip, g.tree[ends[0]], ends[1])
    tip_diameter = np.array(
        [
            2 * np.quantile(ends[1][g.tree[ends[0]] == t], 0.95) if (g.tree[ends[0]] == t).any()
            else np.nan
            for t in range(n_trees)
        ]
    )  # fmt: skip
    cloud_tree = g.tree[anchors.instance]
    roundness = np.array([_roundness(cloud[cloud_tree == t][:, [0, 2]]) for t in range(n_trees)])
    low = np.minimum(rel_roots[:, 1], rel_hubs[:, 1])
    for r in range(MAX_LEAF_RIMS):  # each leaf rim's centre, where the piece has it
        at = np.flatnonzero(np.array([p.n_leaf_rims > r for p in forest.pieces])[g.piece])
        rest = np.stack([p.joint_rest[min(TIP0 + r, p.n_joints - 1), :3, 3] for p in forest.pieces])
        m = pal[forest.bones.offset[at] + TIP0 + r]
        y = np.einsum("nj,nj->n", m[:, 1, :3], rest[g.piece[at]]) + m[:, 1, 3]
        low[at] = np.minimum(low[at], y - base[g.tree[at], 1])
    low[g.parent < 0] = np.inf
    lowest = np.full(n_trees, np.inf)
    np.minimum.at(lowest, g.tree, low)
    quads = np.array([len(p.quads) for p in forest.pieces], np.int64)[g.piece]
    return TreeFigures(
        height=top,
        dbh=dbh,
        crown_width=(hi - lo).mean(axis=1),
        crown_base=crown_base,
        pieces=np.bincount(g.tree, minlength=n_trees).astype(np.int64),
        tip_radius=tip,
        trunk_radius=radius[g.parent < 0],
        tip_diameter=tip_diameter,
        crown_roundness=roundness,
        lowest=lowest,
        bark_triangles=2 * np.bincount(g.tree, weights=quads, minlength=n_trees).astype(np.int64),
    )


def _roundness(xz: F64) -> float:
    """Extent across over extent along the principal axes of points ``(k, 2)`` (2nd to 98th
    percentile, so a stray cloud does not set it); nan for fewer than three points."""
    if len(xz) < 3:
        return float("nan")
    centred = xz - xz.mean(axis=0)
    _, axes = np.linalg.eigh(np.cov(centred.T))
    along = centred @ axes  # columns: minor axis, major axis
    lo, hi = np.percentile(along, [2, 98], axis=0)
    extent = np.sort(hi - lo)
    return float(extent[0] / max(extent[1], 1e-12))


def _ending_rims(forest: Forest, radius: F64) -> tuple[NDArray[np.intp], F64]:
    """Instances whose root rim ends a branch (capped, or an open tip's parent rim) and
    that rim's radius."""
    g = forest.graph
    names = [p.name for p in forest.pieces]
    if "Cap" in names:
        caps = np.flatnonzero(g.piece == names.index("Cap"))
        return caps, radius[caps]
    # no caps: a piece with no children ends at its own leaf rims (radius * rim scale)
    has_child = np.zeros(len(g), bool)
    has_child[g.parent[g.parent >= 0]] = True
    leaf = np.flatnonzero(~has_child)
    return leaf, radius[leaf] * forest.pose.tip_scale[leaf, 0]


def fork_pipe_ratios(forest: Forest, exponent: float) -> F64:
    """``(f,)`` ``sum(r_child^e) / (taper * r_parent)^e`` at every piece with two or more
    children (rest radii from the graph)."""
    g = forest.graph
    kids = g.parent >= 0
    n_kids = np.bincount(g.parent[kids], minlength=len(g))
    total = np.zeros(len(g))
    np.add.at(total, g.parent[kids], g.scale[kids] ** exponent)
    forks = np.flatnonzero(n_kids >= 2)
    return total[forks] / (g.taper[forks] * g.scale[forks]) ** exponent


def tip_directions(forest: Forest) -> F64:
    """``(k, 3)`` unit world axes of the pieces that end branches (posed, no wind)."""
    pal = forest.palette()
    ends, _ = _ending_rims(forest, rim_radius(forest, pal))
    ax = pal[forest.bones.offset[ends] + HUB, :3, 1]
    return ax / np.linalg.norm(ax, axis=1, keepdims=True)
