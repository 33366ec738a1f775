"""Species bark on screen: a grammar with ``bark: birch`` renders with the birch tile set's
pale slices, one with ``oak`` with dark grey-brown ones (no tile folder given)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from forest.gl.context import create_context
from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.usd.read import read_scene
from forest.usd.scene import write_scene
from worker.render.camera import Camera
from worker.render.renderer import Renderer, TessSettings
from worker.render.scene_buffers import scene_bounds


def _bark_pixels(ctx: Any, path: Path) -> np.ndarray:
    """``(k, 3)`` uint8 colours of the pixels the trunk and branches cover."""
    scene = read_scene(path)
    renderer = Renderer(ctx, scene, (64, 64), foliage=None)
    try:
        lo, hi = scene_bounds(scene)
        target = 0.5 * (lo + hi)
        eye = target + np.array([0.0, 0.0, 1.2 * float(np.linalg.norm(hi - lo))])
        cam = Camera(eye=eye, target=target, near=0.05, far=100.0)
        renderer.draw(cam, TessSettings(max_level=4))
        covered = renderer.read_depth() < 1.0
        return renderer.read_color()[..., :3][covered]
    finally:
        renderer.release()  # the session's one context outlives this test


@pytest.mark.parametrize("seed", [5])
def test_birch_renders_pale_and_oak_dark(gl43: Any, tmp_path: Path, seed: int) -> None:
    # a context of its own, as `forest render` makes one per job: this test then does not
    # depend on what earlier tests left in the session's context (llvmpipe memory)
    ctx = create_context()
    means = {}
    try:
        for bark in ("birch", "oak"):
            g = load_preset("almond").model_copy(update={"bark": bark})
            forest = generate_forest(g, seed, ForestOptions(trees=1))
            scene = write_scene(forest, tmp_path / f"{bark}.usdc", skinned=False)
            means[bark] = _bark_pixels(ctx, scene)
    finally:
        ctx.release()
    for bark in ("birch", "oak"):
        px = means[bark]
        assert len(px) > 50
        means[bark] = px.astype(np.float64).mean(axis=0)
    assert means["birch"].mean() > means["oak"].mean() + 40, means
    r, g, b = means["birch"]
    assert b > 0.75 * r  # white, not tinted brown
