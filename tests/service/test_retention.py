"""Artifacts do not live for ever: the reaper deletes a finished job's artifacts
``FOREST_ARTIFACT_TTL_S`` after it finished, and ``DELETE /v1/jobs/{id}/artifacts`` deletes
them on request (the owner's only: 404 for another tenant; 409 while the job runs); the job
stays and says when its artifacts went. The store's part runs on SQLite and PostgreSQL; the
HTTP part through a real ``forest serve``."""

from __future__ import annotations

import time
from collections.abc import Iterator
from datetime import timedelta
from pathlib import Path

import httpx
import pytest
from service_harness import Server
from sqlalchemy import update

from farm.artifacts import ArtifactStore
from farm.db import JobRow, utcnow
from farm.reaper import tidy_once
from farm.store import JobStore

A = {"X-API-Key": "key-a"}
B = {"X-API-Key": "key-b"}
KEYS = {"FOREST_API_KEYS": "key-a=alpha,key-b=beta"}


def finished(store: JobStore, artifacts: ArtifactStore, seed: int, ago_s: float) -> str:
    """A completed job with a file, finished ``ago_s`` seconds ago."""
    row, _ = store.create("forest", {"seed": seed}, max_attempts=3)
    claim = store.claim(row.id, "w", 60)
    assert claim is not None
    folder = artifacts.folder(row.id)
    folder.mkdir(parents=True)
    (folder / "scene.usdc").write_bytes(b"scene")
    assert store.finish(claim, "completed", artifacts=["scene.usdc"])
    with store.session() as s, s.begin():
        s.execute(
            update(JobRow)
            .where(JobRow.id == row.id)
            .values(finished_at=utcnow() - timedelta(seconds=ago_s))
        )
    return row.id


def test_reaper_deletes_artifacts_past_their_ttl(sql_store: JobStore, tmp_path: Path) -> None:
    artifacts = ArtifactStore(tmp_path / "artifacts")
    old = finished(sql_store, artifacts, 1, ago_s=7200)
    fresh = finished(sql_store, artifacts, 2, ago_s=60)
    running, _ = sql_store.create("forest", {"seed": 3}, max_attempts=3)
    assert sql_store.claim(running.id, "w", 60) is not None
    artifacts.folder(running.id).mkdir(parents=True)  # e.g. an upload's input
    assert tidy_once(sql_store, artifacts, artifact_ttl_s=0) == 0  # no TTL: kept for ever
    assert artifacts.folder(old).is_dir()

    assert tidy_once(sql_store, artifacts, artifact_ttl_s=3600) == 1
    assert not artifacts.folder(old).exists()
    gone = sql_store.get(old)
    assert gone is not None and gone.state == "completed"
    assert gone.artifacts == [] and gone.artifacts_deleted_at is not None
    for kept in (fresh, running.id):
        assert artifacts.folder(kept).is_dir()
        row = sql_store.get(kept)
        assert row is not None and row.artifacts_deleted_at is None
    assert tidy_once(sql_store, artifacts, artifact_ttl_s=3600) == 0  # done once
    assert sql_store.expired(3600) == []


def started(data: Path, env: dict[str, str], workers: int) -> Iterator[Server]:
    s = Server(data, KEYS | env, workers=workers).start()
    s.headers = dict(A)
    try:
        yield s
    finally:
        s.stop()


@pytest.fixture
def server(tmp_path: Path) -> Iterator[Server]:
    yield from started(tmp_path / "keep", {}, workers=1)  # no TTL: artifacts stay


@pytest.fixture
def expiring(tmp_path: Path) -> Iterator[Server]:
    yield from started(
        tmp_path / "ttl", {"FOREST_ARTIFACT_TTL_S": "2", "FOREST_HOUSEKEEPING_S": "1"}, 1
    )


def completed_forest(server: Server, seed: int) -> str:
    r = server.post("/v1/forests", {"preset": "almond", "seed": seed, "format": "usda"})
    assert r.status_code == 202, r.text
    job = server.wait(r.json()["id"], timeout=90)
    assert job["state"] == "completed" and job["artifacts"], job
    return str(job["id"])


def test_delete_artifacts_on_request(server: Server) -> None:
    job_id = completed_forest(server, 1)
    url = f"{server.url}/v1/jobs/{job_id}/artifacts"
    assert httpx.delete(url, headers=B, timeout=30).status_code == 404  # not beta's
    assert httpx.delete(f"{server.url}/v1/jobs/{'0' * 32}/artifacts", headers=A).status_code == 404
    r = httpx.delete(url, headers=A, timeout=30)
    assert r.status_code == 200, r.text
    job = r.json()
    assert job["state"] == "completed" and job["artifacts"] == []
    assert job["artifacts_deleted_at"] is not None
    assert server.get(f"/v1/jobs/{job_id}/artifacts/scene.usda").status_code == 404
    assert not (server.data / "artifacts" / job_id).exists()
    again = httpx.delete(url, headers=A, timeout=30)  # deleting again changes nothing
    assert again.status_code == 200 and again.json() == job
    assert server.get(f"/v1/jobs/{job_id}").json() == job
    # a render of it is refused: its scene is gone
    r = server.post("/v1/renders", {"forest_job": job_id})
    assert r.status_code == 422 and r.json()["errors"][0]["loc"] == ["body", "forest_job"]


def test_delete_artifacts_of_a_running_job_is_409(tmp_path: Path) -> None:
    for idle in started(tmp_path / "idle", {}, workers=0):  # nothing runs: it stays queued
        r = httpx.post(f"{idle.url}/v1/forests", json={"preset": "almond"}, headers=A)
        job_id = r.json()["id"]
        r = httpx.delete(f"{idle.url}/v1/jobs/{job_id}/artifacts", headers=A, timeout=30)
        assert r.status_code == 409 and "queued" in r.json()["detail"], r.text
        assert httpx.delete(f"{idle.url}/v1/jobs/{job_id}", headers=A).status_code == 200
        r = httpx.delete(f"{idle.url}/v1/jobs/{job_id}/artifacts", headers=A, timeout=30)
        assert r.status_code == 200 and r.json()["state"] == "canceled"


def test_reaper_expires_artifacts(expiring: Server) -> None:
    job_id = completed_forest(expiring, 2)
    folder = expiring.data / "artifacts" / job_id
    deadline = time.monotonic() + 90  # a 2 s TTL, looked at every second
    job = expiring.get(f"/v1/jobs/{job_id}").json()
    while job["artifacts_deleted_at"] is None and time.monotonic() < deadline:
        time.sleep(0.5)
        job = expiring.get(f"/v1/jobs/{job_id}").json()
    assert job["artifacts_deleted_at"] is not None, expiring.log()
    assert job["state"] == "completed" and job["artifacts"] == []
    assert not folder.exists()
    assert expiring.get(f"/v1/jobs/{job_id}/artifacts/scene.usda").status_code == 404
