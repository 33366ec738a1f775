"""``forest render --clip``: the wind loop (or an orbit) encoded, decoded again by the same
libraries with the frame count, size and rate asked for."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import imageio.v2 as iio2
import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from cli import main
from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.usd.scene import write_scene
from worker.render.clip import MEDIA_TYPES, orbit_camera_eyes, write_clip

FRAMES, FPS = 6, 6.0  # a 1 s clip: long enough to loop (Wind.loop_s)
# imageio-ffmpeg's frame reader leaves its ffmpeg pipe to the garbage collector once the
# frames run out (a ResourceWarning in the library's generator, not in our writer)
pytestmark = pytest.mark.filterwarnings(
    "ignore::ResourceWarning", "ignore::pytest.PytestUnraisableExceptionWarning"
)


@pytest.fixture(scope="module")
def windy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    forest = generate_forest(
        load_preset("alternating"), 2, ForestOptions(trees=1, frames=FRAMES, fps=FPS)
    )
    # the clip loops: the pose after the last frame is the first one
    np.testing.assert_allclose(forest.palette(FRAMES / FPS), forest.palette(0.0), atol=1e-9)
    return write_scene(forest, tmp_path_factory.mktemp("clip") / "windy.usdc")


def video_frames(path: Path) -> tuple[list[np.ndarray], dict[str, Any]]:
    r: Any = iio2.get_reader(path, format="FFMPEG")
    try:
        return [np.asarray(f) for f in r], r.get_meta_data()
    finally:
        r.close()


def decode(path: Path) -> tuple[int, tuple[int, int], float]:
    """Frame count, (width, height) and frames per second, as the encoder's library reads."""
    if path.suffix in (".mp4", ".webm"):
        frames, meta = video_frames(path)
        w, h = meta["size"]
        return len(frames), (int(w), int(h)), float(meta["fps"])
    im: Any
    with Image.open(path) as im:
        n = int(im.n_frames)
        im.seek(min(1, n - 1))  # webp tells a frame's duration once it is read
        im.load()
        return n, im.size, 1000.0 / im.info["duration"]


@pytest.mark.parametrize("suffix", sorted(MEDIA_TYPES))
def test_clip_of_the_wind_loop(windy: Path, tmp_path: Path, suffix: str) -> None:
    clip = tmp_path / f"wind{suffix}"
    res = CliRunner().invoke(
        main, ["render", str(windy), "-o", str(tmp_path / "p.png"), "--clip", str(clip),
               "--width", "64", "--height", "48", "--tess-max", "1",
               "--metrics", str(tmp_path / "m.json")],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    n, size, fps = decode(clip)
    assert n == FRAMES and size == (64, 48)
    # gif and webp store whole milliseconds (gif: 10 ms steps): 6 fps is 167 (gif 170) ms
    assert fps == pytest.approx(FPS, rel=0.05 if suffix in (".gif", ".webp") else 1e-6)
    assert f"wrote {clip}: {FRAMES} frame(s)" in res.output
    assert (tmp_path / "m.json").read_text().count('"cpu_ms"') >= FRAMES  # metrics per frame


def test_orbit_and_frame_count(windy: Path, tmp_path: Path) -> None:
    clip = tmp_path / "orbit.mp4"
    res = CliRunner().invoke(
        main, ["render", str(windy), "-o", str(tmp_path / "p.png"), "--clip", str(clip),
               "--orbit", "--frames", "8", "--fps", "8", "--width", "64", "--height", "48",
               "--tess-max", "1"],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    assert decode(clip) == (8, (64, 48), 8.0)
    frames, _ = video_frames(clip)
    assert np.abs(frames[0].astype(int) - frames[4]).mean() > 2  # the camera went round


def test_orbit_eyes_loop() -> None:
    eyes = orbit_camera_eyes(np.array([3.0, 2.0, 0.0]), np.array([0.0, 1.0, 0.0]), 4)
    np.testing.assert_allclose(eyes[:, 1], 2.0)
    np.testing.assert_allclose(np.hypot(eyes[:, 0], eyes[:, 2]), 3.0)
    np.testing.assert_allclose(eyes[2], [-3.0, 2.0, 0.0], atol=1e-12)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--clip", "x.avi"], "a clip is mp4, webm, gif, webp: name it so"),
        (["--clip", "x.mp4", "--width", "63"], "width: mp4 needs an even width and height"),
        (["--orbit"], "orbit: an orbit is a clip: give --clip too"),
        (["--clip", "x.gif", "--fps", "0"], "fps: must be in (0, 120]"),
    ],
)
def test_clip_bad_options(windy: Path, tmp_path: Path, args: list[str], message: str) -> None:
    res = CliRunner().invoke(
        main, ["render", str(windy), "-o", str(tmp_path / "p.png"),
               *[str(tmp_path / a) if a.startswith("x.") else a for a in args]],
    )  # fmt: skip
    assert res.exit_code == 2
    assert message in res.output


def test_write_clip_rgba_frames(tmp_path: Path) -> None:
    frames = [np.full((8, 10, 4), 40 * i, np.uint8) for i in range(3)]
    write_clip(tmp_path / "a.webp", frames, 10.0)
    assert decode(tmp_path / "a.webp")[:2] == (3, (10, 8))


def test_render_job_clip_artifact_and_missing_bark_warning(windy: Path, tmp_path: Path) -> None:
    """A render job (the worker's task, as the service runs it) asking for a gif clip of a
    scene whose tile folder is gone: the clip is an artifact with its media type, and the
    result and metrics say which bark it fell back on."""
    from farm.artifacts import ArtifactStore
    from schemas.jobs import RenderRequest
    from schemas.metrics import RenderMetrics
    from service.routes.jobs import ARTIFACT_TYPES
    from worker.jobs.context import JobContext
    from worker.jobs.render import run_render

    # the scene's material names a tile folder beside it that is not there (an upload's)
    forest = generate_forest(
        load_preset("alternating"), 2, ForestOptions(trees=1, frames=FRAMES, fps=FPS)
    )
    scene = write_scene(forest, tmp_path / "scene.usdc", tiles="bark_tiles")
    store = ArtifactStore(tmp_path / "artifacts")
    store.publish("a" * 32, scene, "scene.usdc")
    req = RenderRequest(forest_job="a" * 32, width=32, height=24, tess_max=1, clip="gif")
    params = req.model_dump(mode="json") | {"scene": "scene.usdc"}
    out = run_render(JobContext("b" * 32, params, store.scratch("b" * 32), store))
    assert set(out.files) == {"preview.png", "metrics.json", "clip.gif"}
    assert out.result["clip"] == "clip.gif"
    assert ARTIFACT_TYPES[".gif"] == "image/gif"
    assert decode(out.files["clip.gif"])[:2] == (FRAMES, (32, 24))
    metrics = RenderMetrics.model_validate_json(out.files["metrics.json"].read_text())
    assert len(metrics.frames) == FRAMES
    assert len(metrics.warnings) == 1, metrics.warnings
    assert metrics.warnings[0].startswith("bark tiles not found: ")
    assert "bark_tiles" in metrics.warnings[0]
    assert out.result["warnings"] == metrics.warnings


def test_render_job_of_a_still_scene_draws_one_frame(tmp_path: Path) -> None:
    """Frames asked of a scene without wind would all be the same picture: the job draws one,
    and its result and metrics say so."""
    from farm.artifacts import ArtifactStore
    from schemas.jobs import RenderRequest
    from schemas.metrics import RenderMetrics
    from worker.jobs.context import JobContext
    from worker.jobs.render import run_render

    still = generate_forest(load_preset("alternating"), 2, ForestOptions(trees=1))
    store = ArtifactStore(tmp_path / "artifacts")
    store.publish("e" * 32, write_scene(still, tmp_path / "still.usdc"), "scene.usdc")
    req = RenderRequest(forest_job="e" * 32, width=32, height=24, tess_max=1, frames=5)
    params = req.model_dump(mode="json") | {"scene": "scene.usdc"}
    out = run_render(JobContext("f" * 32, params, store.scratch("f" * 32), store))
    note = "the scene is still (no wind frames): rendering 1 frame instead of 5"
    assert out.result["frames"] == 1 and len(out.result["frame_cpu_ms"]) == 1
    assert out.result["warnings"] == [note]
    metrics = RenderMetrics.model_validate_json(out.files["metrics.json"].read_text())
    assert len(metrics.frames) == 1 and metrics.warnings == [note]


def test_render_request_clip_fields() -> None:
    from pydantic import ValidationError

    from schemas.jobs import RenderRequest

    with pytest.raises(ValidationError, match="width: mp4 needs an even width and height"):
        RenderRequest(forest_job="x", width=33, clip="mp4")
    with pytest.raises(ValidationError, match="orbit: an orbit is a clip"):
        RenderRequest(forest_job="x", orbit=True)
    with pytest.raises(ValidationError):
        RenderRequest.model_validate({"forest_job": "x", "clip": "avi"})
    assert RenderRequest(forest_job="x", clip="webm", staged=True).clip == "webm"
    with pytest.raises(ValidationError, match="target: give eye and target together"):
        RenderRequest(forest_job="x", eye=(1.0, 2.0, 3.0))
    with pytest.raises(ValidationError, match="target: must differ from the eye"):
        RenderRequest(forest_job="x", eye=(1.0, 2.0, 3.0), target=(1.0, 2.0, 3.0))
    with pytest.raises(ValidationError):
        RenderRequest(forest_job="x", fov=0.5)


@pytest.mark.parametrize(
    "cam",
    [
        {"eye": (3.0, 1.5, 3.0), "target": (0.0, 1.0, 0.0), "fov": 30.0},
        {"view": "side", "tree": 0},
    ],
)
def test_render_job_camera(windy: Path, tmp_path: Path, cam: dict[str, object]) -> None:
    """A render job's camera (eye and target, or a view of one tree) places it as
    ``forest render`` does."""
    from farm.artifacts import ArtifactStore
    from schemas.jobs import RenderRequest
    from worker.jobs.context import JobContext
    from worker.jobs.render import run_render
    from worker.render.render_file import RenderRequest as Job
    from worker.render.render_file import render_file

    store = ArtifactStore(tmp_path / "artifacts")
    scene = tmp_path / "s.usdc"
    scene.write_bytes(windy.read_bytes())
    store.publish("c" * 32, scene, "scene.usdc")
    req = RenderRequest(forest_job="c" * 32, width=32, height=24, tess_max=1, **cam)  # type: ignore[arg-type]
    params = req.model_dump(mode="json") | {"scene": "scene.usdc"}
    out = run_render(JobContext("d" * 32, params, store.scratch("d" * 32), store))
    from worker.render.camera import CameraSpec

    assert req.staged  # a job is staged unless it asks for the bare mode, as `forest render`
    render_file(Job(scene=windy, output=tmp_path / "cli.png", width=32, height=24,
                    tess_max=1, camera=CameraSpec(**cam), staged=True))  # type: ignore[arg-type]  # fmt: skip
    from forest.bark.tile_folder import read_image_subimages

    a = read_image_subimages(out.files["preview.png"])[0]
    b = read_image_subimages(tmp_path / "cli.png")[0]
    np.testing.assert_array_equal(a, b)
