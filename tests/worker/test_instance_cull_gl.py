"""Per-instance culling and sub-pixel level of detail (worker.render.instance_cull) on a real GL 4.3
context: the GPU keeps exactly the instances that the numpy twin keeps, the frustum test
never drops a piece that shows (the picture is the one drawn without it), and dropping
pieces thinner than a pixel changes a distant forest's picture by little while drawing
far fewer pieces."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from forest.geometry.pieces import piece_library
from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.usd.read import SceneArrays, read_scene
from forest.usd.scene import write_scene
from worker.render.camera import Camera, frame_box
from worker.render.instance_cull import (
    DEFAULT_LOD_PIXELS,
    piece_bounds,
    tube_radius,
    visible_reference,
)
from worker.render.renderer import Renderer, TessSettings
from worker.render.scene_buffers import scene_bounds, scene_points
from worker.render.staging import STAGED


@pytest.fixture(scope="module")
def stand(tmp_path_factory: pytest.TempPathFactory) -> SceneArrays:
    """Twelve birches with wind (thin twigs far from a wide camera, a trunk close to a near
    one), written and read back as the renderer gets them."""
    forest = generate_forest(
        load_preset("birch"), 3, ForestOptions(trees=12, area=(40.0, 40.0), frames=2)
    )
    path = write_scene(forest, tmp_path_factory.mktemp("cull") / "birch.usdc", skinned=False)
    return read_scene(Path(path))


@pytest.fixture
def renderer(gl43: Any, stand: SceneArrays) -> Iterator[Renderer]:
    r = Renderer(gl43, stand, (160, 120), foliage=None)
    yield r
    r.release()


def near_camera(scene: SceneArrays) -> Camera:
    """Close to one tree, looking past it: most of the stand is out of view."""
    tree = scene_points(scene, tree=0)
    lo, hi = tree.min(axis=0), tree.max(axis=0)
    target = 0.5 * (lo + hi)
    eye = target + np.array([0.35, 0.1, 0.45]) * float(np.linalg.norm(hi - lo))
    return Camera(eye=eye, target=target, aspect=160 / 120, near=0.05, far=200.0)


def test_tube_radius_is_the_farthest_surface_point_from_the_joint_polyline() -> None:
    for p in piece_library(1):
        r = tube_radius(p)
        origins = p.joint_rest[:, :3, 3]
        # the root rim sits about the root joint: its ring's radius is within the tube's
        ring = np.linalg.norm(p.positions[p.root_rim] - origins[0], axis=1).max()
        assert 0 < ring <= r + 1e-9
        assert r < np.linalg.norm(np.ptp(p.positions, axis=0))  # far less than the piece
        joints = p.joint_rest.copy()
        joints[:, :3, 3] *= 2.0
        moved = replace(p, positions=p.positions * 2.0, joint_rest=joints)
        assert tube_radius(moved) == pytest.approx(2 * r)


@pytest.mark.parametrize("min_pixels", [0.0, 1.0])
@pytest.mark.parametrize("view", ["near", "whole"])
def test_the_gpu_keeps_what_the_numpy_twin_keeps(
    renderer: Renderer, stand: SceneArrays, view: str, min_pixels: float
) -> None:
    cam = near_camera(stand) if view == "near" else frame_box(*scene_bounds(stand), 160 / 120)
    renderer.buffers.use(1)
    culler = renderer._cull("main", cam, 120, 0.75, min_pixels)
    got = culler.kept()
    bounds = piece_bounds(stand.pieces, renderer.buffers.layout.first)
    want = visible_reference(
        stand.palette(1), stand.bone_offset, stand.proto_indices, bounds, cam, 120, 0.75, min_pixels
    )
    n = stand.n_instances
    assert len(got) == len(np.unique(got))  # each kept instance listed once
    # float32 on the GPU against float64: a borderline instance may fall either way
    assert len(np.setxor1d(got, np.flatnonzero(want))) <= max(2, n // 2000)
    if view == "near" and min_pixels == 0.0:
        assert 0.05 * n < len(got) < 0.7 * n  # the frustum test drops most of the stand


def test_frustum_culling_changes_no_pixel(renderer: Renderer, stand: SceneArrays) -> None:
    cam = near_camera(stand)
    tess = TessSettings(max_level=3.0)
    plain = renderer.draw(cam, tess, frame=1)
    image = renderer.read_color()
    culled = renderer.draw(cam, tess, frame=1, lod_pixels=0.0)
    # the same pieces in another order: only depth ties where two pieces share a rim may
    # resolve the other way, and their bark continues across the rim
    diff = np.abs(renderer.read_color().astype(int) - image.astype(int)).max(axis=-1)
    assert (diff > 8).mean() < 1e-3
    assert culled.drawn_instances is not None and plain.drawn_instances is None
    assert culled.drawn_instances < 0.7 * stand.n_instances
    # conservative: the patches the tessellation stage keeps (it drops those out of view)
    # are all still there, so the same triangles are made from far fewer instances
    assert culled.primitives == plain.primitives
    sky = image[0, 0, :3].astype(int)
    assert (np.abs(image[..., :3].astype(int) - sky).max(axis=-1) > 30).mean() > 0.05


def test_sub_pixel_pieces_go_and_the_distant_picture_stays(gl43: Any, stand: SceneArrays) -> None:
    """The whole stand framed at 320 x 240 with its leaves, as a preview draws it: a twig is
    a hundredth of a pixel there. Half a pixel (the default) draws a few per cent of the
    pieces, and the picture keeps its trees."""
    r = Renderer(gl43, stand, (320, 240))
    try:
        cam = frame_box(*scene_bounds(stand), 320 / 240)
        tess = TessSettings(max_level=1.0)
        plain = r.draw(cam, tess, frame=1)
        image = r.read_color().astype(int)
        lod = r.draw(cam, tess, frame=1, lod_pixels=DEFAULT_LOD_PIXELS)
        after = r.read_color().astype(int)
    finally:
        r.release()
    assert lod.drawn_instances is not None
    assert lod.drawn_instances < 0.1 * stand.n_instances
    assert lod.foliage is not None and plain.foliage is not None
    branches = lambda s: s.primitives - s.foliage.primitives  # noqa: E731
    assert branches(lod) < 0.2 * branches(plain)
    # what goes is thinner than half a pixel: few pixels change, and the trees' cover stays
    changed = (np.abs(after - image).max(axis=-1) > 40).mean()
    assert changed < 0.01, changed
    sky = image[0, 0, :3]
    cover = lambda im: (np.abs(im[..., :3] - sky).max(axis=-1) > 30).mean()  # noqa: E731
    assert cover(after) > 0.85 * cover(image) > 0.02


def test_staged_frame_culls_the_sun_pass_too(gl43: Any, stand: SceneArrays) -> None:
    r = Renderer(gl43, stand, (96, 72), foliage=None, staging=STAGED)
    try:
        cam = near_camera(stand)
        tess = TessSettings(max_level=2.0)
        plain = r.draw(cam, tess)
        culled = r.draw(cam, tess, lod_pixels=0.0)
        assert set(r._cullers) == {"main", "shadow"}
        # both passes keep every patch that their tessellation stage keeps
        assert culled.primitives == plain.primitives
        assert culled.drawn_instances is not None
        assert culled.drawn_instances < stand.n_instances
        # without frustum culling nothing is culled: no pass, and none reported
        assert r.draw(cam, tess, cull=False, lod_pixels=0.0).drawn_instances is None
    finally:
        r.release()


def test_generated_scene_has_the_piece_type_in_each_record(
    renderer: Renderer, stand: SceneArrays
) -> None:
    layout = renderer.buffers.layout
    np.testing.assert_array_equal(layout.records["piece_type"], stand.proto_indices[layout.order])
