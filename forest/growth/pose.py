"""A forest's pose (paper 4.3): per instance, the bends and spreads drawn from the grammar's
ranges on each piece's own key (:func:`draw_pose`). :class:`forest.growth.poser.Poser`
evaluates it (with wind) into bone transforms; :mod:`forest.growth.tropism` turns its bends
toward the vertical and the light."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from forest.geometry.pieces import MAX_LEAF_RIMS, PieceArrays
from forest.geometry.transforms import F64, similarity_scale
from forest.growth import keyed
from forest.growth.expand import PieceGraph, children_radius, rim_tables
from forest.growth.grammar import CompiledGrammar


@dataclass(frozen=True, eq=False)
class PoseParams:
    """Per-instance pose drawn from the grammar's ranges.

    bend_azimuth, bend_angle : (n,) hub rotation about the horizontal axis at that azimuth
    spread_azimuth, spread_angle : (n, R) terminal rotations, likewise (radians)
    tip_scale : (n, R) terminal uniform scale: the rest scale times the radius scale, the
    latter rounded to binary16 (USD stores SkelAnimation scales as half3, and the skinned
    export stores exactly that ratio; rounding here keeps our skinning and USD's identical)
    length : (n,) length scale of each instance (scales its joint offsets)
    phase : (n,) wind phase (per tree, plus a little per depth)
    """

    bend_azimuth: F64
    bend_angle: F64
    spread_azimuth: F64
    spread_angle: F64
    tip_scale: F64
    length: F64
    phase: F64


# pose draws on each piece's key (forest.growth.keyed), past the streams growth took, so a
# tree's pose is its own whatever forest or tile holds it
_SPREAD, _BEND, _WANT = 16, 16 + MAX_LEAF_RIMS, 17 + MAX_LEAF_RIMS
_PHASE = 17 + 2 * MAX_LEAF_RIMS  # on the root's key


def draw_pose(
    graph: PieceGraph,
    pieces: tuple[PieceArrays, ...],
    cg: CompiledGrammar,
) -> PoseParams:
    """Random bends and spreads from the grammar's ranges; lateral rims turned to their
    ``branch_angle`` within the plane of their rest tilt."""
    bend = np.take(cg.alt_bend, graph.alt, axis=0)
    spread = np.take(cg.alt_spread, graph.alt, axis=0)
    sigma = np.take(rest_tip_scale(pieces), graph.piece, axis=0)
    roots = np.flatnonzero(graph.parent < 0)  # one per tree, in tree order
    tree_phase = keyed.draw(graph.key[roots], _PHASE) * (2 * np.pi)
    radius = graph.radius.astype(np.float16).astype(np.float64)
    # draws only where a rim exists (a cap has none, most pieces fewer than MAX_LEAF_RIMS):
    # the same values keyed.pairs gives at those (piece, rim) pairs, at a fraction of the
    # hashing; absent rims keep zeros, which nothing reads
    tab = rim_tables()
    rims = np.take(tab.rims, graph.piece)
    i, r = np.nonzero(np.arange(MAX_LEAF_RIMS) < rims[:, None])
    key = np.take(graph.key, i)
    u = _pairs_at(key, r, _SPREAD)
    spread_azimuth = np.zeros((len(graph), MAX_LEAF_RIMS))
    spread_angle = np.zeros((len(graph), MAX_LEAF_RIMS))
    lo, hi = np.take(spread[:, 0], i), np.take(spread[:, 1], i)
    flat = i * MAX_LEAF_RIMS + r
    np.put(spread_azimuth, flat, u[:, 0] * (2 * np.pi))
    np.put(spread_angle, flat, lo + u[:, 1] * (hi - lo))
    angle = np.take(cg.alt_branch_angle, graph.alt, axis=0)
    if not np.isnan(angle[:, 0]).all():
        # lateral rims of branch-angled pieces only: the draws and the trig are the cost here
        tilt = tab.tilt[np.take(graph.piece, i), r]
        a_lo, a_hi = np.take(angle[:, 0], i), np.take(angle[:, 1], i)
        lat = np.flatnonzero(~np.isnan(a_lo) & (tilt >= 1e-3))
        want = a_lo[lat] + _pairs_at(key[lat], r[lat], _WANT)[:, 0] * (a_hi[lat] - a_lo[lat])
        turn = want - tilt[lat]
        on = turn != 0
        at = flat[lat][on]
        az, ang = _add_tilts(
            np.take(spread_azimuth, at),
            np.take(spread_angle, at),
            tab.tilt_az.ravel()[np.take(graph.piece, i[lat][on]) * MAX_LEAF_RIMS + r[lat][on]],
            turn[on],
        )
        np.put(spread_azimuth, at, az)
        np.put(spread_angle, at, ang)
    u = keyed.pairs(graph.key, _BEND)
    return PoseParams(
        bend_azimuth=u[:, 0] * (2 * np.pi),
        bend_angle=bend[:, 0] + u[:, 1] * (bend[:, 1] - bend[:, 0]),
        spread_azimuth=spread_azimuth,
        spread_angle=spread_angle,
        tip_scale=sigma * children_radius(graph, radius),
        length=graph.length,
        phase=np.take(tree_phase, graph.tree) + 0.35 * graph.depth,
    )


def _pairs_at(keys: NDArray[np.uint64], rim: NDArray[np.intp], stream: int) -> F64:
    """``(k, 2)`` :func:`keyed.pairs` of each key at its own rim's stream ``stream + rim``
    (what ``keyed.pairs(keys, stream, MAX_LEAF_RIMS)[j, rim[j]]`` holds)."""
    h = keyed.mix(keys + np.take(keyed.offsets(stream, MAX_LEAF_RIMS), rim))
    u = h.view(np.uint32).reshape(len(h), 2).astype(np.float64)
    u *= 2.0**-32
    return u


def _add_tilts(az0: F64, angle0: F64, az1: F64, angle1: F64) -> tuple[F64, F64]:
    """Two rotations about horizontal axes (azimuth, angle) as one, by adding their rotation
    vectors (exact for a common axis, close for the small angles of poses)."""
    x = angle0 * np.cos(az0) + angle1 * np.cos(az1)
    z = angle0 * np.sin(az0) + angle1 * np.sin(az1)
    return np.arctan2(z, x), np.hypot(x, z)


def rest_tip_scale(pieces: tuple[PieceArrays, ...]) -> F64:
    """``(p, MAX_LEAF_RIMS)`` each piece's terminals' rest scale (its building
    transforms'), 1 past its leaf rims."""
    out = np.ones((len(pieces), MAX_LEAF_RIMS))
    for i, p in enumerate(pieces):
        out[i, : p.n_leaf_rims] = similarity_scale(p.building)
    return out
