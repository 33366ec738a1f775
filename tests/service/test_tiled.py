"""A tiled forest job (issue 12.1) through a real ``forest serve`` on the embedded backend:
the job fans out into one ``forest_tile`` job per tile (sent a few at a time by the fair
window, farm.fair), its progress aggregates theirs, it completes with a root layer whose
payloads are the tiles' files (the library's own bytes), and cancel stops every tile."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from pxr import Usd
from service_harness import Server, forest_then_render, served

from farm.tiles import tile_job_id
from forest.growth.presets import load_preset
from forest.growth.tiling import TilePlan, generate_tile
from forest.usd.contract import TILES
from forest.usd.tiled import write_tile_file

TILED = {"preset": "almond", "trees": 12, "seed": 5, "area": [20.0, 10.0], "tile_size": 10.0}


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    yield from served(tmp_path_factory.mktemp("tiled"), {})


def test_tiled_forest_job(server: Server, tmp_path: Path) -> None:
    r = server.post("/v1/forests", TILED)
    assert r.status_code == 202, r.text
    job_id = r.json()["id"]
    job = server.wait(job_id, timeout=120)
    assert job["state"] == "completed", job
    assert job["progress"] == 1.0 and job["result"]["tiles"] == 2
    names = sorted(a["name"] for a in job["artifacts"])
    assert names == ["scene.usdc", "scene_tile_0_0.usdc", "scene_tile_1_0.usdc"]
    for name in names:
        (tmp_path / name).write_bytes(server.get(f"/v1/jobs/{job_id}/artifacts/{name}").content)
    stage = Usd.Stage.Open(str(tmp_path / "scene.usdc"), load=Usd.Stage.LoadNone)
    assert len(stage.GetPrimAtPath(TILES).GetAllChildren()) == 2 and not stage.GetLoadSet()
    stage.Load(f"{TILES}/T_1_0")
    assert stage.GetPrimAtPath(f"{TILES}/T_1_0/Forest/Pieces")
    # each tile is the library's own output, whichever worker made it
    plan = TilePlan(12, (20.0, 10.0), 10.0, 5)
    for i, j in plan.tiles():
        ref = tmp_path / f"ref_{i}_{j}.usdc"
        write_tile_file(generate_tile(load_preset("almond"), plan, i, j), ref, "x", i, j)
        assert (tmp_path / f"scene_tile_{i}_{j}.usdc").read_bytes() == ref.read_bytes()
        tile = server.get(f"/v1/jobs/{tile_job_id(job_id, i, j)}").json()
        assert tile["kind"] == "forest_tile" and tile["state"] == "completed", tile


def test_tiled_forest_renders(server: Server) -> None:
    """A render job of a tiled forest draws every tile (their files beside the root in the
    forest job's artifacts); it was accepted and then failed ("missing prim")."""
    forest, job = forest_then_render(server, TILED | {"seed": 6})
    tiles = [
        server.get(f"/v1/jobs/{tile_job_id(forest['id'], i, j)}").json()["result"]["pieces"]
        for i, j in TilePlan(12, (20.0, 10.0), 10.0, 6).tiles()
    ]
    assert job["metrics"]["instances"] == sum(tiles) > 0


def test_cancel_stops_every_tile(server: Server) -> None:
    body = TILED | {"trees": 400, "area": [200.0, 200.0], "tile_size": 20.0, "seed": 9}
    r = server.post("/v1/forests", body)
    assert r.status_code == 202, r.text
    job_id = r.json()["id"]
    deadline = time.monotonic() + 30
    while not server.get(f"/v1/jobs/{job_id}").json()["stage"].startswith("tiles"):
        assert time.monotonic() < deadline, "no tile jobs after 30 s"
        time.sleep(0.1)
    r = httpx.delete(f"{server.url}/v1/jobs/{job_id}", headers=server.headers, timeout=30)
    assert r.status_code == 200, r.text
    job = server.wait(job_id, timeout=60)
    assert job["state"] == "canceled", job
    # every tile ends canceled (a running one is killed at its worker's next heartbeat), had
    # completed before, or was never sent (the fair window held it) and is gone
    ids = [tile_job_id(job_id, i, j) for j in range(10) for i in range(10)]
    states = {
        server.wait(t, timeout=30)["state"] if server.get(f"/v1/jobs/{t}").status_code == 200
        else "gone"
        for t in ids
    }  # fmt: skip
    assert "gone" in states and states <= {"canceled", "completed", "gone"}, states


def test_tiled_request_errors(server: Server) -> None:
    r = server.post("/v1/forests", TILED | {"format": "glb"})
    assert r.status_code == 422 and "tile" in r.text
    r = server.post("/v1/forests", TILED | {"tile_size": 0.001, "area": [1e5, 1e5]})
    assert r.status_code == 422 and "tile_size" in r.text
