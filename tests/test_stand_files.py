"""A stand's files as a job hands them back (issue "mixed-forests", the API half): layer files
beside the root layer (one folder of plain names, as a job's artifacts are), the stand as one
file (flattened, or a .usdz with its pictures), and the cheap check of a recipe's images that
the service runs before any job."""

from __future__ import annotations

import zipfile
from pathlib import Path

import OpenImageIO as oiio
import pytest
from pxr import Usd

from forest.bark.images import check_grey, read_grey
from forest.errors import ForestError
from forest.growth.generate import ForestOptions
from forest.stand.generate import plan_stand
from forest.stand.recipes import LoadedRecipe, recipe_from_object
from forest.usd.contract import STAND_LAYERS
from forest.usd.stand import layer_file, read_stand, stand_file, write_stand

GLADE = Path(__file__).resolve().parents[1] / "forest" / "stand" / "builtin" / "glade.png"
SMALL = {
    "layers": [
        {"name": "almond", "preset": "almond", "share": 0.5},
        {"name": "hazel", "preset": "hazel", "share": 0.5, "role": "understorey"},
    ],
    "terrain": {"seed": 1, "relief": 2.0},
}


def _stand(out: Path, beside: bool, textures: bool = False) -> Path:
    stand = plan_stand(LoadedRecipe(recipe_from_object(SMALL), None), 2, (16.0, 16.0), 4)
    opts = ForestOptions(area=(16.0, 16.0))
    return write_stand(stand, out, opts, skinned=False, textures=textures, beside=beside)


def _prims(stage: Usd.Stage) -> list[str]:
    return sorted(str(p.GetPath()) for p in stage.Traverse())


def test_layer_files_beside_the_root(tmp_path: Path) -> None:
    root = _stand(tmp_path / "scene.usdc", beside=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "scene.usdc",
        "scene_almond.usdc",
        "scene_hazel.usdc",
    ]
    assert layer_file(root, "hazel", True) == tmp_path / "scene_hazel.usdc"
    assert [f.files for f in read_stand(root).layers] == [
        (tmp_path / "scene_almond.usdc",),
        (tmp_path / "scene_hazel.usdc",),
    ]
    # moved elsewhere together (downloaded into another folder), they still compose
    other = tmp_path / "elsewhere"
    other.mkdir()
    for p in tmp_path.glob("scene*.usdc"):
        p.rename(other / p.name)
    stage = Usd.Stage.Open(str(other / "scene.usdc"))
    assert len(list(Usd.PrimRange(stage.GetPrimAtPath(f"{STAND_LAYERS}/hazel")))) > 3


def test_flattened_stand_is_the_composed_stand(tmp_path: Path) -> None:
    root = _stand(tmp_path / "scene.usdc", beside=True)
    flat = stand_file(root, tmp_path / "one.usdc")
    one = Usd.Stage.Open(str(flat))
    assert not one.GetRootLayer().GetExternalReferences()  # it names no other file
    assert _prims(one) == _prims(Usd.Stage.Open(str(root)))


def test_usdz_carries_the_layers_and_pictures(tmp_path: Path) -> None:
    (tmp_path / "parts").mkdir()
    root = _stand(tmp_path / "parts" / "stand.usdc", beside=False, textures=True)
    out = stand_file(root, tmp_path / "stand.usdz")
    names = zipfile.ZipFile(out).namelist()
    assert names[0] == "stand.usdc"
    assert {"stand_layers/almond.usdc", "stand_layers/hazel.usdc"} <= set(names)
    assert any(n.startswith("stand_layers/almond.textures/bark.") for n in names), names
    assert _prims(Usd.Stage.Open(str(out))) == _prims(Usd.Stage.Open(str(root)))


def test_check_grey_reads_what_read_grey_reads() -> None:
    data = GLADE.read_bytes()
    assert check_grey(data, "m") == read_grey(data, "m").shape[::-1]


@pytest.mark.parametrize(
    ("cut", "words"),
    [
        (lambda d: d[: len(d) // 2], "truncated or corrupt"),
        (lambda d: d[:40], "not a readable image"),
        (lambda d: b"plain text, not a picture", "not a PNG"),
        (lambda d: b"", "empty"),
    ],
)
def test_check_grey_refuses_what_does_not_read(cut: object, words: str) -> None:
    data = cut(GLADE.read_bytes())  # type: ignore[operator]
    with pytest.raises(ForestError) as exc:
        check_grey(data, "recipe.layers[0].density_map")
    assert exc.value.path == "recipe.layers[0].density_map"
    assert words in exc.value.message


def test_check_grey_refuses_too_many_pixels_from_the_header(tmp_path: Path) -> None:
    # 5000 x 5000 of one value: a few KB of PNG, 25 M pixels
    path = tmp_path / "wide.png"
    oiio.ImageBuf(oiio.ImageSpec(5000, 5000, 1, "uint8")).write(str(path))
    data = path.read_bytes()
    assert len(data) < 100_000
    with pytest.raises(ForestError, match="more than the"):
        check_grey(data, "m")
