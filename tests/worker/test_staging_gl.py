"""The staged mode (worker.render.staging.STAGED): sun shadows on the ground under a tree, no tree
face black, multisampled edges, the sun's view fitted to what the camera sees."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.usd.read import SceneArrays, read_scene
from forest.usd.scene import write_scene
from worker.render.camera import Camera, box_corners, project, with_ground
from worker.render.renderer import SUN, Renderer, TessSettings
from worker.render.staging import STAGED, Staging, sun_camera

SIZE = (200, 150)


@pytest.fixture(scope="module")
def one_tree(tmp_path_factory: pytest.TempPathFactory) -> SceneArrays:
    forest = generate_forest(load_preset("almond"), 4, ForestOptions(trees=1, area=(1.0, 1.0)))
    return read_scene(write_scene(forest, tmp_path_factory.mktemp("staged") / "tree.usdc"))


def luminance(img: NDArray[np.uint8]) -> NDArray[np.float64]:
    rgb = img[..., :3].astype(np.float64)
    return 0.2126 * rgb[..., 0] + 0.7152 * rgb[..., 1] + 0.0722 * rgb[..., 2]


def crown_and_camera(scene: SceneArrays) -> tuple[NDArray[np.float64], Camera]:
    clouds = scene.foliage_at(0)
    crown = clouds.mean(axis=0)
    # where the sun's ray through the leaf cloud nearest the crown's centre meets the ground
    # (not through the centre itself: an open crown, like the almond's vase, is hollow there)
    inner = clouds[np.argmin(np.linalg.norm(clouds - crown, axis=1))]
    shadow = inner - SUN * (inner[1] / SUN[1])
    target = 0.5 * (shadow + np.array([crown[0], 0.0, crown[2]]))
    target[1] = 0.0
    # from the shadow's side, high up: the crown stands behind its shadow, not over it
    away = -np.array([SUN[0], 0.0, SUN[2]]) / np.hypot(SUN[0], SUN[2])
    eye = target + (2.0 * away + np.array([0.0, 2.5, 0.0])) * crown[1]
    return shadow, with_ground(Camera(eye, target, 50.0, SIZE[0] / SIZE[1], 0.1, 500.0))


def render(ctx: Any, scene: SceneArrays, camera: Camera, staging: Staging, ids: bool = False,
           leaves: bool = True) -> Renderer:  # fmt: skip
    r = Renderer(ctx, scene, SIZE, ids=ids, staging=staging,
                 foliage="impostor" if leaves else None)  # fmt: skip
    r.draw(camera, TessSettings(max_level=4.0))
    return r


def test_ground_under_the_tree_is_in_shadow(gl43: Any, one_tree: SceneArrays) -> None:
    shadow, cam = crown_and_camera(one_tree)
    r = render(gl43, one_tree, cam, STAGED)
    try:
        img = luminance(r.read_color())
    finally:
        r.release()
    # open ground: beside the trunk, across the sun's direction, as far as the shadow is
    base = np.array([one_tree.tree_transforms[0, 0, 3], 0.0, one_tree.tree_transforms[0, 2, 3]])
    off = shadow - base
    sunny = base + np.array([-off[2], 0.0, off[0]])
    (xs, ys), (xo, yo) = project(cam, np.stack([shadow, sunny]), SIZE).astype(int)
    assert 3 <= xs < SIZE[0] - 3 and 3 <= ys < SIZE[1] - 3
    assert 3 <= xo < SIZE[0] - 3 and 3 <= yo < SIZE[1] - 3
    dark = np.median(img[ys - 3 : ys + 4, xs - 3 : xs + 4])
    lit = np.median(img[yo - 3 : yo + 4, xo - 3 : xo + 4])
    assert dark < 0.7 * lit, (dark, lit)


def test_no_tree_face_is_black(gl43: Any, one_tree: SceneArrays) -> None:
    _, cam = crown_and_camera(one_tree)
    # seen from the shadow side too: faces away from the sun still get the sky's fill
    back = Camera(2 * cam.target - cam.eye + np.array([0, 2 * cam.eye[1], 0]), cam.target,
                  cam.fov_y, cam.aspect, cam.near, cam.far)  # fmt: skip
    for camera in (cam, with_ground(back)):
        r = render(gl43, one_tree, camera, STAGED, ids=True)
        try:
            img, ids = luminance(r.read_color()), r.read_ids()
        finally:
            r.release()
        bark = ids[..., 3] == 1
        assert bark.sum() > 100
        face = ids[..., 1][bark].astype(np.int64) * 4096 + ids[..., 2][bark]
        keys, inverse, counts = np.unique(face, return_inverse=True, return_counts=True)
        mean = np.bincount(inverse, img[bark]) / counts
        big = counts >= 4
        # the ambient floor: a face's mean stays above a quarter of the typical face
        assert mean[big].min() > 0.25 * np.median(mean[big]), (mean[big].min(), len(keys))
        assert mean[big].min() > 12.0


def test_msaa_blends_edges_only(gl43: Any, one_tree: SceneArrays) -> None:
    _, cam = crown_and_camera(one_tree)
    plain = Staging(ground=True, sky=True, shadows=True, msaa=0, tone_map=True)
    images, bark = [], None
    for staging in (plain, STAGED):
        # branches alone: alpha-tested leaf cards are not what multisampling smooths
        r = render(gl43, one_tree, cam, staging, ids=staging is plain, leaves=False)
        try:
            assert (r.samples > 1) == (staging.msaa > 0)
            images.append(r.read_color()[..., :3].astype(np.int32))
            if bark is None:
                bark = r.read_ids()[..., 3] == 1
        finally:
            r.release()
    a, b = images
    assert bark is not None
    # the branches' silhouettes, both sides
    edge = np.zeros(a.shape[:2], bool)
    step = bark[:, 1:] != bark[:, :-1]
    edge[:, 1:] |= step
    edge[:, :-1] |= step
    step = bark[1:] != bark[:-1]
    edge[1:] |= step
    edge[:-1] |= step
    near = edge.copy()
    near[1:] |= edge[:-1]
    near[:-1] |= edge[1:]
    near[:, 1:] |= edge[:, :-1]
    near[:, :-1] |= edge[:, 1:]
    changed = np.abs(a - b).max(axis=2) > 3
    assert edge.sum() > 50
    at_edges, inside = changed[edge].mean(), changed[~near].mean()
    # intermediate values at edges (0.137 to 0.2 of them, depending on which GL tests ran
    # before in the process: not found which state), interiors as they were
    assert at_edges > 0.1 and at_edges > 3 * inside, (at_edges, inside)
    assert inside < 0.05, inside


def test_sun_view_covers_what_the_camera_sees() -> None:
    lo, hi = np.array([-5.0, 0.0, -4.0]), np.array([6.0, 9.0, 5.0])
    cam = Camera(np.array([8.0, 3.0, 9.0]), np.array([0.0, 2.0, 0.0]), 40.0, 1.5, 0.1, 60.0)
    sun = np.array([0.45, 0.8, 0.35]) / np.linalg.norm([0.45, 0.8, 0.35])
    light = sun_camera(cam, lo, hi, sun)
    np.testing.assert_allclose(light.forward, -sun, atol=1e-12)
    clip = np.c_[box_corners(lo, hi), np.ones(8)] @ light.view_projection().T
    ndc = clip[:, :3] / clip[:, 3:]
    assert (np.abs(ndc[:, 2]) <= 1).all()  # every caster within the depth range
    # a close-up fits a smaller map than the whole box
    close = Camera(np.array([1.5, 1.0, 1.5]), np.array([0.0, 0.8, 0.0]), 40.0, 1.5, 0.1, 3.0)
    assert max(sun_camera(close, lo, hi, sun).half) < 0.5 * max(light.half)


def test_render_cli_is_staged_unless_bare(tmp_path: Path, one_tree: SceneArrays) -> None:
    from click.testing import CliRunner

    from cli import main
    from forest.bark.tile_folder import read_image_subimages

    looks = {}
    for look, flags in [("default", []), ("staged", ["--staged"]), ("bare", ["--bare"]),
                        ("ground", ["--ground"])]:  # fmt: skip
        out = tmp_path / f"{look}.png"
        res = CliRunner().invoke(
            main, ["render", one_tree.path, "-o", str(out), *flags, "--width", "96",
                   "--height", "64", "--tess-max", "2"],
        )  # fmt: skip
        assert res.exit_code == 0, res.output
        looks[look] = read_image_subimages(out)[0][..., :3].astype(np.int32)
    # --staged, the default now, is still accepted (scripts name it) and changes nothing
    np.testing.assert_array_equal(looks["default"], looks["staged"])
    for a, b in [("default", "bare"), ("default", "ground"), ("bare", "ground")]:
        assert np.abs(looks[a] - looks[b]).max(axis=2).mean() > 4, (a, b)
    # the bare frame's bottom rows are its flat background; staged, the ground is there
    bottom = looks["bare"][-3:].reshape(-1, 3)
    assert np.ptp(bottom, axis=0).max() <= 2
    assert np.abs(looks["default"][-3:].reshape(-1, 3) - bottom).max(axis=1).mean() > 20
    both = CliRunner().invoke(
        main, ["render", one_tree.path, "-o", str(tmp_path / "x.png"), "--staged", "--bare"]
    )
    assert both.exit_code == 2
    assert both.output == "error: staged: --staged and --bare ask for two looks: give one\n"


def test_distant_leaf_clouds_cover_as_in_the_bare_mode(
    gl43: Any, tmp_path_factory: pytest.TempPathFactory
) -> None:
    # A willow seen from afar: its clouds are a few pixels each, so a filtered impostor atlas
    # would be read at coarse mip levels, where averaging the leaves' depth with the empty
    # texels' -1 marker went negative and sparse clouds were discarded (the gallery's stands
    # lost most of their leaves). The staged frame must show as many leaf pixels as the bare.
    forest = generate_forest(load_preset("willow"), 3, ForestOptions(trees=1, area=(1.0, 1.0)))
    scene = read_scene(write_scene(forest, tmp_path_factory.mktemp("willow") / "tree.usdc"))
    crown = scene.foliage_at(0)
    centre = 0.5 * (crown.min(axis=0) + crown.max(axis=0))
    reach = float(np.linalg.norm(crown.max(axis=0) - crown.min(axis=0)))
    eye = centre + np.array([1.0, 0.6, 1.0]) * 2.2 * reach
    cam = Camera(eye, centre, 30.0, SIZE[0] / SIZE[1], 0.1, 10.0 * reach)
    # no ground, sky or shadows: what the leaves change is the leaves themselves
    bare = Staging(ground=False, sky=False)
    filtered = Staging(ground=False, sky=False, tone_map=True)
    covered = []
    for staging in (bare, filtered):
        images = []
        for leaves in (False, True):
            r = render(gl43, scene, cam, staging, leaves=leaves)
            try:
                images.append(r.read_color()[..., :3].astype(np.int32))
            finally:
                r.release()
        covered.append(int((np.abs(images[1] - images[0]).max(axis=2) > 8).sum()))
    assert covered[0] > 300, covered  # the clouds are in view
    assert covered[1] > 0.8 * covered[0], covered
