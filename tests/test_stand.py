"""Mixed forests from a recipe (issue "mixed-forests"), judged from the written USD alone: the
root layer's terrain mesh and the layers' scene files it references, read back with the
scene reader. A test recipe of cheap species (tests/data/recipes/small-mixed.json: two canopy
layers, an understorey and an edge, procedural hills, a density map that clears the western
quarter) keeps it quick."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial import cKDTree

from cli import main
from forest.errors import ForestError, LimitError
from forest.geometry.transforms import similarity_scale
from forest.growth.generate import ForestOptions
from forest.growth.presets import load_preset
from forest.stand.generate import plan_stand
from forest.stand.place import CROWN_RADIUS_M, MIN_SPACING_M
from forest.stand.recipes import LoadedRecipe, load_recipe, recipe_from_object, recipe_names
from forest.usd.read import read_scene
from forest.usd.stand import read_stand, write_stand

DATA = Path(__file__).parent / "data" / "recipes"
RECIPE = DATA / "small-mixed.json"
TREES, AREA, SEED = 2000, (160.0, 160.0), 2
CLEAR_X = -AREA[0] / 2 + AREA[0] / 4  # the density map is 0 west of this


def write(out: Path, tile_size: float | None = None) -> Path:
    stand = plan_stand(load_recipe(RECIPE), TREES, AREA, SEED)
    return write_stand(
        stand, out, ForestOptions(), skinned=False, textures=False, tile_size=tile_size
    )


def stand_trees(root: Path) -> dict[str, tuple[str, np.ndarray, np.ndarray]]:
    """Per layer: its role, tree positions ``(t, 3)`` and sizes ``(t,)`` (the trees' scale
    over their species' trunk radius), from the files the root layer references."""
    out = {}
    for layer in read_stand(root).layers:
        pos, size = [], []
        for f in layer.files:
            s = read_scene(f)
            if not len(s.tree_transforms):
                continue
            pos.append(s.tree_transforms[:, :3, 3])
            size.append(
                similarity_scale(s.tree_transforms) / load_preset(layer.species).trunk_radius
            )
        out[layer.name] = (
            layer.role,
            np.concatenate(pos) if pos else np.zeros((0, 3)),
            np.concatenate(size) if size else np.zeros(0),
        )
    return out


def ground_height(root: Path, x: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Heights of the root layer's terrain mesh (a regular grid of quads) at ``(x, z)``."""
    stand = read_stand(root)
    p = stand.terrain_points
    xs, zs = np.unique(p[:, 0]), np.unique(p[:, 2])
    grid = p[:, 1].reshape(len(zs), len(xs))
    i = np.clip(np.searchsorted(xs, x) - 1, 0, len(xs) - 2)
    j = np.clip(np.searchsorted(zs, z) - 1, 0, len(zs) - 2)
    fx = (x - xs[i]) / (xs[i + 1] - xs[i])
    fz = (z - zs[j]) / (zs[j + 1] - zs[j])
    top = grid[j, i] * (1 - fx) + grid[j, i + 1] * fx
    bottom = grid[j + 1, i] * (1 - fx) + grid[j + 1, i + 1] * fx
    return np.asarray(top * (1 - fz) + bottom * fz)


@pytest.fixture(scope="module")
def stand(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write(tmp_path_factory.mktemp("stand") / "stand.usdc")


@pytest.fixture(scope="module")
def trees(stand: Path) -> dict[str, tuple[str, np.ndarray, np.ndarray]]:
    return stand_trees(stand)


def test_shares_match_the_recipe(trees: dict[str, tuple[str, np.ndarray, np.ndarray]]) -> None:
    recipe = load_recipe(RECIPE).recipe
    total = sum(len(p) for _, p, _ in trees.values())
    assert total == TREES
    for layer in recipe.layers:
        got = len(trees[layer.name][1]) / total
        assert abs(got - (layer.share or 0)) <= 0.05 * (layer.share or 0), (layer.name, got)


def test_no_trunks_closer_than_their_spacing(
    trees: dict[str, tuple[str, np.ndarray, np.ndarray]],
) -> None:
    recipe = load_recipe(RECIPE).recipe
    spacing = {layer.name: layer.spacing for layer in recipe.layers}
    xz = np.concatenate([p[:, [0, 2]] for _, p, _ in trees.values()])
    r = np.concatenate(
        [np.maximum(MIN_SPACING_M, (spacing[n] or 0) * s) for n, (_, _, s) in trees.items()]
    )
    pairs = cKDTree(xz).query_pairs(r.max(), output_type="ndarray")
    d = np.linalg.norm(xz[pairs[:, 0]] - xz[pairs[:, 1]], axis=1)
    need = np.maximum(r[pairs[:, 0]], r[pairs[:, 1]])
    assert (d >= need - 1e-6).all(), (d - need).min()


def test_every_tree_stands_on_the_terrain(
    stand: Path, trees: dict[str, tuple[str, np.ndarray, np.ndarray]]
) -> None:
    p = np.concatenate([p for _, p, _ in trees.values()])
    ground = ground_height(stand, p[:, 0], p[:, 2])
    assert np.ptp(ground) > 1.0  # hills, not level ground
    assert np.abs(p[:, 1] - ground).max() <= 0.01


def test_no_tree_where_the_density_map_is_zero(
    trees: dict[str, tuple[str, np.ndarray, np.ndarray]],
) -> None:
    x = np.concatenate([p[:, 0] for _, p, _ in trees.values()])
    assert x.min() >= CLEAR_X - 1e-6, x.min()


def test_understorey_thinner_under_dense_canopy(
    trees: dict[str, tuple[str, np.ndarray, np.ndarray]],
) -> None:
    canopy = np.concatenate([p[:, [0, 2]] for role, p, _ in trees.values() if role == "canopy"])
    under = np.concatenate([p[:, [0, 2]] for role, p, _ in trees.values() if role == "understorey"])
    cell = 8.0
    x0, z0 = CLEAR_X, -AREA[1] / 2
    nx, nz = int((AREA[0] / 2 - x0) // cell), int(AREA[1] // cell)

    def counts(xz: np.ndarray) -> np.ndarray:
        i = ((xz[:, 0] - x0) // cell).astype(int)
        j = ((xz[:, 1] - z0) // cell).astype(int)
        ok = (i >= 0) & (i < nx) & (j >= 0) & (j < nz)
        return np.bincount(j[ok] * nx + i[ok], minlength=nx * nz)

    c, u = counts(canopy), counts(under)
    dense, open_ = c >= np.percentile(c, 75), c <= np.percentile(c, 25)
    assert u[dense].mean() < 0.85 * u[open_].mean(), (u[dense].mean(), u[open_].mean())


def test_edge_layer_near_the_border(trees: dict[str, tuple[str, np.ndarray, np.ndarray]]) -> None:
    _, rim, _ = trees["rim"]
    _, tall, _ = trees["tall"]

    def border(p: np.ndarray) -> np.ndarray:
        return np.minimum(AREA[0] / 2 - np.abs(p[:, 0]), AREA[1] / 2 - np.abs(p[:, 2]))

    assert np.median(border(rim)) < 0.5 * np.median(border(tall))


def test_sizes_follow_the_recipe(trees: dict[str, tuple[str, np.ndarray, np.ndarray]]) -> None:
    for layer in load_recipe(RECIPE).recipe.layers:
        s = trees[layer.name][2]
        if layer.size.range is not None:
            lo, hi = layer.size.range
            assert s.min() >= lo - 1e-9 and s.max() <= hi + 1e-9
        else:
            mean, sd = layer.size.normal or (0, 0)
            assert abs(s.mean() - mean) < 0.02 and abs(s.std() - sd) < 0.02


def test_young_trees_are_smaller_versions_not_copies() -> None:
    """A sapling of a mixed stand grows fewer branch orders than a mature tree of its
    species: twigs end at the same thickness."""
    stand = plan_stand(load_recipe("mixed-broadleaf"), 60, (120.0, 120.0), 1)
    names = [layer.name for layer in stand.recipe.layers]
    young, old = names.index("young_oak"), names.index("oak")
    a = stand.grow_layer(young, ForestOptions(), trees=_first(stand.placement.layers[young]))
    b = stand.grow_layer(old, ForestOptions(), trees=_first(stand.placement.layers[old]))
    assert a is not None and b is not None
    assert a.graph.order.max() < b.graph.order.max()
    assert len(a.graph) < len(b.graph) / 4


def _first(t):  # type: ignore[no-untyped-def]
    return type(t)(t.ids[:1], t.positions[:1], t.headings[:1], t.sizes[:1])


def test_tiled_equals_untiled(
    tmp_path: Path, trees: dict[str, tuple[str, np.ndarray, np.ndarray]]
) -> None:
    tiled = stand_trees(write(tmp_path / "tiled.usdc", tile_size=50.0))
    assert len(read_stand(tmp_path / "tiled.usdc").layers[0].files) > 1
    for name, (_, p, s) in trees.items():
        q, t = tiled[name][1], tiled[name][2]
        a, b = np.lexsort(p.T), np.lexsort(q.T)
        np.testing.assert_array_equal(p[a], q[b])
        np.testing.assert_array_equal(s[a], t[b])


def test_same_recipe_and_seed_same_bytes(tmp_path: Path, stand: Path) -> None:
    again = write(tmp_path / "stand.usdc")
    assert again.read_bytes() == stand.read_bytes()
    for f in sorted((stand.parent / "stand_layers").glob("*.usdc")):
        assert (tmp_path / "stand_layers" / f.name).read_bytes() == f.read_bytes(), f.name


def test_builtin_recipes_place() -> None:
    assert set(recipe_names()) >= {"mixed-broadleaf", "boreal", "riverside", "orchard"}
    for name in recipe_names():
        stand = plan_stand(load_recipe(name), 400, (200.0, 200.0), 3)
        assert stand.trees == 400, name
        for layer in stand.recipe.layers:
            assert layer.preset is None or layer.preset in CROWN_RADIUS_M


@pytest.mark.parametrize(
    ("edit", "path", "words"),
    [
        (lambda r: r["layers"][0].update(preset="baobab"), "recipe.layers.0.preset", "unknown"),
        (lambda r: r["layers"][0].update(share=0.9), "recipe.layers", "sum to"),
        (lambda r: r["layers"][0].update(share=None, density=-3), "recipe.layers.0", ""),
        (lambda r: r["layers"][1].update(density_map="notes.txt"), "density_map", "not a PNG"),
        (lambda r: r["layers"][1].update(density_map="missing.png"), "density_map", "no image"),
        (lambda r: r["layers"][0].update(size={"range": [1.0, 0.5]}), "recipe.layers.0", "low"),
        (lambda r: r["layers"].append(dict(r["layers"][0])), "name", "twice"),
    ],
)
def test_bad_recipes_name_the_field(tmp_path: Path, edit: object, path: str, words: str) -> None:
    data = json.loads(RECIPE.read_text())
    edit(data)  # type: ignore[operator]
    shutil.copy(DATA / "west-clear.png", tmp_path / "west-clear.png")
    (tmp_path / "notes.txt").write_text("not an image")
    (tmp_path / "r.json").write_text(json.dumps(data))
    with pytest.raises(ForestError) as err:
        plan_stand(load_recipe(tmp_path / "r.json"), 100, AREA, 1)
    assert path in err.value.path and words in err.value.message, str(err.value)


def test_too_many_trees_is_refused_before_work() -> None:
    recipe = recipe_from_object({"layers": [{"name": "a", "preset": "uniform", "density": 20_000}]})
    with pytest.raises(LimitError, match="cap"):
        plan_stand(LoadedRecipe(recipe, None), 1, (1000.0, 1000.0), 1)


def test_too_dense_for_the_area_says_so() -> None:
    recipe = recipe_from_object({"layers": [{"name": "a", "preset": "oak", "share": 1.0}]})
    with pytest.raises(ForestError, match="room for only"):
        plan_stand(LoadedRecipe(recipe, None), 50, (20.0, 20.0), 1)


def test_api_recipes_take_no_paths() -> None:
    recipe = recipe_from_object(
        {"layers": [{"name": "a", "preset": "uniform", "share": 1.0, "density_map": "/etc/hosts"}]}
    )
    with pytest.raises(ForestError, match="data: URI") as err:
        plan_stand(LoadedRecipe(recipe, None), 5, (20.0, 20.0), 1)
    assert "/etc/hosts" not in str(err.value)


def test_cli_recipe(tmp_path: Path) -> None:
    out = tmp_path / "o.usda"
    r = CliRunner().invoke(
        main,
        [
            "generate",
            "--recipe",
            "orchard",
            "--trees",
            "12",
            "--area",
            "40",
            "40",
            "--no-skinned",
            "--no-textures",
            "-o",
            str(out),
            "-q",
        ],
    )
    assert r.exit_code == 0, r.output
    assert "12 tree(s) (12 almond)" in r.output
    rows = np.unique(np.round(stand_trees(out)["almond"][1][:, 2], 6))
    assert len(rows) >= 2 and np.allclose(np.diff(rows) % 7.0, 0.0)
    listed = CliRunner().invoke(main, ["recipes"])
    assert listed.exit_code == 0 and "boreal" in listed.output
    bad = CliRunner().invoke(main, ["generate", "--recipe", "nowhere", "-o", str(out)])
    assert bad.exit_code != 0 and "built-in" in bad.output


def test_stand_as_one_glb(tmp_path: Path) -> None:
    """A stand's .glb: the terrain a mesh node, every layer's trees named after their layer,
    one Wind animation for all, and the Khronos validator finds no error."""
    import pygltflib as gl
    from helpers_gltf import node_tools, run_node

    from forest.gltf.stand import write_stand_glb

    stand = plan_stand(load_recipe(RECIPE), 24, (60.0, 60.0), 1)
    opts = ForestOptions(frames=4)
    out = write_stand_glb(stand, tmp_path / "s.glb", opts, impostor=False, packing="float")
    doc = gl.GLTF2.load(str(out))
    roots = [doc.nodes[n].name for n in doc.scenes[0].nodes]
    assert roots[0] == "Terrain"
    terrain = doc.meshes[doc.nodes[doc.scenes[0].nodes[0]].mesh].primitives[0]
    lo, hi = (
        doc.accessors[terrain.attributes.POSITION].min,
        doc.accessors[terrain.attributes.POSITION].max,
    )
    assert hi[1] - lo[1] > 1.0 and hi[0] - lo[0] == pytest.approx(60.0, abs=1e-3)
    for layer, trees in zip(stand.recipe.layers, stand.placement.layers, strict=True):
        mine = {n for n in roots if n.startswith(f"{layer.name}_Tree_") and n.endswith("_LOD0")}
        assert len(mine) == len(trees), (layer.name, len(mine), len(trees))
    assert [a.name for a in doc.animations] == ["Wind"]
    if node_tools() is None:  # and as shipped: quantized
        out = write_stand_glb(stand, tmp_path / "q.glb", opts, impostor=False)
        report = run_node("validate.mjs", str(out))
        assert report["issues"]["numErrors"] == 0, report["issues"]["messages"][:5]


def _png16(path: Path, grey: np.ndarray) -> None:
    import OpenImageIO as oiio

    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(grey.shape[1], grey.shape[0], 1, "uint16"))
    out.write_image(grey.astype(np.uint16)[:, :, None])  # (h, w, channels)
    out.close()


def test_heightfield_image_keeps_16_bits(tmp_path: Path) -> None:
    """A 16-bit PNG heightfield: trees stand on it to the centimetre, and heights step by
    range / 65535 (not by range / 255, as an 8-bit read would)."""
    z, x = np.mgrid[0:64, 0:64]
    grey = (x * 1000 + z * 7).astype(np.uint16)  # a ramp along x, fine steps along z
    _png16(tmp_path / "h.png", grey)
    recipe = {
        "terrain": {"image": "h.png", "heights": [10.0, 75.535]},
        "layers": [{"name": "a", "preset": "uniform", "share": 1.0, "spacing": 2.0}],
    }
    (tmp_path / "r.json").write_text(json.dumps(recipe))
    stand = plan_stand(load_recipe(tmp_path / "r.json"), 50, (64.0, 64.0), 1)
    h = stand.ground.heights
    np.testing.assert_allclose(h, 10.0 + grey / 65535.0 * 65.535, atol=1e-6)
    assert np.unique(np.round(np.diff(h[:, 0]), 6)).tolist() == [0.007]
    out = write_stand(stand, tmp_path / "h.usdc", ForestOptions(), skinned=False, textures=False)
    p = stand_trees(out)["a"][1]
    assert np.abs(p[:, 1] - ground_height(out, p[:, 0], p[:, 2])).max() <= 0.01


@pytest.mark.parametrize(
    ("data", "words"),
    [
        (b"", "empty"),
        (b"\x89PNG\r\n\x1a\n" + b"\0" * 40, "not a readable image"),
        (b"%PDF-1.7 hello", "not a PNG"),
    ],
)
def test_bad_heightfields_are_named(tmp_path: Path, data: bytes, words: str) -> None:
    (tmp_path / "h.png").write_bytes(data)
    recipe = {
        "terrain": {"image": "h.png"},
        "layers": [{"name": "a", "preset": "uniform", "share": 1.0}],
    }
    (tmp_path / "r.json").write_text(json.dumps(recipe))
    with pytest.raises(ForestError) as err:
        plan_stand(load_recipe(tmp_path / "r.json"), 5, (30.0, 30.0), 1)
    assert err.value.path == "recipe.terrain.image" and words in err.value.message
    assert str(tmp_path) not in str(err.value)


def test_heightfield_extent(tmp_path: Path) -> None:
    """A heightfield of its own extent (its real size): the terrain mesh spans it, the trees
    stand in the forest's area on it; an area larger than the extent is refused."""
    z, x = np.mgrid[0:32, 0:32]
    _png16(tmp_path / "h.png", (np.sin(x / 5.0) * 20000 + 30000 + z * 300).astype(np.uint16))
    recipe = {
        "terrain": {"image": "h.png", "heights": [0.0, 30.0], "extent": [100.0, 80.0]},
        "layers": [{"name": "a", "preset": "uniform", "share": 1.0, "spacing": 2.0}],
    }
    (tmp_path / "r.json").write_text(json.dumps(recipe))
    stand = plan_stand(load_recipe(tmp_path / "r.json"), 40, (50.0, 40.0), 1)
    out = write_stand(stand, tmp_path / "e.usdc", ForestOptions(), skinned=False, textures=False)
    pts = read_stand(out).terrain_points
    assert np.ptp(pts[:, 0]) == pytest.approx(100.0) and np.ptp(pts[:, 2]) == pytest.approx(80.0)
    p = stand_trees(out)["a"][1]
    assert np.abs(p[:, 0]).max() <= 25.0 and np.abs(p[:, 2]).max() <= 20.0
    assert np.abs(p[:, 1] - ground_height(out, p[:, 0], p[:, 2])).max() <= 0.01
    with pytest.raises(ForestError) as err:
        plan_stand(load_recipe(tmp_path / "r.json"), 40, (120.0, 40.0), 1)
    assert err.value.path == "recipe.terrain.extent"
