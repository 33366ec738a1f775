"""Evaluating a forest's pose (and wind) into its bones' local transforms and the palette
(paper 4.3). Local bone transforms are similarities ``Tr(t) @ R @ S(s)``; global ones come
from forward kinematics, one bone level at a time. Palette entries are skinning matrices
``G @ inv(J)``: they map prototype (model-space) points straight to world space.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cache, cached_property

import numpy as np
from numpy.typing import NDArray

from forest.geometry import affine, rim
from forest.geometry.pieces import HUB, MAX_LEAF_RIMS, TIP0, PieceArrays
from forest.geometry.transforms import (
    F64,
    decompose_similarity,
    invert_similarity,
    similarity_scale,
)
from forest.growth.assembly import building_twist_table
from forest.growth.expand import LevelBlock, PieceGraph
from forest.growth.parallel import for_block_groups
from forest.growth.pose import PoseParams, rest_tip_scale
from forest.growth.skeleton import Bones
from forest.growth.wind import Wind, WindField, gust_envelope, wind_field, wind_vectors

LevelHook = Callable[[NDArray[np.intp], F64], None]


@dataclass(frozen=True, eq=False)
class PieceTables:
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
def piece_tables(pieces: tuple[PieceArrays, ...]) -> PieceTables:
    n = len(pieces)
    hub_t = np.zeros((n, 3))
    tip_t = np.zeros((n, MAX_LEAF_RIMS, 3))
    tip_r = np.broadcast_to(np.eye(3), (n, MAX_LEAF_RIMS, 3, 3)).copy()
    for i, p in enumerate(pieces):
        hub_t[i] = p.joint_rest[HUB, :3, 3]
        local = invert_similarity(p.joint_rest[HUB]) @ p.joint_rest[TIP0:]
        tip_t[i, : p.n_leaf_rims] = local[:, :3, 3]
        lin = local[:, :3, :3]
        tip_r[i, : p.n_leaf_rims] = lin / similarity_scale(local)[:, None, None]
    return PieceTables(
        hub_t=hub_t.T.copy(),
        tip_t=tip_t.reshape(-1, 3).T.copy(),
        tip_r=tip_r.reshape(-1, 9).T.copy(),
        tip_scale=rest_tip_scale(pieces).ravel(),
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
    def _wind_fields(self) -> dict[Wind, WindField]:
        return {}

    def _wind_field(self, wind: Wind) -> WindField:
        """The time-independent part of a wind, computed once for all of its frames."""
        if wind not in self._wind_fields:
            self._wind_fields[wind] = wind_field(
                wind, self.graph, self.transforms, self.tree_transforms
            )
        return self._wind_fields[wind]

    def gust_envelope(self, idx: NDArray[np.intp], wind: Wind, time: float) -> F64:
        """``(m,)`` the gust's strength in [0, 1] at the instances ``idx`` at ``time``
        (:func:`forest.growth.wind.gust_envelope`)."""
        return gust_envelope(self._wind_field(wind), wind, idx, time)

    def _wind(self, idx: NDArray[np.intp], wind: Wind | None, time: float) -> F64 | None:
        """Per instance of ``idx``: the wind's rotation vector ``(3, m)`` (radians about its
        direction) in the instance's root frame at ``time``."""
        if wind is None or not wind.strength_deg:
            return None
        return wind_vectors(self._wind_field(wind), wind, idx, self.pose.phase, time)

    def _terminals(
        self, idx: NDArray[np.intp]
    ) -> tuple[
        NDArray[np.intp], NDArray[np.intp], NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]
    ]:
        """``rims, tipstart, pos, r, flat`` of the instances ``idx`` (see _Rotations)."""
        rims = piece_tables(self.pieces).rims[self.graph.piece[idx]]
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
        g, pose, tab = self.graph, self.pose, piece_tables(self.pieces)
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
        g, pose, tab, bones = self.graph, self.pose, piece_tables(self.pieces), self.bones
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
        tab = piece_tables(self.pieces)
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
        tab = piece_tables(self.pieces)
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
