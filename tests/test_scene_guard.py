"""The upload guard (``worker.jobs.scene_guard``) on hostile scenes: each is refused with an error
that names the field (the upload's ``scene`` and the prim or attribute) and no server path,
before the reader composes anything; a real forest scene passes, and a ``.usdz`` gives up
its own bark tiles and nothing else."""

from __future__ import annotations

import zipfile
from pathlib import Path

import pytest
from pxr import Gf, Sdf, Vt

from forest.errors import SceneError
from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.usd.scene import write_scene
from worker.jobs.scene_guard import UploadCaps, check_scene_file, package_tiles

CAPS = UploadCaps(memory_bytes=3072 << 20)


def refused(path: Path, caps: UploadCaps = CAPS) -> str:
    with pytest.raises(SceneError) as info:
        check_scene_file(path, caps)
    error = str(info.value)
    assert error.startswith("scene: "), error
    assert str(path.parent) not in error and "/tmp" not in error, error
    return error


def instancer(path: Path) -> tuple[Sdf.Layer, Sdf.PrimSpec]:
    layer = Sdf.Layer.CreateNew(str(path))
    world = Sdf.PrimSpec(layer, "World", Sdf.SpecifierDef, "Xform")
    forest = Sdf.PrimSpec(world, "Forest", Sdf.SpecifierDef, "Xform")
    return layer, Sdf.PrimSpec(forest, "Pieces", Sdf.SpecifierDef, "PointInstancer")


def usda(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text("#usda 1.0\n" + text)
    return path


@pytest.fixture(scope="module")
def forest_scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("scene")
    forest = generate_forest(load_preset("alternating"), 1, ForestOptions(trees=1, frames=3))
    return write_scene(forest, folder / "scene.usdc")


def test_a_forest_scene_passes(forest_scene: Path) -> None:
    checked = check_scene_file(forest_scene, CAPS)
    assert checked.suffix == ".usdc"
    assert package_tiles(forest_scene, checked, forest_scene.parent / "t") is None


def test_time_sample_bomb(tmp_path: Path) -> None:
    samples = "".join(f"{i}: 1,\n" for i in range(20_000))
    path = usda(
        tmp_path,
        "bomb.usda",
        f'def Xform "World" {{\n double x.timeSamples = {{\n{samples}}}\n}}\n',
    )
    assert refused(path) == "scene: World.x: more than 10000 time samples in the scene"


def test_frames_are_capped_per_attribute(forest_scene: Path) -> None:
    error = refused(forest_scene, UploadCaps(frames=2))
    assert error.endswith("3 time samples (frames), over the cap of 2"), error


def test_instance_bomb_small_file_huge_array(tmp_path: Path) -> None:
    path = tmp_path / "instances.usdc"
    layer, pieces = instancer(path)
    attr = Sdf.AttributeSpec(pieces, "protoIndices", Sdf.ValueTypeNames.IntArray)
    attr.default = Vt.IntArray(3_000_000)  # zeros: a .usdc compresses them to a few KB
    layer.Save()
    assert path.stat().st_size < 100_000
    error = refused(path)
    assert error == (
        "scene: World/Forest/Pieces.protoIndices: 3000000 entries, over the cap of "
        "2000000 instances"
    )


def test_bone_bomb_and_memory_budget(tmp_path: Path) -> None:
    path = tmp_path / "bones.usdc"
    layer, pieces = instancer(path)
    attr = Sdf.AttributeSpec(pieces, "forest:bonePalette", Sdf.ValueTypeNames.Matrix4dArray)
    palette = Vt.Matrix4dArray([Gf.Matrix4d(1.0)] * 5000)
    for t in range(40):  # one value, 40 time codes: the layer stores it once
        layer.SetTimeSample(attr.path, float(t), palette)
    layer.Save()
    where = "scene: World/Forest/Pieces.forest:bonePalette"
    assert refused(path, UploadCaps(bones=4000)) == f"{where}: 5000 bones, over the cap of 4000"
    # 40 samples of 5000 matrices decode to 24.4 MiB: refused after the first one
    error = refused(path, UploadCaps(memory_bytes=48 << 20))
    assert error == (
        f"{where}: the scene's values decode to more than 24 MiB, half the job's memory limit"
    )
    check_scene_file(path, UploadCaps(memory_bytes=50 << 20))


def test_any_array_is_bounded(tmp_path: Path) -> None:
    path = usda(tmp_path, "mesh.usda", 'def Mesh "M" {\n int[] faceVertexCounts = [4, 4, 4]\n}\n')
    error = refused(path, UploadCaps(instances=0))
    assert error == "scene: M.faceVertexCounts: 3 values, over the cap of 0"


@pytest.mark.parametrize(
    ("text", "what"),
    [
        ("(\n subLayers = [@/etc/hosts.usda@]\n)\n", "sublayer '/etc/hosts.usda'"),
        # another job's scene in the artifact store, by absolute and by relative path
        ('def "W" (references = @/srv/forest/artifacts/ab/scene.usdc@) {}\n', "W: reference"),
        ('def "W" (references = @../ab12/scene.usdc@</World>) {}\n', "W: reference"),
        ('def "W" (payload = @./other.usdc@) {}\n', "W: payload"),
        (
            'def "W" (clips = {dictionary c = {asset[] assetPaths = [@/x.usd@]}}) {}\n',
            "W: value clips",
        ),
        ('def Shader "S" {\n asset inputs:file = @/etc/bark.<UDIM>.png@\n}\n', "S.inputs:file"),
        ('def Shader "S" {\n asset inputs:file = @../bark.<UDIM>.png@\n}\n', "S.inputs:file"),
        ('def Shader "S" {\n asset inputs:file = @https://x.example/a.png@\n}\n', "S.inputs:file"),
    ],
)
def test_nothing_outside_the_upload(tmp_path: Path, text: str, what: str) -> None:
    error = refused(usda(tmp_path, "scene.usda", text))
    assert error.startswith(f"scene: {what}"), error
    assert "self-contained" in error or "leaves the upload" in error, error


def package(tmp_path: Path, members: dict[str, bytes], stored: bool = True) -> Path:
    path = tmp_path / "scene.usdz"
    kind = zipfile.ZIP_STORED if stored else zipfile.ZIP_DEFLATED
    with zipfile.ZipFile(path, "w", kind) as z:
        for name, data in members.items():
            z.writestr(name, data)
    return path


SHADER = b'#usda 1.0\ndef Shader "S" {\n asset inputs:file = @%s@\n}\n'


def test_usdz_texture_path_climbing_out(tmp_path: Path) -> None:
    path = package(tmp_path, {"scene.usda": SHADER % b"../tiles/bark.<UDIM>.png"})
    error = refused(path)
    assert error.startswith("scene: S.inputs:file: asset path '../tiles/bark.<UDIM>.png'"), error


@pytest.mark.parametrize(
    ("members", "stored", "what"),
    [
        ({"scene.usda": b"#usda 1.0\n", "../x.png": b"x"}, True, "leaves the package"),
        ({"scene.usda": b"#usda 1.0\n", "x.png": b"x" * 100}, False, "is compressed"),
        ({"scene.usda": b"#usda 1.0\n", "more.usdc": b"PXR-USDC"}, True, "a second layer"),
        ({"x.png": b"x"}, True, "starts with its root layer"),
    ],
)
def test_usdz_members(tmp_path: Path, members: dict[str, bytes], stored: bool, what: str) -> None:
    assert what in refused(package(tmp_path, members, stored))


def test_usdz_gives_up_its_own_tiles_only(tmp_path: Path) -> None:
    path = package(
        tmp_path,
        {
            "scene.usda": SHADER % b"./t/bark.<UDIM>.png",
            "t/bark.1001.png": b"one",
            "t/bark.1002.png": b"two",
            "u/bark.1003.png": b"not the material's folder",
        },
    )
    checked = check_scene_file(path, CAPS)
    assert checked.assets == ("./t/bark.<UDIM>.png",)
    folder = package_tiles(path, checked, tmp_path / "tiles")
    assert folder is not None
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == {
        "bark.1001.png": b"one", "bark.1002.png": b"two",
    }  # fmt: skip


def test_not_usd(tmp_path: Path) -> None:
    path = tmp_path / "x.usdc"
    path.write_bytes(b"\x7fELF not a scene")
    assert refused(path) == "scene: not a USD file (.usda, .usdc or .usdz)"
    path.write_bytes(b"PXR-USDC" + b"\0" * 64)  # the magic, then nothing USD can read
    assert refused(path).startswith("scene: not a readable USD file")
