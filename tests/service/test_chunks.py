"""Frame chunks (farm.chunks) through a real ``forest serve`` with two workers on each backend:
a 48-frame render splits into six ``render_chunk`` jobs of 8 frames (FOREST_RENDER_CHUNK_FRAMES),
run on both workers; the render job assembles the same preview, clip and per-frame metrics
that one worker's render writes (pixel for pixel, llvmpipe); a chunk whose worker is killed
runs again alone, every other chunk once; a canceled render's completed chunks' frames are
deleted by housekeeping."""

from __future__ import annotations

import json
import os
import signal
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import imageio.v3 as iio
import numpy as np
import pytest
from service_harness import Server, served

from farm.artifacts import ArtifactStore
from farm.chunks import chunk_job_id
from worker.jobs.context import JobContext
from worker.jobs.render import run_render

pytestmark = pytest.mark.slow  # two 48-frame renders and a killed worker on every backend

FOREST = {"preset": "alternating", "trees": 2, "seed": 17, "frames": 12, "fps": 12.0}
RENDER = {"width": 64, "height": 48, "tess_max": 2.0, "frames": 48, "clip": "gif"}
CHUNKS = 6


@pytest.fixture(scope="module")
def server(backend: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    # the first attempt of each render's chunk from frame 8 pauses: a window to kill it
    # housekeeping each second: the frames of a canceled render's completed chunks go
    env = backend | {"FOREST_HOUSEKEEPING_S": "1"}
    yield from served(tmp_path_factory.mktemp("chunks"), env, {"pause_chunk_s": 6})


@pytest.fixture(scope="module")
def forest(server: Server) -> dict[str, Any]:
    r = server.post("/v1/forests", FOREST)
    assert r.status_code == 202, r.text
    job = server.wait(r.json()["id"], timeout=300)
    assert job["state"] == "completed", job
    return job


def one_worker(server: Server, forest: dict[str, Any], out: Path) -> dict[str, Path]:
    """The render as one worker runs it (the ``render`` kind, every frame in one run)."""
    out.mkdir()
    params = RENDER | {"forest_job": forest["id"], "scene": forest["result"]["scene"]}
    ctx = JobContext("0" * 32, params, out, ArtifactStore(server.data / "artifacts"))
    return run_render(ctx).files


def artifact(server: Server, job_id: str, name: str) -> bytes:
    r = server.get(f"/v1/jobs/{job_id}/artifacts/{name}")
    assert r.status_code == 200, r.text
    return r.content


def chunks(server: Server, job_id: str) -> list[dict[str, Any]]:
    return [server.get(f"/v1/jobs/{chunk_job_id(job_id, n)}").json() for n in range(CHUNKS)]


def test_chunks_on_two_workers_make_one_workers_frames(
    server: Server, forest: dict[str, Any], tmp_path: Path
) -> None:
    r = server.post("/v1/renders", RENDER | {"forest_job": forest["id"]})
    assert r.status_code == 202, r.text
    job_id = r.json()["id"]
    stages = set()
    deadline = time.monotonic() + 300
    while (job := server.get(f"/v1/jobs/{job_id}").json())["state"] in ("queued", "active"):
        assert time.monotonic() < deadline, job
        stages.add(job["stage"])
        time.sleep(0.1)
    assert job["state"] == "completed", (job, server.log())
    # progress was frames done over frames
    assert any(s.startswith("frames ") and s.endswith("/48") for s in stages), stages
    assert job["result"]["frames"] == 48 and job["result"]["chunks"] == CHUNKS
    names = sorted(a["name"] for a in job["artifacts"])
    assert names == ["clip.gif", "metrics.json", "preview.png"]
    # the chunks were jobs of their own, on both workers
    parts = chunks(server, job_id)
    assert {(c["kind"], c["state"]) for c in parts} == {("render_chunk", "completed")}
    assert len({c["runs"][-1]["worker"] for c in parts}) == 2, parts
    # the chunks' frame files are gone once the clip holds them
    assert sorted(p.name for p in (server.data / "artifacts" / job_id).iterdir()) == names
    metrics = server.get(f"/v1/jobs/{job_id}/artifacts/metrics.json").json()
    assert len(metrics["frames"]) == 48 and len(job["result"]["frame_cpu_ms"]) == 48
    ref = one_worker(server, forest, tmp_path / "one")
    one = json.loads(ref["metrics.json"].read_text())
    assert [f["frame"] for f in metrics["frames"]] == [f["frame"] for f in one["frames"]]
    assert [f["primitives"] for f in metrics["frames"]] == [f["primitives"] for f in one["frames"]]
    (tmp_path / "preview.png").write_bytes(artifact(server, job_id, "preview.png"))
    assert np.array_equal(iio.imread(tmp_path / "preview.png"), iio.imread(ref["preview.png"]))
    clip = artifact(server, job_id, "clip.gif")
    (tmp_path / "clip.gif").write_bytes(clip)
    mine, theirs = iio.imread(tmp_path / "clip.gif"), iio.imread(ref["clip.gif"])
    assert mine.shape[0] == 48 and np.array_equal(mine, theirs)
    assert clip == ref["clip.gif"].read_bytes()


def test_a_killed_chunk_runs_again_alone(server: Server, forest: dict[str, Any]) -> None:
    r = server.post("/v1/renders", RENDER | {"forest_job": forest["id"], "tess_max": 3.0})
    assert r.status_code == 202, r.text
    job_id = r.json()["id"]
    second = chunk_job_id(job_id, 1)  # frames 8-16, paused on its first attempt
    deadline = time.monotonic() + 120
    while True:
        got = server.get(f"/v1/jobs/{second}")
        if got.status_code == 200 and got.json()["stage"] == "test-pause":
            break
        assert time.monotonic() < deadline, got.text
        time.sleep(0.05)
    pid = int(got.json()["worker"].split(":")[1])
    assert pid in server.worker_pids()
    os.kill(pid, signal.SIGKILL)
    job = server.wait(job_id, timeout=300)
    assert job["state"] == "completed", (job, server.log())
    attempts = {c["id"]: c["attempts"] for c in chunks(server, job_id)}
    assert attempts.pop(second) == 2 and set(attempts.values()) == {1}, attempts
    assert job["attempts"] <= 1  # the render job's polls give their attempt back
    assert job["result"]["frames"] == 48
    assert iio.imread(artifact(server, job_id, "clip.gif"), extension=".gif").shape[0] == 48


def test_cancel_cancels_the_chunks(server: Server, forest: dict[str, Any]) -> None:
    r = server.post("/v1/renders", RENDER | {"forest_job": forest["id"], "tess_max": 4.0})
    job_id = r.json()["id"]
    second = chunk_job_id(job_id, 1)
    deadline = time.monotonic() + 120
    while server.get(f"/v1/jobs/{second}").json().get("stage") != "test-pause":
        assert time.monotonic() < deadline
        time.sleep(0.05)
    first = server.wait(chunk_job_id(job_id, 0), timeout=120)  # its frames written
    assert first["state"] == "completed", first
    folder = server.data / "artifacts" / job_id
    # its frames (and those of any other chunk done by now) are in the render's folder
    assert set(first["result"]["files"]) <= {p.name for p in folder.glob("frame_*.png")}
    r = httpx.delete(f"{server.url}/v1/jobs/{job_id}", headers=server.headers, timeout=30)
    assert r.status_code == 200, r.text
    assert server.wait(job_id, timeout=60)["state"] == "canceled"
    states = set()
    for n in range(CHUNKS):
        got = server.get(f"/v1/jobs/{chunk_job_id(job_id, n)}")
        states.add(server.wait(chunk_job_id(job_id, n))["state"] if got.status_code == 200
                   else "gone")  # fmt: skip
    assert "canceled" in states and states <= {"canceled", "completed", "gone"}, states
    # no job lists the completed chunks' frames now: housekeeping deletes them
    while list(folder.glob("frame_*.png")):
        assert time.monotonic() < deadline + 60, sorted(folder.iterdir())
        time.sleep(0.2)


def test_small_render_is_one_job(server: Server, forest: dict[str, Any]) -> None:
    r = server.post("/v1/renders", RENDER | {"forest_job": forest["id"], "frames": 8})
    job = server.wait(r.json()["id"], timeout=120)
    assert job["state"] == "completed" and "chunks" not in job["result"], job
    assert server.get(f"/v1/jobs/{chunk_job_id(job['id'], 0)}").status_code == 404
