"""A tree's joints cut to a budget for the skinned exports (USD's DCC form, glTF's game form).

The generator gives every piece its own bones, thousands per tree; DCC importers and game
engines are slow or capped in the joint count (Blender's USD import time grows about with its
square; a glTF skin past 256 joints needs 16-bit JOINTS_0). So each tree keeps the joints that
carry the most wood: every joint is ranked by its *reach*, the length of the longest path of
wood from it to a tip below it. Reach only grows towards the root (a parent reaches at least
as far as its child, and ties go to the shallower joint), so the kept set of each tree is
connected and holds the root: trunk and main limbs keep their joints, and a merged twig is one
whose wood ends close to its kept joint, which then moves it rigidly (the wind's turn of the
twig against its limb is lost, the limb's own motion is kept exactly).

Vertices of a dropped joint are bound to its nearest kept ancestor (:func:`nearest_kept`,
:func:`merge_influences`); a kept joint's parent is the kept joint above it, so its local
transform is the same as before the cut.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from forest.errors import LimitError
from forest.geometry.transforms import F64

DCC_JOINTS = 1024  # per tree in USD's skinned form: Blender imports an oak in about a second
GAME_JOINTS = 256  # per tree in glTF: engines' skinning caps, and JOINTS_0 fits uint8


def depths(parent: NDArray[np.integer]) -> NDArray[np.intp]:
    """``(n,)`` each joint's number of ancestors (``parent`` -1 at roots), by pointer
    jumping: log2 of the deepest chain passes."""
    depth = (parent >= 0).astype(np.intp)
    up = parent.astype(np.intp).copy()
    while (up >= 0).any():
        has = up >= 0
        above = np.maximum(up, 0)
        depth = depth + np.where(has, depth[above], 0)
        up = np.where(has, up[above], -1)
    return depth


def reaches(parent: NDArray[np.integer], position: F64) -> F64:
    """``(n,)`` the longest path of wood from each joint down to a joint without children,
    measured between the joints' ``position`` ``(n, 3)``; 0 at the tips."""
    depth = depths(parent)
    length = np.zeros(len(parent))
    has = parent >= 0
    length[has] = np.linalg.norm(position[has] - position[parent[has]], axis=1)
    reach = np.zeros(len(parent))
    order = np.argsort(-depth, kind="stable")
    bounds = np.flatnonzero(np.diff(depth[order])) + 1
    for level in np.split(order, bounds):  # deepest first: children before their parents
        level = level[parent[level] >= 0]
        np.maximum.at(reach, parent[level], reach[level] + length[level])
    return reach


def keep_joints(
    parent: NDArray[np.integer], tree: NDArray[np.integer], position: F64, budget: int
) -> NDArray[np.bool_]:
    """``(n,)`` which joints each tree keeps: its ``budget`` joints of the longest reach
    (:func:`reaches`), ties to the shallower joint, then the first. ``tree`` ``(n,)`` is each
    joint's tree (joints of a tree need not be contiguous); the kept set of every tree holds
    its root and every kept joint's parent."""
    if budget < 1:
        raise LimitError(
            f"a tree needs at least one joint, got a budget of {budget}",
            path="joint_budget",
            limit=1,
        )
    reach = reaches(parent, position)
    order = np.lexsort((np.arange(len(parent)), depths(parent), -reach, tree))
    sorted_tree = tree[order]
    first = np.searchsorted(sorted_tree, sorted_tree)  # each tree's first place in the order
    keep = np.zeros(len(parent), bool)
    keep[order] = np.arange(len(order)) - first < budget
    return keep


def nearest_kept(parent: NDArray[np.integer], keep: NDArray[np.bool_]) -> NDArray[np.intp]:
    """``(n,)`` each joint's nearest kept joint going up (itself when kept); every root must be
    kept."""
    if not keep[parent < 0].all():
        raise ValueError("every root joint must be kept")
    up = np.where(keep, np.arange(len(parent)), parent).astype(np.intp)
    while not keep[up].all():  # pointer jumping: log2 of the longest dropped chain passes
        up = np.where(keep[up], up, up[up])
    return up


def merge_influences(index: NDArray[np.integer], weight: F64) -> tuple[NDArray[np.integer], F64]:
    """Skin influences ``(v, k)`` after several joints were mapped to one: per vertex, the
    weights of a repeated joint are summed into its first slot and the repeats keep the
    joint with weight 0 (importers add repeated groups twice, or replace one by the other);
    merged rows are renormalised. Rows without repeats are returned as they were."""
    index, weight = index.copy(), weight.copy()
    merged = np.zeros(len(index), bool)
    for i in range(1, index.shape[1]):
        for j in range(i):  # the first earlier slot with the same joint takes the weight
            same = (index[:, i] == index[:, j]) & (weight[:, i] > 0)
            weight[same, j] += weight[same, i]
            weight[same, i] = 0.0
            merged |= same
    weight[merged] /= weight[merged].sum(axis=1, keepdims=True)
    return index, weight
