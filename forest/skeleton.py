"""Bones of a whole forest (paper 4.3): one palette, an offset per instance, random poses and
time-sampled wind.

Every piece instance owns ``2 + leaf rims`` bones (root, hub, one terminal per leaf rim; see
``forest.pieces``). A child's root bone hangs rigidly under its parent's terminal bone with the
twist as its local transform, so rims stay closed in every pose. Local bone transforms are
similarities ``Tr(t) @ R @ S(s)``; global ones come from forward kinematics, one bone level at
a time. Palette entries are skinning matrices ``G @ inv(J)``: they map prototype (model-space)
points straight to world space.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache, cached_property

import numpy as np
from numpy.typing import NDArray

from forest import affine, rim
from forest.assembly import building_twist_column, building_twist_table
from forest.expand import BLOCK_PIECES, PieceGraph, children_radius
from forest.pieces import MAX_LEAF_RIMS, PieceArrays, skinning_rest_inverse
from forest.transforms import F64, invert_similarity, matrix_to_quat

I32 = NDArray[np.int32]
HUB, TIP0 = 1, 2


@dataclass(frozen=True)
class Wind:
    """Sway about the horizontal axis across ``direction``; amplitude grows linearly with
    depth from ``strength * base`` at the trunk to ``strength`` at the deepest pieces."""

    strength_deg: float = 4.0
    frequency_hz: float = 0.4
    direction_deg: float = 0.0
    base: float = 0.15


@dataclass(frozen=True, eq=False)
class Bones:
    """Bone tables of a forest, in palette order (instance-major, joint-minor).

    offset : (n,) int32 first bone of each instance      instance, joint : (b,) int32
    parent : (b,) int32 parent bone, -1 for tree roots
    rest : (p, MAX_JOINTS, 4, 4) joint frames J per piece; inv_rest their inverses
    piece_rims : (p,) int32 leaf rims per piece
    """

    offset: I32
    instance: I32
    joint: I32
    parent: I32
    rest: F64
    inv_rest: F64
    piece_rims: I32

    def __len__(self) -> int:
        return len(self.instance)


def build_bones(graph: PieceGraph, pieces: tuple[PieceArrays, ...]) -> Bones:
    n_joints = np.array([p.n_joints for p in pieces], np.int32)[graph.piece]
    offset = np.zeros(len(graph), np.int32)
    np.cumsum(n_joints[:-1], out=offset[1:])
    instance = np.repeat(np.arange(len(graph), dtype=np.int32), n_joints)
    joint = (np.arange(len(instance), dtype=np.int32) - offset[instance]).astype(np.int32)
    par_inst = graph.parent[instance]
    # root bone -> the parent's terminal for this rim; hub -> own root; terminal -> own hub
    parent = np.where(
        joint == 0,
        np.where(
            par_inst >= 0, offset[np.maximum(par_inst, 0)] + TIP0 + graph.parent_rim[instance], -1
        ),
        offset[instance] + np.where(joint == HUB, 0, HUB),
    ).astype(np.int32)
    inv = skinning_rest_inverse(pieces)
    return Bones(
        offset=offset,
        instance=instance,
        joint=joint,
        parent=parent,
        rest=invert_similarity(inv),
        inv_rest=inv,
        piece_rims=np.array([p.n_leaf_rims for p in pieces], np.int32),
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


def draw_pose(
    graph: PieceGraph,
    pieces: tuple[PieceArrays, ...],
    alt_bend: F64,
    alt_spread: F64,
    rng: np.random.Generator,
    n_trees: int,
) -> PoseParams:
    n = len(graph)
    bend = alt_bend[graph.alt]
    spread = alt_spread[graph.alt]
    sigma = _rest_tip_scale(pieces)[graph.piece]
    tree_phase = rng.random(n_trees) * 2 * np.pi
    return PoseParams(
        bend_azimuth=rng.random(n) * (2 * np.pi),
        bend_angle=bend[:, 0] + rng.random(n) * (bend[:, 1] - bend[:, 0]),
        spread_azimuth=rng.random((n, MAX_LEAF_RIMS)) * (2 * np.pi),
        spread_angle=spread[:, None, 0]
        + rng.random((n, MAX_LEAF_RIMS)) * (spread[:, None, 1] - spread[:, None, 0]),
        tip_scale=sigma * children_radius(graph).astype(np.float16).astype(np.float64),
        length=graph.length,
        phase=tree_phase[graph.tree] + 0.35 * graph.depth,
    )


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
    """Per piece (p) and leaf rim (r), in the SoA layout of :mod:`forest.affine`.

    hub_t : (3, p) hub offset from the root
    tip_t : (3, p*R) terminal offset from the hub tip_r : (9, p*R) terminal rest rotation
    tip_scale : (p*R,) terminal rest scale sigma
    twists : (12, 6) the six rim twists
    building_twist : (12, p*R*6) ``B_r @ Twist_k``
    """

    hub_t: F64
    tip_t: F64
    tip_r: F64
    tip_scale: F64
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
        twists=affine.from_matrices(rim.twists()),
        building_twist=affine.from_matrices(building_twist_table(pieces).reshape(-1, 4, 4)),
    )


@dataclass(frozen=True, eq=False)
class _Locals:
    """Local transforms of a set of instances (SoA, see :mod:`forest.affine`): roots and hubs
    ``(12, m)``; terminals ``(12, k)`` with their instance position ``pos`` and rim ``r``."""

    root: F64
    hub: F64
    tips: F64
    pos: I32
    r: I32


@dataclass(frozen=True, eq=False)
class Poser:
    """Evaluates a forest's pose (and wind) into local bone transforms or the palette.

    Locals are built for any subset of instances by :meth:`locals_for`, the one definition
    both outputs share: ``Tr(length * t) @ R_wind @ R_bend`` for hubs and
    ``Tr(length * t) @ R_wind @ R_spread @ R_rest @ S(scale)`` for terminals; a root bone's
    local is the tree's model transform or the twist.
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

    def _wind(self, idx: I32, wind: Wind | None, time: float) -> tuple[F64, F64] | None:
        """Per instance of ``idx``: sway angle ``(m,)`` and the wind axis in the instance's
        root frame ``(3, m)`` (one world axis across the wind, turned by the rest rotation)."""
        if wind is None or not wind.strength_deg:
            return None
        d = np.deg2rad(wind.direction_deg)
        world_axis = np.array([np.sin(d), 0.0, -np.cos(d)])  # up x direction
        depth = self.graph.depth[idx]
        deepest = self._tree_depth[self.graph.tree[idx]]
        amp = np.deg2rad(wind.strength_deg) * (
            wind.base + (1 - wind.base) * depth / np.maximum(deepest, 1)
        )
        sway = amp * np.sin(2 * np.pi * wind.frequency_hz * time + self.pose.phase[idx])
        lin = self.transforms[idx, :3, :3]
        axis = np.einsum("nji,j->in", lin, world_axis)  # R^T a, up to the uniform scale
        return sway, axis / np.linalg.norm(axis, axis=0)

    def _hub_and_tip_rotations(
        self, idx: I32, wind: Wind | None, time: float
    ) -> tuple[F64, F64, I32, I32]:
        """Hub locals ``(12, m)``, and the pose rotation ``R_wind @ R_spread`` ``(9, k)`` of
        every terminal with its instance position ``pos`` and rim ``r`` (each ``(k,)``)."""
        g, pose, tab = self.graph, self.pose, _piece_tables(self.pieces)
        piece = g.piece[idx]
        hub = np.empty((12, len(idx)))
        hub_rot = affine.horizontal_rotation(pose.bend_azimuth[idx], pose.bend_angle[idx])
        swaying = self._wind(idx, wind, time)
        if swaying is not None:
            sway, axis = swaying
            hub_rot = affine.compose_linear(affine.axis_angle(axis, sway), hub_rot)
        hub[affine.LIN] = hub_rot
        hub[affine.TRANS] = pose.length[idx] * tab.hub_t[:, piece]
        pos, r = np.nonzero(np.arange(MAX_LEAF_RIMS)[None] < self.bones.piece_rims[piece][:, None])
        inst = idx[pos]
        rot = affine.horizontal_rotation(pose.spread_azimuth[inst, r], pose.spread_angle[inst, r])
        if swaying is not None:
            # in the hub's frame; tips sway half as much as hubs, so the motion ripples up
            # the tree instead of swinging each piece rigidly
            hub_axis = affine.apply_linear(affine.transpose_linear(hub_rot)[:, pos], axis[:, pos])
            rot = affine.compose_linear(affine.axis_angle(hub_axis, 0.5 * sway[pos]), rot)
        return hub, rot, pos.astype(np.int32), r.astype(np.int32)

    def locals_for(self, idx: I32, wind: Wind | None = None, time: float = 0.0) -> _Locals:
        """Local transforms of the instances ``idx``."""
        g, pose, tab = self.graph, self.pose, _piece_tables(self.pieces)
        top = g.parent[idx] < 0
        root = tab.twists[:, g.twist[idx]]
        if top.any():
            root[:, top] = affine.from_matrices(self.tree_transforms[g.tree[idx[top]]])
        hub, rot, pos, r = self._hub_and_tip_rotations(idx, wind, time)
        inst = idx[pos]
        col = g.piece[inst] * MAX_LEAF_RIMS + r
        tips = np.empty((12, len(pos)))
        tips[affine.LIN] = affine.compose_linear(rot, tab.tip_r[:, col]) * pose.tip_scale[inst, r]
        tips[affine.TRANS] = pose.length[inst] * tab.tip_t[:, col]
        return _Locals(root, hub, tips, pos, r)

    def local_transforms(self, wind: Wind | None = None, time: float = 0.0) -> F64:
        """``(b, 4, 4)`` local transforms of every bone (what a SkelAnimation stores)."""
        loc = self.locals_for(np.arange(len(self.graph), dtype=np.int32), wind, time)
        out = np.empty((len(self.bones), 4, 4))
        off = self.bones.offset
        out[off] = affine.to_matrices(loc.root)
        out[off + HUB] = affine.to_matrices(loc.hub)
        out[off[loc.pos] + TIP0 + loc.r] = affine.to_matrices(loc.tips)
        return out

    def palette(
        self, wind: Wind | None = None, time: float = 0.0, row_vectors: bool = False
    ) -> F64:
        """``(b, 4, 4)`` skinning matrices ``G @ inv(J)``, computed block by block of whole
        trees (small enough for the temporaries to stay in cache); transposed for USD with
        ``row_vectors``, so a scene writer needs no second copy."""
        pal = np.empty((len(self.bones), 4, 4))
        for start, stop in self.graph.tree_blocks(BLOCK_PIECES):
            self._palette_block(start, stop, pal, wind, time, row_vectors)
        return pal

    def _palette_block(
        self,
        start: int,
        stop: int,
        pal: F64,
        wind: Wind | None,
        time: float,
        row_vectors: bool,
    ) -> None:
        """Forward kinematics of instances ``[start, stop)``, one depth level at a time, in
        closed forms that skip the terminals' globals.

        With ``J_tip = B_r = Tr(h + t) R_rest S(sigma)`` and the terminal's local
        ``Tr(length t) R S(sigma rho)``, the terminal's palette entry is
        ``G_hub @ [rho R | length t - rho R (t + h)]``; a child's root global is its parent
        terminal's palette entry times ``B_r @ Twist_k``, a constant per piece, rim and twist.
        """
        g, b, pose = self.graph, self.bones, self.pose
        tab = _piece_tables(self.pieces)
        b0 = int(b.offset[start])
        b1 = int(b.offset[stop]) if stop < len(g) else len(b)
        block = np.empty((12, b1 - b0))  # this block's palette, SoA
        for idx in g.levels_in(start, stop):
            off = b.offset[idx] - b0
            par = g.parent[idx]
            piece = g.piece[idx]
            if par[0] < 0:
                root = affine.from_matrices(self.tree_transforms[g.tree[idx]])
            else:
                parent_tip = block[:, b.offset[par] - b0 + TIP0 + g.parent_rim[idx]]
                bt = building_twist_column(g.piece[par], g.parent_rim[idx], g.twist[idx])
                root = affine.compose(parent_tip, tab.building_twist[:, bt])
            block[:, off] = root  # J_root = I
            hub, rot, pos, r = self._hub_and_tip_rotations(idx, wind, time)
            g_hub = affine.compose(root, hub)
            # inv(J_hub) is a pure translation: one matrix-vector product
            hub_pal = g_hub.copy()
            hub_pal[affine.TRANS] -= affine.apply(g_hub, tab.hub_t[:, piece])
            block[:, off + HUB] = hub_pal
            inst = idx[pos]
            col = piece[pos] * MAX_LEAF_RIMS + r
            rho = pose.tip_scale[inst, r] / tab.tip_scale[col]
            m = np.empty((12, len(pos)))
            m[affine.LIN] = rot * rho
            m[affine.TRANS] = pose.length[inst] * tab.tip_t[:, col] - affine.apply_linear(
                m[affine.LIN], tab.tip_t[:, col] + tab.hub_t[:, piece[pos]]
            )
            block[:, off[pos] + TIP0 + r] = affine.compose(g_hub[:, pos], m)
        affine.to_matrices(block, pal[b0:b1], row_vectors)


def rest_palette(bones: Bones, transforms: F64) -> F64:
    """The unposed palette: every bone of an instance equals its topological transform."""
    return transforms[bones.instance]


def local_trs(local: F64) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float16]]:
    """Local similarities -> USD SkelAnimation arrays: translations float3, rotations quatf
    (x, y, z, w), scales half3."""
    lin = local[:, :3, :3]
    s = np.cbrt(np.linalg.det(lin))
    q = matrix_to_quat(lin / s[:, None, None])
    return (
        local[:, :3, 3].astype(np.float32),
        q.astype(np.float32),
        np.repeat(s[:, None], 3, axis=1).astype(np.float16),
    )
