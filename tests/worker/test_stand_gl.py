"""A mixed forest's root layer through the renderer (worker.render.stand, Renderer.add_layer, the
terrain in worker.render.staging): every layer's trees and the terrain in one frame, in the
staged and bare modes, and the root layers that are refused (a layer file outside the root's
folder, a root without its layer files)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner
from numpy.typing import NDArray
from pxr import Sdf

from cli import main
from forest.errors import ForestError
from forest.growth.generate import ForestOptions
from forest.stand.generate import plan_stand
from forest.stand.recipes import load_recipe
from forest.usd.contract import STAND_LAYERS
from forest.usd.read import SceneArrays, read_scene
from forest.usd.stand import write_stand
from schemas.metrics import RenderMetrics
from worker.render.camera import CameraSpec, project
from worker.render.render_file import RenderRequest, load_scene, preview_view, render_file
from worker.render.renderer import SKY, Renderer
from worker.render.staging import STAGED, Staging, TerrainMesh
from worker.render.stand import StandScene, load_stand, stand_view

SIZE = (96, 72)
SKY_RGB = np.round(np.power(SKY, 1 / 2.2) * 255)  # the bare mode's clear colour


@pytest.fixture(scope="module")
def stand_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small mixed broadleaf wood (four layers: oak, birch, hazel, young oak) on its hills."""
    out = tmp_path_factory.mktemp("stand") / "wood.usdc"
    area = (30.0, 30.0)
    stand = plan_stand(load_recipe("mixed-broadleaf"), 14, area, seed=2)
    write_stand(stand, out, ForestOptions(trees=14, area=area), skinned=False)
    return out


@pytest.fixture(scope="module")
def stand(stand_root: Path) -> StandScene:
    return load_stand(stand_root, load_scene)


def _render(
    ctx: Any,
    scenes: tuple[SceneArrays, ...],
    staging: Staging | None,
    terrain: TerrainMesh | None,
    view: Any,
    ids: bool = False,
) -> NDArray[np.uint8]:
    camera, tess = view
    r = Renderer(ctx, scenes[0], SIZE, staging=staging, terrain=terrain, ids=ids)
    try:
        for s in scenes[1:]:
            r.add_layer(s)
        r.draw(camera, tess)
        return r.read_color()[..., :3]
    finally:
        r.release()


def _sky(image: NDArray[np.uint8]) -> NDArray[np.bool_]:
    return bool_(np.abs(image.astype(int) - SKY_RGB).max(axis=-1) <= 2)


def bool_(a: Any) -> NDArray[np.bool_]:
    return np.asarray(a, dtype=bool)


def test_every_layer_and_the_terrain_are_drawn_in_one_frame(gl43: Any, stand: StandScene) -> None:
    assert stand.names == ("oak", "birch", "hazel", "young_oak")
    view = stand_view(stand, SIZE, 4.0)
    bare = Staging(ground=False, sky=False)
    whole = _render(gl43, stand.scenes, bare, stand.terrain, view)
    # the terrain covers the overview where it lies (around points of its mesh), under and
    # between the trees; the sky is above it
    pts = stand.terrain.points
    where = [pts[np.argmin(np.hypot(pts[:, 0] - fx, pts[:, 2] - fz))] for fx in (-9, 0, 9)
             for fz in (-9, 0, 9)]  # fmt: skip
    px = project(view[0], np.array(where), SIZE).astype(int)

    def sky_under_terrain(image: NDArray[np.uint8]) -> float:
        return float(np.mean([_sky(image[y - 3 : y + 4, x - 3 : x + 4]).mean() for x, y in px]))

    assert sky_under_terrain(whole) < 0.05
    assert _sky(whole[:3]).mean() > 0.9
    # without the terrain the sky shows there: the check above can fail
    assert sky_under_terrain(_render(gl43, stand.scenes, bare, None, view)) > 0.3
    # every layer (a species each, with its own bark and leaves) shows: leaving one out
    # changes pixels
    for k, name in enumerate(stand.names):
        rest = stand.scenes[:k] + stand.scenes[k + 1 :]
        without = _render(gl43, rest, bare, stand.terrain, view)
        changed = int((np.abs(without.astype(int) - whole.astype(int)).max(axis=-1) > 8).sum())
        assert changed >= 5, f"layer {name} is not seen ({changed} pixels)"


def _wall(height: float) -> TerrainMesh:
    """A slope rising ``height`` metres per metre towards the far side of the overview (-x,
    -z), level around the origin."""
    g = np.linspace(-60.0, 60.0, 13)
    x, z = np.meshgrid(g, g)
    y = np.maximum(0.0, -(x + z) - 4.0) * height
    pts = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    idx = np.arange(len(pts)).reshape(13, 13)
    quads = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 4)
    return TerrainMesh.from_quads(pts, quads)


@pytest.mark.parametrize("mode", ["staged", "bare"])
def test_the_terrain_replaces_the_sky_it_rises_into(
    gl43: Any, mixed_scene: SceneArrays, mode: str
) -> None:
    """A slope rising behind the trees covers the sky at the top of the picture in the staged
    mode (where it is the lit, shadowed ground) and in the bare mode (drawn plainly)."""
    staging = STAGED if mode == "staged" else Staging(ground=False, sky=False)
    view = preview_view(mixed_scene, SIZE, 4.0, ground=True)
    flat = _render(gl43, (mixed_scene,), staging, None, view)
    wall = _render(gl43, (mixed_scene,), staging, _wall(3.0), view)
    top = slice(0, SIZE[1] // 5)
    sky_flat = flat[top].reshape(-1, 3).astype(int)
    sky_wall = wall[top].reshape(-1, 3).astype(int)
    assert (sky_flat[:, 2] > sky_flat[:, 1]).mean() > 0.9  # blue above the trees
    assert (sky_wall[:, 1] > sky_wall[:, 2]).mean() > 0.9  # the ground's green-brown
    if mode == "staged":  # lit by its normal: the slope facing the sun differs from flat ground
        assert np.ptp(sky_wall.mean(axis=1)) > 5


def test_render_draws_a_stand_from_the_command_line(
    gl_session: Any, stand_root: Path, stand: StandScene, tmp_path: Path
) -> None:
    runs = {}
    for mode in ("--bare", "--ground"):
        met = tmp_path / f"{mode[2:]}.json"
        res = CliRunner().invoke(
            main,
            ["render", str(stand_root), "-o", str(tmp_path / f"{mode[2:]}.png"), "--metrics",
             str(met), "--width", "64", "--height", "48", "--tess-max", "2", mode],
        )  # fmt: skip
        assert res.exit_code == 0, res.output
        runs[mode] = RenderMetrics.model_validate(json.loads(met.read_text()))
    m = runs["--bare"]
    assert m.instances == sum(s.n_instances for s in stand.scenes)
    assert m.frames[0].instances == m.instances
    assert m.piece_types == sum(len(s.pieces) for s in stand.scenes)
    assert m.bones == sum(s.n_bones for s in stand.scenes)
    assert m.foliage is not None and m.foliage.clouds == sum(s.n_foliage for s in stand.scenes)
    assert m.scene == str(stand_root)
    # a close-up of one tree has no meaning across layers
    res = CliRunner().invoke(
        main, ["render", str(stand_root), "-o", str(tmp_path / "t.png"), "--tree", "0"]
    )
    assert res.exit_code != 0 and "mixed forest" in res.output


def _copy_stand(root: Path, to: Path) -> Path:
    to.mkdir()
    shutil.copy(root, to / root.name)
    shutil.copytree(root.with_name(f"{root.stem}_layers"), to / f"{root.stem}_layers")
    return to / root.name


@pytest.mark.parametrize("where", ["../outside/oak.usdc", "absolute"])
def test_a_layer_file_outside_the_roots_folder_is_refused(
    stand_root: Path, tmp_path: Path, where: str
) -> None:
    root = _copy_stand(stand_root, tmp_path / "stand")
    outside = tmp_path / "outside" / "oak.usdc"
    outside.parent.mkdir()
    shutil.copy(root.with_name(f"{root.stem}_layers") / "oak.usdc", outside)
    layer = Sdf.Layer.FindOrOpen(str(root))
    spec = layer.GetPrimAtPath(f"{STAND_LAYERS}/birch")
    spec.referenceList.ClearEdits()
    spec.referenceList.Prepend(Sdf.Reference(str(outside) if where == "absolute" else where))
    layer.Save()
    req = RenderRequest(scene=root, output=tmp_path / "x.png")
    with pytest.raises(ForestError) as err:
        render_file(req)
    text = str(err.value)
    assert "layer 'birch'" in text and "outside the root layer's folder" in text
    assert str(tmp_path) not in text and "\n" not in text
    assert not (tmp_path / "x.png").exists()


def test_a_root_layer_uploaded_alone_is_refused_clearly(stand_root: Path, tmp_path: Path) -> None:
    upload = tmp_path / "upload"
    upload.mkdir()
    root = upload / "scene.usdc"
    shutil.copy(stand_root, root)
    req = RenderRequest(scene=root, output=tmp_path / "x.png", scene_tiles=False)
    with pytest.raises(ForestError) as err:
        render_file(req)
    text = str(err.value)
    assert "layer 'oak'" in text and "not beside the root layer" in text
    assert str(tmp_path) not in text and str(stand_root.parent) not in text


def test_an_eye_level_view_stands_on_the_terrain(stand: StandScene) -> None:
    cam, _ = stand_view(stand, SIZE, 4.0, spec=CameraSpec(view="eye", distance=5.0))
    under = float(stand.floor()(np.asarray(cam.eye[0]), np.asarray(cam.eye[2])))
    assert cam.eye[1] == pytest.approx(under + 1.7)
    assert np.ptp(stand.terrain.points[:, 1]) > 0.5  # hills: the check above can fail
    # the terrain's heights are the mesh's own at its points
    p = stand.terrain.points[::97]
    assert np.allclose(stand.floor()(p[:, 0], p[:, 2]), p[:, 1], atol=1e-6)


def test_read_scene_reads_every_layer_file_alone(stand_root: Path) -> None:
    folder = stand_root.with_name(f"{stand_root.stem}_layers")
    for f in sorted(folder.glob("*.usdc")):
        assert read_scene(f).n_instances > 0


def test_a_tiled_forest_renders_every_tile(tmp_path: Path) -> None:
    """A tiled forest's root layer (forest generate --tile-size) renders: every tile's pieces
    drawn in one frame on level ground, as the untiled forest's; alone, it is refused."""
    from forest.growth.generate import generate_forest
    from forest.growth.presets import load_preset
    from forest.growth.tiling import TilePlan, generate_tile
    from forest.usd.scene import write_scene
    from forest.usd.tiled import write_root, write_tile

    plan = TilePlan(6, (16.0, 8.0), 8.0, 3)
    root = tmp_path / "tiled.usdc"
    entries = [
        write_tile(generate_tile(load_preset("uniform"), plan, i, j), root, i, j)
        for i, j in plan.tiles()
    ]
    write_root(root, entries, meta=plan.meta())
    out = tmp_path / "tiled.png"
    metrics = render_file(
        RenderRequest(scene=root, output=out, width=96, height=72, scene_tiles=False)
    )
    whole = generate_forest(load_preset("uniform"), 3, ForestOptions(trees=6, area=(16.0, 8.0)))
    flat = write_scene(whole, tmp_path / "whole.usdc", skinned=False)
    single = render_file(RenderRequest(scene=flat, output=tmp_path / "w.png", width=96, height=72))
    assert metrics.instances == single.instances == whole.n_instances
    lone = tmp_path / "upload"
    lone.mkdir()
    shutil.copy(root, lone / "scene.usdc")
    with pytest.raises(ForestError) as err:
        render_file(RenderRequest(scene=lone / "scene.usdc", output=tmp_path / "x.png"))
    assert "tile" in str(err.value) and "not beside the root layer" in str(err.value)
    assert str(tmp_path) not in str(err.value)
