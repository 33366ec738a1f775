"""A forest whose branches end in Cap pieces (no leaf rims) renders like any other."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from forest.growth.generate import ForestOptions, generate_forest
from forest.usd.scene import write_scene
from schemas.grammar import Grammar
from tests.test_pieces_cap import CAPPED
from worker.render.render_file import RenderRequest, render_file


def test_capped_forest_renders(gl_session: Any, tmp_path: Path) -> None:
    from PIL import Image

    f = generate_forest(Grammar.model_validate(CAPPED), 5, ForestOptions(trees=2, frames=2))
    scene = write_scene(f, tmp_path / "capped.usdc")
    out = tmp_path / "capped.png"
    m = render_file(RenderRequest(scene=scene, output=out, width=96, height=72, warmup=0))
    assert m.instances == f.n_instances
    img = np.asarray(Image.open(out).convert("RGB"), np.int32)
    background = img[0, 0]
    assert (np.abs(img - background).sum(axis=-1) > 30).mean() > 0.002  # bark was drawn
