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

import numpy as np
from numpy.typing import NDArray

from forest import rim
from forest.expand import PieceGraph, children_radius
from forest.pieces import MAX_LEAF_RIMS, PieceArrays, skinning_rest_inverse
from forest.transforms import F64, axis_angle_matrix, invert_similarity, matrix_to_quat

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
    tip_scale : (n, R) terminal uniform scale, rounded to binary16 (USD stores SkelAnimation
    scales as half3; rounding here keeps our skinning and USD's identical)
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
        tip_scale=(sigma * children_radius(graph)).astype(np.float16).astype(np.float64),
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


def local_transforms(
    graph: PieceGraph,
    bones: Bones,
    pieces: tuple[PieceArrays, ...],
    tree_transforms: F64,
    transforms: F64,
    pose: PoseParams,
    wind: Wind | None = None,
    time: float = 0.0,
) -> F64:
    """``(b, 4, 4)`` local bone transforms at ``time`` seconds (no wind if None).
    ``transforms`` are the instances' topological transforms (wind axes follow them)."""
    hub_t, tip_t, tip_r = _local_tables(pieces)
    n = len(graph)
    out = np.zeros((len(bones), 4, 4))
    out[:, 3, 3] = 1.0
    # wind: one world axis, rotated into each joint's parent frame by the rest orientation
    if wind is not None and wind.strength_deg:
        d = np.deg2rad(wind.direction_deg)
        world_axis = np.array([np.sin(d), 0.0, -np.cos(d)])  # up x direction
        depth_max = np.maximum(_tree_max(graph), 1)
        amp = np.deg2rad(wind.strength_deg) * (
            wind.base + (1 - wind.base) * graph.depth / depth_max
        )
        sway = amp * np.sin(2 * np.pi * wind.frequency_hz * time + pose.phase)
    else:
        world_axis = None
        sway = np.zeros(n)
    # root bones
    roots = bones.offset
    is_tree_root = graph.parent < 0
    out[roots[is_tree_root]] = tree_transforms[graph.tree[is_tree_root]]
    out[roots[~is_tree_root]] = rim.twists()[graph.twist[~is_tree_root]]
    # hub: Tr(length * t) @ R_wind @ R_bend
    hub_rot = horizontal_rotation(pose.bend_azimuth, pose.bend_angle)
    if world_axis is not None:
        frame = _inverse_rotation(transforms)
        wind_axis = np.einsum("nij,j->ni", frame, world_axis)
        hub_rot = axis_angle_matrix(wind_axis, sway)[:, :3, :3] @ hub_rot
    hubs = bones.offset + HUB
    out[hubs, :3, :3] = hub_rot
    out[hubs, :3, 3] = pose.length[:, None] * hub_t[graph.piece]
    # terminals: Tr(length * t) @ R_wind @ R_spread @ R_rest @ S(scale)
    n_rims = np.array([p.n_leaf_rims for p in pieces])[graph.piece]
    inst, r = np.nonzero(np.arange(MAX_LEAF_RIMS)[None] < n_rims[:, None])
    rot = horizontal_rotation(pose.spread_azimuth[inst, r], pose.spread_angle[inst, r])
    if world_axis is not None:
        # the hub frame is the root frame turned by the hub's bend; wind sways tips half as
        # much as hubs so the motion ripples rather than swinging rigidly
        hub_axis = np.einsum("nji,nj->ni", hub_rot[inst], wind_axis[inst])
        rot = axis_angle_matrix(hub_axis, 0.5 * sway[inst])[:, :3, :3] @ rot
    rot = rot @ tip_r[graph.piece[inst], r]
    tips = bones.offset[inst] + TIP0 + r
    out[tips, :3, :3] = rot * pose.tip_scale[inst, r][:, None, None]
    out[tips, :3, 3] = pose.length[inst, None] * tip_t[graph.piece[inst], r]
    return out


def _tree_max(graph: PieceGraph) -> NDArray[np.float64]:
    deepest = np.zeros(int(graph.tree.max()) + 1)
    np.maximum.at(deepest, graph.tree, graph.depth)
    return deepest[graph.tree]


def _inverse_rotation(transforms: F64) -> F64:
    """``(n, 3, 3)`` inverse rotation part of similarities."""
    lin = transforms[:, :3, :3]
    scale = np.cbrt(np.linalg.det(lin))
    return np.swapaxes(lin / scale[:, None, None], -1, -2)


def posed_palette(graph: PieceGraph, bones: Bones, local: F64) -> F64:
    """``(b, 4, 4)`` skinning matrices ``G @ inv(J)`` from local bone transforms.

    Forward kinematics one depth level at a time (root, hub, then terminals of every piece
    of that level at once); each global is turned into its palette entry as soon as it is
    known, so no second pass over the bones is needed."""
    glob = np.empty_like(local)
    pal = np.empty_like(local)
    n_rims = bones.piece_rims
    for idx in graph.levels:
        root = bones.offset[idx]
        par = bones.parent[root]
        g_root = local[root] if par[0] < 0 else glob[par] @ local[root]
        glob[root] = g_root
        pal[root] = g_root  # J_root = I
        g_hub = g_root @ local[root + HUB]
        glob[root + HUB] = g_hub
        piece = graph.piece[idx]
        pal[root + HUB] = g_hub @ bones.inv_rest[piece, HUB]
        for r in range(MAX_LEAF_RIMS):
            has = np.nonzero(n_rims[piece] > r)[0]
            if not len(has):
                break
            tip = root[has] + TIP0 + r
            g_tip = g_hub[has] @ local[tip]
            glob[tip] = g_tip
            pal[tip] = g_tip @ bones.inv_rest[piece[has], TIP0 + r]
    return pal


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
