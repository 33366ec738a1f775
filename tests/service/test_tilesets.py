"""Bark tile sets of the caller's own through a real ``forest serve`` (issue "farm-features",
item 7: the API's parity with the CLI's ``forest tiles`` and ``--tiles``), on the embedded
backend, PostgreSQL + RabbitMQ and PostgreSQL + Redis: photographs uploaded to ``POST
/v1/tilesets`` become a tile set job's artifacts; a forest that names it waits for it, takes
its tile indices from its manifest and renders with its tiles; a ``.glb`` tree carries its
pictures; every bad photograph or reference is one 422 naming its field."""

from __future__ import annotations

import hashlib
import io
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from PIL import Image
from service_harness import Server, served, tree_file

from forest.usd.read import read_scene


@pytest.fixture(scope="module")
def server(backend: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    yield from served(tmp_path_factory.mktemp("serve-tilesets"), backend)


def photo(seed: int, size: int = 200, mode: str = "RGB", fmt: str = "PNG") -> bytes:
    """A bark-like picture: vertical furrows with noise, ``size`` pixels square."""
    rng = np.random.default_rng(seed)
    x = np.arange(size)
    furrows = 0.5 + 0.4 * np.sin(x / (3 + seed) + rng.uniform(0, 6, (size, 1)) * 0.3)
    grey = np.clip(furrows * 200 + rng.normal(0, 18, (size, size)), 0, 255).astype(np.uint8)
    rgb = np.stack([grey, (grey * 0.8).astype(np.uint8), (grey * 0.6).astype(np.uint8)], -1)
    img = Image.fromarray(rgb).convert(mode)
    buf = io.BytesIO()
    img.save(buf, format=fmt)
    return buf.getvalue()


def upload(server: Server, pictures: list[bytes], **form: str) -> httpx.Response:
    files = [("examples", (f"bark{k}.png", p, "image/png")) for k, p in enumerate(pictures)]
    return httpx.post(
        f"{server.url}/v1/tilesets", files=files, data=form, timeout=60, headers=server.headers
    )


def loc(r: httpx.Response) -> list[Any]:
    return list(r.json()["errors"][0]["loc"])


def artifact(server: Server, job: dict[str, Any], name: str) -> bytes:
    url = next(a["url"] for a in job["artifacts"] if a["name"] == name)
    got = server.get(url)
    assert got.status_code == 200, got.text
    return got.content


def test_a_tile_set_from_photographs_dresses_a_forest_and_its_render(
    server: Server, tmp_path: Path
) -> None:
    pictures = [photo(1), photo(2, fmt="JPEG")]
    r = upload(server, pictures, per_class="2", size="64", seed="3")
    assert r.status_code == 202, r.text
    tileset_id = r.json()["id"]
    assert r.json()["kind"] == "tileset"
    # asked at once: the forest (and its render) wait for the tile set, then use it
    body = {
        "preset": "alternating", "trees": 2, "seed": 1, "skinned": False, "tiles": tileset_id,
        "render": {"width": 64, "height": 48},
    }  # fmt: skip
    r = server.post("/v1/forests", body)
    assert r.status_code == 202, r.text
    forest_id = r.json()["id"]
    tileset = server.wait(tileset_id, timeout=180)
    assert tileset["state"] == "completed", tileset
    names = {a["name"] for a in tileset["artifacts"]}
    assert "manifest.json" in names and not any(n.startswith("example") for n in names)
    assert {f"bark.{1001 + k}.png" for k in range(4)} <= names and "bark.1005.png" not in names
    assert tileset["result"]["tiles"] == 4 and tileset["result"]["tile_size"] == 64
    manifest = json.loads(artifact(server, tileset, "manifest.json"))
    digests = [hashlib.sha256(p).hexdigest() for p in pictures]
    assert [s["sha256"] for s in manifest["sources"]] == digests
    assert tileset["params"]["sha256"] == digests  # the job keeps no picture in its params
    assert len(json.dumps(tileset["params"])) < 1_000

    forest = server.wait(forest_id, timeout=300)
    assert forest["state"] == "completed", forest
    (tmp_path / "scene.usdc").write_bytes(artifact(server, forest, "scene.usdc"))
    ours = read_scene(tmp_path / "scene.usdc").tile_indices
    assert ours.max() < 4  # the set's four tiles, not the shipped set's
    render = server.wait(forest["then"][0], timeout=300)
    assert render["state"] == "completed", render
    metrics = json.loads(artifact(server, render, "metrics.json"))
    assert metrics["textures"] == f"the bark tile set of job {tileset_id}"

    # a tree as .glb carries the set's pictures: other bytes than the shipped set's
    tree = {"preset": "alternating", "seed": 1, "format": "glb"}
    plain = tree_file(server, tree).content
    dressed = tree_file(server, tree | {"tiles": tileset_id}).content
    assert dressed[:4] == b"glTF" and dressed != plain
    # a render of the forest, asked later, draws the forest's own tile set
    r = server.post("/v1/renders", {"forest_job": forest_id, "width": 32, "height": 32})
    assert r.status_code == 202, r.text
    job = server.wait(r.json()["id"], timeout=300)
    assert job["state"] == "completed", job.get("error")
    assert json.loads(artifact(server, job, "metrics.json"))["textures"].endswith(tileset_id)


def test_bad_photographs_and_references_are_named(server: Server) -> None:
    ok = photo(4)
    cases = [
        ([b"hello, not a picture"], {}, ["body", "examples", 0], "not a PNG or JPEG"),
        ([ok, photo(5, size=40)], {"size": "64"}, ["body", "examples", 1], "smaller than"),
        ([photo(6, mode="RGBA")], {}, ["body", "examples", 0], "alpha"),
        ([ok[:200]], {}, ["body", "examples", 0], ""),  # a cut-off PNG
        ([ok] * 9, {}, ["body", "examples"], "1-8"),
        ([ok], {"size": "2048"}, ["body", "size"], ""),
        ([ok], {"per_class": "0"}, ["body", "per_class"], ""),
    ]
    for pictures, form, where, words in cases:
        r = upload(server, pictures, **form)
        assert r.status_code == 422, (where, r.text)
        assert loc(r) == where, r.text
        assert words in r.text and "/tmp" not in r.text and "forest-tileset" not in r.text
    r = server.post("/v1/forests", {"preset": "alternating", "seed": 1})
    forest_id = r.json()["id"]
    refs = [
        ({"tiles": "0" * 32}, "no such job"),
        ({"tiles": forest_id}, "not a tile set"),
        ({"tiles": forest_id, "bark": "oak"}, "not both"),
        ({"tiles": forest_id, "tile_size": 10.0}, "tiled forest"),
    ]
    for extra, words in refs:
        r = server.post("/v1/forests", {"preset": "alternating", "seed": 1} | extra)
        assert r.status_code == 422 and words in r.text, (extra, r.text)
        assert "tiles" in r.json()["detail"]
    r = server.post("/v1/trees", {"preset": "alternating", "tiles": "0" * 32})
    assert (r.status_code, loc(r)) == (422, ["body", "tiles"])
