"""``--tree N``: the view frames one tree of the scene (a close-up), centred in the image.
Pure numpy on the scene's arrays (no GL context needed)."""

from __future__ import annotations

import numpy as np
import pytest

from forest.errors import ForestError
from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.usd.read import SceneArrays, read_scene
from forest.usd.scene import write_scene
from worker.render.camera import CameraSpec
from worker.render.foliage import foliage_points
from worker.render.render_file import preview_view
from worker.render.scene_buffers import scene_points


@pytest.fixture(scope="module")
def stand(tmp_path_factory: pytest.TempPathFactory) -> SceneArrays:
    f = generate_forest(load_preset("almond"), 4, ForestOptions(trees=4, area=(30.0, 30.0)))
    path = write_scene(f, tmp_path_factory.mktemp("cam") / "stand.usdc", skinned=False)
    return read_scene(path)


@pytest.mark.parametrize("view", ["overview", "side", "eye"])
@pytest.mark.parametrize("tree", [0, 3])
def test_the_tree_asked_for_is_centred(stand: SceneArrays, view: str, tree: int) -> None:
    size = (480, 640)
    cam, _ = preview_view(stand, size, 8.0, spec=CameraSpec(view=view, tree=tree))
    pts = np.concatenate([scene_points(stand, 0, tree), foliage_points(stand, 0, tree)])
    clip = np.c_[pts, np.ones(len(pts))] @ cam.view_projection().T
    ndc = clip[:, :2] / clip[:, 3:]
    centre = 0.5 * (ndc.min(axis=0) + ndc.max(axis=0))
    # the silhouette, not the world box's centre (a lopsided crown seen obliquely fills its box
    # unevenly): the camera pans until it is centred, to its 1e-3 stopping tolerance
    assert np.abs(centre).max() <= 2e-3
    assert (np.abs(ndc) <= 1.0).all()  # and the whole tree in view
    # a close-up: the other trees are not all in the frame
    everyone = scene_points(stand, 0)
    clip = np.c_[everyone, np.ones(len(everyone))] @ cam.view_projection().T
    inside = (np.abs(clip[:, :2]) <= clip[:, 3:]).all(axis=1) & (clip[:, 3] > 0)
    assert not inside.all()


def test_a_tree_the_scene_lacks_is_named(stand: SceneArrays) -> None:
    with pytest.raises(ForestError, match="tree"):
        preview_view(stand, (64, 64), 8.0, spec=CameraSpec(tree=4))
    with pytest.raises(ForestError, match="tree"):
        preview_view(stand, (64, 64), 8.0, spec=CameraSpec(tree=-1))
