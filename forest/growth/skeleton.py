"""Bones of a whole forest (paper 4.3): one palette, an offset per instance, random poses and
time-sampled wind.

Every piece instance owns ``2 + leaf rims`` bones (root, hub, one terminal per leaf rim; see
``forest.geometry.pieces``). A child's root bone hangs rigidly under its parent's terminal bone
with the twist as its local transform, so rims stay closed in every pose. Local bone transforms are
similarities ``Tr(t) @ R @ S(s)``; global ones come from forward kinematics, one bone level at
a time. Palette entries are skinning matrices ``G @ inv(J)``: they map prototype (model-space)
points straight to world space.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import cache, cached_property

import numpy as np
from numpy.typing import NDArray

from forest.geometry import affine, rim
from forest.geometry.pieces import HUB, MAX_LEAF_RIMS, TIP0, PieceArrays, skinning_rest_inverse
from forest.geometry.transforms import F64, decompose_similarity, invert_similarity
from forest.growth import keyed
from forest.growth.assembly import building_twist_table
from forest.growth.expand import LevelBlock, PieceGraph, children_radius, rim_tables
from forest.growth.grammar import CompiledGrammar
from forest.growth.parallel import for_block_groups

I32 = NDArray[np.int32]
LevelHook = Callable[[NDArray[np.intp], F64], None]


# a clip loops when it lasts at least this many periods of the slow sway (the sway then runs
# at most four times as fast as asked); shorter clips are sampled at the frequencies as asked
LOOP_MIN_CYCLES = 0.25


@dataclass(frozen=True)
class Wind:
    """Wind as a few layered sines per piece, all bending about axes in the horizontal plane.

    Each piece's rotation vector (radians, in its root frame) is ``amp * (lean + sway + gust)``
    about the axis across ``direction`` plus ``amp * side`` about the axis along it, with

    * ``sway``: a slow sine at ``frequency_hz`` with the tree's own phase (neighbours differ);
    * ``gust``: an envelope at ``gust_hz`` that travels downwind at ``gust_speed`` m/s (its
      arrival time grows with distance along the wind) times a faster wobble at about
      ``2.3 * gust_hz`` with a per-piece phase (branch-level motion);
    * ``flutter``: a small fast term at ``flutter_hz`` on the deepest pieces (leaf clouds ride
      their hub bones, so they flutter with them).

    ``amp`` grows linearly with depth from ``strength * base`` at the trunk to ``strength`` at
    the deepest pieces, and with thinness: times ``(trunk radius / radius) ** radius_power``,
    at most ``4``. With ``loop_s`` (a clip of that many seconds; ForestOptions sets it to
    ``frames / fps``) of at least ``LOOP_MIN_CYCLES`` sway periods, every frequency is rounded
    to a distinct non-zero multiple of ``1 / loop_s``, so the pose at ``loop_s`` equals the
    pose at 0 and the clip loops.
    """

    strength_deg: float = 4.0
    frequency_hz: float = 0.4
    direction_deg: float = 0.0
    base: float = 0.15
    sway: float = 0.5
    gust_hz: float = 0.7
    gust: float = 0.8
    gust_speed: float = 6.0
    flutter_hz: float = 2.6
    flutter: float = 0.15
    radius_power: float = 0.25
    loop_s: float = 0.0

    def frequencies(self) -> tuple[float, float, float, float]:
        """``(sway, gust envelope, gust wobble, flutter)`` in Hz, snapped to the loop."""
        want = (self.frequency_hz, self.gust_hz, 2.3 * self.gust_hz, self.flutter_hz)
        if not self.loop_s * self.frequency_hz >= LOOP_MIN_CYCLES:
            # too short a clip to loop: its sway would have to run many times too fast
            return want
        out: list[float] = []
        k_prev = 0
        for f in want:
            # distinct multiples: two terms on one frequency would beat in lockstep
            k = max(k_prev + 1, round(f * self.loop_s))
            out.append(k / self.loop_s)
            k_prev = k
        return out[0], out[1], out[2], out[3]


@dataclass(frozen=True, eq=False)
class Bones:
    """Bone tables of a forest, in palette order (instance-major, joint-minor).

    offset : (n,) int32 first bone of each instance      instance, joint : (b,) int32
    parent : (b,) int32 parent bone, -1 for tree roots
    rest : (p, MAX_JOINTS, 4, 4) joint frames J per piece; inv_rest their inverses
    """

    offset: I32
    instance: I32
    joint: I32
    parent: I32
    rest: F64
    inv_rest: F64

    def __len__(self) -> int:
        return len(self.instance)


def joints_per_instance(graph: PieceGraph, pieces: tuple[PieceArrays, ...]) -> I32:
    """``(n,)`` bones of each instance (its piece's joints): the palette has their sum."""
    return np.take(np.array([p.n_joints for p in pieces], np.int32), graph.piece)


def build_bones(graph: PieceGraph, pieces: tuple[PieceArrays, ...]) -> Bones:
    n_joints = joints_per_instance(graph, pieces)
    offset = np.zeros(len(graph), np.int32)
    np.cumsum(n_joints[:-1], out=offset[1:])
    instance = np.repeat(np.arange(len(graph), dtype=np.int32), n_joints)
    first = np.repeat(offset, n_joints)  # each bone's instance's first bone
    joint = np.arange(len(instance), dtype=np.int32)
    joint -= first
    # hub -> own root; terminal -> own hub; root -> the parent's terminal for this rim
    parent = first + (joint > HUB).astype(np.int32)
    has = graph.parent >= 0
    parent[offset] = -1
    parent[offset[has]] = offset[graph.parent[has]] + TIP0 + graph.parent_rim[has]
    inv = skinning_rest_inverse(pieces)
    return Bones(
        offset=offset,
        instance=instance,
        joint=joint,
        parent=parent,
        rest=invert_similarity(inv),
        inv_rest=inv,
    )


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
    sigma = np.take(_rest_tip_scale(pieces), graph.piece, axis=0)
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


def apply_tropisms(
    graph: PieceGraph,
    bones: Bones,
    pieces: tuple[PieceArrays, ...],
    tree_transforms: F64,
    transforms: F64,
    pose: PoseParams,
    alt_tropism: F64,
) -> tuple[PoseParams, F64]:
    """The pose with each piece's hub bend turned toward the vertical (gravitropism) and the
    light (outward from its trunk, 45 degrees up) by the fractions ``alt_tropism`` ``(A, 2)``
    of the angles between the piece's axis and those directions, and its palette (no wind).

    A piece's axis depends on every bend below it, so the bends are found level by level
    inside one forward-kinematics pass of the palette (the same closed forms, so what is
    measured is what is drawn)."""
    out = replace(pose, bend_azimuth=pose.bend_azimuth.copy(), bend_angle=pose.bend_angle.copy())
    strength = np.take(alt_tropism, graph.alt, axis=0)
    centre = tree_transforms[:, :3, 3]

    def bend_level(idx: NDArray[np.intp], root: F64) -> None:
        gravity, light = strength[idx, 0], strength[idx, 1]
        on = (gravity != 0) | (light != 0)
        if not on.any():
            return
        if not on.all():
            idx, root, gravity, light = idx[on], root[:, on], gravity[on], light[on]
        r = root[affine.LIN]  # rows r00 r01 r02 r10 ... of R, a rotation times a scale
        # the bend as a rotation vector (x, 0, z) about a horizontal axis: tilts toward the
        # vertical and the light add to it, and only the sum goes back to azimuth and angle
        cos_az, sin_az = affine.cos_sin(out.bend_azimuth[idx])
        ang = out.bend_angle[idx]
        x, z = ang * cos_az, ang * sin_az
        # the light: outward from the trunk, 45 degrees up (straight up on the trunk's axis)
        tree = graph.tree[idx]
        ox = root[3] - np.take(centre[:, 0], tree)
        oz = root[11] - np.take(centre[:, 2], tree)
        flat = np.sqrt(ox * ox + oz * oz)
        on_axis = flat < 1e-12
        h = np.where(on_axis, 0.0, 1.0 / np.where(on_axis, 1.0, flat * np.sqrt(2.0)))
        sun_y = np.where(on_axis, 1.0, np.sqrt(0.5))
        sx, sz = ox * h, oz * h
        # R^T d: each direction in the piece's frame; for d = (0, +-1, 0), R's second row
        up = np.sign(gravity)
        x, z = _tilt_toward(x, z, np.abs(gravity), up * r[3], up * r[4], up * r[5])
        if light.any():
            x, z = _tilt_toward(
                x,
                z,
                light,
                r[0] * sx + r[3] * sun_y + r[6] * sz,
                r[1] * sx + r[4] * sun_y + r[7] * sz,
                r[2] * sx + r[5] * sun_y + r[8] * sz,
            )
        out.bend_azimuth[idx] = np.arctan2(z, x)
        out.bend_angle[idx] = np.hypot(x, z)

    poser = Poser(graph, bones, pieces, tree_transforms, transforms, out)
    return out, poser.palette(level_hook=bend_level)


def _tilt_toward(x: F64, z: F64, k: F64, lx: F64, ly: F64, lz: F64) -> tuple[F64, F64]:
    """A horizontal-axis rotation vector ``(x, 0, z)`` plus the fraction ``k`` of the tilt
    that brings the piece's axis (+Y) onto the direction ``(lx, ly, lz)`` (its frame, any
    length): about ``+Y x d``, by ``k`` times the angle between them. Straight away from
    ``d`` there is no preferred side, and no tilt."""
    norm = np.sqrt(lx * lx + ly * ly + lz * lz)
    side = np.sqrt(lx * lx + lz * lz)
    off = np.arccos(np.clip(ly / np.maximum(norm, 1e-300), -1.0, 1.0))
    turn = np.where(side > 1e-9 * norm, k * off / np.maximum(side, 1e-300), 0.0)
    return x + turn * lz, z - turn * lx


def rest_pose(graph: PieceGraph, pieces: tuple[PieceArrays, ...]) -> PoseParams:
    """The pose with every joint at rest (palette = topological transforms)."""
    n = len(graph)
    return PoseParams(
        bend_azimuth=np.zeros(n),
        bend_angle=np.zeros(n),
        spread_azimuth=np.zeros((n, MAX_LEAF_RIMS)),
        spread_angle=np.zeros((n, MAX_LEAF_RIMS)),
        tip_scale=_rest_tip_scale(pieces)[graph.piece],
        length=np.ones(n),
        phase=np.zeros(n),
    )


def _rest_tip_scale(pieces: tuple[PieceArrays, ...]) -> F64:
    out = np.ones((len(pieces), MAX_LEAF_RIMS))
    for i, p in enumerate(pieces):
        out[i, : p.n_leaf_rims] = np.cbrt(np.linalg.det(p.building[:, :3, :3]))
    return out


@dataclass(frozen=True, eq=False)
class _PieceTables:
    """Per piece (p) and leaf rim (r), in the SoA layout of :mod:`forest.geometry.affine`.

    hub_t : (3, p) hub offset from the root
    tip_t : (3, p*R) terminal offset from the hub tip_r : (9, p*R) terminal rest rotation
    tip_scale : (p*R,) terminal rest scale sigma
    tip_th : (3, p*R) terminal offset from the root, ``t + h``
    rims : (p,) intp leaf rims per piece
    twists : (12, 6) the six rim twists
    building_twist : (12, p*R*6) ``B_r @ Twist_k``
    """

    hub_t: F64
    tip_t: F64
    tip_r: F64
    tip_scale: F64
    tip_th: F64
    rims: NDArray[np.intp]
    twists: F64
    building_twist: F64


@cache
def _piece_tables(pieces: tuple[PieceArrays, ...]) -> _PieceTables:
    n = len(pieces)
    hub_t = np.zeros((n, 3))
    tip_t = np.zeros((n, MAX_LEAF_RIMS, 3))
    tip_r = np.broadcast_to(np.eye(3), (n, MAX_LEAF_RIMS, 3, 3)).copy()
    for i, p in enumerate(pieces):
        hub_t[i] = p.joint_rest[HUB, :3, 3]
        local = invert_similarity(p.joint_rest[HUB]) @ p.joint_rest[TIP0:]
        tip_t[i, : p.n_leaf_rims] = local[:, :3, 3]
        lin = local[:, :3, :3]
        tip_r[i, : p.n_leaf_rims] = lin / np.cbrt(np.linalg.det(lin))[:, None, None]
    return _PieceTables(
        hub_t=hub_t.T.copy(),
        tip_t=tip_t.reshape(-1, 3).T.copy(),
        tip_r=tip_r.reshape(-1, 9).T.copy(),
        tip_scale=_rest_tip_scale(pieces).ravel(),
        tip_th=(tip_t + hub_t[:, None]).reshape(-1, 3).T.copy(),
        rims=np.array([p.n_leaf_rims for p in pieces], np.intp),
        twists=affine.from_matrices(rim.twists()),
        building_twist=building_twist_table(pieces),
    )


@dataclass(frozen=True, eq=False)
class _Locals:
    """Local transforms of a set of instances (SoA, see :mod:`forest.geometry.affine`): roots and
    hubs ``(12, m)``; terminals ``(12, k)`` with their instance position ``pos`` and rim ``r``."""

    root: F64
    hub: F64
    tips: F64
    pos: NDArray[np.intp]
    r: NDArray[np.intp]


@dataclass(frozen=True, eq=False)
class Poser:
    """Evaluates a forest's pose (and wind) into local bone transforms or the palette.

    Both outputs take their rotations from :meth:`_rotations`, the one definition of the
    pose: locals (:meth:`locals_for`) are ``Tr(length * t) @ R_wind @ R_bend`` for hubs and
    ``Tr(length * t) @ R_wind @ R_spread @ R_rest @ S(scale)`` for terminals, a root bone's
    local being the tree's model transform or the twist; the palette composes the same
    rotations down each block's depth levels in closed form (:meth:`_palette_block`).
    """

    graph: PieceGraph
    bones: Bones
    pieces: tuple[PieceArrays, ...]
    tree_transforms: F64
    transforms: F64
    pose: PoseParams

    @cached_property
    def _tree_depth(self) -> NDArray[np.int32]:
        """``(t,)`` depth of each tree's deepest piece."""
        deepest = np.zeros(int(self.graph.tree.max()) + 1, np.int32)
        np.maximum.at(deepest, self.graph.tree, self.graph.depth)
        return deepest

    @cached_property
    def _wind_fields(self) -> dict[Wind, _WindField]:
        return {}

    def _wind_field(self, wind: Wind) -> _WindField:
        """The time-independent part of a wind, computed once for all of its frames."""
        if wind not in self._wind_fields:
            g = self.graph
            d = np.deg2rad(wind.direction_deg)
            across = np.array([np.sin(d), 0.0, -np.cos(d)])  # up x direction
            along = np.array([np.cos(d), 0.0, np.sin(d)])
            rot_t = self.transforms[:, :3, :3]
            deepest = np.maximum(np.take(self._tree_depth, g.tree), 1)
            rel = g.depth / deepest
            trunk_r = np.zeros(len(self._tree_depth))
            np.maximum.at(trunk_r, g.tree, g.scale)
            thin = np.clip(
                (np.take(trunk_r, g.tree) / np.maximum(g.scale, 1e-6)) ** wind.radius_power,
                1.0,
                4.0,
            )
            amp = np.deg2rad(wind.strength_deg) * (wind.base + (1 - wind.base) * rel) * thin
            # only the last quarter of each tree's depth flutters, growing to the tips
            flutter = wind.flutter * np.clip((rel - 0.75) / 0.25, 0.0, 1.0) ** 2
            # downwind distance of each tree's base: the gust's delay there
            dist = self.tree_transforms[:, :3, 3] @ along
            delay = np.take(dist, g.tree) / max(wind.gust_speed, 1e-6)
            # a per-piece phase from the instance index (golden-ratio hashing): branch motion
            # out of step with its neighbours, reproducible without a random stream
            piece_phase: F64 = np.mod(np.arange(len(g)) * 0.6180339887498949, 1.0) * (2 * np.pi)
            self._wind_fields[wind] = _WindField(
                amp=amp,
                # contiguous: every frame takes columns of these (einsum returns them
                # Fortran-ordered, and a take along axis 1 of that copies each time)
                across=np.ascontiguousarray(np.einsum("nji,j->in", rot_t, across)),  # R^T a
                along=np.ascontiguousarray(np.einsum("nji,j->in", rot_t, along)),
                flutter=flutter,
                delay=delay,
                piece_phase=piece_phase,
            )
        return self._wind_fields[wind]

    def gust_envelope(self, idx: NDArray[np.intp], wind: Wind, time: float) -> F64:
        """``(m,)`` the gust's strength in [0, 1] at the instances ``idx`` at ``time``: a
        peaked (squared) sine travelling downwind at ``wind.gust_speed``."""
        f_env = wind.frequencies()[1]
        delay = self._wind_field(wind).delay[idx]
        return (0.5 + 0.5 * np.sin(2 * np.pi * f_env * (time - delay))) ** 2

    def _wind(self, idx: NDArray[np.intp], wind: Wind | None, time: float) -> F64 | None:
        """Per instance of ``idx``: the wind's rotation vector ``(3, m)`` (radians about its
        direction) in the instance's root frame at ``time``."""
        if wind is None or not wind.strength_deg:
            return None
        fld = self._wind_field(wind)
        f_sway, _, f_wob, f_flut = wind.frequencies()
        tau = 2 * np.pi * time
        tree_phase = self.pose.phase[idx]
        own = fld.piece_phase[idx]
        env = self.gust_envelope(idx, wind, time)
        bend = (
            0.35  # the mean lean downwind
            + wind.sway * np.sin(tau * f_sway + tree_phase)
            + wind.gust * env * (1.0 + 0.35 * np.sin(tau * f_wob + own))
        )
        flut = fld.flutter[idx]
        side = 0.25 * env * np.sin(tau * f_wob + 1.3 * own) + flut * np.sin(
            tau * f_flut + 2.0 * own
        )
        bend = bend + flut * np.sin(tau * f_flut + own)
        amp = fld.amp[idx]
        return (amp * bend) * np.take(fld.across, idx, axis=1) + (amp * side) * np.take(
            fld.along, idx, axis=1
        )

    def _terminals(
        self, idx: NDArray[np.intp]
    ) -> tuple[
        NDArray[np.intp], NDArray[np.intp], NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]
    ]:
        """``rims, tipstart, pos, r, flat`` of the instances ``idx`` (see _Rotations)."""
        rims = _piece_tables(self.pieces).rims[self.graph.piece[idx]]
        tipstart = np.cumsum(rims) - rims
        pos = np.repeat(np.arange(len(idx)), rims)
        r = np.arange(len(pos)) - tipstart[pos]
        flat = idx[pos] * MAX_LEAF_RIMS + r  # into the (n, R) pose arrays
        return rims, tipstart, pos, r, flat

    def _rotations(self, idx: NDArray[np.intp], wind: Wind | None, time: float) -> _Rotations:
        """Pose rotations of the instances ``idx`` and of their terminals (see _Rotations)."""
        pose = self.pose
        rims, tipstart, pos, r, flat = self._terminals(idx)
        hub = affine.horizontal_rotation(pose.bend_azimuth[idx], pose.bend_angle[idx])
        tip = affine.horizontal_rotation(
            np.take(pose.spread_azimuth, flat), np.take(pose.spread_angle, flat)
        )
        vec = self._wind(idx, wind, time)
        if vec is not None:
            hub = affine.compose_linear(_rotation(vec), hub)
            # in the hub's frame; tips sway half as much as hubs, so the motion ripples up
            # the tree instead of swinging each piece rigidly
            hub_vec = affine.apply_linear(affine.transpose_linear(hub)[:, pos], vec[:, pos])
            tip = affine.compose_linear(_rotation(0.5 * hub_vec), tip)
        return _Rotations(hub, tip, rims, tipstart, pos, r, flat)

    def locals_for(
        self, idx: NDArray[np.intp], wind: Wind | None = None, time: float = 0.0
    ) -> _Locals:
        """Local transforms of the instances ``idx``."""
        g, pose, tab = self.graph, self.pose, _piece_tables(self.pieces)
        top = g.parent[idx] < 0
        root = tab.twists[:, g.twist[idx]]
        if top.any():
            root[:, top] = affine.from_matrices(self.tree_transforms[g.tree[idx[top]]])
        rot = self._rotations(idx, wind, time)
        piece = g.piece[idx]
        hub = np.empty((12, len(idx)))
        hub[affine.LIN] = rot.hub
        hub[affine.TRANS] = pose.length[idx] * tab.hub_t[:, piece]
        inst = idx[rot.pos]
        col = piece[rot.pos] * MAX_LEAF_RIMS + rot.r
        tips = np.empty((12, len(rot.pos)))
        tips[affine.LIN] = affine.compose_linear(rot.tip, tab.tip_r[:, col]) * np.take(
            pose.tip_scale, rot.flat
        )
        tips[affine.TRANS] = pose.length[inst] * tab.tip_t[:, col]
        return _Locals(root, hub, tips, rot.pos, rot.r)

    def rig_parts(self) -> tuple[F64, F64, F64]:
        """What wind never changes of the bones' local transforms (:meth:`locals_for`
        without the hubs' and terminals' rotations, which a rig stores apart): ``(b, 3)``
        translations, ``(b,)`` uniform scales and ``(n, 4)`` xyzw rotations of the instances'
        roots. Hubs turn without scaling; a terminal scales by its pose's ``tip_scale`` (its
        rest rotation has unit determinant); a root is a rim twist or its tree's model
        transform."""
        g, pose, tab, bones = self.graph, self.pose, _piece_tables(self.pieces), self.bones
        _, _, pos, r, flat = self._terminals(np.arange(len(g)))
        off = bones.offset
        translation = np.empty((len(bones), 3))
        scale = np.ones(len(bones))
        root_t, root_q, root_s = (x[g.twist] for x in decompose_similarity(rim.twists()))
        top = np.flatnonzero(g.parent < 0)
        root_t[top], root_q[top], root_s[top] = decompose_similarity(
            self.tree_transforms[g.tree[top]]
        )
        translation[off], scale[off] = root_t, root_s
        translation[off + HUB] = (pose.length * tab.hub_t[:, g.piece]).T
        tips = off[pos] + TIP0 + r
        translation[tips] = (pose.length[pos] * tab.tip_t[:, g.piece[pos] * MAX_LEAF_RIMS + r]).T
        scale[tips] = np.take(pose.tip_scale, flat)
        return translation, scale, root_q

    def local_transforms(self, wind: Wind | None = None, time: float = 0.0) -> F64:
        """``(b, 4, 4)`` local transforms of every bone (what a SkelAnimation stores)."""
        loc = self.locals_for(np.arange(len(self.graph)), wind, time)
        out = np.empty((len(self.bones), 4, 4))
        off = self.bones.offset
        out[off] = affine.to_matrices(loc.root)
        out[off + HUB] = affine.to_matrices(loc.hub)
        out[off[loc.pos] + TIP0 + loc.r] = affine.to_matrices(loc.tips)
        return out

    def joint_rotations(
        self, wind: Wind | None = None, time: float = 0.0, start: int = 0, stop: int | None = None
    ) -> F64:
        """``(9, b - n)`` the local rotations of the bones that turn (every hub and terminal;
        an instance's root never does), in palette order without the roots: what compact
        wind stores per frame (:mod:`forest.growth.rig`). Rotations only: a terminal's local
        linear part is this times its scale. With ``start``/``stop``, the columns of the
        instances ``start:stop`` alone (their bones are contiguous), so a writer can go a
        block at a time."""
        n = len(self.graph)
        stop = n if stop is None else stop
        tab = _piece_tables(self.pieces)
        idx = np.arange(start, stop)
        rot = self._rotations(idx, wind, time)
        col = self.graph.piece[idx[rot.pos]] * MAX_LEAF_RIMS + rot.r
        # bone b of instance i is column b - (i + 1) once the roots are taken out
        ends = np.append(self.bones.offset, len(self.bones))
        base = ends[start] - start
        out = np.empty((9, ends[stop] - stop - base))
        first = self.bones.offset[idx] - idx - base
        out[:, first] = rot.hub
        out[:, first[rot.pos] + 1 + rot.r] = affine.compose_linear(
            rot.tip, np.take(tab.tip_r, col, axis=1)
        )
        return out

    def palette(
        self,
        wind: Wind | None = None,
        time: float = 0.0,
        row_vectors: bool = False,
        level_hook: LevelHook | None = None,
    ) -> F64:
        """``(b, 4, 4)`` skinning matrices ``G @ inv(J)``, computed block by block of whole
        trees (small enough for the temporaries to stay in cache); transposed for USD with
        ``row_vectors``, so a scene writer needs no second copy. ``level_hook(idx, root)``
        sees each level's root globals ``(12, m)`` before that level's rotations are read."""
        pal = np.empty((len(self.bones), 4, 4))
        if wind is not None and wind.strength_deg:
            self._wind_field(wind)  # shared by the threads: made once, before them

        def run(blocks: Sequence[LevelBlock]) -> None:
            scratch = _BlockScratch.for_blocks(blocks, self.bones)
            for blk in blocks:
                self._palette_block(blk, pal, wind, time, row_vectors, level_hook, scratch)

        for_block_groups(run, self.graph.blocks)
        return pal

    def _palette_block(
        self,
        blk: LevelBlock,
        pal: F64,
        wind: Wind | None,
        time: float,
        row_vectors: bool,
        level_hook: LevelHook | None = None,
        scratch: _BlockScratch | None = None,
    ) -> None:
        """Forward kinematics of one block, a depth level at a time, in closed forms that
        skip the hubs' and terminals' globals.

        With ``J_hub = Tr(h)`` and the hub's local ``Tr(length h) R``, the hub's palette entry
        is ``G_root @ [R | length h - R h]``. With ``J_tip = B_r = Tr(h + t) R_rest S(sigma)``
        and the terminal's local ``Tr(length t) R S(sigma rho)``, the terminal's entry is
        ``P_hub @ [rho R | (length - 1) t + (t + h) - rho R (t + h)]``. A child's root global
        is its parent terminal's entry times ``B_r @ Twist_k``, a constant per piece, rim and
        twist. Each level's bones land in contiguous columns (roots, hubs, terminals); one
        gather at the end puts them in palette order.
        """
        g, b, pose = self.graph, self.bones, self.pose
        tab = _piece_tables(self.pieces)
        b0 = int(b.offset[blk.start])
        b1 = int(b.offset[blk.stop]) if blk.stop < len(g) else len(b)
        scratch = scratch or _BlockScratch(b1 - b0)
        cols = scratch.columns(b1 - b0)  # this block's palette, SoA, in computed order
        bone = scratch.bone[: b1 - b0]  # palette row (within the block) of each column
        at = 0  # next free column
        prev = (0, 0, np.zeros(0, np.intp))  # last level: first column of its terminals,
        # its first position in the block's depth order, each instance's first terminal
        for lo, idx in blk.levels():
            n = len(idx)
            piece = g.piece[idx]
            par = g.parent[idx]
            root = cols[:, at : at + n]
            if lo == 0:
                root[:] = affine.from_matrices(self.tree_transforms[g.tree[idx]])
            else:
                tip0, prev_lo, prev_start = prev
                prim = g.parent_rim[idx]
                parent_tip = tip0 + prev_start[blk.rank[par - blk.start] - prev_lo] + prim
                bt = np.take(g.building_twist_column, idx)
                affine.compose(
                    np.take(cols, parent_tip, axis=1),
                    np.take(tab.building_twist, bt, axis=1),
                    out=root,
                )
            if level_hook is not None:
                level_hook(idx, root)
            rot = self._rotations(idx, wind, time)
            h = np.take(tab.hub_t, piece, axis=1)
            local = np.empty((12, n))
            local[affine.LIN] = rot.hub
            local[affine.TRANS] = pose.length[idx] * h - affine.apply_linear(rot.hub, h)
            hub = affine.compose(root, local, out=cols[:, at + n : at + 2 * n])
            k = len(rot.pos)
            tcol = piece[rot.pos] * MAX_LEAF_RIMS + rot.r
            rho = np.take(pose.tip_scale, rot.flat) / np.take(tab.tip_scale, tcol)
            th = np.take(tab.tip_th, tcol, axis=1)
            local = np.empty((12, k))
            local[affine.LIN] = rot.tip * rho
            local[affine.TRANS] = (
                (pose.length[idx[rot.pos]] - 1.0) * np.take(tab.tip_t, tcol, axis=1)
                + th
                - affine.apply_linear(local[affine.LIN], th)
            )
            # one terminal per instance (k == n with no rimless cap among them): no repeat
            one_each = k == n and (n == 0 or rot.rims.min() == 1)
            per_tip = hub if one_each else np.repeat(hub, rot.rims, axis=1)
            affine.compose(per_tip, local, out=cols[:, at + 2 * n : at + 2 * n + k])
            off = b.offset[idx] - b0
            bone[at : at + n] = off
            bone[at + n : at + 2 * n] = off + HUB
            bone[at + 2 * n : at + 2 * n + k] = off[rot.pos] + TIP0 + rot.r
            prev = (at + 2 * n, lo, rot.tipstart)
            at += 2 * n + k
        column = np.empty_like(bone)
        column[bone] = np.arange(len(bone))
        # into palette order a slab at a time: gather the slab's columns into a cache-sized
        # batch, then transpose it into its rows (no block-sized (b, 4, 4) intermediate)
        out = pal[b0:b1]
        for c in range(0, len(column), _SLAB):
            at_c = column[c : c + _SLAB]
            slab = scratch.slab[:, : len(at_c)]
            np.take(cols, at_c, axis=1, out=slab, mode="clip")
            affine.to_matrices(slab, out=out[c : c + len(at_c)], row_vectors=row_vectors)


_SLAB = 2048  # palette rows per slab: (12, 2048) float64 stays in L2


class _BlockScratch:
    """Work arrays of the palette pass, sized for its largest block and shared by all of
    them: fresh arrays per block would be mapped (and page-faulted) anew each time, costing
    as much as the arithmetic."""

    def __init__(self, n_bones: int) -> None:
        self.cols = np.empty(12 * n_bones)
        self.bone = np.empty(n_bones, np.intp)
        self.slab = np.empty((12, _SLAB))

    def columns(self, n: int) -> F64:
        """A C-contiguous ``(12, n)`` view (``np.take`` copies a strided source whole)."""
        return self.cols[: 12 * n].reshape(12, n)

    @classmethod
    def for_blocks(cls, blocks: Sequence[LevelBlock], bones: Bones) -> _BlockScratch:
        ends = np.append(bones.offset, len(bones))
        return cls(max((int(ends[b.stop] - ends[b.start]) for b in blocks), default=0))


def _rotation(vec: F64) -> F64:
    """``(9, m)`` rotations of rotation vectors ``(3, m)`` (axis times angle, radians)."""
    angle = np.sqrt(np.einsum("im,im->m", vec, vec))
    return affine.axis_angle(vec / np.maximum(angle, 1e-300), angle)


@dataclass(frozen=True, eq=False)
class _WindField:
    """A wind's time-independent part per instance: amplitude ``amp`` ``(n,)`` radians, the
    axes across and along the wind in each instance's root frame ``(3, n)``, the flutter weight
    ``(n,)``, the gust's delay ``(n,)`` seconds and a per-piece phase ``(n,)`` radians."""

    amp: F64
    across: F64
    along: F64
    flutter: F64
    delay: F64
    piece_phase: F64


@dataclass(frozen=True, eq=False)
class _Rotations:
    """Pose rotations of ``m`` instances (with wind if any): ``hub`` ``(9, m)``
    ``R_wind @ R_bend``; ``tip`` ``(9, k)`` ``R_wind @ R_spread`` of every terminal,
    instance-major. ``rims`` ``(m,)`` terminals per instance, ``tipstart`` ``(m,)`` the first
    terminal of each; per terminal its instance position ``pos``, rim ``r`` and index
    ``flat`` into ``(n, MAX_LEAF_RIMS)`` pose arrays."""

    hub: F64
    tip: F64
    rims: NDArray[np.intp]
    tipstart: NDArray[np.intp]
    pos: NDArray[np.intp]
    r: NDArray[np.intp]
    flat: NDArray[np.intp]


def rest_palette(bones: Bones, transforms: F64) -> F64:
    """The unposed palette: every bone of an instance equals its topological transform."""
    return transforms[bones.instance]
