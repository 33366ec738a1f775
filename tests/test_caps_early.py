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
from forest.growth.presets import load_preset, preset_names
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


def never_expands(tmp_path: Path) -> dict[str, str]:
    """The environment of a CLI run whose forest expansion fails (a sitecustomize replaces
    it): a refusal under it was made before any tree grew."""
    hook = tmp_path / "hook"
    hook.mkdir()
    (hook / "sitecustomize.py").write_text(
        "import forest.growth.generate as g\n"
        "def _never(*a, **k):\n"
        "    raise SystemExit('expanded')\n"
        "g.expand_in_groups = _never\n"
    )
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(hook), str(ROOT)])}


def test_cli_refuses_a_glb_over_the_vertex_cap_before_growing(tmp_path: Path) -> None:
    """The CLI compiles and checks before it grows: a sitecustomize makes expansion fail."""
    env = never_expands(tmp_path)
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


@pytest.mark.parametrize("preset", preset_names())
def test_every_preset_estimate_near_its_grown_counts(preset: str) -> None:
    """Honest estimates: 10 grown trees' pieces, bones and baked vertices are 0.7-1.2 of the
    estimate (2026-11-27, seed 3: 0.87-1.03; a grammar counted level by level, as
    ``uniform``, spreads most between single trees)."""
    g = load_preset(preset)
    cg = compile_grammar(g)
    f = generate_forest(g, 3, ForestOptions(trees=10), compiled=cg)
    ratios = {
        "pieces": f.n_instances / (cg.expected_pieces * 10),
        "bones": len(f.bones) / (caps.expected_bones(cg) * 10),
        "vertices": baked_vertices(f) / (caps.expected_vertices(cg) * 10),
    }
    assert all(0.7 <= r <= 1.2 for r in ratios.values()), ratios


def _mixed_stand(trees: int, side: float) -> Any:
    from forest.stand.generate import plan_stand
    from forest.stand.recipes import load_recipe

    return plan_stand(load_recipe("mixed-broadleaf"), trees, (side, side), 1)


def test_stand_layers_estimated_at_their_sizes() -> None:
    """A mixed stand's layers are estimated at their trees' sizes: each layer's grown bones
    0.7-1.05 of its estimate, the stand's baked vertices 0.75-1.05 (a young oak, about 0.3 of
    a mature one, grows a sixth of its bones: estimated as mature, the young layer's bones
    came to 0.16 of the estimate and the stand's vertices to 0.66)."""
    stand = _mixed_stand(20, 100.0)
    grown = estimated = 0.0
    for k, cg in enumerate(stand.estimates()):
        n = len(stand.placement.layers[k])
        f = stand.grow_layer(k, ForestOptions(trees=1))
        assert f is not None
        assert 0.7 <= len(f.bones) / (caps.expected_bones(cg) * n) <= 1.05, k
        grown += baked_vertices(f)
        estimated += caps.expected_vertices(cg) * n
    assert 0.75 <= grown / estimated <= 1.05, grown / estimated


def test_stand_refused_before_its_first_layer_grows(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every layer is checked before any grows: a cap only the last layer is over refuses
    the stand without growing the first (it was grown and written, then the last refused)."""
    stand = _mixed_stand(20, 100.0)
    counts = [len(t) for t in stand.placement.layers]
    names = [layer.name for layer in stand.recipe.layers]
    bones = [caps.expected_bones(cg) * n for cg, n in zip(stand.estimates(), counts, strict=True)]
    worst = int(np.argmax(bones))
    cap = int(sorted(bones)[-2] * 24) + 1  # every layer but the largest within it
    monkeypatch.setattr(generate, "expand_in_groups", never_expand)
    with pytest.raises(LimitError) as err:
        caps.check_layers(
            stand.estimates(), counts, names, 24, ForestSettings(max_palette_matrices=cap)
        )
    assert err.value.path == "max_palette_matrices"
    assert err.value.message.startswith(f"layer {names[worst]!r}: ")
    # and within the caps it passes: 20 trees of it write a .glb (6.0 M vertices grown)
    caps.check_layers(stand.estimates(), counts, names, 24, ForestSettings(), glb=True)


def test_cli_refuses_a_stand_before_growing(tmp_path: Path) -> None:
    """``forest generate --recipe``: a .glb over the vertex cap (summed over the layers), a
    scene whose oak layer is over the palette cap and a tiled one whose fullest oak tile is,
    refused before any layer (or tile) grows."""
    env = never_expands(tmp_path)
    for args, said in (
        (["--trees", "200", "-o", "st.glb"], "glTF cap"),
        (["--trees", "3000", "--frames", "24", "-o", "st.usdc"], "max_palette_matrices"),
        # tiled: the fullest tile of its oak layer (251 of its 900 oaks in a 200 m tile)
        (
            ["--trees", "3000", "--frames", "80", "--tile-size", "200", "-o", "st.usdc"],
            "max_palette_matrices",
        ),
    ):
        out = subprocess.run(
            [sys.executable, "-m", "cli", "generate", "--recipe", "mixed-broadleaf", "-q",
             "--area", "400", "400", *args],
            cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert out.returncode == 2, out.stderr
        assert "expanded" not in out.stderr and said in out.stderr, out.stderr
    assert not list(tmp_path.glob("st*"))


def test_largest_tile_counts_as_the_tiles_cut_the_layers() -> None:
    """A tiled stand's layers are checked on their fullest tile, counted as the tiles cut
    them (:meth:`forest.stand.place.LayerTrees.within`)."""
    from forest.usd import stand as usd_stand

    stand = _mixed_stand(200, 150.0)
    size = 40.0  # 4 x 4 tiles, the last row and column narrower
    nx, nz = 4, 4
    tiles = [(i, j) for i in range(nx) for j in range(nz)]
    want = []
    for t in stand.placement.layers:
        cut = [
            t.within(usd_stand._rect(stand.area, size, i, j),
                     usd_stand._closed(stand.area, size, i, j), stand.area)
            for i, j in tiles
        ]  # fmt: skip
        want.append(max(len(c) for c in cut))
    assert usd_stand.largest_tile_counts(stand, size) == want
    assert 0 < max(want) < max(len(t) for t in stand.placement.layers)


def test_stand_glb_vertices_are_counted_as_the_profile_writes_them() -> None:
    """A stand's .glb is written with the game profile by default: 60 oaks fit the cap as
    game levels (about 0.23 M vertices a tree) and not in the film form (0.57 M)."""
    cg = compile_grammar(load_preset("oak"))
    settings = ForestSettings()
    caps.check_layers([cg], [60], ["oak"], 0, settings, glb=True)
    with pytest.raises(LimitError, match="glTF cap"):
        caps.check_layers([cg], [60], ["oak"], 0, settings, glb=True, profile="film")
