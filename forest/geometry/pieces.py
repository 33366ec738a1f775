"""The piece library (paper 4.1): quad-only meshes built in code, with rims, building transforms,
a skeleton and skin weights.

Every piece shares one skeleton layout so assembly and posing vectorise across piece types:

====== ======================================= ==========================================
joint  where (model space)                      role
====== ======================================= ==========================================
0      root-rim centre, identity frame          rigidly attached to the parent's terminal
1      hub: where the piece bends or forks      bend of everything above it
2 + r  leaf rim ``r`` frame (= building B_r)   terminal; its child's root sits here
====== ======================================= ==========================================

Tubes are built ring by ring. A ring is six vertex indices ordered by increasing angle about
the tube's local +Y, and quads are wound ``(a_i, b_i, b_i+1, a_i+1)`` so normals face outward
(right-handed, counter-clockwise front faces, as USD expects).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

import numpy as np
from numpy.typing import NDArray

from forest.geometry import rim
from forest.geometry.transforms import (
    F64,
    axis_angle_matrix,
    invert_similarity,
    scaling,
    transform_points,
    transform_vectors,
    translation,
)
from schemas.tileset import (
    BARK_H,
    BARK_V,
    CLASS_EDGES,
    CROTCH_CCW,
    CROTCH_CW,
    CROTCH_H,
    CROTCH_V,
)

BARK = 1
FORK = 2
MAX_LEAF_RIMS = 3
ROOT, HUB, TIP0 = 0, 1, 2  # the joint layout of every piece (table above)
MAX_JOINTS = TIP0 + MAX_LEAF_RIMS
MAX_INFLUENCES = 4
# Corner st of every quad, in the winding order (a_i, b_i, b_i+1, a_i+1): u runs around the
# tube, v along it, so bark tiles stand upright.
QUAD_ST = np.array([[0.0, 0.0], [0.0, 1.0], [1.0, 1.0], [1.0, 0.0]])


@dataclass(frozen=True, eq=False)
class PieceArrays:
    """One piece's mesh, rims and skeleton.

    positions : (v, 3) float64      normals : (v, 3) float64 (unit)
    quads : (q, 4) int32            tile_class : (q,) int32 (BARK or FORK)
    joint_indices : (v, 4) int32    joint_weights : (v, 4) float64 (rows sum to 1)
    root_rim : (6,) int32           leaf_rims : (r, 6) int32, vertex ``k`` of each rim is
                                    ``building[r] @ root vertex k``
    building : (r, 4, 4) float64    similarity mapping the root rim onto leaf rim ``r``
    joint_rest : (j, 4, 4) float64  joint frames in model space (j = 2 + r)
    joint_parents : (j,) int32      -1 for the root
    """

    name: str
    positions: F64
    normals: F64
    quads: NDArray[np.int32]
    tile_class: NDArray[np.int32]
    joint_indices: NDArray[np.int32]
    joint_weights: F64
    root_rim: NDArray[np.int32]
    leaf_rims: NDArray[np.int32]
    building: F64
    joint_rest: F64
    joint_parents: NDArray[np.int32]

    @property
    def n_leaf_rims(self) -> int:
        return int(self.building.shape[0])

    @property
    def n_joints(self) -> int:
        return int(self.joint_rest.shape[0])

    @property
    def joint_names(self) -> tuple[str, ...]:
        return ("root", "hub", *tuple(f"tip{r}" for r in range(self.n_leaf_rims)))


class _MeshBuilder:
    """Accumulates vertices with dense joint weights, and quads with tile classes."""

    def __init__(self, n_joints: int) -> None:
        self.n_joints = n_joints
        self.points: list[F64] = []
        self.weights: list[F64] = []
        self.quads: list[NDArray[np.int64]] = []
        self.classes: list[NDArray[np.int64]] = []
        self.count = 0

    def add(self, pts: F64, w: F64) -> NDArray[np.int64]:
        pts = np.atleast_2d(pts)
        w = np.broadcast_to(w, (len(pts), self.n_joints))
        idx = np.arange(self.count, self.count + len(pts))
        self.points.append(pts)
        self.weights.append(np.array(w))
        self.count += len(pts)
        return idx

    def strip(
        self, a: NDArray[np.int64], b: NDArray[np.int64], cls: int, skip: tuple[int, ...] = ()
    ) -> None:
        """Quads between consecutive rings ``a`` and ``b`` (each (6,)), except columns ``skip``."""
        cols = np.array([i for i in range(rim.SIDES) if i not in skip])
        nxt = (cols + 1) % rim.SIDES
        self.quads.append(np.stack([a[cols], b[cols], b[nxt], a[nxt]], axis=-1))
        self.classes.append(np.full(len(cols), cls))

    def positions(self) -> F64:
        return np.concatenate(self.points)

    def move(self, idx: NDArray[np.int64], pts: F64) -> None:
        """Set the positions of vertices ``idx`` (after they were added)."""
        pos = self.positions()
        pos[idx] = pts
        self.points = [pos]
        self.weights = [self.dense_weights()]

    def dense_weights(self) -> F64:
        return np.concatenate(self.weights)


def _onehot(j: int, n: int) -> F64:
    w = np.zeros(n)
    w[j] = 1.0
    return w


def _leaf_frame(base: F64, tilt_z: float, length: float, scale: float) -> F64:
    """Building transform of a leaf rim reached from ``base`` by leaning +Y by ``tilt_z``
    radians about +Z (negative leans toward +X) and going ``length`` along that axis."""
    rot = axis_angle_matrix([0.0, 0.0, 1.0], tilt_z)
    axis = rot[:3, 1]
    return translation(base + length * axis) @ rot @ scaling(scale)


def _align_ring(idx: NDArray[np.int64], pts: F64, frame: F64) -> NDArray[np.int64]:
    """Order six loop vertices ``idx`` like the canonical rim as seen from ``frame``: sort by
    angle about the frame's +Y, then rotate the cycle onto the rim angles 30 + 60k."""
    local = transform_points(invert_similarity(frame), pts)
    ang = np.mod(np.arctan2(local[:, 2], local[:, 0]), 2 * np.pi)
    order = np.argsort(ang)
    ang = ang[order]
    shifts = [
        np.abs(np.angle(np.exp(1j * (np.roll(ang, -k) - rim.ANGLES)))).sum()
        for k in range(rim.SIDES)
    ]
    return np.roll(idx[order], -int(np.argmin(shifts)))


def _hermite_rings(p0: F64, t0: F64, p1: F64, t1: F64, us: F64) -> F64:
    """``(k, 6, 3)`` rings at parameters ``us`` in [0, 1] (``(k,)``, or ``(k, 6)`` one per
    vertex) between ring ``p0`` and ring ``p1`` (each (6, 3)) on cubic Hermite curves leaving
    along ``t0`` and arriving along ``t1`` ((3,), tangents in units of each curve's chord)."""
    u = np.asarray(us, np.float64)
    u = u[:, None, None] if u.ndim == 1 else u[:, :, None]
    span = np.linalg.norm(p1 - p0, axis=-1, keepdims=True)
    h00, h10 = 2 * u**3 - 3 * u**2 + 1, u**3 - 2 * u**2 + u
    h01, h11 = -2 * u**3 + 3 * u**2, u**3 - u**2
    return h00 * p0 + h10 * span * t0 + h01 * p1 + h11 * span * t1


class _PieceBuilder:
    """Shared steps of every piece: stems on the rim cone, branches to leaf rims, normals."""

    def __init__(self, name: str, hub: F64, leaves: list[F64], universal_root: bool = True) -> None:
        self.name = name
        self.universal_root = universal_root
        self.hub = np.asarray(hub, dtype=np.float64)
        self.leaves = leaves
        self.nj = 2 + len(leaves)
        self.mesh = _MeshBuilder(self.nj)
        self.root_rim: NDArray[np.int64] | None = None
        self.leaf_rims: list[NDArray[np.int64] | None] = [None] * len(leaves)
        self.crotch: set[tuple[int, int]] = set()

    def stem_weights(self, y: F64, top: float, tip: int | None) -> F64:
        """Weights along a vertical stem: root -> hub below the hub, hub -> tip above it."""
        y = np.atleast_1d(y)
        w = np.zeros((len(y), self.nj))
        h = self.hub[1]
        below = y <= h
        u = np.where(below, y / h, (y - h) / max(top - h, 1e-12))
        w[below, 0] = 1 - u[below]
        w[below, 1] = u[below]
        if tip is None:
            w[~below, 1] = 1.0
        else:
            w[~below, 1] = 1 - u[~below]
            w[~below, 2 + tip] = u[~below]
        return w

    def stem(
        self,
        heights: list[float],
        top: float,
        tip: int | None,
        leaf_frame: F64 | None,
        ring_at: Callable[[float], F64] = rim.cone_ring,
    ) -> list[NDArray[np.int64]]:
        """Rings ``ring_at(y)`` (default: on the root cone) at ``heights``; if ``leaf_frame`` is
        given the last ring is that leaf rim (the stem is then one frustum of the cone).
        Returns the ring indices."""
        rings = []
        for y in heights:
            pts = ring_at(float(y))
            rings.append(self.mesh.add(pts, self.stem_weights(np.full(6, y), top, tip)))
        self.root_rim = rings[0]
        if leaf_frame is not None:
            self.leaf_rims[tip if tip is not None else 0] = rings[-1]
        return rings

    def branch(
        self,
        start: NDArray[np.int64],
        start_dir: F64,
        r: int,
        segments: int,
        cls_first: NDArray[np.int64] | int,
        knee: float = 1.0,
    ) -> None:
        """A tube from the six-vertex loop ``start`` to leaf rim ``r``; the last quad ring lies
        on the leaf's rim cone, ``knee`` leaf units deep. ``cls_first`` is the tile class of
        the first quad ring."""
        frame = self.leaves[r]
        pos = self.mesh.positions()
        start = _align_ring(start, pos[start], frame)
        # the loop's edges are the crotch: where this branch meets the stem or its sibling
        self.crotch.update(_edge_key(a, b) for a, b in zip(start, np.roll(start, -1), strict=True))
        w_start = self.mesh.dense_weights()[start]
        # the ring one cone row below the leaf rim, in leaf space: ``knee`` deep, so that
        # row's quads are about as long as they are wide
        k_local = rim.cone_ring(-knee)
        k_pts = transform_points(frame, k_local)
        leaf_pts = transform_points(frame, rim.rim_ring())
        axis = transform_vectors(frame, np.array([[0.0, 1.0, 0.0]]))[0]
        # as many rows to the knee as the curves are long in ring edges; each vertex's curve
        # is cut where its rows are equal shares of that length, so tiles stay near square
        # where the tube narrows and on the short side of a leaning branch
        probe_u = np.linspace(0.0, 1.0, 65)
        path = _hermite_rings(pos[start], start_dir, k_pts, axis, probe_u)  # (65, 6, 3)
        edge = np.linalg.norm(path - np.roll(path, -1, axis=1), axis=-1)  # (65, 6)
        edge = 0.5 * (edge + np.roll(edge, 1, axis=1))  # about each vertex
        step = np.linalg.norm(np.diff(path, axis=0), axis=-1)  # (64, 6)
        s = np.cumsum(step / (0.5 * (edge[1:] + edge[:-1])), axis=0)
        s = np.concatenate([np.zeros((1, rim.SIDES)), s])  # (65, 6) length in edges
        n_rows = max(1, round(float(s[-1].mean()))) * segments
        frac = np.linspace(0.0, 1.0, n_rows + 1)[1:-1]
        us = np.stack(
            [np.interp(frac * s[-1, j], s[:, j], probe_u) for j in range(rim.SIDES)], axis=-1
        )
        mids = list(_hermite_rings(pos[start], start_dir, k_pts, axis, us))
        ring_pts = [*mids, k_pts, leaf_pts]
        n = len(ring_pts)
        prev = start
        tip = _onehot(TIP0 + r, self.nj)
        for i, pts in enumerate(ring_pts, start=1):
            u = i / n
            idx = self.mesh.add(pts, (1 - u) * w_start + u * tip)
            if i == 1 and not np.isscalar(cls_first):
                # per-column classes for the first quad ring (fork region)
                cols = np.asarray(cls_first)
                for c in (BARK, FORK):
                    skip = tuple(int(k) for k in np.nonzero(cols != c)[0])
                    if len(skip) < rim.SIDES:
                        self.mesh.strip(prev, idx, c, skip)
            else:
                self.mesh.strip(prev, idx, int(cls_first) if i == 1 else BARK)
            prev = idx
        self.leaf_rims[r] = prev

    def finish(self) -> PieceArrays:
        pos = self.mesh.positions()
        quads = np.concatenate(self.mesh.quads).astype(np.int32)
        rims = [np.asarray(self.root_rim), *(np.asarray(lr) for lr in self.leaf_rims)]
        quads = _orient_quads(quads, np.concatenate(rims))
        tile_class = _tile_classes(quads, self.crotch)
        normals = _vertex_normals(pos, quads)
        assert self.root_rim is not None
        if self.universal_root:
            normals[self.root_rim] = rim.rim_normals()
        # a cap has no leaf rims: (0, 6) and (0, 4, 4), never a failed stack of nothing
        leaf_rims = np.array([np.asarray(lr) for lr in self.leaf_rims], np.int32).reshape(-1, 6)
        building = np.array(self.leaves, np.float64).reshape(-1, 4, 4)
        for r, frame in enumerate(self.leaves):
            # rim vertices carry the predetermined cone normals, so joints match exactly
            normals[leaf_rims[r]] = transform_vectors(frame, rim.rim_normals())
            pos[leaf_rims[r]] = transform_points(frame, rim.rim_ring())
        if self.universal_root:
            pos[self.root_rim] = rim.rim_ring()
        dense = self.mesh.dense_weights()
        if dense.shape[1] < MAX_INFLUENCES:  # pad so every piece has four influence slots
            dense = np.pad(dense, ((0, 0), (0, MAX_INFLUENCES - dense.shape[1])))
        order = np.argsort(-dense, axis=1, kind="stable")[:, :MAX_INFLUENCES]
        wts = np.take_along_axis(dense, order, axis=1)
        wts /= wts.sum(axis=1, keepdims=True)
        joint_rest = np.concatenate([np.eye(4)[None], translation(self.hub)[None], building])
        parents = np.array([-1, 0] + [1] * len(self.leaves), dtype=np.int32)
        return PieceArrays(
            name=self.name,
            positions=pos,
            normals=normals,
            quads=quads,
            tile_class=tile_class,
            joint_indices=np.where(wts > 0, order, 0).astype(np.int32),
            joint_weights=wts,
            root_rim=np.asarray(self.root_rim, dtype=np.int32),
            leaf_rims=leaf_rims,
            building=building,
            joint_rest=joint_rest,
            joint_parents=parents,
        )


# Sides of a quad (a, b, c, d) as corner pairs in QUAD_ST terms: u runs a -> d, v runs a -> b.
SIDE_CORNERS = {"left": (0, 1), "top": (1, 2), "right": (3, 2), "bottom": (0, 3)}
_SIDES = tuple(SIDE_CORNERS)
_OPPOSITE = {frozenset(("left", "right")), frozenset(("top", "bottom"))}
# Quarter-turn joins (a tile meeting a neighbour turned 90 degrees, as around a crotch or an
# apex, where the mesh cannot be one upright grid): the side pairs whose edge pattern must be
# the horizontal one turned clockwise (see schemas.tileset) or counter-clockwise.
_QUARTER_CW = {frozenset(("left", "bottom")), frozenset(("right", "top"))}
_QUARTER_CCW = {frozenset(("left", "top")), frozenset(("right", "bottom"))}


def _edge_key(a: int | np.integer, b: int | np.integer) -> tuple[int, int]:
    return (int(min(a, b)), int(max(a, b)))


def _quad_sides(quads: NDArray[np.int32]) -> dict[tuple[int, int], list[tuple[int, str]]]:
    """Undirected edge -> the (quad, side) pairs holding it."""
    out: dict[tuple[int, int], list[tuple[int, str]]] = {}
    for q, quad in enumerate(quads):
        for side, (i, j) in SIDE_CORNERS.items():
            out.setdefault(_edge_key(quad[i], quad[j]), []).append((q, side))
    return out


def _joins(sa: str, sb: str) -> bool:
    """Whether tiles can meet with sides ``sa`` and ``sb`` on one edge: opposite sides, or a
    quarter turn; never the same side (a half turn: no edge pattern continues then)."""
    pair = frozenset((sa, sb))
    return sa != sb and (pair in _OPPOSITE or pair in _QUARTER_CW or pair in _QUARTER_CCW)


@cache  # the orientation search asks the same (quad, turn, edge) again at every budget
def _side_of(quad: tuple[int, ...], turn: int, a: int, b: int) -> str:
    c = quad[turn:] + quad[:turn]  # corners turned; plain tuples: np.roll per call was most
    # of the library's build time
    return next(s for s, (i, j) in SIDE_CORNERS.items() if {c[i], c[j]} == {a, b})


def _orient_quads(quads: NDArray[np.int32], rim_vertices: NDArray[np.int64]) -> NDArray[np.int32]:
    """Quads with their corners turned (a cyclic shift, so the winding stays) so that every
    edge two quads share joins their tiles' sides as :func:`_joins` allows. Tubes are built
    upright (v along the tube) and stay so; only quads near a crotch or an apex, where an
    upright grid cannot close, turn: the fewest turns found by a depth-first search over the
    quads within two steps of a bad edge, never one that touches a rim (rims join pieces
    upright). ``(q, 4)`` int32 in, ``(q, 4)`` int32 out."""
    edges = {k: v for k, v in _quad_sides(quads).items() if len(v) == 2}
    nbrs: dict[int, list[tuple[int, int, int]]] = {q: [] for q in range(len(quads))}
    for (a, b), [(qa, _), (qb, _)] in edges.items():
        nbrs[qa].append((qb, a, b))
        nbrs[qb].append((qa, a, b))
    bad = {q for (qa, sa), (qb, sb) in edges.values() if not _joins(sa, sb) for q in (qa, qb)}
    if not bad:
        return quads
    on_rim = np.isin(quads, rim_vertices).sum(axis=1) >= 2
    near = set(bad)
    for _ in range(2):
        near |= {n for q in list(near) for n, _, _ in nbrs[q]}
    free = [q for q in sorted(near) if not on_rim[q]]
    # plain lists: the search reads single elements, which numpy boxes one call at a time
    turn = [0] * len(quads)
    done = [True] * len(quads)
    for q in free:
        done[q] = False
    corners = [tuple(int(v) for v in quad) for quad in quads]

    def fits(q: int) -> bool:
        return all(
            _joins(_side_of(corners[q], turn[q], a, b), _side_of(corners[n], turn[n], a, b))
            for n, a, b in nbrs[q]
            if done[n]
        )

    def search(i: int, budget: int) -> bool:
        if i == len(free):
            return True
        q = free[i]
        for t in (0, 1, 3, 2):
            if t and not budget:
                break
            turn[q], done[q] = t, True
            if fits(q) and search(i + 1, budget - (t != 0)):
                return True
        turn[q], done[q] = 0, False
        return False

    for budget in range(len(free) + 1):  # fewest turns first
        if search(0, budget):
            rows = (np.arange(4)[None] + np.array(turn)[:, None]) % 4
            return np.take_along_axis(quads, rows.astype(np.intp), axis=1)
    raise AssertionError("no tile orientation joins every edge")  # pragma: no cover


def _tile_classes(quads: NDArray[np.int32], crotch: set[tuple[int, int]]) -> NDArray[np.int32]:
    """``(q,)`` int32 tile class of each quad: the class of
    :data:`schemas.tileset.CLASS_EDGES` whose sides carry the colours of the quad's
    edges. An edge's colour: a quarter-turn colour where it joins tiles turned a quarter
    apart, a crotch colour on a branch's crotch loop, else bark (``-h`` on top and bottom,
    ``-v`` on left and right)."""
    colour: dict[tuple[int, int], str] = {}
    for key, holders in _quad_sides(quads).items():
        pair = frozenset(side for _, side in holders)
        if pair in _QUARTER_CW:
            colour[key] = CROTCH_CW
        elif pair in _QUARTER_CCW:
            colour[key] = CROTCH_CCW
        elif key in crotch:
            colour[key] = CROTCH_H if holders[0][1] in ("top", "bottom") else CROTCH_V
    by_edges = {(e.left, e.right, e.top, e.bottom): cid for cid, e in CLASS_EDGES.items()}
    out = np.empty(len(quads), np.int32)
    for q, quad in enumerate(quads):
        sides = {}
        for side, (i, j) in SIDE_CORNERS.items():
            plain = BARK_H if side in ("top", "bottom") else BARK_V
            sides[side] = colour.get(_edge_key(quad[i], quad[j]), plain)
        wanted = (sides["left"], sides["right"], sides["top"], sides["bottom"])
        if wanted not in by_edges:
            raise AssertionError(f"no tile class has edges {wanted}")  # a new crotch layout
        out[q] = by_edges[wanted]
    return out


def _vertex_normals(pos: F64, quads: NDArray[np.int32]) -> F64:
    """Area-weighted vertex normals of a quad mesh (each quad as two triangles)."""
    a, b, c, d = (pos[quads[:, i]] for i in range(4))
    fn = np.cross(c - a, d - b)  # quad normal from its diagonals, twice its area
    n = np.zeros_like(pos)
    for i in range(4):
        np.add.at(n, quads[:, i], fn)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


STEM_HEIGHT = 4.0
# A full-height stem is one frustum of the rim cone, so its leaf rim scale follows from the
# slope: 1 - 4 * 3/64 = 0.8125, exactly representable in binary16.
STEM_SCALE = 1.0 - STEM_HEIGHT * rim.CONE_SLOPE


def make_i_piece(segments: int = 1) -> PieceArrays:
    """I: a slightly narrowing cylinder, one leaf rim straight above the root rim."""
    leaf = translation([0.0, STEM_HEIGHT, 0.0]) @ scaling(STEM_SCALE)
    pb = _PieceBuilder("I", np.array([0.0, STEM_HEIGHT / 2, 0.0]), [leaf])
    heights = _profile_heights(rim.cone_ring, 0.0, STEM_HEIGHT, segments)
    rings = pb.stem(heights, STEM_HEIGHT, 0, leaf)
    for a, b in itertools.pairwise(rings):
        pb.mesh.strip(a, b, BARK)
    return pb.finish()


def make_y_piece(segments: int = 1) -> PieceArrays:
    """Y: a symmetric fork with two co-dominant stems leaning +-30 degrees in the XY plane."""
    y_j = 1.5  # junction height on the root cone
    tilt, length, scale = np.deg2rad(30.0), 2.4, 0.75
    base = np.array([0.42, y_j + 0.35, 0.0])
    right = _leaf_frame(base, -tilt, length, scale)
    left = _leaf_frame(base * [-1, 1, 1], tilt, length, scale)
    pb = _PieceBuilder("Y", np.array([0.0, y_j, 0.0]), [right, left])
    rings = pb.stem(_profile_heights(rim.cone_ring, 0.0, y_j, segments), y_j, None, None)
    for a, b in itertools.pairwise(rings):
        pb.mesh.strip(a, b, BARK)
    top = rings[-1]
    crotch = pb.mesh.add(
        np.array([[0.0, y_j + 0.75, 0.4], [0.0, y_j + 0.75, -0.4]]), _onehot(1, pb.nj)
    )
    # top ring indices: 0:30, 1:90, 2:150, 3:210, 4:270, 5:330 degrees
    right_loop = np.array([top[0], top[1], crotch[0], crotch[1], top[4], top[5]])
    left_loop = np.array([top[1], top[2], top[3], top[4], crotch[1], crotch[0]])
    up = np.array([0.0, 1.0, 0.0])
    for r, loop in enumerate((right_loop, left_loop)):
        frame = pb.leaves[r]
        aligned = _align_ring(loop, pb.mesh.positions()[loop], frame)
        # the three quads leaving the crotch are the fork region (paper Fig. 10)
        cls = np.where(np.isin(aligned, crotch) | np.isin(np.roll(aligned, -1), crotch), FORK, BARK)
        pb.branch(aligned, up, r, segments, cls)
    return pb.finish()


# Rings bounding the lateral holes of T and Psi (and one between); the rows around the holes
# are about as tall as the stem is wide, so their tiles are near square.
HOLE = (0.68, 1.36, 2.12)
HOLE_DROP = 0.25  # how far below their ring the holes' upper corners sit


def _stem_with_holes(
    pb: _PieceBuilder, columns: tuple[int, ...], segments: int, leaf: F64
) -> dict[int, NDArray[np.int64]]:
    """A full-height stem to leaf rim 0 with a two-quad hole in each of ``columns`` between
    rings at heights :data:`HOLE` (0.8 to 2.4: every row 0.8 high, so the stem's quads are
    near square); returns each hole's six-vertex loop."""
    lo, mid, hi = HOLE
    lower = [lo * i / segments for i in range(segments)]
    upper = [hi + (STEM_HEIGHT - hi) * i / (2 * segments) for i in range(1, 2 * segments + 1)]
    heights = [*lower, lo, mid, hi, *upper]
    rings = pb.stem(heights, STEM_HEIGHT, 0, leaf)
    i1 = segments  # ring at HOLE[0]
    for k, (a, b) in enumerate(itertools.pairwise(rings)):
        hole_row = i1 <= k < i1 + 2
        pb.mesh.strip(a, b, BARK, columns if hole_row else ())
    r1, r2, r3 = rings[i1], rings[i1 + 1], rings[i1 + 2]
    loops = {}
    for c in columns:
        d = (c + 1) % rim.SIDES
        # the hole's upper corners sit lower than their ring: the lateral leans up, so its
        # upper side is short; this lengthens it (and its tiles) to match the lower side
        top = np.array([r3[c], r3[d]])
        pb.mesh.move(top, pb.mesh.positions()[top] - [0.0, HOLE_DROP, 0.0])
        loops[c] = np.array([r1[c], r1[d], r2[d], r3[d], r3[c], r2[c]])
    return loops


LATERAL_KNEE = 0.7  # a short lateral's cone row below its leaf rim (quads still 0.69 square)


def _lateral(pb: _PieceBuilder, loop: NDArray[np.int64], r: int, segments: int) -> None:
    """A lateral from the hole ``loop`` to leaf rim ``r``. It leaves half way between the
    hole's outward direction and its own axis, with half-length tangents: of the shapes
    tried, the one whose quads are closest to square."""
    pos = pb.mesh.positions()[loop]
    out = pos.mean(axis=0) * [1.0, 0.0, 1.0]
    out /= np.linalg.norm(out)
    axis = pb.leaves[r][:3, 1] / np.linalg.norm(pb.leaves[r][:3, 1])
    d = out + axis
    pb.branch(loop, 0.5 * d / np.linalg.norm(d), r, segments, FORK, LATERAL_KNEE)


def make_side_piece(segments: int = 1) -> PieceArrays:
    """Side branch (the paper's perpendicular piece): the stem goes on to leaf rim 0 and one
    thinner lateral leaves through a hole in the +X face to leaf rim 1."""
    stem_leaf = translation([0.0, STEM_HEIGHT, 0.0]) @ scaling(STEM_SCALE)
    base = np.array([rim.RADIUS - 1.6 * rim.CONE_SLOPE, 1.6, 0.0]) * [0.85, 1, 1]
    lateral = _leaf_frame(base, np.deg2rad(-50.0), 1.7, 0.5625)
    pb = _PieceBuilder("T", np.array([0.0, 1.6, 0.0]), [stem_leaf, lateral])
    loops = _stem_with_holes(pb, (5,), segments, stem_leaf)
    _lateral(pb, loops[5], 1, segments)
    return pb.finish()


def make_psi_piece(segments: int = 1) -> PieceArrays:
    """Psi: a planar trifurcation; the stem goes on to leaf rim 0, two laterals leave through
    the +X and -X faces to leaf rims 1 and 2."""
    stem_leaf = translation([0.0, STEM_HEIGHT, 0.0]) @ scaling(STEM_SCALE)
    x = (rim.RADIUS - 1.6 * rim.CONE_SLOPE) * 0.85
    right = _leaf_frame(np.array([x, 1.6, 0.0]), np.deg2rad(-45.0), 1.7, 0.625)
    left = _leaf_frame(np.array([-x, 1.6, 0.0]), np.deg2rad(45.0), 1.7, 0.625)
    pb = _PieceBuilder("Psi", np.array([0.0, 1.6, 0.0]), [stem_leaf, right, left])
    # columns: 5 spans 330..30 degrees (+X face), 2 spans 150..210 degrees (-X face)
    loops = _stem_with_holes(pb, (5, 2), segments, stem_leaf)
    _lateral(pb, loops[5], 1, segments)
    _lateral(pb, loops[2], 2, segments)
    return pb.finish()


def _profile_heights(
    ring_at: Callable[[float], F64], y0: float, y1: float, segments: int
) -> list[float]:
    """Heights from ``y0`` to ``y1`` of the rings of the tube ``ring_at(y)`` (a ``(6, 3)`` ring
    at height ``y``), spaced so every row is about as long along the tube as its ring edges:
    rows split the arc length, measured in local edge lengths, evenly, and there are as many
    rows as that length rounded (so bark tiles stay near square), times ``segments``."""
    ys = np.linspace(y0, y1, 257)
    rings = np.stack([ring_at(float(y)) for y in ys])  # (257, 6, 3)
    edge = np.linalg.norm(rings - np.roll(rings, -1, axis=1), axis=-1).mean(axis=1)
    step = np.linalg.norm(np.diff(rings, axis=0), axis=-1).mean(axis=1)
    s = np.concatenate([[0.0], np.cumsum(step / (0.5 * (edge[1:] + edge[:-1])))])
    n = max(1, round(float(s[-1]))) * segments
    return [float(y) for y in np.interp(np.linspace(0.0, s[-1], n + 1), s, ys)]


CAP_BASE = 0.95  # the row next to the root rim lies on the rim cone up to here
CAP_TOP = 2.4  # height of the last ring, which the apex quads close
CAP_TIP = 0.3  # circumradius of the last ring
CAP_APEX = 0.35  # apex height above the last ring


def _cap_ring(y: float) -> F64:
    """``(6, 3)`` ring of the cap at height ``y``: the rim cone up to :data:`CAP_BASE`, then
    a taper leaving the cone tangentially (to first order) and narrowing to :data:`CAP_TIP`."""
    if y <= CAP_BASE:
        return rim.cone_ring(y)
    r1 = 1.0 - rim.CONE_SLOPE * CAP_BASE
    t = (y - CAP_BASE) / (CAP_TOP - CAP_BASE)
    return rim.rim_ring(y, CAP_TIP + (r1 - CAP_TIP) * (1.0 - t * t))


def make_cap_piece(segments: int = 1) -> PieceArrays:
    """Cap: closes a branch. A cone row on the root rim, a taper to a small hexagon, and three
    quads around a raised apex close it, so a branch ends in a point (quad-only, no leaf rims;
    joints: root and hub only)."""
    pb = _PieceBuilder("Cap", np.array([0.0, CAP_BASE, 0.0]), [])
    heights = [CAP_BASE * i / segments for i in range(segments)]
    heights += _profile_heights(_cap_ring, CAP_BASE, CAP_TOP, segments)
    rings = pb.stem(heights, CAP_TOP, None, None, _cap_ring)
    for a, b in itertools.pairwise(rings):
        pb.mesh.strip(a, b, BARK)
    top = rings[-1]
    apex = pb.mesh.add(np.array([0.0, CAP_TOP + CAP_APEX, 0.0]), _onehot(HUB, pb.nj))[0]
    # a hexagon as three quads (apex, 2k+2, 2k+1, 2k): the ring runs clockwise seen from
    # above, so this order is counter-clockwise there and the normals face outward (+Y)
    k = 2 * np.arange(3)
    pb.mesh.quads.append(
        np.stack([np.full(3, apex), top[(k + 2) % 6], top[k + 1], top[k]], axis=-1)
    )
    pb.mesh.classes.append(np.full(3, BARK))
    return pb.finish()


FLARE_TOP = 2.2  # the flare has died out at this height; above it the stem is the rim cone
FLARE = 0.6  # extra radius at the ground, as a fraction of the cone radius
LOBE = 0.5  # buttress lobes: alternate vertices flare by (1 + LOBE) and (1 - LOBE) of FLARE


def _flare_ring(y: float) -> F64:
    """``(6, 3)`` ring of the flared trunk base at height ``y``."""
    f = FLARE * max(0.0, 1.0 - y / FLARE_TOP) ** 2
    k = 1.0 + f * (1.0 + LOBE * (-1.0) ** np.arange(rim.SIDES))
    return rim.cone_ring(y) * np.stack([k, np.ones(rim.SIDES), k], axis=-1)


def make_flare_piece(segments: int = 1) -> PieceArrays:
    """Flare: a trunk base. Like I (one leaf rim straight up, the same building transform),
    but the lower rings flare out into three buttress lobes.

    Its root rim is the ground end of a tree and is attached to nothing, so it is *not* the
    universal rim: wider than it, lobed, with normals from the mesh. Use Flare only as a tree's
    first piece (its leaf rim is universal, so anything may grow on it)."""
    leaf = translation([0.0, STEM_HEIGHT, 0.0]) @ scaling(STEM_SCALE)
    pb = _PieceBuilder("Flare", np.array([0.0, STEM_HEIGHT / 2, 0.0]), [leaf], universal_root=False)
    heights = _profile_heights(_flare_ring, 0.0, STEM_HEIGHT, segments)
    rings = pb.stem(heights, STEM_HEIGHT, 0, leaf, _flare_ring)
    for a, b in itertools.pairwise(rings):
        pb.mesh.strip(a, b, BARK)
    return pb.finish()


# New pieces go at the end: a piece's index here is its prototype index in written scenes.
MAKERS = {
    "I": make_i_piece,
    "Y": make_y_piece,
    "T": make_side_piece,
    "Psi": make_psi_piece,
    "Cap": make_cap_piece,
    "Flare": make_flare_piece,
}
PIECE_NAMES: tuple[str, ...] = tuple(MAKERS)


def piece_library(segments: int = 1) -> tuple[PieceArrays, ...]:
    """All pieces at one resolution, in :data:`PIECE_NAMES` order (the prototype order)."""
    # cached by the value: a cache on this signature keeps piece_library() and
    # piece_library(1) apart and built the library twice (half a second each)
    return _piece_library(segments)


@cache
def _piece_library(segments: int) -> tuple[PieceArrays, ...]:
    return tuple(make(segments) for make in MAKERS.values())


def skinning_rest_inverse(pieces: tuple[PieceArrays, ...]) -> F64:
    """``(p, MAX_JOINTS, 4, 4)`` inverse rest joint frames, identity-padded."""
    out = np.broadcast_to(np.eye(4), (len(pieces), MAX_JOINTS, 4, 4)).copy()
    for i, p in enumerate(pieces):
        out[i, : p.n_joints] = invert_similarity(p.joint_rest)
    return out
