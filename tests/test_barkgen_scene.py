"""Species bark wiring: a grammar's ``bark`` names a shipped tile set; the scene's bark
material carries it (``forest:barkTileSet``) with the set's mean colour as its flat colour,
and the renderer loads that set when no tile folder is given."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pxr import Usd, UsdShade

from forest.bark.tilesets import SETS, mean_colour, set_dir
from forest.errors import GrammarError
from forest.growth.compile import compile_grammar
from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.usd.contract import BARK_TILE_SET
from forest.usd.read import read_scene
from forest.usd.scene import write_scene
from schemas.grammar import Grammar
from schemas.tileset import DEFAULT_MANIFEST
from worker.render.textures import tile_images


def _grammar(bark: str) -> Grammar:
    return load_preset("almond").model_copy(update={"bark": bark})


@pytest.fixture(scope="module")
def birch_scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    forest = generate_forest(_grammar("birch"), 3, ForestOptions(trees=1))
    return write_scene(forest, tmp_path_factory.mktemp("birch") / "birch.usda")


def test_unknown_bark_is_a_grammar_error_on_bark() -> None:
    with pytest.raises(GrammarError) as err:
        compile_grammar(_grammar("baobab"))
    assert err.value.path == "bark" and "birch" in str(err.value)


def test_every_shipped_set_compiles() -> None:
    """The names a grammar's ``bark`` accepts are exactly the sets shipped on disk, and each
    compiles into the grammar the scene is written from."""
    on_disk = {p.parent.name for p in set_dir(SETS[0]).parent.glob("*/manifest.json")}
    assert on_disk == set(SETS)
    for name in SETS:
        assert compile_grammar(_grammar(name)).grammar.bark == name


def test_scene_names_the_set_and_its_mean_colour(birch_scene: Path) -> None:
    stage = Usd.Stage.Open(str(birch_scene))
    mat = stage.GetPrimAtPath("/World/Looks/Bark")
    assert mat.GetAttribute(BARK_TILE_SET).Get() == "birch"
    surface = UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/Bark/Surface"))
    # textured by default: the tiles' texture, the set's mean colour as its fallback
    (source,) = surface.GetInput("diffuseColor").GetConnectedSources()[0]
    colour = np.array(source.source.GetInput("fallback").Get())[:3]
    assert np.allclose(colour, mean_colour("birch"), atol=1e-6)
    assert colour.min() > 0.4  # pale: birch is white (linear RGB)
    assert max(mean_colour("oak")) < 0.3


def test_renderer_loads_the_named_set(birch_scene: Path) -> None:
    scene = read_scene(birch_scene)
    assert scene.bark_tile_set == "birch" and scene.tile_folder is None
    images = tile_images(scene.manifest, None, scene.tile_folder, bark=scene.bark_tile_set)
    assert "birch" in images.source
    # pale slices bound, not the default's brown (the black foot's slices come after)
    assert images.slices[: DEFAULT_MANIFEST.n_slices, ..., :3].mean() > 170
    # an explicit tile folder (``forest generate --tiles``) still wins; one without the lower
    # trunk's slices shows its bark there too
    oak = tile_images(scene.manifest, set_dir("oak"), scene.tile_folder, bark="birch")
    assert "oak" in oak.source and oak.slices[..., :3].mean() < 140
    n = DEFAULT_MANIFEST.n_slices
    assert oak.n_slices == scene.manifest.n_slices > n
    assert np.array_equal(oak.slices[n : n + 8], oak.slices[:8])  # lower bark: oak's bark
    assert np.array_equal(oak.slices[n + 8 : n + 12], oak.slices[8:12])  # and fork


def test_generate_with_tiles_folder_keeps_working(tmp_path: Path) -> None:
    tiles = tmp_path / "tiles"
    tiles.mkdir()
    for f in set_dir("pine").iterdir():
        (tiles / f.name).write_bytes(f.read_bytes())
    forest = generate_forest(_grammar("birch"), 3, ForestOptions(trees=1))
    path = write_scene(forest, tmp_path / "s.usda", tiles="tiles")
    scene = read_scene(path)
    assert scene.tile_folder == tiles and scene.bark_tile_set == "birch"
    images = tile_images(scene.manifest, None, scene.tile_folder, bark=scene.bark_tile_set)
    assert "tiles" in images.source and "birch" not in images.source
