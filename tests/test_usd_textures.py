"""USD scenes textured by default (issue 24.1, 24.5): a .usda/.usdc names the species' bark
tiles and the leaf picture in ``<stem>.textures/`` by ``./`` paths that resolve from any
working directory; a .usdz carries a bark atlas and the leaf picture under ``./`` names,
holds the skinned trees only and passes ``usdchecker --arkit``; leaf cards are cut by alpha
in every form; ``--no-textures`` keeps flat colours and writes no folder."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from pxr import Ar, Sdf, Usd, UsdGeom, UsdShade

from cli import main
from forest.bark.atlas import atlas_uv, slice_files
from forest.bark.tilesets import set_dir
from forest.growth.generate import Forest, ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.usd.contract import FOREST, REPRESENTATION, SKINNED, TREES
from forest.usd.scene import write_scene
from forest.usd.textures import TILE_INSET
from schemas.tileset import UDIM_TOKEN
from tests.helpers_lod import impostor_pictures

ROOT = Path(__file__).resolve().parents[1]
ARKIT_CHECK = ROOT / "tests" / "usdz_arkit_check.py"
# a Python whose pxr still has UsdUtils.ComplianceChecker (usd-core 25.x; 26.x removed it):
# FOREST_ARKIT_PYTHON, else .venv-arkit's (tests/setup_arkit_venv.sh, run by `make test`)
ARKIT_PYTHON = Path(
    os.environ.get("FOREST_ARKIT_PYTHON") or ROOT / ".venv-arkit" / "bin" / "python"
)
ARKIT_SETUP = "bash tests/setup_arkit_venv.sh"
# where the checker must run: CI (.ci/run sets FOREST_REQUIRE_ARKIT; CI=true as CI services do)
ARKIT_REQUIRED = os.environ.get("FOREST_REQUIRE_ARKIT") == "1" or os.environ.get("CI") == "true"


@pytest.fixture(scope="module")
def birch() -> Forest:
    return generate_forest(load_preset("birch"), 3, ForestOptions(trees=1, frames=2))


def texture_inputs(stage: Usd.Stage) -> dict[str, str]:
    """Every UsdUVTexture's ``inputs:file`` asset path, by shader path."""
    found = {}
    for prim in stage.Traverse():
        shader = UsdShade.Shader(prim)
        if prim.IsA(UsdShade.Shader) and shader.GetShaderId() == "UsdUVTexture":
            found[str(prim.GetPath())] = shader.GetInput("file").Get().path
    return found


def resolved_files(stage: Usd.Stage, asset: str, n_tiles: int) -> list[str]:
    """What ``asset`` resolves to through Ar from the root layer: each UDIM tile up to
    ``n_tiles`` for a pattern, else the one file."""
    names = [asset.replace(UDIM_TOKEN, str(1001 + k)) for k in range(n_tiles)]
    layer = stage.GetRootLayer()
    return [
        str(Ar.GetResolver().Resolve(Sdf.ComputeAssetPathRelativeToLayer(layer, n)))
        for n in (names if UDIM_TOKEN in asset else [asset])
    ]


def cut_by_alpha(stage: Usd.Stage) -> None:
    """Both leaf materials take ``opacity`` from a UsdUVTexture's alpha, threshold 0.5."""
    for name in ("Leaf", "LeafTinted"):
        surface = UsdShade.Shader(stage.GetPrimAtPath(f"/World/Looks/{name}/Surface"))
        assert surface.GetInput("opacityThreshold").Get() == 0.5, name
        (link,) = surface.GetInput("opacity").GetConnectedSources()[0]
        assert link.sourceName == "a"
        assert UsdShade.Shader(link.source.GetPrim()).GetShaderId() == "UsdUVTexture"


@pytest.mark.parametrize("suffix", [".usda", ".usdc"])
def test_textures_resolve_beside_the_scene_from_another_working_directory(
    birch: Forest, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, suffix: str
) -> None:
    scene_dir, elsewhere = tmp_path / "scene", tmp_path / "elsewhere"
    scene_dir.mkdir()
    # a decoy in the working directory: resolving against it would be the bug
    shutil.copytree(set_dir("default"), elsewhere / "b.textures")
    scene = write_scene(birch, scene_dir / f"b{suffix}")
    monkeypatch.chdir(elsewhere)

    stage = Usd.Stage.Open(str(scene))
    inputs = texture_inputs(stage)
    assert sorted(inputs.values()) == [
        "./b.textures/bark.<UDIM>.png",
        "./b.textures/leaf-birch.png",
        "./b.textures/leaf-birch.png",
    ]
    shipped = slice_files(set_dir("birch"))
    assert len(shipped) == birch.manifest.n_slices
    for asset in set(inputs.values()):
        for resolved in resolved_files(stage, asset, len(shipped)):
            assert resolved and Path(resolved).parent == scene_dir / "b.textures", resolved
            assert Path(resolved).is_file()
    # the species' own tiles, byte for byte, and nothing else in the folder
    folder = scene_dir / "b.textures"
    assert sorted(p.name for p in folder.iterdir()) == sorted(
        [p.name for p in shipped] + ["leaf-birch.png", *impostor_pictures(1)]
    )
    for p in shipped:
        assert (folder / p.name).read_bytes() == p.read_bytes()
    cut_by_alpha(stage)
    # every bark quad strictly inside its tile: Blender drew a face reaching u = 10 magenta
    pv = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath(f"{TREES}/Tree_00000/Bark")).GetPrimvar("st")
    st = np.asarray(pv.ComputeFlattened(), np.float64).reshape(-1, 4, 2)
    local = st - np.floor(st.mean(axis=1, keepdims=True))
    assert (local > 0).all() and (local < 1).all() and st[..., 0].max() < 10


def test_tiles_option_names_its_folder_and_keeps_the_leaf_picture(
    birch: Forest, tmp_path: Path
) -> None:
    """``tiles`` still names the given folder (copied nowhere); the leaf picture, which no
    tile folder holds, goes into ``<stem>.textures/``."""
    shutil.copytree(set_dir("birch"), tmp_path / "mine")
    scene = write_scene(birch, tmp_path / "b.usdc", tiles="mine")
    inputs = set(texture_inputs(Usd.Stage.Open(str(scene))).values())
    assert inputs == {"./mine/bark.<UDIM>.png", "./b.textures/leaf-birch.png"}
    written = sorted(p.name for p in (tmp_path / "b.textures").iterdir())
    assert written == sorted(["leaf-birch.png", *impostor_pictures(1)])


def test_no_textures_keeps_flat_colours_and_writes_no_folder(tmp_path: Path) -> None:
    args = ["generate", "--preset", "birch", "--trees", "1", "--frames", "1", "--quiet"]
    result = CliRunner().invoke(main, [*args, "--no-textures", "-o", str(tmp_path / "f.usdc")])
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.usdc"]
    stage = Usd.Stage.Open(str(tmp_path / "f.usdc"))
    assert texture_inputs(stage) == {}
    bark = UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/Bark/Surface"))
    assert bark.GetInput("diffuseColor").Get() is not None
    leaf = UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/Leaf/Surface"))
    assert not leaf.GetInput("opacity")
    # and the default writes the folder
    result = CliRunner().invoke(main, [*args, "-o", str(tmp_path / "g.usdc")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "g.textures" / "bark.1001.png").is_file()


def test_usdz_carries_an_atlas_and_the_leaf_picture_under_dot_paths(
    birch: Forest, tmp_path: Path
) -> None:
    out = write_scene(birch, tmp_path / "b.usdz")
    plain = write_scene(birch, tmp_path / "b.usdc")
    with zipfile.ZipFile(out) as z:
        names = z.namelist()
    assert names[0] == "b.usdc"
    pictures = ["bark.png", "leaf-birch.png", *impostor_pictures(1, packed=True)]
    assert sorted(names[1:]) == sorted(f"textures/{name}" for name in pictures)
    stage = Usd.Stage.Open(str(out))
    inputs = texture_inputs(stage)
    assert set(inputs.values()) == {"./textures/bark.png", "./textures/leaf-birch.png"}
    for asset in inputs.values():
        (resolved,) = resolved_files(stage, asset, 1)
        assert resolved == f"{out}[{asset.removeprefix('./')}]", resolved
    cut_by_alpha(stage)
    # the package holds the skinned trees only: no instanced form, no PointInstancer spec
    vset = stage.GetPrimAtPath(FOREST).GetVariantSet(REPRESENTATION)
    assert vset.GetVariantNames() == [SKINNED]
    layer = stage.GetRootLayer()
    specs: list[str] = []

    def visit(path: Sdf.Path) -> None:  # every prim spec, inside variants too
        spec = layer.GetObjectAtPath(path)
        if isinstance(spec, Sdf.PrimSpec):
            specs.append(spec.typeName)

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    assert "PointInstancer" not in specs and "SkelRoot" in specs
    # the bark's st: the UDIM st of the .usdc mapped into the atlas (t up)
    tree = f"{TREES}/Tree_00000/Bark"

    def st(s: Usd.Stage) -> np.ndarray:
        pv = UsdGeom.PrimvarsAPI(s.GetPrimAtPath(tree)).GetPrimvar("st")
        return np.asarray(pv.ComputeFlattened(), np.float64).reshape(-1, 4, 2)

    inset = st(Usd.Stage.Open(str(plain)))
    tile = np.floor(inset.mean(axis=1, keepdims=True))
    udim = tile + (inset - tile - TILE_INSET) / (1.0 - 2.0 * TILE_INSET)  # the quads' own st
    uv = atlas_uv(udim, birch.manifest.n_slices, 128).astype(np.float64)
    packed = st(stage)
    np.testing.assert_allclose(packed[..., 0], uv[..., 0], atol=1e-5)
    np.testing.assert_allclose(packed[..., 1], 1.0 - uv[..., 1], atol=1e-5)
    assert (packed >= 0).all() and (packed <= 1).all()


def test_usdz_passes_the_arkit_compliance_checker(birch: Forest, tmp_path: Path) -> None:
    """``UsdUtils.ComplianceChecker(arkit=True)``, i.e. ``usdchecker --arkit``, on a .usdz
    written with the defaults (levels of detail; the impostor's picture under ./textures/
    where GL bakes it): in this Python where its USD still has the checker, else in
    :data:`ARKIT_PYTHON` (usd-core 25.5). Missing there, it fails in CI and skips elsewhere."""
    out = write_scene(birch, tmp_path / "b.usdz")
    names = zipfile.ZipFile(out).namelist()
    assert {f"textures/{name}" for name in impostor_pictures(1, packed=True)} <= set(names)
    from pxr import UsdUtils

    if hasattr(UsdUtils, "ComplianceChecker"):
        python = sys.executable
    elif ARKIT_PYTHON.exists():
        python = str(ARKIT_PYTHON)
    else:
        why = (
            f"usd-core 26 has no UsdUtils.ComplianceChecker and {ARKIT_PYTHON} does not exist: "
            f"create it with `{ARKIT_SETUP}` or set FOREST_ARKIT_PYTHON to a Python with "
            "usd-core 25.x"
        )
        if ARKIT_REQUIRED:
            pytest.fail(why)
        pytest.skip(why)
    proc = subprocess.run(
        [python, str(ARKIT_CHECK), str(out)],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
        env={k: v for k, v in os.environ.items() if k != "PYTHONPATH"},
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    found = json.loads(proc.stdout.splitlines()[-1])
    assert found["failed"] == [] and found["errors"] == [], found
