"""The skinned writer's weld (coincident rim vertices) and the proxy's skin sources."""

from __future__ import annotations

import itertools

import fast_simplification
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from forest.geometry.weld import close_pairs, weld_labels
from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.usd.skinned import PROXY_KEEP, WELD_TOL, nearest_source, tree_mesh, tree_slices


def brute_labels(points: np.ndarray, tol: float) -> np.ndarray:
    """Lowest index of each point's group, by all pairs and a plain union-find."""
    parent = list(range(len(points)))

    def root(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    for i, j in itertools.combinations(range(len(points)), 2):
        if np.sum((points[i] - points[j]) ** 2) <= tol * tol:
            a, b = root(i), root(j)
            parent[max(a, b)] = min(a, b)
    return np.array([root(i) for i in range(len(points))])


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(2, 120))
def test_weld_groups_equal_all_pairs(seed: int, n: int) -> None:
    rng = np.random.default_rng(seed)
    base = rng.uniform(-1.0, 1.0, (n, 3))
    # copies within the tolerance (chains of them too), exact copies, and points on one
    # axis-aligned plane, as a trunk's ring vertices at x = 0
    near = base[rng.integers(0, n, n // 2)] + rng.uniform(-0.5, 0.5, (n // 2, 3)) * 1e-6
    chain = near[: n // 4] + rng.uniform(-0.5, 0.5, (n // 4, 3)) * 1e-6
    plane = base[: n // 3].copy()
    plane[:, 0] = 0.0
    points = rng.permutation(np.concatenate([base, near, chain, base[: n // 5], plane]))
    tol = 1e-6
    pairs = close_pairs(points, tol)
    assert (pairs[:, 0] < pairs[:, 1]).all()
    np.testing.assert_array_equal(weld_labels(len(points), pairs), brute_labels(points, tol))


def test_weld_of_no_or_one_point() -> None:
    assert close_pairs(np.zeros((0, 3)), 1e-6).shape == (0, 2)
    assert close_pairs(np.zeros((1, 3)), 1e-6).shape == (0, 2)
    np.testing.assert_array_equal(weld_labels(3, np.zeros((0, 2), np.intp)), [0, 1, 2])


@pytest.mark.parametrize("preset", ["oak", "spruce"])
def test_tree_mesh_welds_every_rim(preset: str) -> None:
    """Welded, no two vertices of the bark mesh coincide, and every quad keeps its shape (to
    a tenth of a millimetre: a chain of vertices each within the tolerance of the next joins
    as one group, as a KD-tree's pairs and connected components joined them too)."""
    f = generate_forest(load_preset(preset), 2, ForestOptions(trees=1))
    ((inst, bones),) = tree_slices(f)
    raw = tree_mesh(f, inst, bones, np.eye(4), f.palette())
    pts, _, quads, *_ = tree_mesh(f, inst, bones, np.eye(4), f.palette(), weld=True)
    assert len(pts) < len(raw[0])
    assert len(close_pairs(pts, WELD_TOL)) == 0
    np.testing.assert_allclose(pts[quads], raw[0][raw[2]], rtol=0, atol=1e-4)


def test_proxy_vertices_take_skin_from_what_collapsed_into_them() -> None:
    f = generate_forest(load_preset("oak"), 2, ForestOptions(trees=1))
    ((inst, bones),) = tree_slices(f)
    pts, _, quads, *_ = tree_mesh(f, inst, bones, np.eye(4), f.palette(), weld=True)
    tris = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    pts32 = pts.astype(np.float32)
    *_, coll = fast_simplification.simplify(pts32, tris, 1.0 - PROXY_KEEP, return_collapses=True)
    p2, _, to_proxy = fast_simplification.replay_simplification(pts32, tris, coll)
    p2 = np.asarray(p2, np.float64)
    near = nearest_source(pts, p2, np.asarray(to_proxy, np.intp))
    assert (near >= 0).all()
    np.testing.assert_array_equal(to_proxy[near], np.arange(len(p2)))
    # and it is the nearest of them
    d_near = np.sum((pts[near] - p2) ** 2, axis=1)
    d_all = np.sum((pts - p2[to_proxy]) ** 2, axis=1)
    best = np.full(len(p2), np.inf)
    np.minimum.at(best, to_proxy[to_proxy >= 0], d_all[to_proxy >= 0])
    np.testing.assert_array_equal(d_near, best)
