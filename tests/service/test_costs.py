"""Costs bounded before work starts, in the API process (no worker runs): a forest whose
estimated memory or scene bytes pass the caps, a tree too costly to answer in the API process
and a grammar of too many rules are each 422 naming the field and the cap; a forest within
them passes."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import httpx
import pytest

from farm.db import migrate
from forest.settings import ForestSettings
from service import inputs
from service.app import create_app
from service.settings import ServiceSettings


def post(settings: ServiceSettings, path: str, body: dict[str, Any]) -> httpx.Response:
    migrate(settings.db_url)  # what the app's start-up does (the transport runs no lifespan)
    settings.artifacts.mkdir(parents=True, exist_ok=True)
    app = create_app(settings, reaper=False)

    async def send() -> httpx.Response:
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1") as client:
            return await client.post(path, json=body)

    return asyncio.run(send())


def refused(r: httpx.Response, loc: list[str], cap: str) -> str:
    assert r.status_code == 422, r.text
    detail = r.json()["errors"][0]
    assert detail["loc"] == ["body", *loc], detail
    assert f"({cap})" in detail["msg"], detail
    return str(detail["msg"])


def test_the_issue_forest_is_refused_by_the_memory_cap(tmp_path: Path) -> None:
    """10,000 trees x 44 frames: about 9.5 GB when it ran, more than a worker's 8 Gi."""
    body = {"preset": "alternating", "trees": 10_000, "frames": 44}
    msg = refused(post(ServiceSettings(data_dir=tmp_path), "/v1/forests", body), ["trees"],
                  "max_forest_memory_mb")  # fmt: skip
    assert msg.startswith("about ") and "the cap is 4096 MiB" in msg, msg


def test_scene_bytes_cap(tmp_path: Path) -> None:
    settings = ServiceSettings(data_dir=tmp_path, max_scene_bytes=64 << 20)
    body = {"preset": "alternating", "trees": 500, "frames": 24, "format": "usda"}
    refused(post(settings, "/v1/forests", body), ["trees"], "max_scene_bytes")


def test_tiles_are_capped_each(tmp_path: Path) -> None:
    settings = ServiceSettings(data_dir=tmp_path, max_forest_memory_mb=300)
    body = {"preset": "alternating", "trees": 4000, "area": [400, 400], "tile_size": 100,
            "frames": 8}  # fmt: skip
    msg = refused(post(settings, "/v1/forests", body), ["trees"], "max_forest_memory_mb")
    assert "memory per tile" in msg, msg


def test_a_tree_too_costly_for_the_api_process(tmp_path: Path) -> None:
    settings = ServiceSettings(data_dir=tmp_path, max_forest_memory_mb=512)
    body = {"preset": "oak", "frames": 480}
    refused(post(settings, "/v1/trees", body), ["preset"], "max_forest_memory_mb")


def test_a_grammar_of_4000_rules_is_refused(tmp_path: Path) -> None:
    n = 4000
    rules = {
        f"R{i}": [{"piece": "I", "successors": [{"symbol": f"R{i + 1}"} if i + 1 < n else None]}]
        for i in range(n)
    }
    body = {"grammar": {"name": "chain", "axiom": "R0", "rules": rules}}
    refused(post(ServiceSettings(data_dir=tmp_path), "/v1/forests", body), ["grammar", "rules"],
            "max_grammar_rules")  # fmt: skip


def test_a_forest_within_the_caps_passes(tmp_path: Path) -> None:
    """2,000 trees x 4 frames: about a quarter of the default memory cap; queued, not 422."""
    settings = ServiceSettings(data_dir=tmp_path)
    body = {"preset": "alternating", "trees": 2_000, "frames": 4}
    r = post(settings, "/v1/forests", body)
    assert r.status_code == 202, r.text
    assert r.json()["state"] == "queued"


def test_palette_cap_before_any_work(tmp_path: Path) -> None:
    """1,000 oaks x 24 frames: within raised memory and scene caps, but about 110 M palette
    matrices, over the library's 50 M; refused from the grammar's estimate (it was queued, and
    the worker refused it only once grown)."""
    settings = ServiceSettings(data_dir=tmp_path, max_forest_memory_mb=1 << 20,
                               max_scene_bytes=1 << 40)  # fmt: skip
    body = {"preset": "oak", "trees": 1000, "frames": 24}
    msg = refused(post(settings, "/v1/forests", body), ["frames"], "max_palette_matrices")
    assert "use fewer frames or trees" in msg, msg


def test_tree_palette_cap(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(inputs, "get_settings", lambda: ForestSettings(max_palette_matrices=1000))
    body = {"preset": "oak", "frames": 1}
    refused(post(ServiceSettings(data_dir=tmp_path), "/v1/trees", body), ["preset"],
            "max_palette_matrices")  # fmt: skip


def test_glb_vertex_cap_before_any_work(tmp_path: Path) -> None:
    """1,000 oaks bake to about 226 M vertices as the (game) .glb, over the glTF writer's
    25 M (100 write); the scene bytes cap set aside, which would refuse them first."""
    settings = ServiceSettings(
        data_dir=tmp_path, max_forest_memory_mb=1 << 20, max_scene_bytes=1 << 40
    )
    body = {"preset": "oak", "trees": 1000, "format": "glb"}
    r = post(settings, "/v1/forests", body)
    assert r.status_code == 422, r.text
    detail = r.json()["errors"][0]
    assert detail["loc"] == ["body", "trees"] and "glTF cap" in detail["msg"], detail


def test_recipe_layers_estimated_at_their_sizes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A recipe's palette is checked per layer on its estimate at the layer's tree sizes: 50
    young oaks (size about 0.3) pass a cap twice their estimate, which 50 mature oaks' count
    is far over (each layer was estimated as mature trees, and refused here); a cap under
    their estimate refuses them, naming the layer and the cap."""
    from forest.caps import expected_bones, layer_estimates
    from forest.growth.compile import compile_grammar
    from forest.growth.presets import load_preset
    from schemas.recipe import Recipe

    layer = {"name": "young_oak", "preset": "oak", "share": 1.0, "size": {"normal": [0.3, 0.06]}}
    recipe = {"name": "young-oaks", "layers": [layer]}
    oak = compile_grammar(load_preset("oak"))
    young = layer_estimates(Recipe.model_validate(recipe), [oak], ForestSettings())[0]
    assert expected_bones(young) < expected_bones(oak) / 3
    body = {"recipe": recipe, "trees": 50, "area": [60, 60], "frames": 2}

    def with_cap(cap: float) -> httpx.Response:
        library = ForestSettings(max_palette_matrices=int(cap))
        monkeypatch.setattr(inputs, "get_settings", lambda: library)
        return post(ServiceSettings(data_dir=tmp_path / str(int(cap))), "/v1/forests", body)

    young_matrices = expected_bones(young) * 50 * 2
    assert expected_bones(oak) * 50 * 2 > 2 * young_matrices  # a mature estimate: refused
    r = with_cap(2 * young_matrices)
    assert r.status_code == 202, r.text
    msg = refused(with_cap(young_matrices / 2), ["frames"], "max_palette_matrices")
    assert msg.startswith("layer 'young_oak': "), msg
