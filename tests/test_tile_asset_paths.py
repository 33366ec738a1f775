"""Bark tile paths anchored to the layer (issue 14.4, first half): a scene's material names its
tiles ``./tiles/bark.<UDIM>.png``, which USD resolves against the layer's folder whatever the
working directory; a bare ``tiles/...`` is a search path that Blender resolved against the
working directory instead."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from pxr import Ar, Sdf, Usd

from forest.bark.tilesets import default_dir
from forest.growth.generate import Forest, ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.usd.contract import BARK_TILES
from forest.usd.materials import tile_asset_path
from forest.usd.read import read_scene
from forest.usd.scene import write_scene
from schemas.tileset import UDIM_TOKEN


@pytest.fixture(scope="module")
def small_forest() -> Forest:
    return generate_forest(load_preset("uniform"), 5, ForestOptions(trees=1, frames=1))


@pytest.mark.parametrize(
    ("tiles", "expected"),
    [
        ("tiles", "./tiles/bark.<UDIM>.png"),
        ("tiles/", "./tiles/bark.<UDIM>.png"),
        ("a/b", "./a/b/bark.<UDIM>.png"),
        ("./tiles", "./tiles/bark.<UDIM>.png"),
        ("../shared/tiles", "../shared/tiles/bark.<UDIM>.png"),
        (".", "./bark.<UDIM>.png"),
        ("/abs/tiles", "/abs/tiles/bark.<UDIM>.png"),
        # URLs are for an asset resolver: kept whole, never "./http://..." (issue 26.9)
        ("http://cdn.example/tiles", "http://cdn.example/tiles/bark.<UDIM>.png"),
        ("s3+https://b/t/", "s3+https://b/t/bark.<UDIM>.png"),
    ],
)
def test_tile_asset_path_is_anchored(tiles: str, expected: str) -> None:
    assert tile_asset_path(tiles) == expected


@pytest.mark.parametrize("suffix", [".usda", ".usdc"])
def test_tiles_resolve_beside_the_layer_from_another_working_directory(
    small_forest: Forest, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, suffix: str
) -> None:
    scene_dir, elsewhere = tmp_path / "scene", tmp_path / "elsewhere"
    for d in (scene_dir / "tiles", elsewhere / "tiles"):
        d.mkdir(parents=True)
        # a decoy beside the working directory: resolving against it would be the bug
        shutil.copy(default_dir() / "bark.1001.png", d / "bark.1001.png")
    scene = write_scene(small_forest, scene_dir / f"forest{suffix}", tiles="tiles")
    monkeypatch.chdir(elsewhere)

    stage = Usd.Stage.Open(str(scene))
    asset = stage.GetPrimAtPath(BARK_TILES).GetAttribute("inputs:file").Get()
    assert asset.path == "./tiles/bark.<UDIM>.png"
    anchored = Sdf.ComputeAssetPathRelativeToLayer(stage.GetRootLayer(), asset.path)
    first = anchored.replace(UDIM_TOKEN, "1001")
    resolved = Ar.GetResolver().Resolve(first)
    assert resolved and Path(str(resolved)) == scene_dir / "tiles" / "bark.1001.png"
    assert Path(str(resolved)).is_file()
    assert read_scene(scene).tile_folder == scene_dir / "tiles"


def test_a_user_folder_named_like_a_texture_folder_is_still_read(
    small_forest: Forest, tmp_path: Path
) -> None:
    """The writer flags its own copy of the shipped set (``forest:barkTilesShipped``), so a
    tile folder of the user's whose name ends in ``.textures`` is read as given, and the
    copy in ``<stem>.textures/`` is not (the renderer reads the shipped set itself)."""
    mine = tmp_path / "mine.textures"
    mine.mkdir()
    shutil.copy(default_dir() / "bark.1001.png", mine / "bark.1001.png")
    given = write_scene(small_forest, tmp_path / "given.usdc", tiles="mine.textures")
    assert read_scene(given).tile_folder == mine
    shipped = write_scene(small_forest, tmp_path / "own.usdc")
    assert (tmp_path / "own.textures" / "bark.1001.png").is_file()
    assert read_scene(shipped).tile_folder is None
