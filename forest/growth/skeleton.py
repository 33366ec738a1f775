"""Bones of a whole forest (paper 4.3): one palette, an offset per instance.

Every piece instance owns ``2 + leaf rims`` bones (root, hub, one terminal per leaf rim; see
``forest.geometry.pieces``). A child's root bone hangs rigidly under its parent's terminal bone
with the twist as its local transform, so rims stay closed in every pose. The pose
(:mod:`forest.growth.pose`) and wind (:mod:`forest.growth.wind`) turn the bones;
:class:`forest.growth.poser.Poser` evaluates them into the palette.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from forest.geometry.pieces import HUB, TIP0, PieceArrays, skinning_rest_inverse
from forest.geometry.transforms import F64, invert_similarity
from forest.growth.expand import PieceGraph

I32 = NDArray[np.int32]


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


def rest_palette(bones: Bones, transforms: F64) -> F64:
    """The unposed palette: every bone of an instance equals its topological transform."""
    return transforms[bones.instance]
