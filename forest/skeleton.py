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

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import cache, cached_property

import numpy as np
from numpy.typing import NDArray

from forest import rim
from forest.expand import PieceGraph, children_radius
from forest.pieces import MAX_LEAF_RIMS, PieceArrays, skinning_rest_inverse
from forest.transforms import F64, axis_angle_matrix, invert_similarity, matrix_to_quat

I32 = NDArray[np.int32]
HUB, TIP0 = 1, 2
# instances per block of trees evaluated together: big enough to amortise numpy's per-call
# cost, small enough that a level's temporaries stay in cache and blocks spread over cores
BLOCK_PIECES = 16384


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


@cache
def _local_tables(pieces: tuple[PieceArrays, ...]) -> tuple[F64, F64, F64]:
    """Rest local offsets: hub translation (p, 3); terminal translation (p, R, 3) and
    rotation (p, R, 3, 3) relative to the hub."""
    hub_t = np.zeros((len(pieces), 3))
    tip_t = np.zeros((len(pieces), MAX_LEAF_RIMS, 3))
    tip_r = np.broadcast_to(np.eye(3), (len(pieces), MAX_LEAF_RIMS, 3, 3)).copy()
    for i, p in enumerate(pieces):
        hub_t[i] = p.joint_rest[HUB, :3, 3]
        local = invert_similarity(p.joint_rest[HUB]) @ p.joint_rest[TIP0:]
        tip_t[i, : p.n_leaf_rims] = local[:, :3, 3]
        lin = local[:, :3, :3]
        tip_r[i, : p.n_leaf_rims] = lin / np.cbrt(np.linalg.det(lin))[:, None, None]
    return hub_t, tip_t, tip_r


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
        root frame ``(m, 3)`` (one world axis across the wind, turned by the rest rotation)."""
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
        axis = np.einsum("nji,j->ni", lin, world_axis)  # R^T a, up to the uniform scale
        return sway, axis / np.linalg.norm(axis, axis=-1, keepdims=True)

    def locals_for(
        self, idx: I32, wind: Wind | None = None, time: float = 0.0
    ) -> tuple[F64, F64, F64, I32, I32]:
        """Local transforms of the instances ``idx``: roots ``(m, 4, 4)``, hubs ``(m, 4, 4)``,
        terminals ``(k, 4, 4)`` with their position in ``idx`` and rim, each ``(k,)``."""
        g, pose = self.graph, self.pose
        hub_t, tip_t, tip_r = _local_tables(self.pieces)
        m = len(idx)
        piece = g.piece[idx]
        top = g.parent[idx] < 0
        root = rim.twists()[g.twist[idx]]
        root[top] = self.tree_transforms[g.tree[idx[top]]]
        hub = np.zeros((m, 4, 4))
        hub[:, 3, 3] = 1.0
        hub_rot = horizontal_rotation(pose.bend_azimuth[idx], pose.bend_angle[idx])
        swaying = self._wind(idx, wind, time)
        if swaying is not None:
            sway, axis = swaying
            hub_rot = axis_angle_matrix(axis, sway)[:, :3, :3] @ hub_rot
        hub[:, :3, :3] = hub_rot
        hub[:, :3, 3] = pose.length[idx, None] * hub_t[piece]
        pos, r = np.nonzero(np.arange(MAX_LEAF_RIMS)[None] < self.bones.piece_rims[piece][:, None])
        inst = idx[pos]
        rot = horizontal_rotation(pose.spread_azimuth[inst, r], pose.spread_angle[inst, r])
        if swaying is not None:
            # in the hub's frame; tips sway half as much as hubs, so the motion ripples up
            # the tree instead of swinging each piece rigidly
            hub_axis = np.einsum("nji,nj->ni", hub_rot[pos], axis[pos])
            rot = axis_angle_matrix(hub_axis, 0.5 * sway[pos])[:, :3, :3] @ rot
        tips = np.zeros((len(pos), 4, 4))
        tips[:, 3, 3] = 1.0
        tips[:, :3, :3] = (rot @ tip_r[piece[pos], r]) * pose.tip_scale[inst, r][:, None, None]
        tips[:, :3, 3] = pose.length[inst, None] * tip_t[piece[pos], r]
        return root, hub, tips, pos.astype(np.int32), r.astype(np.int32)

    def local_transforms(self, wind: Wind | None = None, time: float = 0.0) -> F64:
        """``(b, 4, 4)`` local transforms of every bone (what a SkelAnimation stores)."""
        idx = np.arange(len(self.graph), dtype=np.int32)
        root, hub, tips, pos, r = self.locals_for(idx, wind, time)
        out = np.empty((len(self.bones), 4, 4))
        off = self.bones.offset
        out[off] = root
        out[off + HUB] = hub
        out[off[pos] + TIP0 + r] = tips
        return out

    def palette(self, wind: Wind | None = None, time: float = 0.0) -> F64:
        """``(b, 4, 4)`` skinning matrices ``G @ inv(J)``.

        Trees are independent, so blocks of whole trees run on all cores (numpy releases the
        GIL in the batched products); within a block, see :meth:`_palette_block`."""
        pal = np.empty((len(self.bones), 4, 4))
        blocks = self.graph.tree_blocks(BLOCK_PIECES)
        with ThreadPoolExecutor(max_workers=min(len(blocks), os.cpu_count() or 1)) as pool:
            list(pool.map(lambda ab: self._palette_block(ab[0], ab[1], pal, wind, time), blocks))
        return pal

    def _palette_block(
        self, start: int, stop: int, pal: F64, wind: Wind | None, time: float
    ) -> None:
        """Forward kinematics of instances ``[start, stop)`` one depth level at a time: roots,
        hubs, then terminals of every piece of the level at once. Each global becomes its
        palette entry as soon as it is known; only the terminals' globals are kept, for the
        next level's roots."""
        g, b = self.graph, self.bones
        prev_tips: F64 | None = None
        level_pos = np.empty(stop - start, np.int32)
        for idx in g.levels_in(start, stop):
            level_pos[idx - start] = np.arange(len(idx), dtype=np.int32)
            root, hub, tips, pos, r = self.locals_for(idx, wind, time)
            par = g.parent[idx]
            if prev_tips is not None:
                root = prev_tips[level_pos[par - start], g.parent_rim[idx]] @ root
            off = b.offset[idx]
            pal[off] = root  # J_root = I
            g_hub = root @ hub
            piece = g.piece[idx]
            # inv(J_hub) is a pure translation: apply it as one matrix-vector product
            hub_pal = g_hub.copy()
            hub_pal[:, :3, 3] += np.einsum(
                "nij,nj->ni", g_hub[:, :3, :3], b.inv_rest[piece, HUB, :3, 3]
            )
            pal[off + HUB] = hub_pal
            g_tips = g_hub[pos] @ tips
            pal[off[pos] + TIP0 + r] = g_tips @ b.inv_rest[piece[pos], TIP0 + r]
            prev_tips = np.empty((len(idx), MAX_LEAF_RIMS, 4, 4))
            prev_tips[pos, r] = g_tips


def horizontal_rotation(azimuth: F64, angle: F64) -> F64:
    """``(..., 3, 3)`` rotations by ``angle`` about the horizontal axis (cos az, 0, sin az)."""
    x, z = np.cos(azimuth), np.sin(azimuth)
    c, s = np.cos(angle), np.sin(angle)
    k = 1.0 - c
    m = np.empty((*np.shape(angle), 3, 3))
    m[..., 0, 0] = c + x * x * k
    m[..., 0, 1] = -z * s
    m[..., 0, 2] = x * z * k
    m[..., 1, 0] = z * s
    m[..., 1, 1] = c
    m[..., 1, 2] = -x * s
    m[..., 2, 0] = x * z * k
    m[..., 2, 1] = x * s
    m[..., 2, 2] = c + z * z * k
    return m


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
