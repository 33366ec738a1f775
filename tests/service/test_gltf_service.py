"""glTF through the service (embedded backend: the format is the route's and the task's
business, not the broker's): ``POST /v1/trees`` with ``format: glb`` answers the library's
own bytes as ``model/gltf-binary``; a forest job publishes ``scene.glb``; a render of it is
refused on ``forest_job`` (the renderer reads USD)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from service_harness import Server, served

from farm.requests import options_from_request
from forest.gltf.document import write_glb
from forest.growth.generate import generate_forest
from forest.growth.presets import load_preset
from schemas.jobs import ForestRequest, TreeRequest

MEDIA = "model/gltf-binary"


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    yield from served(tmp_path_factory.mktemp("serve-gltf"), {})


def reference(tmp: Path, req: TreeRequest) -> bytes:
    assert req.preset is not None
    forest = generate_forest(load_preset(req.preset), req.seed, options_from_request(req))
    return write_glb(forest, tmp / "ref.glb").read_bytes()


def test_tree_as_glb(server: Server, tmp_path: Path) -> None:
    body = {"preset": "almond", "seed": 3, "format": "glb", "frames": 2}
    r = server.post("/v1/trees", body)
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == MEDIA
    assert r.headers["content-disposition"] == 'attachment; filename="almond-3.glb"'
    assert r.content == reference(tmp_path, TreeRequest.model_validate(body))


def test_forest_job_as_glb_and_no_render_of_it(server: Server, tmp_path: Path) -> None:
    body = {"preset": "almond", "trees": 2, "seed": 5, "format": "glb", "frames": 2}
    r = server.post("/v1/forests", body)
    assert r.status_code == 202, r.text
    job = server.wait(r.json()["id"])
    assert job["state"] == "completed", job
    assert [a["name"] for a in job["artifacts"]] == ["scene.glb"]
    scene = server.get(job["artifacts"][0]["url"])
    assert scene.headers["content-type"] == MEDIA
    assert scene.content == reference(tmp_path, ForestRequest.model_validate(body))
    r = server.post("/v1/renders", {"forest_job": job["id"], "width": 32, "height": 32})
    assert r.status_code == 422, r.text
    assert r.json()["errors"][0]["loc"][-1] == "forest_job"


def test_unknown_format_names_the_field(server: Server) -> None:
    r = server.post("/v1/trees", {"preset": "almond", "format": "gltf"})
    assert r.status_code == 422
    assert r.json()["errors"][0]["loc"] == ["body", "format"]
