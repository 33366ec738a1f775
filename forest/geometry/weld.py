"""Groups of coincident points, for welding the rims of joined pieces into one mesh.

numpy only: the skinned writer runs in every small ``forest generate``, and scipy's KD-tree
and graph packages took a third of a second to import there, longer than the weld itself.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

# sorting along a direction no piece's geometry is aligned with: points a rotation or a
# mirror puts on one axis-aligned plane (a trunk's ring vertices at x = 0) would otherwise
# share a coordinate and make the sweep's windows long
_SWEEP = np.array([0.5773502691896258, 0.6180339887498949, 0.5332154198159911])
_SWEEP /= np.linalg.norm(_SWEEP)


def close_pairs(points: NDArray[np.float64], tol: float) -> NDArray[np.intp]:
    """``(m, 2)`` index pairs ``i < j`` of the points at most ``tol`` apart (as
    ``cKDTree.query_pairs``): a sweep over the points sorted along one direction, since two
    points ``tol`` apart are at most ``tol`` apart along it."""
    n = len(points)
    if n < 2:
        return np.zeros((0, 2), np.intp)
    key = points @ _SWEEP
    order = np.argsort(key, kind="stable")
    key = key[order]
    # candidates of sorted point k: the sorted points k + 1 .. end[k] - 1
    end = np.searchsorted(key, key + tol, side="right")
    span = end - np.arange(n)
    found = []
    k = np.flatnonzero(span > 1)
    for d in range(1, int(span.max())):
        k = k[span[k] > d]
        i, j = order[k], order[k + d]
        diff = points[i] - points[j]
        near = np.einsum("ij,ij->i", diff, diff) <= tol * tol
        found.append(np.stack([i[near], j[near]], axis=1))
    pairs = np.concatenate(found) if found else np.zeros((0, 2), np.intp)
    return np.sort(pairs, axis=1)


def weld_labels(n: int, pairs: NDArray[np.intp]) -> NDArray[np.intp]:
    """Per point of ``n``, the lowest index of its group: the points joined to it by chains
    of ``pairs`` (connected components; label propagation with pointer jumping, which ends
    in a few rounds for the small groups a weld makes)."""
    label = np.arange(n)
    if not len(pairs):
        return label
    i, j = pairs[:, 0], pairs[:, 1]
    while True:
        low = np.minimum(label[i], label[j])
        new = label.copy()
        np.minimum.at(new, i, low)
        np.minimum.at(new, j, low)
        new = new[new]
        if np.array_equal(new, label):
            return label
        label = new
