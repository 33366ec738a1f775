"""The scenes import into real Blender (4.2 or newer, the ``bpy`` package from PyPI).

Blender runs in its own venv, ``.venv-blender`` (bpy pins its own Python and numpy), made by
``bash tests/setup_blender_venv.sh``; the check itself is tests/blender_import_check.py, run
in a subprocess. What USD itself computes (instance transforms, UsdSkel skinning on every
frame) is written here with pxr and handed to the check to compare with what Blender shows.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pxr import Usd, UsdGeom, UsdSkel

from forest.bark.atlas import slice_files
from forest.bark.images import read_pixels
from forest.bark.tilesets import default_dir, set_dir
from forest.growth.generate import Forest, ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.usd.contract import (
    FOLIAGE,
    IMPOSTOR_MATERIAL,
    LOD,
    PIECES,
    lod_variant,
    tree_name,
)
from forest.usd.contract import TREES as TREES_PATH
from forest.usd.scene import impostor_available, write_scene
from forest.usd.skinned import tree_slices

pytestmark = pytest.mark.slow  # Blender (bpy) imports and renders in a subprocess

ROOT = Path(__file__).resolve().parents[1]
BLENDER_PY = ROOT / ".venv-blender" / "bin" / "python"
CHECK = ROOT / "tests" / "blender_import_check.py"
RENDER = ROOT / "tests" / "blender_render.py"
TEXTURE_CHECK = ROOT / "tests" / "blender_texture_check.py"
SETUP = "bash tests/setup_blender_venv.sh"
TREES, FRAMES = 2, 6


def usd_expectations(path: Path, out: Path, forest: Forest) -> int:
    """Instance world transforms and per-tree skinned Bark and Leaves points (every frame,
    world space), as USD computes them, column-vector convention, with each leaf vertex's
    branch radius (metres: the radius of the piece its cloud sits on). Returns the
    PointInstancer's count."""
    stage = Usd.Stage.Open(str(path))
    default = Usd.TimeCode.Default()
    xfs, names_ = [], []
    # the instancers the default representation composes (none for skinned: each tree once)
    for where in (PIECES, FOLIAGE):
        prim = stage.GetPrimAtPath(where)
        if not prim or not prim.IsActive():
            continue
        inst = UsdGeom.PointInstancer(prim)
        l2w = np.array(inst.ComputeLocalToWorldTransform(default))
        xfs += [np.array(m) @ l2w for m in inst.ComputeInstanceTransformsAtTime(default, default)]
        protos = inst.GetPrototypesRel().GetTargets()
        names_ += [protos[i].name for i in inst.GetProtoIndicesAttr().Get()]
    xf = np.array(xfs).reshape(-1, 4, 4).transpose(0, 2, 1)
    names = np.array(names_)
    data: dict[str, Any] = {
        "up_axis": np.array(str(UsdGeom.GetStageUpAxis(stage))),
        "instance_xforms": xf,
        "instance_protos": names,
    }
    frames = range(int(stage.GetStartTimeCode()), int(stage.GetEndTimeCode()) + 1)
    cache = UsdSkel.Cache()
    trees = stage.GetPrimAtPath("/World/Forest/Trees").GetChildren()
    for k, tree in enumerate(trees):
        root = UsdSkel.Root(tree)
        cache.Populate(root, Usd.PrimDefaultPredicate)
        (binding,) = cache.ComputeSkelBindings(root, Usd.PrimDefaultPredicate)
        skel_q = cache.GetSkelQuery(binding.GetSkeleton())
        targets = {t.GetPrim().GetName(): t for t in binding.GetSkinningTargets()}
        for name, key in (("Bark", "skinned_points"), ("Leaves", "leaves_points")):
            target = targets[name]
            mesh = UsdGeom.Mesh(target.GetPrim())
            per_frame = []
            for f in frames:
                tc = Usd.TimeCode(f)
                points = mesh.GetPointsAttr().Get(tc)
                xfs = skel_q.ComputeSkinningTransforms(tc)
                assert target.ComputeSkinnedPoints(xfs, points, tc)
                # skinned points are in skeleton space
                to_world = np.array(
                    UsdGeom.Xformable(binding.GetSkeleton()).ComputeLocalToWorldTransform(tc)
                )
                p = np.c_[np.array(points, np.float64), np.ones(len(points))] @ to_world
                per_frame.append(p[:, :3])
            data[f"{key}_{k}"] = np.array(per_frame)
        data[f"leaves_radius_{k}"] = leaf_vertex_radius(forest, k)
        assert len(data[f"leaves_radius_{k}"]) == data[f"leaves_points_{k}"].shape[1]
    data["tree_names"] = np.array([t.GetName() for t in trees])
    np.savez(out, **data)
    return len(xf)


def leaf_vertex_radius(forest: Forest, tree: int) -> np.ndarray:
    """``(v,)`` float64: for each vertex of tree ``tree``'s Leaves mesh, the radius of the
    branch its cloud sits on (clouds in anchor order, as forest.usd.skinned.leaves_mesh
    writes them)."""
    anchors = forest.foliage_anchors()
    inst, _ = tree_slices(forest)[tree]
    sel = np.flatnonzero((anchors.instance >= inst.start) & (anchors.instance < inst.stop))
    counts = np.array([len(m.positions) for m in anchors.models()])
    radius = forest.graph.scale[anchors.instance[sel]]
    return np.repeat(radius, counts[anchors.model[sel]]).astype(np.float64)


FORMS = ("usda", "usdc", "usdz", "tiles")
Run = tuple[Forest, int, dict[str, Any], subprocess.CompletedProcess[str]]


@pytest.fixture(scope="module")
def small_forest() -> Forest:
    return generate_forest(load_preset("almond"), 3, ForestOptions(trees=TREES, frames=FRAMES))


@pytest.fixture(scope="module", params=FORMS)
def blender_run(
    request: pytest.FixtureRequest,
    small_forest: Forest,
    tmp_path_factory: pytest.TempPathFactory,
) -> Run | str:
    """The check's run on a small forest written with the defaults (skinned: it has fewer
    than SKINNED_MAX_TREES trees) as .usda, .usdc, .usdz, or .usdc with ``--tiles`` (the
    package's default tile set copied beside the scene), imported from another working
    directory; or why there is none (each test then fails, never skips: a missing Blender
    venv is a broken setup, not an optional extra)."""
    if not BLENDER_PY.exists():
        return (
            f"{BLENDER_PY.relative_to(ROOT)} does not exist: Blender (bpy from PyPI) lives "
            f"in its own venv; create it with `{SETUP}` (the CI script runs it)"
        )
    form: str = request.param
    forest = small_forest
    tmp = tmp_path_factory.mktemp(f"blender-{form}")
    (tmp / "scene").mkdir()
    (tmp / "elsewhere").mkdir()  # Blender runs from another working directory
    extra: list[str] = []
    if form == "tiles":
        shutil.copytree(default_dir(), tmp / "scene" / "tiles")
        scene = write_scene(forest, tmp / "scene" / "forest.usdc", tiles="tiles")
        extra = ["--tile-images", str(len(slice_files(default_dir())))]
    else:
        scene = write_scene(forest, tmp / "scene" / f"forest.{form}")
        if form != "usdz":  # the species' tiles in forest.textures/ (a .usdz: one atlas)
            extra = ["--tile-images", str(len(slice_files(set_dir(forest.grammar.bark))))]
    n_usd = usd_expectations(scene, tmp / "expect.npz", forest)
    out = tmp / "report.json"
    proc = subprocess.run(
        [
            str(BLENDER_PY),
            str(CHECK),
            str(scene),
            "--instances",
            "0",  # the skinned default: no instancer composed
            "--trees",
            str(TREES),
            "--frames",
            str(FRAMES),
            "--expect",
            str(tmp / "expect.npz"),
            "--json-out",
            str(out),
            *extra,
        ],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp / "elsewhere",
    )
    if not out.exists():
        return (
            f"the Blender check crashed (exit {proc.returncode}):\n{proc.stdout[-3000:]}"
            f"\n{proc.stderr[-3000:]}"
        )
    report = json.loads(out.read_text())
    sys.stdout.write(json.dumps(report, indent=1, sort_keys=True) + "\n")
    return forest, n_usd, report, proc


def ran(blender_run: Run | str) -> Run:
    if isinstance(blender_run, str):
        pytest.fail(blender_run, pytrace=False)
    return blender_run


def test_blender_shows_each_tree_once(blender_run: Run | str) -> None:
    """The skinned default composes no instancer: the pieces and leaf clouds are not drawn
    over the skinned trees."""
    _, n_usd, report, _ = ran(blender_run)
    assert n_usd == 0
    assert report["instances"] == 0, report["point_instancers"]
    assert report["prototypes_drawn_standalone"] == []


def test_blender_one_armature_per_tree_with_wind(blender_run: Run | str) -> None:
    _, _, report, _ = ran(blender_run)
    assert report["armatures"] == TREES
    assert report["skinned_meshes"] == 2 * TREES  # bark and leaves
    assert report["scene_frame_range"] == [0, FRAMES - 1]
    trees = report["trees"]
    assert len(trees) == TREES
    for name, tree in trees.items():
        assert tree["action"], name
        assert tree["keyframes"] == FRAMES and tree["key_range"] == [0, FRAMES - 1], tree
        assert tree["bone_motion"] > 1e-6, name
        assert tree["vertex_motion"] > 1e-6, name


def test_blender_check_passes(blender_run: Run | str) -> None:
    """Everything the check looks at, skinning against UsdSkel included."""
    _, _, report, proc = ran(blender_run)
    assert proc.returncode == 0 and report["ok"], "\n".join(report["failures"])


def test_blender_skinned_within_one_percent_of_height(blender_run: Run | str) -> None:
    """Every visible vertex (bark and leaves) at every frame, the first and the last among
    them: the bark within 1 % of the tree's height of UsdSkel's skinning (the check itself
    holds it to 0.1 % of the tree's diagonal), each leaf within its branch's radius."""
    _, _, report, _ = ran(blender_run)
    for name, tree in report["trees"].items():
        assert tree["skin_error_of_size"] is not None, name
        assert tree["skin_error"] <= tree["skin_tolerance"], (name, tree)
        assert tree["leaves_error_of_branch_radius"] <= 1.0, (name, tree)


def test_blender_renders_leaves_and_bark_in_their_colours(blender_run: Run | str) -> None:
    """Blender's materials carry the species' colours, not its default grey-white (which
    every leaf rendered in while the leaf colour came only through a primvar reader)."""
    forest, _, report, _ = ran(blender_run)
    mats = report["materials"]
    leaf = mats["Leaf"]
    want = forest.foliage_anchors().color.astype(np.float64).mean(axis=0)
    np.testing.assert_allclose(leaf["base_color"], want, atol=1e-5)
    assert not leaf["linked"]
    assert leaf["base_color"][1] > max(leaf["base_color"][0], leaf["base_color"][2])  # green
    assert mats["Bark"]["linked"]  # the tile images (or a .usdz's atlas): textured by default


def test_blender_renders_green_leaves(tmp_path: Path) -> None:
    """A Cycles render of the imported tree (what an artist sees after File > Import): leaf
    green covers part of the picture (the leaves rendered white while their colour came only
    through a primvar reader, and a pine's flew off to kilometres)."""
    if not BLENDER_PY.exists():
        pytest.fail(f"{BLENDER_PY.relative_to(ROOT)} does not exist: run `{SETUP}`", pytrace=False)
    for preset in ("almond", "pine"):
        forest = generate_forest(load_preset(preset), 3, ForestOptions(trees=1))
        scene = write_scene(forest, tmp_path / f"{preset}.usdc")
        out = tmp_path / f"{preset}.png"
        proc = subprocess.run(
            [str(BLENDER_PY), str(RENDER), str(scene), str(out), "--size", "128", "--samples", "4"],
            capture_output=True, text=True, timeout=300, cwd=tmp_path,
        )  # fmt: skip
        assert proc.returncode == 0 and out.exists(), proc.stdout[-2000:] + proc.stderr[-2000:]
        rgb = read_pixels(out)[..., :3].astype(np.float64)
        # leaf green, blue-green included (a Scots pine's needles): greener than red by a
        # margin and than blue at all (the sky is bluer than green, the ground grey)
        green = (rgb[..., 1] > 1.15 * rgb[..., 0]) & (rgb[..., 1] > rgb[..., 2])
        # cards cut to their needles and leaves (the textured default): a pine's thin crown
        # is 0.34 % of the picture (0.73 % as uncut squares with --no-textures)
        assert green.mean() > 0.002, f"{preset}: {green.mean():.4f} of the pixels are leaf green"


def test_blender_loads_every_udim_tile(blender_run: Run | str) -> None:
    """A .usda/.usdc (its species' tiles in forest.textures/, or a --tiles folder): Blender
    finds and reads every bark.<UDIM>.png from another working directory (the path is
    anchored to the layer). A .usdz carries one atlas instead (no UDIM in a package)."""
    forest, _, report, _ = ran(blender_run)
    if "udim_tiles" not in report:
        assert report.get("tiled_images") is None
        return
    folder = default_dir() if "tiles/" in report["udim_path"] else set_dir(forest.grammar.bark)
    assert report["udim_tiles"] == len(slice_files(folder))
    assert report["udim_loaded"] and report["udim_missing"] == []


@pytest.mark.parametrize("suffix", [".usdc", ".usdz"])
def test_blender_imports_textured_birch_and_renders_bark_and_cut_leaves(
    tmp_path: Path, suffix: str
) -> None:
    """A birch written with the defaults, imported from another folder
    (tests/blender_texture_check.py): every image node of the bark and leaf materials holds
    a picture Blender read (39 UDIM tiles from forest.textures/, or the .usdz's atlas), the
    bark's colour and the leaves' alpha come from them; a small Cycles render shows leaf
    green and no magenta (a missing tile: faces of tile column 9 reaching u = 10 were)."""
    if not BLENDER_PY.exists():
        pytest.fail(f"{BLENDER_PY.relative_to(ROOT)} does not exist: run `{SETUP}`", pytrace=False)
    forest = generate_forest(load_preset("birch"), 3, ForestOptions(trees=1, frames=2))
    (tmp_path / "scene").mkdir()
    (tmp_path / "elsewhere").mkdir()
    scene = write_scene(forest, tmp_path / "scene" / f"birch{suffix}")
    out = tmp_path / "render.png"
    proc = subprocess.run(
        [str(BLENDER_PY), str(TEXTURE_CHECK), str(scene), "--render", str(out), "--size", "320"],
        capture_output=True, text=True, timeout=300, cwd=tmp_path / "elsewhere",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    report = json.loads(proc.stdout.splitlines()[-1])
    (bark,) = report["materials"]["Bark"]["images"]
    if suffix == ".usdz":
        assert bark["source"] == "FILE" and bark["packed"]
    else:
        assert bark["source"] == "TILED" and bark["tiles"] == forest.manifest.n_slices
        assert Path(bark["filepath"]).parent == tmp_path / "scene" / "birch.textures"
    assert all(im["loaded"] for m in report["materials"].values() for im in m["images"])
    rgb = read_pixels(out)[..., :3].astype(np.float64)
    green = (rgb[..., 1] > 1.15 * rgb[..., 0]) & (rgb[..., 1] > rgb[..., 2])
    # Blender's missing-texture magenta, shaded: red and blue well above green
    magenta = (rgb[..., 0] > 1.25 * rgb[..., 1] + 10) & (rgb[..., 2] > 1.25 * rgb[..., 1] + 10)
    assert green.mean() > 0.002 and magenta.sum() == 0, (green.mean(), magenta.sum())


@pytest.mark.skipif(not impostor_available(), reason="no GL here: no impostor is baked")
@pytest.mark.parametrize("suffix", [".usdc", ".usdz"])
def test_blender_loads_the_impostor_pictures(tmp_path: Path, suffix: str) -> None:
    """The default birch seen at ``lod3`` (a layer beside it referencing it, the tree's
    variant selected: Blender's importer takes the selection it finds), imported from another
    folder: the impostor's material reads its cards' picture (from birch.textures/, or from
    ./textures/ inside the .usdz) for colour and alpha, and nothing else is drawn."""
    if not BLENDER_PY.exists():
        pytest.fail(f"{BLENDER_PY.relative_to(ROOT)} does not exist: run `{SETUP}`", pytrace=False)
    forest = generate_forest(load_preset("birch"), 3, ForestOptions(trees=1, frames=2))
    (tmp_path / "scene").mkdir()
    (tmp_path / "elsewhere").mkdir()
    scene = write_scene(forest, tmp_path / "scene" / f"birch{suffix}")
    far = Usd.Stage.CreateNew(str(tmp_path / "scene" / "far.usda"))
    far.DefinePrim("/World").GetReferences().AddReference(f"./{scene.name}")
    far.SetDefaultPrim(far.GetPrimAtPath("/World"))
    tree = far.OverridePrim(f"{TREES_PATH}/{tree_name(0)}")
    tree.GetVariantSets().GetVariantSet(LOD).SetVariantSelection(lod_variant(3))
    far.GetRootLayer().Save()
    proc = subprocess.run(
        [str(BLENDER_PY), str(TEXTURE_CHECK), far.GetRootLayer().realPath, "--impostor"],
        capture_output=True, text=True, timeout=300, cwd=tmp_path / "elsewhere",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    report = json.loads(proc.stdout.splitlines()[-1])
    assert set(report["materials"]) == {IMPOSTOR_MATERIAL}, report["materials"]
    (cards,) = report["materials"][IMPOSTOR_MATERIAL]["images"]
    assert cards["loaded"], cards
    if suffix == ".usdc":
        assert Path(cards["filepath"]).parent == tmp_path / "scene" / "birch.textures"


def test_explicit_skinned_is_the_small_default(small_forest: Forest, tmp_path: Path) -> None:
    """``--skinned`` on a small forest writes the very file the default writes (so the runs
    above cover it byte for byte)."""
    # one name in two folders: a scene names its own texture folder, <stem>.textures
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    a = write_scene(small_forest, tmp_path / "a" / "f.usdc").read_bytes()
    b = write_scene(small_forest, tmp_path / "b" / "f.usdc", skinned=True).read_bytes()
    assert a == b


def test_blender_imports_a_mixed_forest(tmp_path: Path) -> None:
    """A mixed forest's root layer (forest generate --recipe): Blender composes every layer's
    scene file it references, from another folder: one armature per tree of every layer, the
    wind on each, and the terrain with its Ground material."""
    from forest.stand.generate import plan_stand
    from forest.stand.recipes import load_recipe
    from forest.usd.stand import write_stand

    recipe = ROOT / "tests" / "data" / "recipes" / "small-mixed.json"
    stand = plan_stand(load_recipe(recipe), 6, (40.0, 40.0), 1)
    (tmp_path / "stand").mkdir()
    (tmp_path / "elsewhere").mkdir()
    scene = write_stand(stand, tmp_path / "stand" / "wood.usdc", ForestOptions(frames=4))
    proc = subprocess.run(
        [str(BLENDER_PY), str(CHECK), str(scene), "--instances", "0", "--trees", "6",
         "--frames", "4"],
        capture_output=True, text=True, timeout=300, cwd=tmp_path / "elsewhere",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    report = json.loads(proc.stdout.splitlines()[-1])
    assert report["failures"] == [] and report["armatures"] == 6
    assert report["materials"]["Ground"]["base_color"] == pytest.approx([0.2, 0.17, 0.11])
