"""End to end through a real ``forest serve``: a forest job, its scene, a render of it, sync
trees, idempotency, listing, and client errors (on the embedded default and on PostgreSQL +
RabbitMQ)."""

from __future__ import annotations

import json
import struct
import uuid
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from pxr import Usd
from service_harness import Server, reference_scene, served

from forest.usd.read import read_scene
from schemas.metrics import RenderMetrics

# posed (not the skinned small-scene default), so the scene also fits an upload's body cap
FOREST = {
    "preset": "almond", "trees": 3, "seed": 7, "format": "usdc", "frames": 2, "skinned": False,
}  # fmt: skip


@pytest.fixture(scope="module")
def server(backend: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    yield from served(tmp_path_factory.mktemp("serve"), backend | {"FOREST_MAX_IMAGE_SIZE": "1024"})


def test_forest_job_then_render(server: Server, tmp_path: Path) -> None:
    r = server.post("/v1/forests", FOREST)
    assert r.status_code == 202, r.text
    assert r.headers["location"] == f"/v1/jobs/{r.json()['id']}"
    job = server.wait(r.json()["id"])
    assert job["state"] == "completed", job
    assert job["progress"] == 1.0 and job["attempts"] == 1
    assert [a["name"] for a in job["artifacts"]] == ["scene.usdc"]
    scene = server.get(job["artifacts"][0]["url"])
    assert scene.status_code == 200
    assert scene.headers["content-type"] == "model/vnd.usd"
    path = tmp_path / "scene.usdc"
    path.write_bytes(scene.content)
    arrays = read_scene(path)
    assert arrays.n_instances == job["result"]["pieces"]
    assert scene.content == reference_scene(tmp_path, FOREST)
    # HEAD: the same headers (size, type, name), no body
    head = httpx.head(f"{server.url}{job['artifacts'][0]['url']}", headers=server.headers)
    assert head.status_code == 200 and head.content == b"", head.status_code
    for name in ("content-length", "content-type", "content-disposition", "etag"):
        assert head.headers[name] == scene.headers[name], name
    other = httpx.head(f"{server.url}/v1/jobs/{job['id']}/artifacts/x.png", headers=server.headers)
    assert other.status_code == 404

    r = server.post(
        "/v1/renders", {"forest_job": job["id"], "width": 48, "height": 32, "frames": 2}
    )
    assert r.status_code == 202, r.text
    render = server.wait(r.json()["id"], timeout=90)
    assert render["state"] == "completed", render
    names = {a["name"]: a["url"] for a in render["artifacts"]}
    assert set(names) == {"preview.png", "metrics.json"}
    png = server.get(names["preview.png"])
    assert png.headers["content-type"] == "image/png"
    assert png.content[:8] == b"\x89PNG\r\n\x1a\n"
    assert struct.unpack(">II", png.content[16:24]) == (48, 32)
    metrics = RenderMetrics.model_validate_json(server.get(names["metrics.json"]).content)
    assert (metrics.width, metrics.height, len(metrics.frames)) == (48, 32, 2)
    assert metrics.instances == job["result"]["pieces"]

    # the same scene uploaded as a file renders the same picture
    r = httpx.post(
        f"{server.url}/v1/renders/upload",
        files={"scene": ("forest.usdc", scene.content, "application/octet-stream")},
        data={"width": "48", "height": "32", "frames": "2"},
        timeout=30,
    )
    assert r.status_code == 202, r.text
    uploaded = server.wait(r.json()["id"], timeout=90)
    assert uploaded["state"] == "completed", uploaded
    assert server.get(f"/v1/jobs/{uploaded['id']}/artifacts/preview.png").content == png.content
    assert render["params"]["staged"] is uploaded["params"]["staged"] is True  # the default
    r = httpx.post(
        f"{server.url}/v1/renders/upload",
        files={"scene": ("notes.txt", b"hello", "text/plain")},
        timeout=30,
    )
    assert (r.status_code, loc(r)) == (422, ["body", "scene"])

    text = server.get("/metrics").text
    assert 'forest_http_requests_total{method="POST",route="/v1/forests",status="202"}' in text
    assert "forest_render_frame_ms_count 4.0" in text
    assert 'forest_job_duration_seconds_count{kind="forest"}' in text


@pytest.mark.parametrize(
    ("fmt", "media"),
    [("usda", "model/vnd.usda"), ("usdc", "model/vnd.usd"), ("usdz", "model/vnd.usdz+zip")],
)
def test_tree_is_answered_synchronously(
    server: Server, tmp_path: Path, fmt: str, media: str
) -> None:
    body = {"preset": "almond", "seed": 3, "format": fmt}
    r = server.post("/v1/trees", body)
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == media
    assert r.headers["content-disposition"] == f'attachment; filename="almond-3.{fmt}"'
    assert r.content == reference_scene(tmp_path, body | {"trees": 1}, "tree")
    path = tmp_path / f"tree.{fmt}"
    path.write_bytes(r.content)
    if fmt == "usdz":  # the skinned tree only, its pictures inside
        stage = Usd.Stage.Open(str(path))
        assert stage.GetPrimAtPath("/World/Forest/Trees/Tree_00000")
        assert not stage.GetPrimAtPath("/World/Forest/Pieces")
    else:
        assert read_scene(path).n_instances > 0


def test_idempotency_key_gives_one_job(server: Server) -> None:
    key = uuid.uuid4().hex
    body = FOREST | {"seed": 99, "trees": 1}
    first = server.post("/v1/forests", body, headers={"Idempotency-Key": key})
    second = server.post("/v1/forests", body, headers={"Idempotency-Key": key})
    assert first.status_code == second.status_code == 202
    assert first.json()["id"] == second.json()["id"]
    other = server.post("/v1/forests", body | {"seed": 100}, headers={"Idempotency-Key": key})
    assert other.status_code == 409
    server.wait(first.json()["id"])
    page = server.get("/v1/jobs?kind=forest&limit=200").json()
    assert sum(j["params"]["seed"] == 99 for j in page["items"]) == 1


def test_list_filters_and_pages(server: Server) -> None:
    ids = [
        server.post("/v1/forests", FOREST | {"seed": 200 + i, "trees": 1}).json()["id"]
        for i in range(3)
    ]
    for i in ids:
        server.wait(i)
    page = server.get("/v1/jobs?state=completed&kind=forest&limit=2&offset=0").json()
    assert page["limit"] == 2 and len(page["items"]) == 2 and page["total"] >= 3
    assert all(j["state"] == "completed" and j["kind"] == "forest" for j in page["items"])
    nxt = server.get("/v1/jobs?state=completed&kind=forest&limit=2&offset=2").json()
    assert not {j["id"] for j in nxt["items"]} & {j["id"] for j in page["items"]}
    assert server.get("/v1/jobs?state=nope").status_code == 422


def loc(r: object) -> list[object]:
    errors = r.json()["errors"]  # type: ignore[attr-defined]
    return list(errors[0]["loc"])


GRAMMAR_OF_ONE = {"axiom": "A", "rules": {"A": [{"piece": "I", "successors": [None]}]}}


def test_client_errors_name_the_field(server: Server) -> None:
    r = server.post("/v1/trees", {"preset": "nope"})
    assert (r.status_code, loc(r)) == (422, ["body", "preset"])
    for body in ({}, {"preset": "almond", "grammar": GRAMMAR_OF_ONE}):
        r = server.post("/v1/trees", body)
        assert (r.status_code, r.json()["errors"]) == (422, [{
            "loc": ["body", "preset"], "pointer": "#/preset", "type": "value_error",
            "msg": "give exactly one of preset (a name), grammar (an object) or recipe",
        }]), r.text  # fmt: skip
    bad = json.loads((Path(__file__).parents[2] / "forest/growth/presets/hazel.json").read_text())
    first = next(iter(bad["rules"]))
    bad["rules"][first][0]["successors"] = [{"symbol": "Nowhere"}] * len(
        bad["rules"][first][0]["successors"]
    )
    r = server.post("/v1/trees", {"grammar": bad})
    assert r.status_code == 422, r.text
    assert loc(r)[:3] == ["body", "grammar", "rules"], r.text
    r = server.post("/v1/forests", {"preset": "almond", "trees": 10**5})
    assert (r.status_code, loc(r)) == (422, ["body", "trees"])
    r = server.post("/v1/renders", {"forest_job": "0" * 32})
    assert (r.status_code, loc(r)) == (422, ["body", "forest_job"])
    done = server.post("/v1/forests", FOREST | {"trees": 1}).json()["id"]
    server.wait(done)
    r = server.post("/v1/renders", {"forest_job": done, "width": 4096})
    assert (r.status_code, loc(r)) == (422, ["body", "width"])
    assert server.get("/v1/jobs/nope").status_code == 404
    assert server.get(f"/v1/jobs/{done}/artifacts/other.png").status_code == 404
    assert server.get(f"/v1/jobs/{done}/artifacts/..%2Fjobs.sqlite").status_code == 404
    assert server.get("/v1/jobs/" + "0" * 32).status_code == 404
    big = {"preset": "almond", "pad": "x" * (5 << 20)}
    assert server.post("/v1/trees", big).status_code == 413
    r = server.post("/v1/trees", {"preset": "almond", "frames": -1})
    assert (r.status_code, loc(r)) == (422, ["body", "frames"])
    assert server.get("/healthz").json() == {"status": "ok", "checks": {}}
    ready = server.get("/readyz").json()
    assert ready["checks"] == {"database": "ok", "broker": "ok", "data_volume": "ok"}
    assert ready["data_free_bytes"] > 0
