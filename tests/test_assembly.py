"""Assembly and posing (paper 4.2, 4.3): rims of every parent and child coincide at rest, posed
and in the wind, so a skinned tree is one crack-free surface."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from forest.geometry import rim
from forest.geometry.tolerances import (
    SIMILARITY_SCALE_REL,
    TEST_RIM_NORMAL_ABS,
    TEST_RIM_POSITION_REL,
)
from forest.growth.expand import BLOCK_PIECES
from forest.growth.generate import Forest, ForestOptions, generate_forest
from forest.growth.presets import load_preset, preset_names
from tests.helpers_skin import bbox_diagonal, skin_forest

PRESETS = preset_names()
SEEDS = st.integers(min_value=0, max_value=2**63 - 1)
TIMES = st.floats(min_value=0.0, max_value=30.0, allow_nan=False)
WELD_REL = 1e-6


def make_forest(name: str, seed: int, trees: int = 2) -> Forest:
    return generate_forest(load_preset(name), seed, ForestOptions(trees=trees, frames=2))


def palettes(f: Forest, times: tuple[float, float]) -> list[tuple[str, np.ndarray]]:
    """Rest, posed, and posed with wind at two times."""
    return [("rest", f.rest_palette()), ("posed", f.palette(None))] + [
        (f"wind t={t:g}", f.palette(t)) for t in times
    ]


def tree_sizes(f: Forest, pos: list[np.ndarray]) -> np.ndarray:
    sizes = np.empty(f.options.trees)
    for t in range(f.options.trees):
        inst = np.nonzero(f.graph.tree == t)[0]
        sizes[t] = bbox_diagonal(np.concatenate([pos[i] for i in inst]))
    return sizes


def open_tips(f: Forest) -> list[tuple[int, int]]:
    """(instance, leaf rim) of every leaf rim that no child sits on."""
    g = f.graph
    taken = {(int(p), int(r)) for p, r in zip(g.parent, g.parent_rim, strict=True) if p >= 0}
    return [
        (i, r)
        for i in range(len(g))
        for r in range(f.pieces[g.piece[i]].n_leaf_rims)
        if (i, r) not in taken
    ]


def check_rims(f: Forest, palette: np.ndarray, label: str) -> None:
    pos, nrm = skin_forest(f, palette)
    sizes = tree_sizes(f, pos)
    assert (sizes > 0).all()
    g = f.graph
    child = np.nonzero(g.parent >= 0)[0]
    parent = g.parent[child]
    # every child's root rim and its parent's leaf rim, stacked: (children, SIDES, 3)
    a = np.stack([pos[c][f.pieces[g.piece[c]].root_rim] for c in child])
    an = np.stack([nrm[c][f.pieces[g.piece[c]].root_rim] for c in child])
    leaf = [
        f.pieces[g.piece[p]].leaf_rims[r] for p, r in zip(parent, g.parent_rim[child], strict=True)
    ]
    b = np.stack([pos[p][v] for p, v in zip(parent, leaf, strict=True)])
    bn = np.stack([nrm[p][v] for p, v in zip(parent, leaf, strict=True)])
    tol = TEST_RIM_POSITION_REL * sizes[g.tree[child]]
    dist = np.linalg.norm(a[:, :, None] - b[:, None], axis=-1)  # (children, SIDES, SIDES)
    # as sets: every vertex of either rim has a partner on the other within tol
    far = dist.min(axis=2).max(axis=1)
    worst = int(np.argmax(far - tol))
    assert (far <= tol).all(), (label, int(child[worst]), far[worst], tol[worst])
    assert (dist.min(axis=1).max(axis=1) <= tol).all(), label
    match = dist.argmin(axis=2)
    # the partner is the one the twist predicts: T(child) = T(parent) @ B @ Twist(k)
    want = (np.arange(rim.SIDES) - g.twist[child][:, None]) % rim.SIDES
    wrong = np.nonzero((match != want).any(axis=1))[0]
    assert not len(wrong), (label, child[wrong[:5]])
    partner = np.take_along_axis(bn, match[..., None], axis=1)
    normal_err = np.abs(an - partner).max(axis=(1, 2))
    assert (normal_err <= TEST_RIM_NORMAL_ABS).all(), (label, child[np.argmax(normal_err)])


def weld(points: np.ndarray, tol: float) -> np.ndarray:
    """Index of each point's cluster, merging points closer than ``tol`` (transitively)."""
    pairs = cKDTree(points).query_pairs(tol, output_type="ndarray")
    n = len(points)
    adj = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(adj, directed=False)[1]


def loop_edges(v: np.ndarray) -> set[tuple[int, int]]:
    """Undirected edges of the closed loop ``v``, as sorted index pairs."""
    e = [(int(v[k]), int(v[(k + 1) % len(v)])) for k in range(len(v))]
    return {(min(a, b), max(a, b)) for a, b in e}


def check_welded_boundary(f: Forest, palette: np.ndarray, label: str) -> None:
    pos, _ = skin_forest(f, palette)
    g = f.graph
    tips = open_tips(f)
    for t in range(f.options.trees):
        inst = np.nonzero(g.tree == t)[0].tolist()
        starts = np.cumsum([0] + [len(pos[i]) for i in inst])
        start = dict(zip(inst, starts[:-1].tolist(), strict=True))
        pts = np.concatenate([pos[i] for i in inst])
        faces = np.concatenate(
            [
                f.pieces[g.piece[i]].quads[:, [0, 1, 2, 0, 2, 3]].reshape(-1, 3) + start[i]
                for i in inst
            ]
        )
        # relative to the tree, but well inside its smallest quad (a twig's cap is millimetres
        # across on a 30 m tree, and deep pieces are far smaller still at rest)
        edges = np.linalg.norm(pts[faces] - pts[np.roll(faces, 1, axis=1)], axis=-1)
        tol = min(WELD_REL * bbox_diagonal(pts), 0.01 * edges.min())
        label_of = weld(pts, tol)
        mesh = trimesh.Trimesh(pts, label_of[faces], process=False, validate=False)
        # no triangle collapsed by the weld
        assert (np.diff(np.sort(mesh.faces, axis=1), axis=1) > 0).all(), label

        root = int(inst[0])
        assert g.parent[root] < 0
        expected = loop_edges(label_of[start[root] + f.pieces[g.piece[root]].root_rim])
        tree_tips = [(i, r) for i, r in tips if g.tree[i] == t]
        for i, r in tree_tips:
            expected |= loop_edges(label_of[start[i] + f.pieces[g.piece[i]].leaf_rims[r]])
        assert len(expected) == rim.SIDES * (1 + len(tree_tips)), label
        # each undirected edge as one integer: a 1-D unique, far faster than rows (axis=0)
        n = np.int64(len(pts))
        edge = mesh.edges_sorted.astype(np.int64)
        edge_key, counts = np.unique(edge[:, 0] * n + edge[:, 1], return_counts=True)
        once = edge_key[counts == 1]
        boundary = set(zip((once // n).tolist(), (once % n).tolist(), strict=True))
        assert boundary == expected, (label, t, len(boundary), len(expected))
        assert counts.max() <= 2, label  # no fins where three surfaces meet
        assert mesh.is_winding_consistent, label


# few examples: each checks every rim of two mature trees (thousands) in four palettes
@pytest.mark.parametrize("name", PRESETS)
@settings(max_examples=8, deadline=None)
@given(seed=SEEDS, t0=TIMES, t1=TIMES)
def test_rims_coincide_at_rest_posed_and_in_wind(
    name: str, seed: int, t0: float, t1: float
) -> None:
    f = make_forest(name, seed)
    assert f.n_instances > f.options.trees  # something grew beyond the trunks
    for label, pal in palettes(f, (t0, t1)):
        check_rims(f, pal, f"{name} seed={seed} {label}")


@pytest.mark.parametrize("name", PRESETS)
@settings(max_examples=4, deadline=None)
@given(seed=SEEDS, t0=TIMES, t1=TIMES)
def test_welded_tree_is_open_only_at_trunk_and_tips(
    name: str, seed: int, t0: float, t1: float
) -> None:
    f = make_forest(name, seed)
    for label, pal in palettes(f, (t0, t1)):
        check_welded_boundary(f, pal, f"{name} seed={seed} {label}")


def is_similarity(m: np.ndarray, rel: float) -> bool:
    lin = m[..., :3, :3]
    s = np.cbrt(np.linalg.det(lin))
    gram = np.swapaxes(lin, -1, -2) @ lin
    err = np.abs(gram - (s * s)[..., None, None] * np.eye(3)).max(axis=(-1, -2))
    bottom = np.array_equal(m[..., 3, :], np.broadcast_to([0.0, 0.0, 0.0, 1.0], m[..., 3, :].shape))
    return bool(bottom and (s > 0).all() and (err <= rel * s * s).all())


@pytest.mark.parametrize("name", PRESETS)
@settings(max_examples=5, deadline=None)
@given(seed=SEEDS)
def test_rest_palette_repeats_transforms(name: str, seed: int) -> None:
    f = make_forest(name, seed)
    n_joints = np.array([p.n_joints for p in f.pieces])[f.graph.piece]
    assert len(f.bones) == n_joints.sum()
    np.testing.assert_array_equal(f.rest_palette(), np.repeat(f.transforms, n_joints, axis=0))
    np.testing.assert_array_equal(f.bones.instance, np.repeat(np.arange(f.n_instances), n_joints))
    np.testing.assert_array_equal(f.bones.offset[1:], np.cumsum(n_joints)[:-1])


@pytest.mark.parametrize("name", PRESETS)
@settings(max_examples=5, deadline=None)
@given(seed=SEEDS, t=TIMES)
def test_transforms_and_palettes_are_similarities(name: str, seed: int, t: float) -> None:
    f = make_forest(name, seed)
    assert is_similarity(f.tree_transforms, SIMILARITY_SCALE_REL)
    assert is_similarity(f.transforms, SIMILARITY_SCALE_REL)
    for pal in (f.palette(None), f.palette(t)):
        assert is_similarity(pal, SIMILARITY_SCALE_REL)


@pytest.mark.parametrize("name", PRESETS)
@settings(max_examples=5, deadline=None)
@given(seed=SEEDS, trees=st.integers(min_value=1, max_value=4))
def test_tree_roots_are_tree_transforms(name: str, seed: int, trees: int) -> None:
    f = make_forest(name, seed, trees)
    g = f.graph
    roots = np.nonzero(g.parent < 0)[0]
    np.testing.assert_array_equal(g.tree[roots], np.arange(trees))  # one root per tree
    np.testing.assert_array_equal(g.depth[roots], 0)
    np.testing.assert_array_equal(f.transforms[roots], f.tree_transforms)
    # tree-major order, parents before children, children in the parent's tree one level down
    assert (np.diff(g.tree) >= 0).all()
    kids = np.nonzero(g.parent >= 0)[0]
    assert (g.parent[kids] < kids).all()
    np.testing.assert_array_equal(g.tree[g.parent[kids]], g.tree[kids])
    np.testing.assert_array_equal(g.depth[g.parent[kids]] + 1, g.depth[kids])


@pytest.mark.parametrize("name", PRESETS)
@settings(max_examples=5, deadline=None)
@given(seed=SEEDS, data=st.data())
def test_topological_transform_formula(name: str, seed: int, data: st.DataObject) -> None:
    f = make_forest(name, seed)
    g = f.graph
    kids = np.nonzero(g.parent >= 0)[0]
    picks = data.draw(st.lists(st.sampled_from(kids.tolist()), min_size=1, max_size=8))
    tw = rim.twists()
    for c in picks:
        p = g.parent[c]
        b = f.pieces[g.piece[p]].building[g.parent_rim[c]]
        expect = f.transforms[p] @ b @ tw[g.twist[c]]
        np.testing.assert_allclose(
            f.transforms[c], expect, rtol=0, atol=1e-12 * np.abs(expect).max()
        )
    # and the whole chain from the root, as a product in one go
    c = picks[0]
    chain = [c]
    while g.parent[chain[-1]] >= 0:
        chain.append(int(g.parent[chain[-1]]))
    m = f.tree_transforms[g.tree[c]]
    for parent, child in zip(chain[::-1][:-1], chain[::-1][1:], strict=True):
        m = m @ f.pieces[g.piece[parent]].building[g.parent_rim[child]] @ tw[g.twist[child]]
    np.testing.assert_allclose(f.transforms[c], m, rtol=0, atol=1e-12 * np.abs(m).max())


def forest_arrays(f: Forest) -> dict[str, np.ndarray]:
    g = f.graph
    out = {
        k: getattr(g, k)
        for k in (
            "tree",
            "parent",
            "parent_rim",
            "depth",
            "piece",
            "symbol",
            "alt",
            "twist",
            "length",
            "radius",
        )
    }
    out |= {
        "tree_transforms": f.tree_transforms,
        "transforms": f.transforms,
        "tile_indices": f.tile_indices,
        "foliage": f.foliage_instance,
        "bend_angle": f.pose.bend_angle,
        "spread_angle": f.pose.spread_angle,
        "palette": f.palette(None),
        "wind": f.palette(0.5),
    }
    return out


@pytest.mark.parametrize("name", PRESETS)
@settings(max_examples=3, deadline=None)
@given(seed=SEEDS)
def test_same_seed_same_arrays(name: str, seed: int) -> None:
    a, b = forest_arrays(make_forest(name, seed)), forest_arrays(make_forest(name, seed))
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


@pytest.mark.parametrize("name", PRESETS)
@settings(max_examples=3, deadline=None)
@given(seed=SEEDS)
def test_different_seeds_differ(name: str, seed: int) -> None:
    a, b = make_forest(name, seed), make_forest(name, seed + 1)
    assert not np.array_equal(a.tree_transforms, b.tree_transforms)
    pa, pb = a.palette(None), b.palette(None)
    assert pa.shape != pb.shape or not np.array_equal(pa, pb)


def test_equal_topologies_get_different_poses() -> None:
    f = generate_forest(load_preset("alternating"), 11, ForestOptions(trees=3, frames=2))
    g = f.graph
    per_tree = [np.nonzero(g.tree == t)[0] for t in range(3)]
    # the alternating grammar has one alternative per symbol: every tree has one topology
    for inst in per_tree[1:]:
        assert len(inst) == len(per_tree[0])
        for key in ("piece", "parent_rim", "depth", "symbol"):
            np.testing.assert_array_equal(getattr(g, key)[inst], getattr(g, key)[per_tree[0]])
        np.testing.assert_array_equal(
            g.parent[inst][1:] - inst[0], g.parent[per_tree[0]][1:] - per_tree[0][0]
        )
    local = f.local_bones(None)
    posed = f.palette(None)
    rest = f.rest_palette()
    bones_of = [np.nonzero(np.isin(f.bones.instance, inst))[0] for inst in per_tree]
    hub = f.bones.joint == 1
    in_tree = []
    for t, b in enumerate(bones_of):
        # pose relative to the tree's own frame, so placement and heading do not count
        inv_m = np.linalg.inv(f.tree_transforms[t])
        in_tree.append(inv_m @ posed[b])
        assert not np.allclose(posed[b], rest[b])  # posing moved bones
    for t in (1, 2):
        b0, bt = bones_of[0], bones_of[t]
        assert not np.allclose(local[b0[hub[b0]]], local[bt[hub[bt]]], atol=1e-6)
        assert not np.allclose(in_tree[0], in_tree[t], atol=1e-6)


def test_wind_moves_bones_over_time() -> None:
    f = make_forest("alternating", 3)
    p0, p1, still = f.palette(0.0), f.palette(0.7), f.palette(None)
    assert not np.allclose(p0, p1)
    assert not np.allclose(p0, still)
    roots = f.bones.offset[f.graph.parent < 0]
    # trunks stay planted: the root bone carries the tree transform only
    np.testing.assert_array_equal(p0[roots], f.tree_transforms)


def forward_kinematics(parent: np.ndarray, local: np.ndarray) -> np.ndarray:
    """Globals of bones from their locals, by matrix products down the parent links (no
    blocks, no depth order, no closed forms: the plain definition)."""
    glob = np.full_like(local, np.nan)
    done = parent < 0
    glob[done] = local[done]
    while not done.all():
        ready = ~done & done[np.maximum(parent, 0)]
        glob[ready] = glob[parent[ready]] @ local[ready]
        done |= ready
    return glob


@pytest.mark.parametrize("name", PRESETS)
@pytest.mark.parametrize("block", [7, 64, 1 << 20])
def test_blocked_passes_equal_the_plain_definitions(
    name: str, block: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Assembly and palette run block by block in depth order and write each level's
    results in one gather; with blocks of a few trees or one, they equal the textbook forms:
    ``T(child) = T(parent) B Twist`` and ``palette = FK(locals) @ inv(J)``."""
    monkeypatch.setattr("forest.growth.expand.BLOCK_PIECES", block)
    f = generate_forest(load_preset(name), 5, ForestOptions(trees=12, frames=2))
    assert len(f.graph.blocks) > 1 or block > len(f.graph)
    g = f.graph
    tw = rim.twists()
    local = np.empty_like(f.transforms)
    roots = g.parent < 0
    local[roots] = f.tree_transforms[g.tree[roots]]
    kids = np.nonzero(~roots)[0]
    for c in kids:
        b = f.pieces[g.piece[g.parent[c]]].building[g.parent_rim[c]]
        local[c] = b @ tw[g.twist[c]]
    topo = forward_kinematics(g.parent, local)
    np.testing.assert_allclose(f.transforms, topo, rtol=0, atol=1e-12 * np.abs(topo).max())
    inv_rest = f.bones.inv_rest[g.piece[f.bones.instance], f.bones.joint]
    for time in (None, 0.4):
        glob = forward_kinematics(f.bones.parent, f.local_bones(time))
        expect = glob @ inv_rest
        np.testing.assert_allclose(
            f.palette(time), expect, rtol=0, atol=1e-12 * np.abs(expect).max()
        )


def test_forest_whose_last_tree_spans_a_block_boundary() -> None:
    """265 alternating trees of 62 pieces: the last tree holds piece 16384, the block size
    (cutting a block there crashed with an IndexError: no tree starts after it)."""
    assert BLOCK_PIECES == 16384
    f = generate_forest(load_preset("alternating"), 1, ForestOptions(trees=265))
    starts = np.flatnonzero(np.diff(f.graph.tree, prepend=-1))
    assert starts[-1] < 16384 < len(f.graph)
    assert [(b.start, b.stop) for b in f.graph.blocks] == [(0, len(f.graph))]
    assert np.isfinite(f.palette(None)).all()
