"""Mixed forests from a recipe through a real ``forest serve`` (issue "mixed-forests"), on the
embedded backend, PostgreSQL + RabbitMQ and PostgreSQL + Redis: ``GET /v1/recipes``; a forest
job of a recipe completes with its root layer and one file per layer, which open together in
usd-core once downloaded; ``POST /v1/trees`` answers a small stand as one file; every bad
recipe is one 422 naming its field, before any job, and never names a server path."""

from __future__ import annotations

import base64
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from pxr import Usd, UsdGeom
from service_harness import Server, forest_then_render, served, tree_file

from forest.stand.generate import plan_stand
from forest.stand.recipes import LoadedRecipe, recipe_from_object, recipe_names
from forest.usd.contract import STAND_LAYERS, TERRAIN
from forest.usd.read import read_scene
from forest.usd.stand import read_stand

BUILTIN = Path(__file__).resolve().parents[2] / "forest" / "stand" / "builtin"
GLADE = "data:image/png;base64," + base64.b64encode((BUILTIN / "glade.png").read_bytes()).decode()
# two small species over procedural hills, the canopy's trees only where the glade map allows
INLINE: dict[str, Any] = {
    "name": "tiny-mix",
    "terrain": {"seed": 3, "relief": 2.0},
    "layers": [
        {"name": "almond", "preset": "almond", "share": 0.5, "density_map": GLADE},
        {"name": "hazel", "preset": "hazel", "share": 0.5, "role": "understorey"},
    ],
}
STAND = {"recipe": INLINE, "trees": 4, "area": [24.0, 24.0], "seed": 3, "skinned": False}


@pytest.fixture(scope="module")
def server(backend: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    yield from served(tmp_path_factory.mktemp("serve-stands"), backend)


def test_recipes_are_listed(server: Server) -> None:
    # public, as the presets are: a wrong key does not hide them
    r = httpx.get(f"{server.url}/v1/recipes", headers={"X-API-Key": "nope"}, timeout=30)
    assert r.status_code == 200, r.text
    recipes = r.json()["recipes"]
    assert [x["name"] for x in recipes] == recipe_names()
    boreal = next(x for x in recipes if x["name"] == "boreal")
    assert boreal["description"] and "spruce: spruce (canopy)" in boreal["layers"]


def test_recipe_forest_job(server: Server, tmp_path: Path) -> None:
    r = server.post("/v1/forests", STAND)
    assert r.status_code == 202, r.text
    job = server.wait(r.json()["id"], timeout=300)
    assert job["state"] == "completed", job
    # the job answers its inline density map elided (the worker read it whole: it placed)
    shown = job["params"]["recipe"]["layers"][0]["density_map"]
    assert shown.startswith("data:image/png;base64,... (") and shown.endswith("elided)")
    assert len(json.dumps(job["params"])) < 2_000
    names = sorted(a["name"] for a in job["artifacts"])
    assert names == ["scene.usdc", "scene_almond.usdc", "scene_hazel.usdc"]
    # the library places the same trees from the same request
    ref = plan_stand(LoadedRecipe(recipe_from_object(INLINE), None), 4, (24.0, 24.0), 3)
    want = {"almond": len(ref.placement.layers[0]), "hazel": len(ref.placement.layers[1])}
    assert job["result"]["layers"] == want and job["result"]["trees"] == 4
    assert job["result"]["scene"] == "scene.usdc" and job["result"]["pieces"] > 0
    for a in job["artifacts"]:
        got = server.get(a["url"])
        assert got.status_code == 200 and got.headers["content-type"] == "model/vnd.usd"
        assert len(got.content) == a["size"]
        (tmp_path / a["name"]).write_bytes(got.content)
    stage = Usd.Stage.Open(str(tmp_path / "scene.usdc"))
    assert stage.GetPrimAtPath(TERRAIN).IsA(UsdGeom.Mesh)
    for layer, count in want.items():
        prim = stage.GetPrimAtPath(f"{STAND_LAYERS}/{layer}")
        assert prim.IsValid() and prim.HasAuthoredReferences()
        assert prim.GetAttribute("forest:trees").Get() == count
        # the reference resolved: the layer's own forest scene is composed under it
        assert len(list(Usd.PrimRange(prim))) > 3, layer
    layer_files = stage.GetRootLayer().GetExternalReferences()
    assert sorted(layer_files) == ["./scene_almond.usdc", "./scene_hazel.usdc"]


def test_recipe_forest_renders(server: Server, tmp_path: Path) -> None:
    """A render job of a recipe forest draws every layer over the terrain (the root layer's
    references resolve beside it in the forest job's files)."""
    forest, job = forest_then_render(server, STAND, (96, 72))
    # every layer drawn: the render's pieces are the layer files' together
    pieces = 0
    for a in forest["artifacts"]:
        if a["name"] != "scene.usdc":
            (tmp_path / a["name"]).write_bytes(server.get(a["url"]).content)
            pieces += read_scene(tmp_path / a["name"]).n_instances
    assert job["metrics"]["instances"] == pieces > 0


def _open_one_file(data: bytes, path: Path) -> Usd.Stage:
    path.write_bytes(data)
    stage = Usd.Stage.Open(str(path))
    assert stage is not None
    assert stage.GetPrimAtPath(TERRAIN).IsA(UsdGeom.Mesh)
    for layer in ("almond", "hazel"):
        prim = stage.GetPrimAtPath(f"{STAND_LAYERS}/{layer}")
        assert prim.IsValid() and len(list(Usd.PrimRange(prim))) > 3, layer
    return stage


@pytest.mark.parametrize("fmt", ["usdc", "usdz"])
def test_tree_route_answers_a_stand_as_one_file(server: Server, tmp_path: Path, fmt: str) -> None:
    body = {"recipe": INLINE, "trees": 2, "area": [16.0, 16.0], "seed": 1, "format": fmt}
    r = tree_file(server, body)
    if fmt == "usdc":
        assert r.headers["content-disposition"] == 'attachment; filename="tiny-mix-1.usdc"'
    stage = _open_one_file(r.content, tmp_path / f"stand.{fmt}")
    if fmt == "usdc":  # flattened: it names no other file
        assert not stage.GetRootLayer().GetExternalReferences()
    else:  # packaged with its layers and their pictures
        import zipfile

        members = zipfile.ZipFile(tmp_path / "stand.usdz").namelist()
        assert any(m.endswith(".png") for m in members), members


def test_builtin_recipe_by_name_on_the_tree_route(server: Server, tmp_path: Path) -> None:
    body = {"recipe": "orchard", "trees": 2, "area": [16.0, 16.0], "skinned": False}
    r = tree_file(server, body)
    (tmp_path / "orchard.usdc").write_bytes(r.content)
    stage = Usd.Stage.Open(str(tmp_path / "orchard.usdc"))
    assert stage.GetPrimAtPath(f"{STAND_LAYERS}/almond").GetAttribute("forest:trees").Get() == 2


def _layer(**kw: Any) -> dict[str, Any]:
    return {"recipe": {"layers": [{"name": "a", "preset": "almond", "share": 1.0} | kw]}}


_PNG = (BUILTIN / "glade.png").read_bytes()
HALF_PNG = "data:image/png;base64," + base64.b64encode(_PNG[: len(_PNG) // 2]).decode()
TEXT_URI = "data:image/png;base64," + base64.b64encode(b"not an image at all").decode()
# 3 successors per piece, 40 levels deep: about 3^33 pieces expected
BUSHY = {
    "axiom": "A",
    "max_depth": 40,
    "rules": {"A": [{"piece": "Psi", "successors": [{"symbol": "A"}] * 3}]},
}

BAD: list[tuple[str, str, dict[str, Any], list[Any], str]] = [
    ("unknown preset", "/v1/forests", _layer(preset="nope"),
     ["recipe", "layers", 0, "preset"], "unknown preset 'nope'"),
    ("unknown built-in", "/v1/forests", {"recipe": "nope"}, ["recipe"], "no built-in recipe"),
    ("a path for a name", "/v1/forests", {"recipe": "../etc/passwd"}, ["recipe"], "not a recipe"),
    ("shares do not sum", "/v1/forests",
     {"recipe": {"layers": [{"name": "a", "preset": "oak", "share": 0.5},
                            {"name": "b", "preset": "birch", "share": 0.2}]}},
     ["recipe", "layers"], "sum to 0.7"),
    ("negative density", "/v1/forests", _layer(share=None, density=-3.0),
     ["recipe", "layers", 0, "density"], "greater than 0"),
    ("density map not an image", "/v1/forests", _layer(density_map=TEXT_URI),
     ["recipe", "layers", 0, "density_map"], "not a PNG"),
    ("density map truncated", "/v1/forests", _layer(density_map=HALF_PNG),
     ["recipe", "layers", 0, "density_map"], "truncated"),
    ("density map not base64", "/v1/forests", _layer(density_map="data:image/png;base64,@@"),
     ["recipe", "layers", 0, "density_map"], "base64"),
    ("density map a server path", "/v1/forests", _layer(density_map="/etc/hostname"),
     ["recipe", "layers", 0, "density_map"], "data: URI"),
    ("terrain image unreadable", "/v1/forests",
     {"recipe": _layer()["recipe"] | {"terrain": {"image": TEXT_URI}}},
     ["recipe", "terrain", "image"], "not a PNG"),
    ("area too large for densities", "/v1/forests",
     _layer(share=None, density=400.0) | {"area": [1e6, 1e6]}, ["area"], "at most"),
    ("too many trees", "/v1/forests", _layer() | {"trees": 150_000}, ["trees"], "at most"),
    ("pieces over the cap", "/v1/forests",
     {"recipe": {"layers": [{"name": "a", "preset": "oak", "share": 1.0}]}, "trees": 9000,
      "area": [600.0, 600.0]}, ["trees"], "pieces"),
    ("no room on the area", "/v1/forests", _layer() | {"trees": 500, "area": [20.0, 20.0]},
     ["trees"], "cannot hold them"),
    ("no room for the densities", "/v1/forests",
     _layer(share=None, density=5000.0, spacing=3.0) | {"area": [40.0, 40.0]},
     ["area"], "cannot hold them"),
    ("a deep inline grammar", "/v1/forests",
     {"recipe": {"layers": [{"name": "a", "grammar": BUSHY, "share": 1.0}]}, "trees": 1},
     ["recipe", "layers", 0, "grammar"], "pieces per tree"),
    ("preset and recipe", "/v1/forests", _layer() | {"preset": "oak"}, ["recipe"], "exactly one"),
    ("glb", "/v1/forests", _layer() | {"format": "glb"}, ["format"], "written as usda, usdc"),
    ("usdz forest", "/v1/forests", _layer() | {"format": "usdz"}, ["format"], "usda, usdc"),
    ("glb file", "/v1/trees", _layer() | {"format": "glb"}, ["format"], "usda, usdc, usdz"),
    ("unknown preset, one file", "/v1/trees", _layer(preset="nope"),
     ["recipe", "layers", 0, "preset"], "unknown preset"),
    ("trees without a recipe", "/v1/trees", {"preset": "oak", "trees": 3}, ["trees"], "recipe"),
    ("too big for one file", "/v1/trees",
     {"recipe": {"layers": [{"name": "a", "preset": "oak", "share": 1.0}]}, "trees": 400,
      "area": [200.0, 200.0]}, ["trees"], "pieces"),
]  # fmt: skip


@pytest.mark.parametrize(("route", "body", "loc", "words"), [b[1:] for b in BAD],
                         ids=[b[0] for b in BAD])  # fmt: skip
def test_bad_recipe_names_its_field(
    server: Server, route: str, body: dict[str, Any], loc: list[Any], words: str
) -> None:
    before = server.get("/v1/jobs").json()["total"]
    r = server.post(route, body)
    assert r.status_code == 422, r.text
    assert r.headers["content-type"] == "application/problem+json"
    problem = r.json()
    assert len(problem["errors"]) == 1, problem
    err = problem["errors"][0]
    assert err["loc"] == ["body", *loc], problem
    assert words in err["msg"], problem
    assert problem["detail"].startswith(err["loc"][1]), problem
    # no server path: neither the data folder nor the package's
    text = r.text
    assert str(server.data) not in text and str(BUILTIN) not in text and "/work" not in text
    assert server.get("/v1/jobs").json()["total"] == before  # refused before any job


def test_huge_data_uri_is_refused_at_the_door(server: Server) -> None:
    body = _layer(density_map="data:image/png;base64," + "A" * (2 << 20))
    r = server.post("/v1/forests", body)
    assert r.status_code == 413, r.text


def test_recipe_is_kept_in_the_job(server: Server) -> None:
    """A forest job's params hold the recipe as sent (a name stays a name), so the worker
    reads the same recipe, and a built-in one's images come from the package."""
    r = server.post(
        "/v1/forests", {"recipe": "orchard", "trees": 2, "area": [16.0, 16.0], "skinned": False}
    )
    assert r.status_code == 202, r.text
    assert r.json()["params"]["recipe"] == "orchard"
    job = server.wait(r.json()["id"], timeout=300)
    assert job["state"] == "completed", job
    assert sorted(a["name"] for a in job["artifacts"]) == ["scene.usdc", "scene_almond.usdc"]
    assert json.dumps(job).find("builtin") < 0


def test_tiled_recipe_forest(server: Server, tmp_path: Path) -> None:
    """A recipe's forest with tile_size: one tile job per tile writes each layer's trees in
    it; the root layer references them over the terrain, tree for tree the untiled stand's
    placement, and it renders."""
    body = STAND | {"trees": 12, "area": [40.0, 30.0], "tile_size": 20.0, "seed": 4}
    r = server.post("/v1/forests", body)
    assert r.status_code == 202, r.text
    job = server.wait(r.json()["id"], timeout=300)
    assert job["state"] == "completed", job
    assert job["result"]["tiles"] == 4 and job["result"]["trees"] == 12
    for a in job["artifacts"]:
        (tmp_path / a["name"]).write_bytes(server.get(a["url"]).content)
    assert all(n.startswith("scene_tile_") for n in (a["name"] for a in job["artifacts"])
               if n != "scene.usdc")  # fmt: skip
    ref = plan_stand(LoadedRecipe(recipe_from_object(INLINE), None), 12, (40.0, 30.0), 4)
    got = {}
    for layer in read_stand(tmp_path / "scene.usdc").layers:
        xyz = [read_scene(f).tree_transforms[:, :3, 3] for f in layer.files]
        got[layer.name] = np.concatenate(xyz) if xyz else np.zeros((0, 3))
    for layer, trees in zip(ref.recipe.layers, ref.placement.layers, strict=True):
        a, b = got[layer.name], trees.positions
        np.testing.assert_allclose(a[np.lexsort(a.T)], b[np.lexsort(b.T)], atol=1e-5)
    r = server.post("/v1/renders", {"forest_job": job["id"], "width": 64, "height": 48})
    assert r.status_code == 202, r.text
    render = server.wait(r.json()["id"], timeout=300)
    assert render["state"] == "completed", render
