"""NVIDIA's USD validator (``usd-validation-nvidia[usd]``) on every form we write, and
ARKit's rules for the .usdz as far as ``pxr.UsdValidation`` and the stage itself tell
(issue 14.7).

The validator lives in its own venv, ``.venv-validator`` (its ``usd`` extra pins an older
usd-core than ours), made by ``bash tests/setup_validator_venv.sh`` (``make test`` runs it);
the scenes are written by this venv and the validator only reads them, as a subprocess.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import zipfile
from collections import Counter
from pathlib import Path

import pytest
from pxr import Ar, Sdf, Usd, UsdGeom, UsdShade, UsdValidation

from forest.bark.tilesets import default_dir
from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.usd.scene import write_scene
from tests.helpers_lod import impostor_pictures

pytestmark = pytest.mark.slow  # NVIDIA's validator in its own venv

ROOT = Path(__file__).resolve().parents[1]
VALIDATE = ROOT / ".venv-validator" / "bin" / "nvidia_usd_validate"
SETUP = "bash tests/setup_validator_venv.sh"
# Warnings that stay (docs/usd.md, "Validators"): the prototypes' faceVarying st and the foliage's
# forest:* primvars are read flat by the reader and the renderer (IndexedPrimvarChecker); the
# leaves' per-vertex displayColor likewise; caps meet their parent at a rim ring shared by
# more than two quads (ManifoldChecker, the decimated proxy and a few bark vertices).
ALLOWED_WARNINGS = {"IndexedPrimvarChecker", "ManifoldChecker"}
# The one failure a .usda gets: its large arrays in ASCII (docs/usd.md: .usda is for reading).
USDA_FAILURE = "UsdAsciiPerformanceChecker"
# ARKit (usdchecker --arkit, ARKitPrimTypeChecker / ARKitShaderChecker): the prim types and
# shader ids Quick Look draws
ARKIT_PRIM_TYPES = {
    "",
    "Scope",
    "Xform",
    "Camera",
    "Shader",
    "Material",
    "Mesh",
    "Sphere",
    "Cube",
    "Cylinder",
    "Cone",
    "Capsule",
    "GeomSubset",
    "Points",
    "SkelRoot",
    "Skeleton",
    "SkelAnimation",
    "BlendShape",
    "SpatialAudio",
}
ARKIT_SHADERS = {
    "UsdPreviewSurface",
    "UsdUVTexture",
    "UsdTransform2d",
    "UsdPrimvarReader_float",
    "UsdPrimvarReader_float2",
    "UsdPrimvarReader_float3",
    "UsdPrimvarReader_float4",
    "UsdPrimvarReader_int",
    "UsdPrimvarReader_string",
    "UsdPrimvarReader_normal",
    "UsdPrimvarReader_point",
    "UsdPrimvarReader_vector",
    "UsdPrimvarReader_matrix",
}


@pytest.fixture(scope="module")
def scenes(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Every form: usda, usdc, usdz (each the small-forest default, skinned), a posed .usdc
    (--no-skinned), and --tiles with the package's default tile set beside the scene, as
    .usdc and packed in a .usdz. One tree in the wind: the validator takes ~17 s a tree."""
    folder = tmp_path_factory.mktemp("nvidia")
    forest = generate_forest(load_preset("almond"), 11, ForestOptions(trees=1, frames=2))
    shutil.copytree(default_dir(), folder / "tiles")
    forms: dict[str, tuple[str, dict[str, object]]] = {
        "usda": ("f.usda", {}),
        "usdc": ("f.usdc", {}),
        "usdz": ("f.usdz", {}),
        "posed": ("posed.usdc", {"skinned": False}),
        "tiles": ("tiles.usdc", {"tiles": "tiles"}),
        "tiles-usdz": ("tiles.usdz", {"tiles": "tiles"}),
    }
    return {
        k: write_scene(forest, folder / name, **kw)  # type: ignore[arg-type]
        for k, (name, kw) in forms.items()
    }


def nvidia_validate(scene: Path, out: Path) -> dict[str, Counter[str]]:
    """Run the validator on ``scene`` from another working directory; issues per severity,
    counted by rule."""
    if not VALIDATE.exists():
        pytest.fail(
            f"{VALIDATE.relative_to(ROOT)} does not exist: NVIDIA's validator lives in its own "
            f"venv; create it with `{SETUP}` (make test runs it)",
            pytrace=False,
        )
    report = out / f"{scene.name}.json"
    proc = subprocess.run(
        [str(VALIDATE), str(scene), "--json-output", str(report)],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=out,
    )
    assert report.exists(), f"validator exit {proc.returncode}:\n{proc.stderr[-3000:]}"
    found: dict[str, Counter[str]] = {}
    for rule in json.loads(report.read_text())["rules"]:
        for issue in rule["issues"]:
            found.setdefault(issue["severity"], Counter())[rule["rule"]["name"]] += 1
    return found


@pytest.mark.parametrize("form", ["usda", "usdc", "usdz", "posed", "tiles", "tiles-usdz"])
def test_nvidia_validator_no_failures_or_errors(
    scenes: dict[str, Path], tmp_path: Path, form: str
) -> None:
    found = nvidia_validate(scenes[form], tmp_path)
    assert set(found) <= {"FAILURE", "WARNING", "ERROR", "INFO"}, found
    assert not found.get("ERROR"), found
    failures = found.get("FAILURE", Counter())
    if form == "usda":  # exactly the one documented rule, once
        assert failures == Counter({USDA_FAILURE: 1}), found
    else:
        assert not failures, found
    assert set(found.get("WARNING", ())) <= ALLOWED_WARNINGS, found


def test_usdz_follows_arkit_rules(scenes: dict[str, Path]) -> None:
    """What usdchecker --arkit checked, minus what usd-core 26 can no longer run
    (UsdUtils.ComplianceChecker is gone): the package validators of pxr.UsdValidation
    (uncompressed, aligned, allowed file types, encapsulated), a .usdc root layer, only
    ARKit's prim types in the composed default (no PointInstancer; UsdSkel allowed), only
    UsdPreviewSurface networks, and every texture packed in the .usdz (the full checker:
    tests/test_usd_textures.py with a usd-core 25 Python)."""
    path = scenes["tiles-usdz"]
    stage = Usd.Stage.Open(str(path))
    registry = UsdValidation.ValidationRegistry()
    names = [m.name for m in registry.GetValidatorMetadataForKeyword("UsdzValidators")]
    usdz = registry.GetOrLoadValidatorsByName(names)
    assert {n.split(":")[-1] for n in names} >= {
        "UsdzPackageValidator",
        "RootPackageValidator",
        "FileExtensionValidator",
        "PackageEncapsulationValidator",
    }
    errors = UsdValidation.ValidationContext(usdz).Validate(stage)
    assert [e.GetMessage() for e in errors] == []

    with zipfile.ZipFile(path) as z:
        names = z.namelist()
    assert names[0] == "tiles.usdc"  # the root layer: crate
    # the tiles as one atlas (no UDIM inside a package), the leaf picture and the impostors'
    pictures = ["bark.png", "leaf-almond.png", *impostor_pictures(1, packed=True)]
    assert sorted(names[1:]) == sorted(f"textures/{name}" for name in pictures)

    types = Counter(p.GetTypeName() for p in stage.Traverse())
    assert set(types) <= ARKIT_PRIM_TYPES, types
    assert types["PointInstancer"] == 0 and types["SkelRoot"] == 1

    shaders = set()
    for prim in stage.Traverse():
        if prim.IsA(UsdShade.Shader):
            shaders.add(UsdShade.Shader(prim).GetShaderId())
            for inp in UsdShade.Shader(prim).GetInputs():
                value = inp.Get()
                if isinstance(value, Sdf.AssetPath) and value.path:
                    # anchored (./): Blender finds nothing in a package otherwise
                    assert value.path.startswith("./") and "<UDIM>" not in value.path
                    first = Sdf.ComputeAssetPathRelativeToLayer(stage.GetRootLayer(), value.path)
                    resolved = str(Ar.GetResolver().Resolve(first))
                    assert resolved.startswith(f"{path}["), (value.path, resolved)
        elif prim.IsA(UsdGeom.Gprim) and UsdGeom.Imageable(prim).ComputePurpose() in (
            UsdGeom.Tokens.default_,
            UsdGeom.Tokens.render,
        ):  # what Quick Look draws (not the proxy)
            material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
            assert material, f"{prim.GetPath()} has no material"
    assert shaders <= ARKIT_SHADERS and "UsdPreviewSurface" in shaders, shaders
