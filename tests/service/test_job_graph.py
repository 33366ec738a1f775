"""The job graph (farm/graph.py) through the API: a forest and its render in one request, a
render of a forest still running, and what waits for a job that fails or is canceled."""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from service_harness import Server, served

FOREST = {"preset": "almond", "seed": 3}
RENDER = {"width": 64, "height": 48}


@pytest.fixture(scope="module")
def server(backend: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    yield from served(tmp_path_factory.mktemp("graph"), backend)


def test_forest_and_its_render_in_one_request(server: Server) -> None:
    r = server.post("/v1/forests", FOREST | {"render": RENDER})
    assert r.status_code == 202, r.text
    forest = r.json()
    assert len(forest["then"]) == 1 and forest["after"] == []
    render = server.get(f"/v1/jobs/{forest['then'][0]}").json()
    assert render["kind"] == "render" and render["after"] == [forest["id"]]
    assert render["params"]["forest_job"] == forest["id"]
    # a render of a forest that is not done yet waits for it too
    r = server.post("/v1/renders", {"forest_job": forest["id"]} | RENDER | {"width": 32})
    assert r.status_code == 202, r.text
    second = r.json()
    done = server.wait(forest["id"], timeout=300)
    assert done["state"] == "completed", done
    assert sorted(done["then"]) == sorted([render["id"], second["id"]])
    for job_id in (render["id"], second["id"]):
        job = server.wait(job_id, timeout=300)
        assert job["state"] == "completed", job
        assert job["params"]["scene"] == done["result"]["scene"]
        assert any(a["name"] == "preview.png" for a in job["artifacts"])
    # the same request again (idempotency key) answers the same pair, no second render
    key = {"Idempotency-Key": "graph-1"}
    first = server.post("/v1/forests", FOREST | {"render": RENDER}, headers=key).json()
    again = server.post("/v1/forests", FOREST | {"render": RENDER}, headers=key).json()
    assert again["id"] == first["id"] and again["then"] == first["then"]


def test_bad_dependencies_are_refused(server: Server) -> None:
    r = server.post("/v1/forests", FOREST | {"after": ["0" * 32]})
    assert r.status_code == 422 and "after" in r.text and "no such job" in r.text, r.text
    r = server.post("/v1/forests", FOREST | {"format": "glb", "render": RENDER})
    assert r.status_code == 422 and "glTF" in r.text, r.text
    r = server.post("/v1/forests", FOREST | {"render": RENDER | {"width": 100_000}})
    assert r.status_code == 422, r.text
    # a render that cannot be made (its webhook refused here) makes no forest either
    total = server.get("/v1/jobs").json()["total"]
    r = server.post("/v1/forests", FOREST | {"render": RENDER | {"webhook": "https://x.test/h"}})
    assert r.status_code == 422 and r.json()["errors"][0]["loc"][1:] == ["render", "webhook"]
    assert server.get("/v1/jobs").json()["total"] == total


@pytest.mark.parametrize("backend", ["pg-redis"], indirect=True)
def test_failure_and_cancel_reach_what_waits(backend: dict[str, str], tmp_path: Path) -> None:
    env = backend | {"FOREST_MAX_ATTEMPTS": "1"}
    for paused in served(tmp_path / "paused", env, {"pause_first_s": 30}):
        # a job that fails: its worker is killed in its only attempt, the reaper fails it
        parent = paused.post("/v1/forests", FOREST).json()
        job = paused.wait(parent["id"], states=("active",), timeout=60)
        r = paused.post("/v1/forests", FOREST | {"after": [parent["id"]], "render": RENDER})
        assert r.status_code == 202, r.text
        child = r.json()
        assert child["stage"] == "waiting for 1 job(s)"
        while not (job := paused.get(f"/v1/jobs/{parent['id']}").json())["worker"]:
            time.sleep(0.05)
        os.kill(int(job["worker"].split(":")[1]), signal.SIGKILL)
        assert paused.wait(parent["id"], timeout=60)["state"] == "failed"
        failed = paused.wait(child["id"], timeout=30)
        assert failed["state"] == "failed", failed
        assert f"job {parent['id']} it waited for failed" in failed["error"]
        last = paused.wait(child["then"][0], timeout=30)
        assert last["state"] == "failed" and child["id"] in last["error"], last
        # cancel cascades: what waits for a canceled job is canceled
        parent = paused.post("/v1/forests", FOREST | {"seed": 5}).json()
        waiting = paused.post("/v1/forests", FOREST | {"seed": 6, "after": [parent["id"]]}).json()
        r = httpx.delete(f"{paused.url}/v1/jobs/{parent['id']}", headers=paused.headers)
        assert r.status_code in (200, 202), r.text
        assert paused.wait(parent["id"], timeout=60)["state"] == "canceled"
        done = paused.wait(waiting["id"], timeout=60)
        assert done["state"] == "canceled", done
        assert f"job {parent['id']} it waited for was canceled" in done["error"]


def test_bark_choice_on_the_api(server: Server) -> None:
    """API parity with the CLI's --bark (not part of the graph; this module's server is up)."""
    r = server.post("/v1/trees", FOREST | {"format": "usda", "bark": "birch"})
    if r.status_code == 202:  # not done within the wait: the job's file
        job = server.wait(r.json()["id"], timeout=300)
        r = httpx.get(f"{server.url}{job['artifacts'][0]['url']}", headers=server.headers)
    assert r.status_code == 200, r.text
    assert 'forest:barkTileSet = "birch"' in r.text
    r = server.post("/v1/forests", {"recipe": "orchard", "bark": "oak"})
    assert r.status_code == 422 and "bark" in r.text, r.text
