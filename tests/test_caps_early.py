"""Caps estimated from the compiled grammar before expansion (forest.caps): a forest over the
palette or the glTF vertex cap is refused without growing it, in the library and the CLI; the
estimates stay near the grown forest's counts; a still forest's posed values are authored
once each."""

from __future__ import annotations

import os
import subprocess
import sys
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pygltflib as gl
import pytest
from pxr import Usd

from forest import caps
from forest.errors import LimitError
from forest.gltf.document import baked_vertices, write_glb
from forest.growth import generate
from forest.growth.compile import compile_grammar
from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.settings import ForestSettings
from forest.usd.contract import PIECES
from forest.usd.read import read_scene
from forest.usd.scene import write_scene

ROOT = Path(__file__).resolve().parents[1]


def never_expand(*args: Any, **kwargs: Any) -> Any:
    raise AssertionError("expanded a forest its caps refuse")


def test_palette_cap_refused_before_expansion(monkeypatch: pytest.MonkeyPatch) -> None:
    """The issue's 1,000 oaks x 24 frames: refused from the estimate, never grown."""
    cg = compile_grammar(load_preset("oak"))
    monkeypatch.setattr(generate, "expand_in_groups", never_expand)
    with pytest.raises(LimitError) as err:
        generate_forest(load_preset("oak"), 1, ForestOptions(trees=1000, frames=24), compiled=cg)
    assert err.value.path == "max_palette_matrices"
    assert err.value.limit == 50_000_000
    assert "use fewer frames or trees" in err.value.message


def test_palette_estimate_bounds_the_grown_forest() -> None:
    """A cap between the grown forest's palette and the estimate: refused before expansion;
    the estimate is within 15 % above the forest's bones (an upper bound here)."""
    g = load_preset("hazel")
    cg = compile_grammar(g)
    f = generate_forest(g, 3, ForestOptions(trees=10), compiled=cg)
    estimate = caps.expected_bones(cg) * 10
    assert len(f.bones) <= estimate <= 1.15 * len(f.bones)
    settings = ForestSettings(max_palette_matrices=int(estimate) - 1)
    with pytest.raises(LimitError) as err:
        generate_forest(g, 3, ForestOptions(trees=10), settings=settings, compiled=cg)
    assert err.value.path == "max_palette_matrices"


@pytest.mark.parametrize("preset", ["alternating", "oak"])
def test_vertex_estimate_near_the_baked_count(preset: str) -> None:
    g = load_preset(preset)
    cg = compile_grammar(g)
    f = generate_forest(g, 2, ForestOptions(trees=10), compiled=cg)
    ratio = baked_vertices(f) / (caps.expected_vertices(cg) * 10)
    assert 0.8 <= ratio <= 1.05, ratio


def test_close_tips_counted_from_a_sample() -> None:
    """Caps and finishing chains, which counting by depth cannot see, are in the kinds."""
    g = load_preset("alternating").model_copy(update={"close_tips": True})
    cg = compile_grammar(g)
    f = generate_forest(g, 1, ForestOptions(trees=20), compiled=cg)
    assert 0.8 <= len(f.bones) / (caps.expected_bones(cg) * 20) <= 1.0


def test_game_vertex_estimate_near_the_written_count(tmp_path: Path) -> None:
    """The game profile's estimate counts what its levels write (welded LOD0 bark, each
    level's leaf cards), with its margin: 0.89 of it over every preset (2026-11-27)."""
    f = generate_forest(load_preset("oak"), 3, ForestOptions(trees=1))
    path = write_glb(f, tmp_path / "oak.glb", impostor=False)
    doc = gl.GLTF2.load(str(path))
    positions = {p.attributes.POSITION for m in doc.meshes for p in m.primitives}
    written = sum(doc.accessors[a].count for a in positions)
    assert 0.85 <= written / baked_vertices(f, "game") <= 1.0
    assert baked_vertices(f, "game") < 0.5 * baked_vertices(f, "film")


def test_glb_vertex_cap_refused_before_expansion() -> None:
    cg = compile_grammar(load_preset("oak"))
    caps.check_glb_vertices(cg, 100)  # 100 oaks write as game (about 21 M vertices)
    for trees, profile in ((100, "film"), (1000, "game")):
        with pytest.raises(LimitError) as err:
            caps.check_glb_vertices(cg, trees, profile=profile)
        assert err.value.path == "trees" and "glTF cap" in err.value.message
    caps.check_glb_vertices(cg, 40, profile="film")  # 40 film oaks (about 23 M vertices)


def test_cli_refuses_a_glb_over_the_vertex_cap_before_growing(tmp_path: Path) -> None:
    """The CLI compiles and checks before it grows: a sitecustomize makes expansion fail."""
    hook = tmp_path / "hook"
    hook.mkdir()
    (hook / "sitecustomize.py").write_text(
        "import forest.growth.generate as g\n"
        "def _never(*a, **k):\n"
        "    raise SystemExit('expanded')\n"
        "g.expand_in_groups = _never\n"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(hook), str(ROOT)])}
    for args in (
        ["--trees", "1000", "-o", "f.glb"],
        ["--trees", "100", "--profile", "film", "-o", "f.glb"],
        ["--trees", "1000", "--frames", "24", "-o", "f.usdc"],
    ):
        out = subprocess.run(
            [sys.executable, "-m", "cli", "generate", "--preset", "oak", "-q", *args],
            cwd=tmp_path,
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert out.returncode == 2, out.stderr
        assert "expanded" not in out.stderr
        assert ("glTF cap" in out.stderr) or ("max_palette_matrices" in out.stderr), out.stderr
    assert not list(tmp_path.glob("f.*"))


def test_still_forest_posed_values_authored_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Every attribute is set at most once per time (a still forest's first sample is its
    default: it was authored twice); the file reads back as the forest."""
    f = generate_forest(load_preset("alternating"), 5, ForestOptions(trees=4))
    seen: Counter[tuple[str, str]] = Counter()
    original = Usd.Attribute.Set

    def counting(self: Usd.Attribute, value: Any, *time: Any) -> Any:
        seen[(str(self.GetPath()), str(time[0] if time else Usd.TimeCode.Default()))] += 1
        return original(self, value, *time)

    monkeypatch.setattr(Usd.Attribute, "Set", counting)
    path = write_scene(f, tmp_path / "still.usdc", skinned=False)
    monkeypatch.undo()
    twice = {k: n for k, n in seen.items() if n > 1}
    assert not twice, twice
    assert any("positions" in p for p, _ in seen)
    stage = Usd.Stage.Open(str(path))
    for attr in stage.GetPrimAtPath(PIECES).GetAttributes():
        assert not attr.GetTimeSamples(), attr.GetPath()
    scene = read_scene(path)
    assert scene.times == [None]
    np.testing.assert_array_equal(scene.proto_indices, f.graph.piece)
    np.testing.assert_allclose(scene.palette(0), f.palette(), atol=1e-5)
