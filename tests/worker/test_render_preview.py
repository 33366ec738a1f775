"""``forest render`` as a user runs it: a golden preview of a small seeded forest, the metrics
JSON, tile-set folders, and one error line with exit code 2 for what cannot work.

The golden scene and image live in ``tests/data/``: ``FOREST_UPDATE_GOLDEN=1`` writes the image
again (and the scene, if it was deleted: the scene is kept fixed so that the golden tests the
renderer, not the generator). A failing comparison writes the render and an amplified diff
into ``tests/output/``.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner
from numpy.typing import NDArray
from pxr import Usd, Vt

from cli import main
from forest.bark.images import write_png
from forest.bark.tile_folder import read_image_subimages
from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.usd.read import read_scene
from forest.usd.scene import write_scene
from schemas.metrics import RenderMetrics
from schemas.tileset import DEFAULT_MANIFEST
from worker.render.clip import ORBIT_FRAMES
from worker.render.render_file import RenderRequest, frames_to_draw, preview_view
from worker.render.renderer import Renderer
from worker.render.textures import procedural_tiles

ROOT = Path(__file__).parents[2]
DATA = ROOT / "tests" / "data"
OUTPUT = ROOT / "tests" / "output"
GOLDEN_SCENE = DATA / "render_forest.usdc"
GOLDEN_PNG = DATA / "render_preview.png"
GOLDEN_SIZE = (128, 96)
UPDATE = os.environ.get("FOREST_UPDATE_GOLDEN") == "1"
# llvmpipe output is stable across runs; these leave room for another Mesa's rounding
# (mean of 1 level in 255) and a few edge pixels rasterised differently (0.5 %)
MEAN_ABS_TOL = 1.0
BAD_PIXEL_LEVEL = 32
BAD_PIXEL_FRACTION = 0.005


def read_png(path: Path) -> NDArray[np.uint8]:
    return read_image_subimages(path)[0]


def make_golden_scene() -> Path:
    forest = generate_forest(
        load_preset("almond"), 3, ForestOptions(trees=3, frames=2, area=(3.0, 3.0))
    )
    DATA.mkdir(exist_ok=True)
    # posed, flat colours: a small fixed file (the renderer's bark comes from the tile set)
    return write_scene(forest, GOLDEN_SCENE, skinned=False, textures=False)


def test_golden_preview(gl43: Any) -> None:
    if UPDATE and not GOLDEN_SCENE.exists():
        make_golden_scene()
    scene = read_scene(GOLDEN_SCENE)
    # the placeholder bark, made here: the golden tests the renderer, not a tile set's pixels
    images = procedural_tiles(scene.manifest, scene.manifest.n_slices)
    renderer = Renderer(gl43, scene, GOLDEN_SIZE, images)
    try:
        camera, tess = preview_view(scene, GOLDEN_SIZE, tess_max=6.0, frame=1)
        renderer.draw(camera, tess, frame=1)
        image = renderer.read_color()
    finally:
        renderer.release()
    if UPDATE:
        write_png(GOLDEN_PNG, image)
        pytest.skip("golden preview written; rerun without FOREST_UPDATE_GOLDEN")
    golden = read_png(GOLDEN_PNG)
    assert golden.shape == image.shape
    diff = np.abs(image.astype(np.int16) - golden.astype(np.int16)).max(axis=-1)
    mean, bad = float(diff.mean()), float((diff > BAD_PIXEL_LEVEL).mean())
    if mean > MEAN_ABS_TOL or bad > BAD_PIXEL_FRACTION:
        OUTPUT.mkdir(exist_ok=True)
        write_png(OUTPUT / "render_preview.actual.png", image)
        amplified = np.clip(diff * 4, 0, 255).astype(np.uint8)
        rgba = np.dstack([amplified] * 3 + [np.full_like(amplified, 255)])
        write_png(OUTPUT / "render_preview.diff.png", rgba)
        pytest.fail(
            f"preview differs from {GOLDEN_PNG.name}: mean {mean:.2f} levels, {bad:.2%} "
            f"pixels off by > {BAD_PIXEL_LEVEL}; see {OUTPUT}/render_preview.diff.png "
            "(FOREST_UPDATE_GOLDEN=1 rewrites the golden files when the change is intended)"
        )
    # the forest is in the picture: bark pixels are not sky
    sky = golden[0, 0, :3].astype(int)
    assert (np.abs(image[..., :3].astype(int) - sky).max(axis=-1) > 40).mean() > 0.01


def run_cli(*args: str) -> Any:
    return CliRunner().invoke(main, list(args))


def test_render_writes_preview_and_metrics(gl_session: Any, tmp_path: Path) -> None:
    out, met = tmp_path / "p.png", tmp_path / "m.json"
    res = run_cli(
        "render",
        str(GOLDEN_SCENE),
        "-o",
        str(out),
        "--metrics",
        str(met),
        "--width",
        "64",
        "--height",
        "48",
        "--tess-max",
        "4",
        "--frames",
        "3",
        "--bare",  # the paper's set-up: no shadow pass in the draw calls counted below
    )
    assert res.exit_code == 0, res.output
    assert read_png(out).shape == (48, 64, 4)
    m = RenderMetrics.model_validate(json.loads(met.read_text()))
    assert (m.width, m.height, m.mode) == (64, 48, "instanced")
    assert [f.frame for f in m.frames] == [0, 1, 0]  # wind frames wrap around the samples
    assert m.frames[1].time == pytest.approx(1 / 24)
    # one instanced call per piece type, plus the foliage billboards (pass 1 ran in warm-up)
    n_types = len(set(read_scene(GOLDEN_SCENE).proto_indices))
    assert all(f.draw_calls == n_types + 1 for f in m.frames)
    assert m.foliage is not None and m.foliage.mode == "impostor"
    assert all(f.instances == m.instances > 0 for f in m.frames)
    # tessellated: at least two triangles per quad of the pieces drawn (the cull pass keeps
    # the thick ones: at 64 x 48 px, 122 of the almonds' 2,660 pieces)
    drawn = min(f.drawn_instances or 0 for f in m.frames)
    assert m.median.primitives >= 2 * m.quads * drawn / m.instances > 0
    assert m.tessellation.max_level == 4.0
    # the cull pass ran (sub-pixel LOD at its default) and says what it kept
    assert m.lod_pixels == 0.5
    assert all(
        f.drawn_instances is not None and 0 < f.drawn_instances <= m.instances for f in m.frames
    )
    assert m.renderer and m.renderer in res.output
    assert m.textures  # the package's default tile set, or the procedural placeholder


def test_render_per_instance_draws_once_per_piece(gl_session: Any, tmp_path: Path) -> None:
    met = tmp_path / "m.json"
    res = run_cli(
        "render", str(GOLDEN_SCENE), "-o", str(tmp_path / "p.png"), "--metrics", str(met),
        "--width", "32", "--height", "32", "--per-instance", "--bare",
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    m = RenderMetrics.model_validate_json(met.read_text())
    assert m.mode == "per_instance"
    assert m.frames[0].draw_calls == m.instances + 1  # + the foliage billboards
    assert m.lod_pixels is None and m.frames[0].drawn_instances is None  # no cull pass


def test_still_scene_renders_one_frame(gl_session: Any, tmp_path: Path) -> None:
    still = write_scene(
        generate_forest(load_preset("almond"), 3, ForestOptions(trees=1)), tmp_path / "s.usdc"
    )
    met = tmp_path / "m.json"
    res = run_cli(
        "render", str(still), "-o", str(tmp_path / "p.png"), "--metrics", str(met),
        "--width", "32", "--height", "24", "--tess-max", "2", "--frames", "5", "--quiet",
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    note = "the scene is still (no wind frames): rendering 1 frame instead of 5"
    assert res.stderr == f"warning: {note}\n"  # --quiet drops the progress, not a warning
    assert "median of 1 frame(s)" in res.stdout
    m = RenderMetrics.model_validate_json(met.read_text())
    assert len(m.frames) == 1 and m.warnings == [note]


def test_frames_to_draw() -> None:
    """The frames drawn: as asked, one of a scene with one pose (and a note) unless the camera
    orbits, a clip without ``frames`` the whole wind loop."""
    still: Any = SimpleNamespace(n_frames=1, times=[None])
    posed: Any = SimpleNamespace(n_frames=1, times=[0.0])
    windy: Any = SimpleNamespace(n_frames=24, times=[k / 24 for k in range(24)])

    def req(**kw: Any) -> RenderRequest:
        return RenderRequest(scene=Path("s.usdc"), output=Path("p.png"), **kw)

    assert frames_to_draw(req(frames=5), still) == (
        1,
        "the scene is still (no wind frames): rendering 1 frame instead of 5",
    )
    assert frames_to_draw(req(frames=3), posed) == (
        1,
        "the scene has one wind frame: rendering 1 frame instead of 3",
    )
    assert frames_to_draw(req(), still) == (1, None)
    assert frames_to_draw(req(frames=5), windy) == (5, None)
    gif = Path("c.gif")
    assert frames_to_draw(req(clip=gif), windy) == (24, None)
    assert frames_to_draw(req(clip=gif), still) == (1, None)
    assert frames_to_draw(req(clip=gif, orbit=True), still) == (ORBIT_FRAMES, None)
    assert frames_to_draw(req(clip=gif, orbit=True, frames=8), still) == (8, None)


def write_tile_folder(folder: Path, colour: tuple[int, int, int], as_array: bool) -> None:
    import OpenImageIO as oiio

    folder.mkdir()
    n = DEFAULT_MANIFEST.n_slices  # no manifest in the folder: the default classes' slices
    tile = np.zeros((8, 8, 3), np.uint8)
    tile[:] = colour
    if as_array:
        path = str(folder / "bark_array.tif")
        out = oiio.ImageOutput.create(path)
        specs = [oiio.ImageSpec(8, 8, 3, "uint8") for _ in range(n)]
        assert out.open(path, specs)
        for k in range(n):
            if k:
                assert out.open(path, specs[k], "AppendSubimage")
            assert out.write_image(tile)
        out.close()
    else:
        for k in range(n):
            write_png(
                folder / f"bark.{1001 + k}.png",
                np.dstack([tile, np.full((8, 8), 255)]).astype(np.uint8),
            )


@pytest.mark.parametrize("as_array", [False, True])
def test_render_reads_a_tile_set_folder(gl_session: Any, tmp_path: Path, as_array: bool) -> None:
    write_tile_folder(tmp_path / "tiles", (200, 30, 30), as_array)
    out, met = tmp_path / "p.png", tmp_path / "m.json"
    res = run_cli(
        "render", str(GOLDEN_SCENE), "-o", str(out), "--metrics", str(met),
        "--width", "64", "--height", "64", "--tiles", str(tmp_path / "tiles"),
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    m = RenderMetrics.model_validate_json(met.read_text())
    assert m.textures.startswith(str(tmp_path / "tiles"))
    img = read_png(out)[..., :3].astype(int)
    reddish = (img[..., 0] > img[..., 1] + 40) & (img[..., 0] > img[..., 2] + 40)
    assert reddish.sum() > 20  # the bark shows the folder's red tiles


def test_render_finds_the_tile_set_through_the_material(gl_session: Any, tmp_path: Path) -> None:
    forest = generate_forest(load_preset("almond"), 3, ForestOptions(trees=1))
    scene = write_scene(forest, tmp_path / "s.usda", tiles="tiles")
    write_tile_folder(tmp_path / "tiles", (30, 30, 200), as_array=False)
    met = tmp_path / "m.json"
    res = run_cli(
        "render", str(scene), "-o", str(tmp_path / "p.png"), "--metrics", str(met),
        "--width", "32", "--height", "32",
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "bark.<UDIM>.png" in RenderMetrics.model_validate_json(met.read_text()).textures


def test_scene_breaking_the_contract_gets_one_line(gl_session: Any, tmp_path: Path) -> None:
    broken = tmp_path / "broken.usda"
    shutil.copy(GOLDEN_SCENE, tmp_path / "golden.usdc")
    stage = Usd.Stage.Open(str(tmp_path / "golden.usdc"))
    attr = stage.GetPrimAtPath("/World/Forest/Pieces").GetAttribute("primvars:forest:tileIndices")
    tiles = np.array(attr.Get(), np.int32)
    tiles[0] = 99
    attr.Set(Vt.IntArray.FromNumpy(tiles))
    stage.GetRootLayer().Export(str(broken))
    res = run_cli("render", str(broken), "-o", str(tmp_path / "p.png"))
    assert res.exit_code == 2
    assert res.output == (
        "error: /World/Forest/Pieces.primvars:forest:tileIndices: instance 0 has tile index "
        "99 outside the tile set's 27 slices\n"
    )
    assert not (tmp_path / "p.png").exists()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--width", "0"], "error: width: must be in [1, 8192], got 0"),
        (["--tess-max", "100"], "error: tess_max: must be in [1, 64], got 100.0"),
        (["--frame", "5"], "error: frame: the scene has 2 palette sample(s)"),
        # checked though no clip uses it: a given option is never ignored
        (["--fps", "nan"], "error: fps: must be in (0, 120], got nan"),
        (["--alpha", "inf"], "error: alpha: must be in [0, 1], got inf"),
        (["--ground", "--staged"], "error: staged: --staged and --ground ask for two looks"),
    ],
)
def test_bad_options_get_one_line(tmp_path: Path, args: list[str], message: str) -> None:
    res = run_cli("render", str(GOLDEN_SCENE), "-o", str(tmp_path / "p.png"), *args)
    assert res.exit_code == 2
    assert res.output.startswith(message) and res.output.count("\n") == 1


def test_missing_egl_names_the_packages(tmp_path: Path) -> None:
    """A real run where glcontext cannot load libEGL: the user is told what to install."""
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
        "GLCONTEXT_LINUX_LIBEGL": "libEGL-missing.so",
    }
    res = subprocess.run(
        [sys.executable, "-m", "cli", "render", str(GOLDEN_SCENE), "-o", "p.png"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 2
    assert res.stderr.startswith("error: gl.egl: libEGL not found")
    assert "apt-get install libegl1 libegl-mesa0" in res.stderr
    assert res.stderr.count("\n") == 1
