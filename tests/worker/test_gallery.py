"""``forest gallery`` and the camera and staging it needs: named views and explicit cameras
frame what they promise (numpy, and a pixel of a rendered frame), the ground shows under the
trees, and the gallery writes every file with a tree on the ground in it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner
from numpy.typing import NDArray

from cli import main
from cli.sheets.gallery import (
    GalleryOptions,
    bar_length,
    frame_tree,
    make_gallery,
    posed_vertices,
    scene_surface_points,
)
from forest.bark.tile_folder import read_image_subimages
from forest.errors import ForestError
from forest.usd.read import SceneArrays
from worker.render.camera import (
    EYE_HEIGHT,
    FRAME_MARGIN,
    CameraSpec,
    box_corners,
    place_camera,
    project,
)
from worker.render.render_file import preview_view
from worker.render.renderer import Renderer
from worker.render.scene_buffers import scene_points
from worker.render.staging import Staging
from worker.render.textures import procedural_tiles

SIZE = (96, 72)
# two of the paper's presets, which stay as they are
PRESETS = ("alternating", "uniform")


def read_png(path: Path) -> NDArray[np.uint8]:
    return read_image_subimages(path)[0]


def in_frame(camera: Any, points: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(m, 2)`` normalised device x, y of ``points``."""
    clip = np.c_[points, np.ones(len(points))] @ camera.view_projection().T
    assert (clip[:, 3] > 0).all()
    return clip[:, :2] / clip[:, 3:]


# -- cameras, numpy ----------------------------------------------------------------------------


def test_overview_is_todays_default(mixed_scene: SceneArrays) -> None:
    """The default spec is the old automatic camera (so golden previews stay)."""
    from worker.render.camera import frame_points

    pts = scene_points(mixed_scene)
    old = frame_points(pts, 4 / 3)
    new = place_camera(CameraSpec(), pts, 4 / 3)
    np.testing.assert_array_equal(old.view_projection(), new.view_projection())


@pytest.mark.parametrize("view", ["overview", "side", "eye"])
def test_named_views_frame_the_box(mixed_scene: SceneArrays, view: str) -> None:
    pts = scene_points(mixed_scene)
    corners = box_corners(pts.min(axis=0), pts.max(axis=0))
    cam = place_camera(CameraSpec(view=view), pts, 4 / 3)
    ndc = in_frame(cam, pts)
    assert np.abs(ndc).max() <= 1.0 + 1e-9  # everything in view
    centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    np.testing.assert_allclose(cam.target, centre)
    if view == "side":
        assert cam.eye[1] == pytest.approx(centre[1])  # horizontal, at mid-height
        assert np.abs(ndc).max() > 0.85  # tight: the margin is a fraction of the distance
    if view == "eye":
        assert cam.eye[1] == EYE_HEIGHT
        # the least distance: the box's corners touch the margin
        assert np.abs(in_frame(cam, corners)).max() == pytest.approx(1 / (1 + FRAME_MARGIN))
    if view == "overview":
        back = (cam.eye - cam.target) / np.linalg.norm(cam.eye - cam.target)
        assert np.degrees(np.arcsin(back[1])) == pytest.approx(18.0)


def test_explicit_camera_projects_its_target_to_the_centre(mixed_scene: SceneArrays) -> None:
    eye, target = np.array([3.0, 2.0, 9.0]), np.array([0.5, 1.0, 0.0])
    spec = CameraSpec(eye=(3.0, 2.0, 9.0), target=(0.5, 1.0, 0.0), fov=30.0)
    cam = place_camera(spec, scene_points(mixed_scene), 2.0)
    np.testing.assert_allclose(project(cam, target[None], (200, 100)), np.array([[100.0, 50.0]]))
    # a point above the target at the target's depth, tan(15 deg) * depth up: the top edge
    depth = float(np.linalg.norm(target - eye))
    up = cam.view()[1, :3]
    above = target + up * depth * np.tan(np.radians(15.0))
    np.testing.assert_allclose(
        project(cam, above[None], (200, 100)), np.array([[100.0, 0.0]]), atol=1e-9
    )
    assert cam.near < cam.far


@pytest.mark.parametrize(
    ("spec", "path"),
    [
        (CameraSpec(view="top"), "view"),
        (CameraSpec(eye=(0.0, 1.0, 2.0)), "target"),
        (CameraSpec(target=(0.0, 1.0, 2.0)), "eye"),
        (CameraSpec(eye=(1.0, 1.0, 1.0), target=(1.0, 1.0, 1.0)), "target"),
        (CameraSpec(eye=(float("nan"), 1.0, 1.0), target=(0.0, 0.0, 0.0)), "eye"),
        (CameraSpec(fov=0.0), "fov"),
        (CameraSpec(view="eye", distance=-1.0), "distance"),
    ],
)
def test_bad_camera_names_the_field(spec: CameraSpec, path: str) -> None:
    with pytest.raises(ForestError) as info:
        spec.check()
    assert info.value.path == path


def test_ground_reaches_into_the_clip_planes(mixed_scene: SceneArrays) -> None:
    pts = scene_points(mixed_scene)
    bare = place_camera(CameraSpec(view="eye"), pts, 1.0)
    staged = place_camera(CameraSpec(view="eye"), pts, 1.0, ground=True)
    assert staged.far > 20 * np.linalg.norm(staged.target - staged.eye)
    assert staged.near <= min(bare.near, EYE_HEIGHT)


def test_posed_vertices_bound_the_tree(mixed_scene: SceneArrays) -> None:
    """The skinned surface lies inside the bones' boxes and reaches near their top."""
    verts = posed_vertices(mixed_scene, frame=1)
    n_vertices = sum(
        len(p.positions) * int((mixed_scene.proto_indices == t).sum())
        for t, p in enumerate(mixed_scene.pieces)
    )
    assert verts.shape == (n_vertices, 3)
    boxes = scene_points(mixed_scene, frame=1)
    assert (verts.min(axis=0) >= boxes.min(axis=0) - 1e-9).all()
    assert (verts.max(axis=0) <= boxes.max(axis=0) + 1e-9).all()


def test_bar_length_follows_height() -> None:
    assert [bar_length(h) for h in (0.6, 2.0, 3.0, 9.0, 18.0, 30.0)] == [
        0.5,
        1.0,
        1.0,
        5.0,
        10.0,
        10.0,
    ]


# -- rendered frames ---------------------------------------------------------------------------


def test_explicit_camera_pixel_shows_the_trunk(gl43: Any, mixed_scene: SceneArrays) -> None:
    """Looking from 4 m at a point 30 cm up the first tree's trunk, the centre pixel is that
    tree's root piece; a pixel at the top corner is empty."""
    root = mixed_scene.tree_transforms[0, :3, 3]
    target = root + np.array([0.0, 0.3, 0.0])
    eye = target + np.array([0.0, 0.5, 4.0])
    spec = CameraSpec(
        eye=(eye[0], eye[1], eye[2]), target=(target[0], target[1], target[2]), fov=30.0
    )
    images = procedural_tiles(mixed_scene.manifest, mixed_scene.manifest.n_slices)
    renderer = Renderer(gl43, mixed_scene, SIZE, images, ids=True, foliage=None)
    try:
        cam, tess = preview_view(mixed_scene, SIZE, 4.0, foliage=False, spec=spec)
        renderer.draw(cam, tess)
        ids = renderer.read_ids()
    finally:
        renderer.release()
    x, y = (int(v) for v in project(cam, [target], SIZE)[0])
    assert ids[y, x, 3] == 1
    instance = ids[y, x, 1]
    assert mixed_scene.tree[instance] == 0 and mixed_scene.depth[instance] == 0
    assert ids[0, 0, 3] == 0


def test_ground_shows_under_the_trees(gl43: Any, mixed_scene: SceneArrays) -> None:
    """With staging, the lower rows are the ground (drawn, depth < 1, green-brown) and the
    top rows a sky bluer than the ground; without, the bottom stays the flat clear colour."""
    images = procedural_tiles(mixed_scene.manifest, mixed_scene.manifest.n_slices)
    frames = []
    for staging in (Staging(), None):
        renderer = Renderer(gl43, mixed_scene, SIZE, images, foliage=None, staging=staging)
        try:
            cam, tess = preview_view(
                mixed_scene, SIZE, 2.0, foliage=False, spec=CameraSpec(view="eye"), ground=True
            )
            renderer.draw(cam, tess)
            frames.append((renderer.read_color().astype(int), renderer.read_depth()))
        finally:
            renderer.release()
    (staged, depth), (bare, bare_depth) = frames
    bottom = staged[-4:, :, :3].reshape(-1, 3)
    assert (depth[-4:] < 1.0).all()
    assert (bottom[:, 1] > bottom[:, 2]).all()  # green over blue: not the sky
    top = staged[:4, :, :3].reshape(-1, 3)
    assert (top[:, 2] > top[:, 1]).all()
    assert (bare_depth[-4:] == 1.0).all()
    assert len(np.unique(bare[-4:, :, :3].reshape(-1, 3), axis=0)) == 1


def test_single_tree_framing_and_bar(mixed_scene: SceneArrays) -> None:
    pts = scene_surface_points(mixed_scene)
    root = mixed_scene.tree_transforms[0, :3, 3]
    shot = frame_tree(pts, root, 0.75)
    assert shot.height == pytest.approx(pts[:, 1].max() - root[1])
    ndc = in_frame(shot.camera, np.concatenate([pts, shot.bar]))
    assert np.abs(ndc).max() <= 1.0
    np.testing.assert_allclose(shot.bar[1] - shot.bar[0], [0.0, shot.bar_metres, 0.0])
    assert shot.bar[0, 1] == root[1]  # the bar stands on the ground


@pytest.mark.slow  # a tree and a stand per preset, staged; 11 s on llvmpipe
def test_gallery_writes_images_of_trees_on_the_ground(gl43: Any, tmp_path: Path) -> None:
    lines: list[str] = []
    reports: list[tuple[str, int, int]] = []
    out = tmp_path / "gallery"
    entries = make_gallery(
        GalleryOptions(output=out, presets=PRESETS, size=(120, 160), seed=3, stand_trees=4),
        echo=lines.append,
        progress=lambda *report: reports.append(report),
    )
    kinds = ("", "_leaves", "_base", "_stand")
    names = [f"{p}{s}.png" for p in PRESETS for s in kinds] + ["contact_sheet.png", "closeups.png"]
    assert sorted(p.name for p in out.iterdir()) == sorted(names)
    assert len(lines) == len(names) and all(line.startswith("wrote ") for line in lines)
    assert reports == [("images", k, len(names)) for k in range(len(names) + 1)]
    assert [e.preset for e in entries] == list(PRESETS)
    for e in entries:
        assert e.height > 0.5
        for path, (w, h) in ((e.single, (120, 160)), (e.stand, (160, 120))):
            image = read_png(path)[..., :3].astype(int)
            assert image.shape == (h, w, 3)
            # the sky is bluer than green; the tree (leaves green, bark dark) is not
            sky_top = image[h // 8 : int(0.4 * h)]
            tree = (sky_top[..., 1] > sky_top[..., 2]) | (sky_top.max(axis=-1) < 110)
            assert tree.mean() > 0.02, path
            low = image[-h // 10 :].reshape(-1, 3)
            ground = (low[:, 1] > low[:, 2]) & (low[:, 0] > low[:, 2])
            assert ground.mean() > 0.5, path
    sheet = read_png(out / "contact_sheet.png")
    assert sheet.shape[0] > 160 and sheet.shape[1] > 2 * 120
    # the same seed draws the same images
    again = tmp_path / "again"
    make_gallery(
        GalleryOptions(output=again, presets=PRESETS[:1], size=(120, 160), seed=3, stand_trees=4),
        echo=lambda line: None,
    )
    first = PRESETS[0]
    np.testing.assert_array_equal(read_png(again / f"{first}.png"), read_png(out / f"{first}.png"))


@pytest.mark.parametrize(
    ("args", "field"),
    [
        (["--size", "12x"], "size"),
        (["--size", "10x10"], "size"),
        (["--presets", "nosuch"], "presets"),
        (["--presets", ","], "presets"),
    ],
)
def test_gallery_cli_input_errors(tmp_path: Path, args: list[str], field: str) -> None:
    result = CliRunner().invoke(main, ["gallery", "-o", str(tmp_path / "g"), *args])
    assert result.exit_code == 2, result.output
    assert f"error: {field}:" in result.output
