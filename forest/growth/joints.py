"""The forest's bones as the joints of its skinned forms (USD's skinned trees, glTF's skins,
the levels of detail): :class:`DccJoints`, all of them or cut to a budget per tree
(:mod:`forest.growth.joint_budget`), and each tree's range of them."""

from __future__ import annotations

from dataclasses import dataclass
from weakref import WeakKeyDictionary

import numpy as np
from numpy.typing import NDArray

from forest.geometry.transforms import F64, invert_similarity
from forest.growth.generate import Forest
from forest.growth.joint_budget import keep_joints, nearest_kept


@dataclass(frozen=True, eq=False)
class DccJoints:
    """The forest's bones as the joints of its skinned forms (USD and glTF).

    A piece that hangs on a parent's terminal has its root bone at a rim twist from that
    terminal, the same in every frame (wind turns hubs and terminals, never a root), so the
    root's skinning matrix is the terminal's: ``G_t L (J_t L)^-1 = G_t J_t^-1``. Such roots
    are left out and their vertices bound to the terminal, a third of every tree's bones:
    DCC importers are slow in the joint count (Blender's import time grows about with its
    square: an oak of 9,794 bones took 11.7 s, a spruce of 17,069 took 47 s).

    bone : (k,) the generator's bone of each joint (ascending: trees stay contiguous)
    parent : (k,) parent joint, -1 at a tree's root
    of_bone : (b,) each bone's joint (a left-out root: its parent terminal's; with a joint
        budget, a dropped bone: the nearest kept joint above it)
    via : (k,) the left-out root between a joint and its parent terminal, else -1
    """

    bone: NDArray[np.intp]
    parent: NDArray[np.intp]
    of_bone: NDArray[np.intp]
    via: NDArray[np.intp]

    def __len__(self) -> int:
        return len(self.bone)

    def locals(self, local: F64) -> F64:
        """The bones' local transforms ``(b, 4, 4)`` -> the joints' ``(k, 4, 4)``: a joint
        under a left-out root takes that root's (constant) twist into its own."""
        out = local[self.bone]
        hung = self.via >= 0
        out[hung] = local[self.via[hung]] @ out[hung]
        return out


_JOINTS: WeakKeyDictionary[Forest, dict[int | None, DccJoints]] = WeakKeyDictionary()


def dcc_joints(forest: Forest, budget: int | None = None) -> DccJoints:
    """The forest's :class:`DccJoints` (made once per forest and budget): every bone but the
    hung roots, or with ``budget`` at most that many per tree, those of the longest reach
    (:mod:`forest.growth.joint_budget`); a dropped bone's ``of_bone`` is then its nearest kept
    joint above it."""
    made = _JOINTS.setdefault(forest, {})
    if budget not in made:
        made[budget] = _all_joints(forest) if budget is None else _cut(forest, budget)
    return made[budget]


def _all_joints(forest: Forest) -> DccJoints:
    b, g = forest.bones, forest.graph
    left_out = np.zeros(len(b), bool)
    left_out[b.offset[g.parent >= 0]] = True
    bone = np.flatnonzero(~left_out)
    index = np.full(len(b), -1, np.intp)
    index[bone] = np.arange(len(bone))
    up = b.parent[bone].astype(np.intp)
    via = np.where((up >= 0) & left_out[np.maximum(up, 0)], up, -1)
    up = np.where(via >= 0, b.parent[np.maximum(via, 0)], up)
    of_bone = index.copy()
    of_bone[left_out] = index[b.parent[left_out]]
    return DccJoints(
        bone=bone,
        parent=np.where(up >= 0, index[np.maximum(up, 0)], -1),
        of_bone=of_bone,
        via=via,
    )


def _cut(forest: Forest, budget: int) -> DccJoints:
    """The joints of :func:`_all_joints` cut to ``budget`` per tree. The kept set is closed
    under parents, so a kept joint's parent and the left-out root between them (``via``) are
    those it had: its local transforms are unchanged."""
    full = dcc_joints(forest)
    position = bind_transforms(forest, forest.palette())[full.bone, :3, 3]
    tree = forest.graph.tree[forest.bones.instance[full.bone]]
    keep = keep_joints(full.parent, tree, position, budget)
    index = np.cumsum(keep) - 1
    return DccJoints(
        bone=full.bone[keep],
        parent=np.where(full.parent[keep] >= 0, index[full.parent[keep]], -1),
        of_bone=index[nearest_kept(full.parent, keep)[full.of_bone]],
        via=full.via[keep],
    )


def tree_slices(forest: Forest, budget: int | None = None) -> list[tuple[slice, slice]]:
    """Per tree: its instance range and its range of :func:`dcc_joints` ``(forest, budget)``
    (both contiguous, tree-major)."""
    tree = forest.graph.tree
    starts = np.searchsorted(tree, np.arange(forest.options.trees + 1))
    dcc = dcc_joints(forest, budget)
    first = dcc.of_bone[forest.bones.offset]  # each instance's root's joint
    n_joints = len(dcc)
    n = len(first)
    out = []
    for i in range(forest.options.trees):
        a, z = int(starts[i]), int(starts[i + 1])
        out.append((slice(a, z), slice(int(first[a]), int(first[z]) if z < n else n_joints)))
    return out


def bind_transforms(forest: Forest, still: F64) -> F64:
    """``(b, 4, 4)`` joint frames of the posed, windless forest in their tree's space (the
    skeleton's space): each entry of ``still`` (prototype space -> world) times the joint's
    rest frame in its prototype."""
    b, g = forest.bones, forest.graph
    to_tree = invert_similarity(forest.tree_transforms)[g.tree[b.instance]]
    return to_tree @ still @ b.rest[g.piece[b.instance], b.joint]
