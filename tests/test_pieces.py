"""The piece library (paper 4.1, 4.2): quad meshes whose rims interlock by construction."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from forest.geometry import rim
from forest.geometry.pieces import (
    BARK,
    FORK,
    MAX_INFLUENCES,
    PIECE_NAMES,
    PieceArrays,
    piece_library,
)
from forest.geometry.transforms import invert_similarity, transform_points, transform_vectors
from schemas.tileset import BARK_H, CLASS_EDGES, QUARTER_TURN, TileEdges

SEGMENTS = (1, 2)
CASES = [(s, name) for s in SEGMENTS for name in PIECE_NAMES]
IDS = [f"{name}-seg{s}" for s, name in CASES]
TOL = 1e-12
# Flare's root rim is a tree's ground end, attached to nothing: wider than the universal rim
GROUND_PIECES = ("Flare",)


@pytest.fixture(params=CASES, ids=IDS)
def piece(request: pytest.FixtureRequest) -> PieceArrays:
    segments, name = request.param
    p = piece_library(segments)[PIECE_NAMES.index(name)]
    assert p.name == name
    return p


def rim_edges(ring: np.ndarray) -> set[tuple[int, int]]:
    """Undirected edges of a closed six-vertex loop, as sorted index pairs."""
    v = [int(x) for x in ring]
    return {(min(v[k], v[(k + 1) % len(v)]), max(v[k], v[(k + 1) % len(v)])) for k in range(len(v))}


def all_rims(p: PieceArrays) -> list[np.ndarray]:
    return [p.root_rim, *p.leaf_rims]


def adjacent_ring(p: PieceArrays, ring: np.ndarray) -> np.ndarray:
    """Vertices of the quads that hold an edge of ``ring``, minus the ring itself."""
    edges = rim_edges(ring)
    out: set[int] = set()
    for quad in p.quads:
        q = [int(v) for v in quad]
        quad_edges = {(min(q[i], q[(i + 1) % 4]), max(q[i], q[(i + 1) % 4])) for i in range(4)}
        if quad_edges & edges:
            out.update(v for v in q if v not in set(int(r) for r in ring))
    return np.array(sorted(out))


def triangles(p: PieceArrays) -> np.ndarray:
    q = p.quads
    return np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])


def piece_mesh(p: PieceArrays) -> trimesh.Trimesh:
    return trimesh.Trimesh(p.positions, triangles(p), process=False, validate=False)


def boundary_edges(mesh: trimesh.Trimesh) -> set[tuple[int, int]]:
    rows = trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1)
    return {(int(a), int(b)) for a, b in mesh.edges_sorted[rows]}


def test_library_order_and_counts() -> None:
    for s in SEGMENTS:
        lib = piece_library(s)
        assert tuple(p.name for p in lib) == PIECE_NAMES
        assert [p.n_leaf_rims for p in lib] == [1, 2, 2, 3, 0, 1]


def test_quad_only(piece: PieceArrays) -> None:
    q = piece.quads
    assert q.ndim == 2 and q.shape[1] == 4
    assert q.dtype == np.int32
    assert q.min() >= 0 and q.max() < len(piece.positions)
    # four distinct corners, no degenerate quads
    assert all(len(set(row.tolist())) == 4 for row in q)
    # every vertex is used by some quad
    assert np.array_equal(np.unique(q), np.arange(len(piece.positions)))
    a, b, c, d = (piece.positions[q[:, i]] for i in range(4))
    assert (np.linalg.norm(np.cross(c - a, d - b), axis=-1) > 1e-6).all()


def test_root_rim_is_the_universal_rim(piece: PieceArrays) -> None:
    assert piece.root_rim.shape == (rim.SIDES,)
    if piece.name in GROUND_PIECES:
        # wider than the universal rim, in the root plane, its ring still ordered by angle
        pos = piece.positions[piece.root_rim]
        np.testing.assert_array_equal(pos[:, 1], 0.0)
        assert (np.hypot(pos[:, 0], pos[:, 2]) > rim.RADIUS).all()
        ang = np.arctan2(pos[:, 2], pos[:, 0])
        np.testing.assert_allclose(np.mod(ang, 2 * np.pi), rim.ANGLES, atol=1e-12)
        return
    assert np.array_equal(piece.positions[piece.root_rim], rim.rim_ring())
    assert np.array_equal(piece.normals[piece.root_rim], rim.rim_normals())


def test_leaf_rims_are_building_images_of_root_rim(piece: PieceArrays) -> None:
    # images of the universal rim (which is every root rim but a ground piece's)
    root_pos, root_nrm = rim.rim_ring(), rim.rim_normals()
    assert piece.leaf_rims.shape == (piece.n_leaf_rims, rim.SIDES)
    for r in range(piece.n_leaf_rims):
        b = piece.building[r]
        leaf = piece.leaf_rims[r]
        np.testing.assert_allclose(
            piece.positions[leaf], transform_points(b, root_pos), rtol=0, atol=TOL
        )
        lin = b[:3, :3] / np.cbrt(np.linalg.det(b[:3, :3]))
        np.testing.assert_allclose(piece.normals[leaf], root_nrm @ lin.T, rtol=0, atol=TOL)


def test_rims_are_disjoint(piece: PieceArrays) -> None:
    verts = np.concatenate(all_rims(piece))
    assert len(np.unique(verts)) == len(verts)


def test_normals_are_unit(piece: PieceArrays) -> None:
    np.testing.assert_allclose(np.linalg.norm(piece.normals, axis=-1), 1.0, atol=1e-12)


@pytest.mark.parametrize("which", ["root", "leaf"])
def test_quad_ring_next_to_rim_lies_on_rim_cone(piece: PieceArrays, which: str) -> None:
    if which == "root" and piece.name in GROUND_PIECES:
        pytest.skip("a ground piece's root rim is attached to nothing")
    frames = [np.eye(4)] if which == "root" else list(piece.building)
    rings = [piece.root_rim] if which == "root" else list(piece.leaf_rims)
    for frame, ring in zip(frames, rings, strict=True):
        adj = adjacent_ring(piece, ring)
        assert len(adj) == rim.SIDES, f"{piece.name}: ring next to a rim has {len(adj)} vertices"
        local = transform_points(invert_similarity(frame), piece.positions[adj])
        radius = np.hypot(local[:, 0], local[:, 2])
        np.testing.assert_allclose(radius, 1.0 - rim.CONE_SLOPE * local[:, 1], rtol=0, atol=1e-9)
        # one ring, at one height on the cone, on the far side of the rim from the rim's normal
        np.testing.assert_allclose(local[:, 1], local[0, 1], atol=1e-9)
        assert local[0, 1] < -1e-3 if which == "leaf" else local[0, 1] > 1e-3


def test_rim_normals_are_cone_normals(piece: PieceArrays) -> None:
    """The predetermined normal is perpendicular to the cone's generator at each rim vertex."""
    for frame, ring in zip([np.eye(4), *piece.building], all_rims(piece), strict=True):
        if ring is piece.root_rim and piece.name in GROUND_PIECES:
            continue
        local_n = transform_vectors(invert_similarity(frame), piece.normals[ring])
        local_p = transform_points(invert_similarity(frame), piece.positions[ring])
        radial = local_p * [1.0, 0.0, 1.0]
        generator = np.array([0.0, 1.0, 0.0]) - rim.CONE_SLOPE * radial
        np.testing.assert_allclose(np.einsum("ij,ij->i", local_n, generator), 0.0, atol=1e-12)
        assert (np.einsum("ij,ij->i", local_n, radial) > 0).all()


def test_building_transforms_are_similarities(piece: PieceArrays) -> None:
    assert piece.building.shape == (piece.n_leaf_rims, 4, 4)
    for b in piece.building:
        np.testing.assert_array_equal(b[3], [0.0, 0.0, 0.0, 1.0])
        lin = b[:3, :3]
        s = np.cbrt(np.linalg.det(lin))
        assert s > 0  # no mirroring
        np.testing.assert_allclose(lin.T @ lin, s * s * np.eye(3), rtol=0, atol=1e-12)
    np.testing.assert_allclose(piece.joint_rest[2:], piece.building, atol=0)


@pytest.mark.parametrize("k", range(rim.SIDES))
def test_twists_map_rim_onto_itself(k: int) -> None:
    tw = rim.twists()
    assert tw.shape == (rim.SIDES, 4, 4)
    ring = rim.rim_ring()
    moved = transform_points(tw[k], ring)
    dist = np.linalg.norm(moved[:, None] - ring[None], axis=-1)
    match = dist.argmin(axis=1)
    assert dist.min(axis=1).max() < 1e-12
    assert sorted(match.tolist()) == list(range(rim.SIDES))  # a permutation
    # a right-handed turn about +Y by k sixths moves every vertex k places back in the rim's
    # order (the rim is ordered by increasing atan2(z, x))
    assert np.array_equal(match, (np.arange(rim.SIDES) - k) % rim.SIDES)
    # twisted rim normals are rim normals too
    np.testing.assert_allclose(
        transform_vectors(tw[k], rim.rim_normals()), rim.rim_normals()[match], atol=1e-12
    )


def test_skin_arrays_have_four_influences(piece: PieceArrays) -> None:
    """PieceArrays documents ``(v, 4)`` joint indices and weights, and the USD writers
    author them with elementSize MAX_INFLUENCES, so every piece must have four columns
    (padded with weight 0), even one with fewer than four joints."""
    n = len(piece.positions)
    assert piece.joint_indices.shape == (n, MAX_INFLUENCES)
    assert piece.joint_weights.shape == (n, MAX_INFLUENCES)


def test_skin_weights(piece: PieceArrays) -> None:
    ji, jw = piece.joint_indices, piece.joint_weights
    n = len(piece.positions)
    assert ji.shape == jw.shape
    assert ji.shape[0] == n and 1 <= ji.shape[1] <= MAX_INFLUENCES
    assert ji.dtype == np.int32
    assert (jw >= 0).all()
    np.testing.assert_allclose(jw.sum(axis=1), 1.0, rtol=0, atol=1e-12)
    assert ji.min() >= 0 and ji.max() < piece.n_joints
    # no joint listed twice with weight on it
    for row_i, row_w in zip(ji, jw, strict=True):
        used = row_i[row_w > 0]
        assert len(set(used.tolist())) == len(used)


def test_rim_vertices_bound_to_one_joint(piece: PieceArrays) -> None:
    joints = [0] + [2 + r for r in range(piece.n_leaf_rims)]
    for joint, ring in zip(joints, all_rims(piece), strict=True):
        for v in ring:
            w = piece.joint_weights[v]
            i = piece.joint_indices[v]
            assert w[i == joint].sum() == 1.0, (piece.name, joint, int(v), i, w)
            assert (w[i != joint] == 0.0).all()


def test_skeleton_layout(piece: PieceArrays) -> None:
    assert piece.n_joints == 2 + piece.n_leaf_rims
    np.testing.assert_array_equal(piece.joint_rest[0], np.eye(4))
    np.testing.assert_array_equal(piece.joint_parents, [-1, 0] + [1] * piece.n_leaf_rims)
    assert len(piece.joint_names) == piece.n_joints


def test_tile_classes(piece: PieceArrays) -> None:
    assert piece.tile_class.shape == (len(piece.quads),)
    assert set(np.unique(piece.tile_class).tolist()) <= set(CLASS_EDGES)
    assert (piece.tile_class == BARK).any()
    if piece.name in ("Y", "T", "Psi"):
        assert (piece.tile_class == FORK).any()
    else:
        assert not (piece.tile_class == FORK).any()
    if piece.name in ("I", "Flare"):  # one upright grid: bark only
        assert (piece.tile_class == BARK).all()


def test_winding_consistent_and_boundary_only_on_rims(piece: PieceArrays) -> None:
    mesh = piece_mesh(piece)
    assert mesh.is_winding_consistent
    # every edge is shared by at most two triangles
    _, counts = np.unique(mesh.edges_sorted, axis=0, return_counts=True)
    assert counts.max() <= 2
    expected: set[tuple[int, int]] = set()
    for ring in all_rims(piece):
        expected |= rim_edges(ring)
    assert boundary_edges(mesh) == expected


def test_capped_piece_is_watertight_with_outward_normals(piece: PieceArrays) -> None:
    mesh = piece_mesh(piece)
    # orient each cap from the mesh's own boundary edges: a cap triangle walks a boundary
    # edge backwards, so the capped mesh is consistently wound iff the piece was
    directed = mesh.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    pos = [piece.positions]
    caps: list[tuple[int, int, int]] = []
    n = len(piece.positions)
    for ring in all_rims(piece):
        centre = n + len(caps) // rim.SIDES
        ring_set = set(int(v) for v in ring)
        rim_dir = [(int(a), int(b)) for a, b in directed if a in ring_set and b in ring_set]
        assert len(rim_dir) == rim.SIDES
        caps += [(b, a, centre) for a, b in rim_dir]
        pos.append(piece.positions[ring].mean(axis=0, keepdims=True))
    capped = trimesh.Trimesh(
        np.concatenate(pos), np.concatenate([mesh.faces, caps]), process=False, validate=False
    )
    assert capped.is_watertight
    assert capped.is_winding_consistent
    assert capped.volume > 0
    assert capped.is_volume


def test_vertex_normals_face_outward(piece: PieceArrays) -> None:
    """Stored normals agree in sign with the winding's face normals around each vertex."""
    mesh = piece_mesh(piece)
    fn = np.cross(
        mesh.vertices[mesh.faces[:, 1]] - mesh.vertices[mesh.faces[:, 0]],
        mesh.vertices[mesh.faces[:, 2]] - mesh.vertices[mesh.faces[:, 0]],
    )
    acc = np.zeros_like(piece.positions)
    for i in range(3):
        np.add.at(acc, mesh.faces[:, i], fn)
    assert (np.einsum("ij,ij->i", acc, piece.normals) > 0).all()


def test_library_is_cached_and_deterministic() -> None:
    assert piece_library(1) is piece_library(1)
    from forest.geometry.pieces import MAKERS

    for name, make in MAKERS.items():
        a, b = make(1), piece_library(1)[PIECE_NAMES.index(name)]
        for field in (
            "positions",
            "normals",
            "quads",
            "tile_class",
            "joint_indices",
            "joint_weights",
            "root_rim",
            "leaf_rims",
            "building",
        ):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field))


def tile_stretch(p: PieceArrays) -> np.ndarray:
    """``(q,)`` along-branch over around-branch length of each quad's tile (QUAD_ST: v runs
    along corners 0->1 and 3->2, u along 0->3 and 1->2): 1 for a square texel footprint."""
    c = p.positions[p.quads]
    along = np.linalg.norm(c[:, 1] - c[:, 0], axis=-1) + np.linalg.norm(c[:, 2] - c[:, 3], axis=-1)
    around = np.linalg.norm(c[:, 3] - c[:, 0], axis=-1) + np.linalg.norm(c[:, 2] - c[:, 1], axis=-1)
    return along / around


@pytest.mark.parametrize("name", PIECE_NAMES)
def test_tiles_are_near_square_at_default_resolution(name: str) -> None:
    """Every quad maps one whole bark tile: at segments=1 no tile is stretched more than 1.5x
    along or around the branch, rim rows included (no 'sausage links')."""
    p = piece_library(1)[PIECE_NAMES.index(name)]
    ratio = tile_stretch(p)
    worst = int(np.argmax(np.maximum(ratio, 1 / ratio)))
    assert ratio.min() >= 1 / 1.5 and ratio.max() <= 1.5, (name, worst, ratio[worst])


SIDE_CORNERS = {"left": (0, 1), "top": (1, 2), "right": (3, 2), "bottom": (0, 3)}


def edge_disagreements(
    p: PieceArrays, edges: dict[int, TileEdges]
) -> list[tuple[tuple[int, int], str, str, str, str]]:
    """Shared edges whose two tiles do not continue one edge pattern: (edge, side and colour
    of either quad). Tiles continue one pattern across an edge when both sides name the same
    colour and the sides are opposite (left-right, top-bottom), or a quarter turn apart with
    that turn's colour (left-bottom or right-top: clockwise; left-top or right-bottom:
    counter-clockwise). The same side on both (a half turn) never continues a pattern."""
    holders: dict[tuple[int, int], list[tuple[str, str]]] = {}
    for q, quad in enumerate(p.quads):
        e = edges[int(p.tile_class[q])]
        for side, (i, j) in SIDE_CORNERS.items():
            key = (min(int(quad[i]), int(quad[j])), max(int(quad[i]), int(quad[j])))
            holders.setdefault(key, []).append((side, getattr(e, side)))
    bad = []
    for key, h in holders.items():
        if len(h) != 2:
            continue
        (sa, ca), (sb, cb) = h
        pair = {sa, sb}
        if pair in ({"left", "right"}, {"top", "bottom"}):
            ok = ca == cb and ca not in QUARTER_TURN
        elif pair in ({"left", "bottom"}, {"right", "top"}):
            ok = ca == cb and QUARTER_TURN.get(ca) == "cw"
        elif pair in ({"left", "top"}, {"right", "bottom"}):
            ok = ca == cb and QUARTER_TURN.get(ca) == "ccw"
        else:
            ok = False
        if not ok:
            bad.append((key, sa, ca, sb, cb))
    return bad


def test_tile_edge_colours_agree_on_every_shared_edge(piece: PieceArrays) -> None:
    """Paper 5.1: every edge two quads share joins tiles whose sides carry one edge colour
    (and whose patterns line up), so no seam shows at a crotch or an apex."""
    assert set(np.unique(piece.tile_class).tolist()) <= set(CLASS_EDGES)
    assert edge_disagreements(piece, CLASS_EDGES) == []


def test_rim_edges_are_upright_bark(piece: PieceArrays) -> None:
    """Across rims between pieces (any twist): the child's root-rim quads have their bottom
    side, the parent's leaf-rim quads their top side on the rim, both bark-h."""
    for ring, want in [(piece.root_rim, "bottom"), *((lr, "top") for lr in piece.leaf_rims)]:
        rim_edges_ = rim_edges(ring)
        found = 0
        for q, quad in enumerate(piece.quads):
            for side, (i, j) in SIDE_CORNERS.items():
                key = (min(int(quad[i]), int(quad[j])), max(int(quad[i]), int(quad[j])))
                if key in rim_edges_:
                    found += 1
                    assert side == want, (piece.name, q, side)
                    assert getattr(CLASS_EDGES[int(piece.tile_class[q])], side) == BARK_H
        assert found == rim.SIDES
