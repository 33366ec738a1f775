"""The renderer on a real GL 4.3 context (Mesa llvmpipe in CI): skinning and matrix layout,
Phong quad tessellation against a numpy reference, no cracks at shared rims, per-quad tile
lookup, and the frame statistics. Tessellated vertices are captured from the tessellation
evaluation shader (``CAPTURE``: an SSBO append) with the rasteriser off."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray
from pxr import Usd
from scipy.spatial import cKDTree

from forest.geometry.tolerances import TEST_RIM_NORMAL_GPU_ABS, TEST_RIM_POSITION_REL
from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.usd.read import SceneArrays, read_scene
from forest.usd.scene import write_scene
from tests.helpers_skin import skin
from worker.render.camera import Camera, frame_box
from worker.render.renderer import Renderer, TessSettings
from worker.render.scene_buffers import scene_bounds, scene_points

F64 = NDArray[np.float64]
# Outer level k of a quad patch belongs to the edge between these corners (shaders/piece.tesc)
EDGE_CORNERS = ((0, 1), (0, 3), (3, 2), (1, 2))
ON_EDGE_EPS = 1e-6


@pytest.fixture
def renderer(gl43: Any, mixed_scene: SceneArrays) -> Iterator[Renderer]:
    r = Renderer(gl43, mixed_scene, (96, 96), ids=True)
    yield r
    r.release()


def diagonal(scene: SceneArrays) -> float:
    lo, hi = scene_bounds(scene)
    return float(np.linalg.norm(hi - lo))


def camera_at(scene: SceneArrays, distance: float) -> Camera:
    """A camera looking at the forest's centre from ``distance`` metres."""
    lo, hi = scene_bounds(scene)
    target = 0.5 * (lo + hi)
    eye = target + distance * np.array([0.5, 0.35, 0.79]) / np.linalg.norm([0.5, 0.35, 0.79])
    return Camera(eye=eye, target=target, near=0.05, far=10 * distance + 100)


def skinned_corners(
    scene: SceneArrays, cap: NDArray[np.void], frame: int, palette: F64 | None = None
) -> tuple[F64, F64]:
    """numpy skinning of the four corners of every captured vertex's patch: ``(m, 4, 3)``,
    with the scene's palette of ``frame`` (or ``palette``)."""
    pal = scene.palette(frame) if palette is None else palette
    inst, quad = cap["ids"][:, 0], cap["ids"][:, 1]
    pos, nrm = np.empty((len(cap), 4, 3)), np.empty((len(cap), 4, 3))
    for t, piece in enumerate(scene.pieces):
        sel = np.nonzero(scene.proto_indices[inst] == t)[0]
        if not len(sel):
            continue
        users, row = np.unique(inst[sel], return_inverse=True)
        p, n = skin(pal, scene.bone_offset[users], piece)
        corners = piece.quads[quad[sel]]
        pos[sel], nrm[sel] = p[row[:, None], corners], n[row[:, None], corners]
    return pos, nrm


def patch_distances(renderer: Renderer, scene: SceneArrays, cam: Camera, frame: int = 0) -> F64:
    """Distance from the eye to every patch's centre (where the shader takes its inner level),
    from a level-1 capture skinned in numpy. Tests set their LOD from these, not from metres
    tied to one layout of the trees."""
    cap = renderer.capture(cam, TessSettings(max_level=1.0), frame=frame)
    corners, _ = skinned_corners(scene, cap, frame)
    return np.linalg.norm(corners.mean(axis=1) - cam.eye, axis=1)


def phong_reference(corners: F64, normals: F64, uv: F64, alpha: float) -> tuple[F64, F64]:
    """Phong tessellation of quads: bilinear point ``p`` of the corners, projected onto each
    corner's tangent plane, the projections blended bilinearly, mixed with ``p`` by alpha."""
    u, v = uv[:, 0:1], uv[:, 1:2]
    w = np.concatenate([(1 - u) * (1 - v), (1 - u) * v, u * v, u * (1 - v)], axis=1)
    p = np.einsum("mk,mka->ma", w, corners)
    along = np.einsum("mka,mka->mk", p[:, None] - corners, normals)
    proj = p[:, None] - along[..., None] * normals
    pos = (1 - alpha) * p + alpha * np.einsum("mk,mka->ma", w, proj)
    n = np.einsum("mk,mka->ma", w, normals)
    return pos, n / np.linalg.norm(n, axis=1, keepdims=True)


# -- skinning and matrix layout ------------------------------------------------------------


def test_skinned_corners_match_numpy_and_the_palette_is_column_major(
    renderer: Renderer, mixed_scene: SceneArrays
) -> None:
    cam = camera_at(mixed_scene, 10.0)
    cap = renderer.capture(cam, TessSettings(max_level=1.0), frame=1)
    assert len(cap) >= 4 * sum(len(mixed_scene.pieces[t].quads) for t in mixed_scene.proto_indices)
    uv = cap["coord"][:, :2].astype(np.float64)
    assert np.isin(uv, (0.0, 1.0)).all()  # level 1: corners only
    corners, normals = skinned_corners(mixed_scene, cap, frame=1)
    which = np.select(
        [(uv[:, 0] == 0) & (uv[:, 1] == 0), uv[:, 0] == 0, uv[:, 1] == 1], [0, 1, 2], 3
    )
    want = corners[np.arange(len(cap)), which]
    got = cap["position"][:, :3]
    tol = TEST_RIM_POSITION_REL * diagonal(mixed_scene)
    np.testing.assert_allclose(got, want, atol=tol)
    np.testing.assert_allclose(cap["normal"][:, :3], normals[np.arange(len(cap)), which], atol=1e-5)
    # the other reading of the same matrices (rows taken as columns) would put the corners
    # far away: the test sees a palette built or read in the wrong order
    transposed = np.swapaxes(mixed_scene.palette(1), -1, -2)
    wrong, _ = skinned_corners(mixed_scene, cap, frame=1, palette=transposed)
    assert np.abs(got - wrong[np.arange(len(cap)), which]).max() > 100 * tol


def test_unskinned_path_places_rest_pieces_with_the_instance_transform(
    renderer: Renderer, mixed_scene: SceneArrays
) -> None:
    cap = renderer.capture(
        camera_at(mixed_scene, 10.0), TessSettings(max_level=1.0), skinning=False
    )
    inst, quad = cap["ids"][:, 0], cap["ids"][:, 1]
    uv = cap["coord"][:, :2]
    which = np.select(
        [(uv[:, 0] == 0) & (uv[:, 1] == 0), uv[:, 0] == 0, uv[:, 1] == 1], [0, 1, 2], 3
    )
    want = np.empty((len(cap), 3))
    for k in range(len(cap)):
        piece = mixed_scene.pieces[mixed_scene.proto_indices[inst[k]]]
        p = piece.positions[piece.quads[quad[k], which[k]]]
        m = mixed_scene.transforms[inst[k]]
        want[k] = m[:3, :3] @ p + m[:3, 3]
    tol = TEST_RIM_POSITION_REL * diagonal(mixed_scene)
    np.testing.assert_allclose(cap["position"][:, :3], want, atol=tol)


# -- Phong tessellation --------------------------------------------------------------------


@pytest.mark.parametrize(
    ("alpha", "max_level", "lod_half"), [(0.75, 5.0, 0.0), (1.0, 9.0, 2.0), (0.0, 4.0, 0.0)]
)
def test_phong_quad_tessellation_matches_numpy(
    renderer: Renderer, mixed_scene: SceneArrays, alpha: float, max_level: float, lod_half: float
) -> None:
    cam = camera_at(mixed_scene, 6.0)
    # full detail at the nearest patch, then the level halves every lod_half metres
    near = float(patch_distances(renderer, mixed_scene, cam, frame=2).min())
    tess = TessSettings(max_level=max_level, alpha=alpha, lod_near=near, lod_half=lod_half)
    cap = renderer.capture(cam, tess, frame=2)
    uv = cap["coord"][:, :2].astype(np.float64)
    assert ((uv > 0.05) & (uv < 0.95)).all(axis=1).sum() > 1000  # many interior points
    corners, normals = skinned_corners(mixed_scene, cap, frame=2)
    want, want_n = phong_reference(corners, normals, uv, alpha)
    tol = TEST_RIM_POSITION_REL * diagonal(mixed_scene)
    np.testing.assert_allclose(cap["position"][:, :3], want, atol=tol)
    np.testing.assert_allclose(cap["normal"][:, :3], want_n, atol=1e-5)
    if alpha > 0:  # the test is not vacuous: Phong moves points off the bilinear patch
        bilinear, _ = phong_reference(corners, normals, uv, 0.0)
        assert np.linalg.norm(want - bilinear, axis=1).max() > 100 * tol


def test_levels_fall_off_with_distance_like_the_formula(
    renderer: Renderer, mixed_scene: SceneArrays
) -> None:
    cam = camera_at(mixed_scene, 4.0)
    # the nearest tenth of the patches at the cap, the farthest past four halvings (below the
    # floor of 1): the levels cover both clamps and the falloff between them
    d = patch_distances(renderer, mixed_scene, cam)
    near = float(np.quantile(d, 0.1))
    tess = TessSettings(max_level=12.0, lod_near=near, lod_half=float(d.max() - near) / 4)
    cap = renderer.capture(cam, tess)
    corners, _ = skinned_corners(mixed_scene, cap, frame=0)
    centre = corners.mean(axis=1)
    want = tess.level(np.linalg.norm(centre - cam.eye, axis=1))
    np.testing.assert_allclose(cap["coord"][:, 2], want, rtol=1e-4)
    assert want.max() == 12.0 and want.min() == 1.0 and ((want > 1) & (want < 3)).any()


# -- no cracks -----------------------------------------------------------------------------


def rim_edge_table(scene: SceneArrays) -> NDArray[np.int64]:
    """``(types, q_max, 4)``: the rim each patch edge lies on (0 root, 1 + r leaf rim r) or -1."""
    q_max = scene.tile_indices.shape[1]
    table = np.full((len(scene.pieces), q_max, 4), -1)
    for t, piece in enumerate(scene.pieces):
        for k, rim in enumerate([piece.root_rim, *piece.leaf_rims]):
            inside = np.isin(piece.quads, rim)
            for e, (a, b) in enumerate(EDGE_CORNERS):
                table[t, : len(piece.quads), e][inside[:, a] & inside[:, b]] = k
    return table


def rim_sides(scene: SceneArrays, cap: NDArray[np.void]) -> tuple[dict[str, F64], dict[str, F64]]:
    """Captured vertices on joints: the child's root-rim side and the parent's leaf-rim side,
    each keyed by the child instance (``key``), with position, normal and edge level."""
    inst, quad = cap["ids"][:, 0], cap["ids"][:, 1]
    u, v = cap["coord"][:, 0], cap["coord"][:, 1]
    on = np.stack([u < ON_EDGE_EPS, v < ON_EDGE_EPS, u > 1 - ON_EDGE_EPS, v > 1 - ON_EDGE_EPS], 1)
    edges = rim_edge_table(scene)[scene.proto_indices[inst], quad]  # (m, 4)
    rim_at = np.where(on & (edges >= 0), edges, -1)
    edge = rim_at.argmax(axis=1)
    rim = rim_at.max(axis=1)
    child_of = np.full((scene.n_instances, 3), -1)
    has_parent = np.nonzero(scene.parent >= 0)[0]
    child_of[scene.parent[has_parent], scene.parent_rim[has_parent]] = has_parent
    key = np.where(rim == 0, np.where(scene.parent[inst] >= 0, inst, -1), -1)
    leaf = rim >= 1
    key_parent = np.full(len(cap), -1)
    key_parent[leaf] = child_of[inst[leaf], rim[leaf] - 1]

    def side(keys: NDArray[np.int64]) -> dict[str, F64]:
        sel = keys >= 0
        return {
            "key": keys[sel],
            "pos": cap["position"][sel, :3].astype(np.float64),
            "normal": cap["normal"][sel, :3].astype(np.float64),
            "level": cap["outer"][sel, edge[sel]].astype(np.float64),
            # a patch corner lies on two edges of two patches: its level is ambiguous
            "corner": on[sel].sum(axis=1) > 1,
        }

    return side(key), side(key_parent)


def largest_gap(a: dict[str, F64], b: dict[str, F64], scale: float) -> tuple[float, float, float]:
    """Largest distance from a point of one side to the nearest point of the other side at
    the same joint (both ways), with the normal and edge-level differences of those pairs.

    The normal is compared with the best of the other side's points at that place (within
    the position tolerance of the nearest): with fractional spacing the tessellator may put a
    vertex microns from a rim corner, and the corner, a hair nearer, has another normal (a
    birch twig at level 4 paired so showed 5.9e-4 rad where its true partner agrees to 3e-8)."""
    sep = 1e3 * scale  # keys far apart in a fourth coordinate: no match across joints
    same_place = TEST_RIM_POSITION_REL * scale
    ta = cKDTree(np.c_[a["pos"], a["key"] * sep])
    tb = cKDTree(np.c_[b["pos"], b["key"] * sep])
    gap, normal, level = 0.0, 0.0, 0.0
    for src, tree, dst in ((a, tb, b), (b, ta, a)):
        k = min(4, tree.n)
        d, j = tree.query(np.c_[src["pos"], src["key"] * sep], k=k)
        d, j = d.reshape(len(d), k), j.reshape(len(j), k)
        gap = max(gap, float(d[:, 0].max()))
        diff = np.abs(src["normal"][:, None] - dst["normal"][j]).max(axis=2)
        there = d <= d[:, :1] + same_place
        normal = max(normal, float(np.where(there, diff, np.inf).min(axis=1).max()))
        j = j[:, 0]
        inner = ~src["corner"] & ~dst["corner"][j]
        if inner.any():  # at level 1 a rim has corners only
            level = max(level, float(np.abs(src["level"] - dst["level"][j])[inner].max()))
    return gap, normal, level


@pytest.mark.parametrize(
    ("max_level", "distance", "lod_half", "frame"),
    [(3.0, 2.0, 1.0, 0), (7.5, 5.0, 2.0, 1), (16.0, 12.0, 5.0, 2), (10.0, 3.0, 0.0, 1)],
)
def test_no_cracks_on_shared_rims(
    renderer: Renderer,
    mixed_scene: SceneArrays,
    max_level: float,
    distance: float,
    lod_half: float,
    frame: int,
) -> None:
    scale = diagonal(mixed_scene)
    cam = camera_at(mixed_scene, distance)
    # full detail at the nearest patch, then the level halves every lod_half metres
    near = float(patch_distances(renderer, mixed_scene, cam, frame=frame).min())
    tess = TessSettings(max_level=max_level, alpha=0.75, lod_near=near, lod_half=lod_half)
    cap = renderer.capture(cam, tess, frame=frame)
    child, parent = rim_sides(mixed_scene, cap)
    joints = np.count_nonzero(mixed_scene.parent >= 0)
    assert len(np.unique(child["key"])) == joints == len(np.unique(parent["key"]))
    # tessellation added vertices on the rims (6 corners per rim without it)
    assert len(np.unique(np.round(child["pos"], 6), axis=0)) > 6 * joints
    if lod_half > 0:  # levels differ along the tree, fractional ones included
        assert np.ptp(child["level"]) > 0.5
        assert (np.abs(child["level"] - np.round(child["level"])) > 0.05).any()
    gap, normal, level = largest_gap(child, parent, scale)
    assert gap <= TEST_RIM_POSITION_REL * scale, f"crack of {gap:.3g} m"
    assert normal <= TEST_RIM_NORMAL_GPU_ABS
    assert level <= 1e-3 * max_level


def test_crack_check_sees_mismatched_levels(renderer: Renderer, mixed_scene: SceneArrays) -> None:
    """The rim comparison is not vacuous: a child tessellated at another level than its parent
    leaves T-junctions the check finds."""
    scale = diagonal(mixed_scene)
    cam = camera_at(mixed_scene, 5.0)
    child, _ = rim_sides(mixed_scene, renderer.capture(cam, TessSettings(max_level=3.0)))
    _, parent = rim_sides(mixed_scene, renderer.capture(cam, TessSettings(max_level=6.0)))
    gap, _, _ = largest_gap(child, parent, scale)
    assert gap > 100 * TEST_RIM_POSITION_REL * scale


# -- tiles ---------------------------------------------------------------------------------


def test_fragment_tile_index_is_the_one_stored_in_usd(
    renderer: Renderer, mixed_scene: SceneArrays, mixed_scene_path: Any
) -> None:
    stage = Usd.Stage.Open(str(mixed_scene_path))
    attr = stage.GetPrimAtPath("/World/Forest/Pieces").GetAttribute("primvars:forest:tileIndices")
    stored = np.asarray(attr.Get(), np.int32).reshape(mixed_scene.n_instances, -1)
    lo, hi = scene_bounds(mixed_scene)
    renderer.draw(frame_box(lo, hi, 1.0), TessSettings(max_level=2.0))
    ids = renderer.read_ids()
    covered = ids[..., 3] == 1
    tile, inst, quad = ids[covered, 0], ids[covered, 1], ids[covered, 2]
    assert covered.sum() > 300
    n_quads = np.array([len(p.quads) for p in mixed_scene.pieces])[mixed_scene.proto_indices]
    assert (quad < n_quads[inst]).all()  # gl_PrimitiveID counts quads of one instance
    np.testing.assert_array_equal(tile, stored[inst, quad])
    assert len(np.unique(inst)) >= 5 and len(np.unique(tile)) >= 6
    assert len(set(zip(inst.tolist(), quad.tolist(), strict=True))) > 40


# -- frame statistics ----------------------------------------------------------------------


def test_draw_calls_and_primitives(renderer: Renderer, mixed_scene: SceneArrays) -> None:
    cam = frame_box(*scene_bounds(mixed_scene), 1.0)
    quads = sum(len(mixed_scene.pieces[t].quads) for t in mixed_scene.proto_indices)
    types = len(np.unique(mixed_scene.proto_indices))
    flat = renderer.draw(cam, TessSettings(max_level=1.0))
    assert flat.draw_calls == types == 4
    assert flat.primitives == 2 * quads  # level 1: two triangles a quad
    naive = renderer.draw(cam, TessSettings(max_level=1.0), per_instance=True)
    assert naive.draw_calls == mixed_scene.n_instances
    assert naive.primitives == flat.primitives
    fine = renderer.draw(cam, TessSettings(max_level=5.0))
    # fractional odd level 5 on every edge: 5 x 5 quads of two triangles
    assert fine.primitives == 50 * quads
    assert flat.cpu_ms > 0 and (flat.gpu_ms is None or flat.gpu_ms >= 0)


# -- frustum culling -----------------------------------------------------------------------


def test_frustum_culling_drops_only_patches_out_of_view(
    renderer: Renderer, mixed_scene: SceneArrays
) -> None:
    # close to one tree, looking past it: much of the forest is out of view (the target is
    # on the tree, not a fixed point of the forest's box, which may be empty space)
    tree = scene_points(mixed_scene, tree=0)
    target = 0.5 * (tree.min(axis=0) + tree.max(axis=0))
    cam = Camera(eye=target + np.array([1.2, 0.4, 1.6]), target=target, near=0.05, far=50.0)
    tess = TessSettings(max_level=4.0, alpha=1.0)
    full = renderer.capture(cam, tess, cull=False)
    kept = renderer.capture(cam, tess, cull=True)
    patch = lambda cap: set(zip(cap["ids"][:, 0].tolist(), cap["ids"][:, 1].tolist(), strict=True))  # noqa: E731
    dropped = patch(full) - patch(kept)
    assert patch(kept) <= patch(full)
    assert len(dropped) > 0.3 * len(patch(full))
    # conservative: every tessellated vertex of a dropped patch is outside the frustum
    key = list(zip(full["ids"][:, 0].tolist(), full["ids"][:, 1].tolist(), strict=True))
    gone = np.array([k in dropped for k in key])
    clip = np.c_[full["position"][gone, :3], np.ones(gone.sum())] @ cam.view_projection().T
    inside = (np.abs(clip[:, :3]) <= clip[:, 3:]).all(axis=1)
    assert not inside.any()
    # and the picture does not change
    with_cull = renderer.draw(cam, tess, cull=True)
    image = renderer.read_color()
    without = renderer.draw(cam, tess, cull=False)
    np.testing.assert_array_equal(renderer.read_color(), image)
    assert with_cull.primitives < without.primitives
    sky = image[0, 0, :3].astype(int)
    assert (np.abs(image[..., :3].astype(int) - sky).max(axis=-1) > 30).mean() > 0.05


@settings(max_examples=8, deadline=None)
# a vertex microns from a rim corner: paired with the corner it showed 5.9e-4 rad
@example(preset="birch", seed=160, level=4.0, frame=1)
@given(
    preset=st.sampled_from(["alternating", "uniform", "almond", "hazel", "birch"]),
    seed=st.integers(0, 2**32 - 1),
    level=st.floats(1.5, 12.0),
    frame=st.integers(0, 1),
)
def test_no_cracks_for_any_preset_and_seed(
    gl_session: Any, tmp_path_factory: pytest.TempPathFactory, preset: str, seed: int,
    level: float, frame: int,
) -> None:  # fmt: skip
    """Posed and windblown trees of every preset keep their rims closed on the GPU."""
    if gl_session.version_code < 430:
        pytest.skip("needs OpenGL 4.3")
    forest = generate_forest(load_preset(preset), seed, ForestOptions(trees=1, frames=2))
    scene = read_scene(write_scene(forest, tmp_path_factory.mktemp("h") / "t.usdc"))
    renderer = Renderer(gl_session, scene, (16, 16))
    try:
        scale = diagonal(scene)
        tess = TessSettings(max_level=level, lod_half=0.2 * scale)
        cap = renderer.capture(camera_at(scene, 0.5 * scale), tess, frame=frame)
        child, parent = rim_sides(scene, cap)
        assert len(np.unique(child["key"])) == np.count_nonzero(scene.parent >= 0) > 0
        gap, normal, _ = largest_gap(child, parent, scale)
        assert gap <= TEST_RIM_POSITION_REL * scale
        assert normal <= TEST_RIM_NORMAL_GPU_ABS
    finally:
        renderer.release()
    assert gl_session.error == "GL_NO_ERROR"
