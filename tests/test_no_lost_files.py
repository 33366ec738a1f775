"""No write touches a file but the one named (issue 14.1): every writer (USD in each format,
the CLI, tile sets, render previews and metrics, the service's artifacts) stages its output
in a private folder beside the target and renames it over the target; a failed write leaves
the old output byte-identical and no temporaries behind."""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from pxr import Usd, UsdShade, UsdUtils

import forest.usd.files
import forest.usd.scene
from bench.tiles import procedural_examples
from cli import main
from farm.artifacts import ArtifactStore
from forest.atomic import all_replaced_when_written, replaced_when_written, write_text
from forest.bark import tileset as tileset_mod
from forest.bark.tileset import TileGeometry, build_tileset, default_classes, write_tileset
from forest.errors import OutputError, SceneError
from forest.growth.generate import Forest, ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.usd.contract import BARK_TILES
from forest.usd.files import FORMATS
from forest.usd.read import read_scene
from forest.usd.scene import write_scene
from tests.helpers_lod import impostor_pictures

STEM = "forest"


@pytest.fixture(scope="module")
def small_forest() -> Forest:
    return generate_forest(load_preset("uniform"), 5, ForestOptions(trees=1, frames=2))


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (recursively, hidden ones too) -> its bytes."""
    return {
        str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


def entries(folder: Path) -> set[str]:
    """Every name under ``folder``, folders included: a leftover private folder shows."""
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


def neighbours(folder: Path) -> dict[str, bytes]:
    """A file of every format with the scene's stem and with another stem, plus a PNG and a
    name like the old fixed temporaries (``.forest.tmp.usdc``), each with distinct bytes."""
    made = {}
    for stem in (STEM, "other", f".{STEM}.tmp"):
        for suffix in (*FORMATS, ".png"):
            name = f"{stem}{suffix}"
            made[name] = f"existing {name}\n".encode()
            (folder / name).write_bytes(made[name])
    return made


# --- USD, every format -------------------------------------------------------------------


@pytest.mark.parametrize("suffix", FORMATS)
def test_writing_a_format_leaves_every_other_file_alone(
    small_forest: Forest, tmp_path: Path, suffix: str
) -> None:
    before = neighbours(tmp_path)
    target = f"{STEM}{suffix}"
    write_scene(small_forest, tmp_path / target, skinned=True)
    after = snapshot(tmp_path)
    # nothing new but the target (which existed) and, beside a .usda/.usdc, its pictures
    pictures = {n for n in set(after) - set(before) if n.startswith(f"{STEM}.textures/")}
    assert bool(pictures) == (suffix != ".usdz")
    assert set(after) == set(before) | pictures
    for name, data in before.items():
        if name != target:
            assert after[name] == data, f"{name} was touched writing {target}"
    assert after[target] != before[target]
    if suffix == ".usdz":  # the skinned trees only: nothing the reader rebuilds pieces from
        Usd.Stage.Open(str(tmp_path / target))
    else:
        read_scene(tmp_path / target)


@pytest.mark.parametrize("suffix", FORMATS)
def test_writing_over_the_same_name_replaces_it_atomically(
    small_forest: Forest, tmp_path: Path, suffix: str
) -> None:
    target = tmp_path / f"{STEM}{suffix}"
    target.write_bytes(b"old scene")
    old_inode = target.stat().st_ino
    with open(target, "rb") as reader:  # a reader that opened the old file keeps it whole
        write_scene(small_forest, target)
        assert reader.read() == b"old scene"
    assert target.stat().st_ino != old_inode  # a rename, not a rewrite in place
    others = entries(tmp_path) - {target.name}
    if suffix == ".usdz":
        assert others == set()
        assert Usd.Stage.Open(str(target)) is not None
    else:
        assert others and all(e.startswith(f"{STEM}.textures") for e in others), others
        assert read_scene(target).seed == 5


def test_rewriting_a_scene_replaces_its_pictures_and_nothing_else(
    small_forest: Forest, tmp_path: Path
) -> None:
    """A second write of ``forest.usdc`` renames fresh pictures over the old ones, removes
    the pictures of ours the new scene does not name (another family's leaf, a slice past
    the set) and leaves a file of the user's in the folder alone; equal input, equal bytes."""
    target = tmp_path / f"{STEM}.usdc"
    write_scene(small_forest, target)
    folder = tmp_path / f"{STEM}.textures"
    first = snapshot(tmp_path)
    (folder / "leaf-needle.png").write_bytes(b"stale leaf")
    (folder / "bark.1999.png").write_bytes(b"stale tile")
    (folder / "bark.1001.png").write_bytes(b"overwritten")
    (folder / "notes.txt").write_bytes(b"mine")
    write_scene(small_forest, target)
    second = snapshot(tmp_path)
    assert second.pop(f"{STEM}.textures/notes.txt") == b"mine"
    assert second == first
    assert entries(tmp_path) == {e for e in first} | {
        f"{STEM}.textures",
        f"{STEM}.textures/notes.txt",
    }


def _raise(*_args: object, **_kwargs: object) -> None:
    raise RuntimeError("exporter failed mid-write")


@pytest.mark.parametrize("suffix", FORMATS)
@pytest.mark.parametrize(
    "where",
    [
        (forest.usd.scene, "bark_material"),  # mid-export, the layer half built
        (forest.usd.files, "_zero_zip_times"),  # usdz: after packing, before the rename
        (forest.usd.files, "move_into_place"),  # the very last step
    ],
    ids=["export", "package", "rename"],
)
def test_a_failed_write_leaves_the_old_output_and_no_temporaries(
    small_forest: Forest,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    suffix: str,
    where: tuple[object, str],
) -> None:
    if suffix != ".usdz" and where[1] == "_zero_zip_times":
        pytest.skip("only a .usdz is packed")
    before = neighbours(tmp_path)
    monkeypatch.setattr(*where, _raise)
    with pytest.raises(RuntimeError, match="exporter failed"):
        write_scene(small_forest, tmp_path / f"{STEM}{suffix}")
    assert snapshot(tmp_path) == before
    assert entries(tmp_path) == set(before)


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_an_unwritable_folder_is_an_output_error(small_forest: Forest, tmp_path: Path) -> None:
    before = neighbours(tmp_path)
    tmp_path.chmod(0o555)
    try:
        with pytest.raises(OutputError, match="not writable"):
            write_scene(small_forest, tmp_path / f"{STEM}.usdz")
    finally:
        tmp_path.chmod(0o755)
    assert snapshot(tmp_path) == before


def test_cli_generate_usdz_keeps_the_usdc_beside_it(tmp_path: Path) -> None:
    """The reported loss: ``forest generate -o X.usdz`` deleted an existing ``X.usdc``."""
    before = neighbours(tmp_path)
    out = tmp_path / f"{STEM}.usdz"
    args = ["generate", "--preset", "uniform", "--trees", "1", "--frames", "1", "-o", str(out)]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    after = snapshot(tmp_path)
    assert set(after) == set(before)
    assert all(after[n] == d for n, d in before.items() if n != out.name)
    # the layer, and the pictures it carries (nothing of the folder's own files)
    pictures = ["bark.png", "leaf-broadleaf.png", *impostor_pictures(1, packed=True)]
    assert sorted(zipfile.ZipFile(out).namelist()) == [
        f"{STEM}.usdc",
        *sorted(f"textures/{name}" for name in pictures),
    ]


def usdz_problems(path: Path) -> list[str]:
    """What USD's own checks find wrong with a .usdz: ``UsdUtils.ComplianceChecker`` without
    the ARKit rules where this USD build ships it, else every registered UsdValidation
    validator (newer builds, such as usd-core 0.26, replaced the checker with those; the
    package-layout ones among them are the checker's usdz rules)."""
    if hasattr(UsdUtils, "ComplianceChecker"):
        checker = UsdUtils.ComplianceChecker(arkit=False)
        checker.CheckCompliance(str(path))
        return [*checker.GetErrors(), *checker.GetFailedChecks()]
    from pxr import UsdValidation

    validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
    names = {v.GetMetadata().name for v in validators}
    assert "usdUtilsValidators:UsdzPackageValidator" in names
    errors = UsdValidation.ValidationContext(validators).Validate(Usd.Stage.Open(str(path)))
    return [f"{e.GetName()}: {e.GetMessage()}" for e in errors]


@pytest.mark.parametrize("skinned", [False, True])
def test_usdz_is_compliant(small_forest: Forest, tmp_path: Path, skinned: bool) -> None:
    out = write_scene(small_forest, tmp_path / f"{STEM}.usdz", skinned=skinned)
    assert usdz_problems(out) == []


def test_usdz_packs_the_atlas_of_the_tiles_beside_the_scene(
    small_forest: Forest, tmp_path: Path
) -> None:
    """The layer is written in a private folder, yet ``tiles`` means the scene's folder: the
    package holds the atlas of those tiles (no UDIM inside a package), named ``./...``."""
    from forest.bark.atlas import make_atlas, read_slices
    from forest.bark.images import read_pixels, write_png
    from forest.bark.tilesets import default_dir

    tiles = tmp_path / "tiles"
    tiles.mkdir()
    # a set of its own (the default set's slices upside down), not the shipped one
    mine = read_slices(default_dir(), small_forest.manifest.n_slices)[:, ::-1].copy()
    for k in range(len(mine)):
        write_png(tiles / f"bark.{1001 + k}.png", mine[k])
    out = write_scene(small_forest, tmp_path / f"{STEM}.usdz", tiles="tiles")
    stage = Usd.Stage.Open(str(out))
    asset = stage.GetPrimAtPath(BARK_TILES).GetAttribute("inputs:file").Get()
    assert asset.path == "./textures/bark.png"
    picture = tmp_path / "atlas.png"
    with zipfile.ZipFile(out) as z:
        picture.write_bytes(z.read("textures/bark.png"))
    np.testing.assert_array_equal(read_pixels(picture)[..., :3], make_atlas(mine))
    assert usdz_problems(out) == []
    assert {e for e in entries(tmp_path) if not e.startswith("tiles")} == {
        out.name,
        "atlas.png",
    }


def test_usdz_cuts_its_leaf_cards_with_the_picture_it_carries(
    small_forest: Forest, tmp_path: Path
) -> None:
    """In a .usdz both leaf materials take opacity from the leaf picture (threshold 0.5), a
    PNG inside the package whose bottom row is the cards' t = 0 (the stem end); a .usdc
    written without textures binds no texture, points at none and writes no folder."""
    import OpenImageIO as oiio

    from forest.growth.foliage import leaf_texture

    out = write_scene(small_forest, tmp_path / f"{STEM}.usdz")
    stage = Usd.Stage.Open(str(out))
    for name in ("Leaf", "LeafTinted"):
        surface = UsdShade.Shader(stage.GetPrimAtPath(f"/World/Looks/{name}/Surface"))
        assert surface.GetInput("opacityThreshold").Get() == 0.5
        (link,) = surface.GetInput("opacity").GetConnectedSources()[0]
        source = link.source
        assert link.sourceName == "a"
        assert source.GetPrim().GetAttribute("info:id").Get() == "UsdUVTexture"
        asset = source.GetPrim().GetAttribute("inputs:file").Get()
        assert not os.path.isabs(asset.path) and "[" in asset.resolvedPath  # inside the package
    picture = tmp_path / "leaf.png"
    assert asset.path.startswith("./")  # Blender finds nothing in a package otherwise
    with zipfile.ZipFile(out) as z:
        picture.write_bytes(z.read(asset.path.removeprefix("./")))
    pixels = oiio.ImageBuf(str(picture)).get_pixels(oiio.UINT8)
    alpha = leaf_texture(small_forest.grammar.leaves.family)[..., 3]
    assert 0 < (alpha > 0).mean() < 1  # a leaf's outline, not a square
    np.testing.assert_array_equal(pixels[::-1, :, 3], alpha)
    assert usdz_problems(out) == []

    plain = write_scene(small_forest, tmp_path / f"{STEM}.usdc", textures=False)
    stage = Usd.Stage.Open(str(plain))
    surface = UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/Leaf/Surface"))
    assert not surface.GetInput("opacity") and entries(tmp_path) == {
        out.name,
        plain.name,
        "leaf.png",
    }


# --- the atomic writer itself ------------------------------------------------------------


def test_atomic_writer_failure_and_success(tmp_path: Path) -> None:
    before = neighbours(tmp_path)
    target = tmp_path / f"{STEM}.png"
    with pytest.raises(RuntimeError), replaced_when_written(target) as tmp:
        assert tmp.name == target.name and tmp.parent.parent == tmp_path
        tmp.write_bytes(b"half")
        raise RuntimeError
    assert snapshot(tmp_path) == before and entries(tmp_path) == set(before)
    write_text(target, "new")
    assert target.read_text() == "new" and entries(tmp_path) == set(before)
    with pytest.raises(OutputError, match="cannot write"):
        write_text(tmp_path / "missing" / "x.json", "x")


def test_outputs_written_together_are_replaced_together(tmp_path: Path) -> None:
    a, b = tmp_path / "a.png", tmp_path / "b.json"
    a.write_bytes(b"old a")
    b.write_bytes(b"old b")
    with pytest.raises(OutputError) as info, all_replaced_when_written([a, b]) as (ta, tb):
        ta.write_bytes(b"new a")
        raise OutputError("encoder failed", path=str(tb))
    assert info.value.path == str(b)  # the user's name, never the private folder's
    assert (a.read_bytes(), b.read_bytes()) == (b"old a", b"old b")
    assert entries(tmp_path) == {"a.png", "b.json"}


# --- tile sets ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def tiny_sets() -> tuple[tileset_mod.TileSet, tileset_mod.TileSet]:
    ex = procedural_examples(120)
    geom = TileGeometry.for_size(40)
    return (
        build_tileset(ex, default_classes(2, 2), geom, 4),
        build_tileset(ex, default_classes(2, 2), geom, 5),
    )


def test_tile_set_writer_touches_only_its_files(
    tiny_sets: tuple[tileset_mod.TileSet, tileset_mod.TileSet], tmp_path: Path
) -> None:
    folder = tmp_path / "tiles"
    folder.mkdir()
    others = {"notes.txt": b"mine", "bark.png": b"not a slice", ".manifest.tmp.json": b"x"}
    for name, data in others.items():
        (folder / name).write_bytes(data)
    written = write_tileset(tiny_sets[0], folder)
    assert all(p.parent == folder and p.is_file() for p in written)
    after = snapshot(folder)
    assert set(after) == set(others) | {p.name for p in written}
    assert all(after[n] == d for n, d in others.items())


@pytest.mark.parametrize("fail", ["write_png", "write_texture_array", "write_text"])
def test_a_failed_tile_set_write_leaves_the_old_set(
    tiny_sets: tuple[tileset_mod.TileSet, tileset_mod.TileSet],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    fail: str,
) -> None:
    folder = tmp_path / "tiles"
    write_tileset(tiny_sets[0], folder)
    before = snapshot(folder)
    real = getattr(tileset_mod, fail)
    calls = []

    def fails_on_second(*args: object) -> object:
        calls.append(args)
        if len(calls) >= 2 or fail != "write_png":
            raise OutputError("encoder failed", path=str(args[0]))
        return real(*args)

    monkeypatch.setattr(tileset_mod, fail, fails_on_second)
    with pytest.raises(OutputError, match="encoder failed") as info:
        write_tileset(tiny_sets[1], folder)
    assert Path(info.value.path).parent == folder  # names the set's file, not the staging one
    assert snapshot(folder) == before
    assert entries(folder) == set(before)


# --- render preview + metrics ------------------------------------------------------------


@pytest.fixture(scope="module")
def gl_ok() -> None:
    from forest.gl.context import GLUnavailableError, create_context

    try:
        create_context(require=330).release()
    except GLUnavailableError as exc:
        if os.environ.get("FOREST_REQUIRE_GL") == "1":
            raise
        pytest.skip(f"no EGL context: {exc}")


@pytest.mark.parametrize("fail", [None, "write_png", "write_metrics", "render_metrics"])
def test_render_outputs_are_replaced_together_or_not_at_all(
    gl_ok: None,
    small_forest: Forest,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    fail: str | None,
) -> None:
    import worker.render.render_file
    from worker.render.render_file import RenderRequest, render_file

    (tmp_path / "scene").mkdir()
    scene = write_scene(small_forest, tmp_path / "scene" / f"{STEM}.usdc")
    tmp_path = tmp_path / "out"
    tmp_path.mkdir()
    before = neighbours(tmp_path)
    png, metrics = tmp_path / f"{STEM}.png", tmp_path / "metrics.json"
    metrics.write_bytes(b"old metrics")
    before[metrics.name] = b"old metrics"
    if fail is not None:
        monkeypatch.setattr(worker.render.render_file, fail, _raise)
    req = RenderRequest(scene=scene, output=png, metrics=metrics, width=32, height=24)
    if fail is None:
        render_file(req)
        after = snapshot(tmp_path)
        assert set(after) == set(before)
        changed = {n for n in before if after[n] != before[n]}
        assert changed == {png.name, metrics.name}
        assert after[png.name].startswith(b"\x89PNG")
    else:
        with pytest.raises(RuntimeError, match="exporter failed"):
            render_file(req)
        assert snapshot(tmp_path) == before
    assert entries(tmp_path) == set(before)


# --- the service's artifacts -------------------------------------------------------------


def test_artifact_publish_touches_only_its_name(tmp_path: Path) -> None:
    store = ArtifactStore(tmp_path / "artifacts")
    job = "0123456789abcdef0123456789abcdef"
    folder = store.folder(job)
    folder.mkdir(parents=True)
    (folder / "scene.usdc").write_bytes(b"usdc artifact")
    (folder / "scene.usdz").write_bytes(b"old usdz")
    scratch = store.scratch(job)
    (scratch / "scene.usdz").write_bytes(b"new usdz")
    store.publish(job, scratch / "scene.usdz", "scene.usdz")
    assert snapshot(folder) == {"scene.usdc": b"usdc artifact", "scene.usdz": b"new usdz"}
    assert entries(folder) == {"scene.usdc", "scene.usdz"}


def test_generated_scene_reads_back_with_its_values(small_forest: Forest, tmp_path: Path) -> None:
    """Moving the layer out of its private folder keeps it whole (same arrays as direct);
    a .usdz, which holds the skinned trees only, is refused by the reader by name."""
    for suffix in FORMATS:
        path = write_scene(small_forest, tmp_path / f"{STEM}{suffix}", textures=False)
        if suffix == ".usdz":
            with pytest.raises(SceneError, match="only the 'skinned' trees"):
                read_scene(path)
            continue
        np.testing.assert_array_equal(read_scene(path).tree, small_forest.graph.tree)
    assert entries(tmp_path) == {f"{STEM}{s}" for s in FORMATS}
