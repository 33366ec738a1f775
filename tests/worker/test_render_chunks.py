"""Frame chunks of a render (``render_chunk``, farm.chunks): a chunk draws each of its frames
pixel for pixel as the whole run draws it (the frame depends on its index only: its palette
sample, its orbit camera, the same warm-up), so the frames of chunks run anywhere make the
same preview and clip as one run (llvmpipe here)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.usd.scene import write_scene
from worker.render.clip import write_clip
from worker.render.render_file import RenderRequest, frame_png, render_chunk, render_file

FRAMES = 10


@pytest.fixture(scope="module")
def windy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    forest = generate_forest(
        load_preset("alternating"), 3, ForestOptions(trees=2, frames=FRAMES, fps=10.0)
    )
    return write_scene(forest, tmp_path_factory.mktemp("chunks") / "windy.usdc")


def chunk_frames(req: RenderRequest, ranges: list[tuple[int, int]], out: Path) -> list[Path]:
    """Every chunk of ``ranges`` drawn by a renderer of its own (as on another worker)."""
    out.mkdir()
    for a, b in ranges:
        metrics, fps = render_chunk(replace(req, frame_range=(a, b), frames_dir=out))
        assert metrics is not None and [f.frame for f in metrics.frames] == list(range(a, b))
        assert fps == 10.0
    return [out / frame_png(k) for k in range(req.frames)]


@pytest.mark.parametrize("orbit", [False, True], ids=["wind", "orbit"])
def test_chunks_draw_the_frames_of_one_run(windy: Path, tmp_path: Path, orbit: bool) -> None:
    req = RenderRequest(
        scene=windy, output=tmp_path / "preview.png", width=64, height=48, tess_max=2.0,
        frames=FRAMES, staged=True, orbit=orbit, clip=tmp_path / "one.gif",
    )  # fmt: skip
    one = render_file(req)  # one worker: every frame in one run, its preview and clip
    chunks = chunk_frames(req, [(0, 4), (4, 8), (8, 10)], tmp_path / "chunks")
    whole = chunk_frames(req, [(0, FRAMES)], tmp_path / "whole")
    pictures = [iio.imread(p) for p in chunks]
    for k, (a, b) in enumerate(zip(pictures, (iio.imread(p) for p in whole), strict=True)):
        assert np.array_equal(a, b), f"frame {k} differs"
    assert len({p.tobytes() for p in pictures}) > 1  # the frames move (wind, orbit)
    assert np.array_equal(iio.imread(req.output), pictures[0])  # the preview is frame 0
    write_clip(tmp_path / "chunks.gif", [p[..., :3] for p in pictures], 10.0)
    assert (tmp_path / "chunks.gif").read_bytes() == (tmp_path / "one.gif").read_bytes()
    assert len(one.frames) == FRAMES


def test_a_still_scene_draws_one_frame(tmp_path: Path) -> None:
    """A still scene draws one frame however many are asked: the chunks past it draw none."""
    forest = generate_forest(load_preset("alternating"), 3, ForestOptions(trees=1))
    scene = write_scene(forest, tmp_path / "still.usdc")
    (tmp_path / "f").mkdir()
    req = RenderRequest(
        scene=scene, output=tmp_path / "p.png", width=32, height=32, frames=12,
        frames_dir=tmp_path / "f",
    )  # fmt: skip
    first, _ = render_chunk(replace(req, frame_range=(0, 6)))
    assert first is not None and len(first.frames) == 1 and first.warnings
    later, _ = render_chunk(replace(req, frame_range=(6, 12)))
    assert later is None and sorted(p.name for p in (tmp_path / "f").iterdir()) == [frame_png(0)]
