"""``GET /v1/jobs/{id}/events`` on every backend: a real job's Server-Sent Events carry every
state change in order (queued -> active -> completed), its progress and its log lines (their
ids increasing, the same lines ``GET /v1/jobs/{id}/log`` answers), then ``end``, and the stream
closes; another tenant's job is 404 and no key 401, as ``GET /v1/jobs/{id}``; a stream is
capped in duration while its job runs, and ``Last-Event-ID`` resumes the log."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Iterator
from typing import Any

import httpx
import pytest
from httpx_sse import connect_sse
from service_harness import Server

KEYS = {"alice": "key-alice", "bob": "key-bob"}
ENV = {"FOREST_API_KEYS": "key-alice=alice,key-bob=bob"}
BODY = {"preset": "hazel", "trees": 2, "seed": 51, "format": "usdc"}


@pytest.fixture(scope="module")
def idle(backend: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """A server with no job worker: its jobs wait, queued, until a test starts one."""
    server = Server(tmp_path_factory.mktemp("events"), backend | ENV, workers=0)
    server.headers = {"X-API-Key": KEYS["alice"]}
    server.start()
    try:
        yield server
    finally:
        server.stop()


def events(
    server: Server, job_id: str, last_id: str | None = None, on_first: Any = None
) -> list[Any]:
    """Every event of one stream, until the server closes it."""
    headers = server.headers | ({"Last-Event-ID": last_id} if last_id else {})
    got: list[Any] = []
    with (
        httpx.Client(timeout=httpx.Timeout(10, read=120)) as client,
        connect_sse(
            client, "GET", f"{server.url}/v1/jobs/{job_id}/events", headers=headers
        ) as source,
    ):
        assert source.response.headers["content-type"].startswith("text/event-stream")
        for sse in source.iter_sse():
            got.append(sse)
            if len(got) == 1 and on_first is not None:
                on_first()
    return got


def start_worker(server: Server) -> subprocess.Popen[bytes]:
    run = server.data / "run"
    run.mkdir(parents=True, exist_ok=True)
    with open(run / "sse-worker.log", "ab") as log:
        return subprocess.Popen(
            [sys.executable, "-m", "worker", "-Q", "default,render,gpu,cpu", "--name", "sse@%h"],
            env=server.env, stdout=log, stderr=subprocess.STDOUT,
        )  # fmt: skip


def test_events_of_a_real_job(idle: Server) -> None:
    job_id = idle.post("/v1/forests", BODY).json()["id"]
    workers: list[subprocess.Popen[bytes]] = []
    try:
        # the job is queued (no worker yet) as the stream opens; a worker starts once the
        # first event is in
        got = events(idle, job_id, on_first=lambda: workers.append(start_worker(idle)))
    finally:
        for w in workers:
            w.terminate()
            w.wait(30)
    kinds = [e.event for e in got]
    states = [json.loads(e.data)["state"] for e in got if e.event == "state"]
    assert states == ["queued", "active", "completed"], kinds
    assert kinds[0] == "state" and kinds[-1] == "end", kinds
    assert json.loads(got[-1].data) == {"state": "completed"}
    # between active and completed: progress up to the last stage, and the log lines
    progress = [json.loads(e.data) for e in got if e.event == "progress"]
    assert progress[-1]["stage"] == "completed" and progress[-1]["progress"] == 1
    # progress is sampled at each poll (a loaded host may pass a stage between two), so it
    # only ever grows; every stage change is in the log
    assert [p["progress"] for p in progress] == sorted(p["progress"] for p in progress)
    logs = [e for e in got if e.event == "log"]
    messages = [json.loads(e.data)["message"] for e in logs]
    assert any(m.startswith("stage write") for m in messages), messages
    ids = [int(e.id) for e in logs]
    assert ids == sorted(ids) and len(ids) == len(set(ids)) and len(ids) >= 4
    first_active = kinds.index("state", 1)
    assert kinds.index("log") > first_active  # an attempt's lines come after it started
    assert kinds.index("state", first_active + 1) > max(
        i for i, k in enumerate(kinds) if k == "log"
    )  # completed after every line
    # the same lines as the log answers
    log = idle.get(f"/v1/jobs/{job_id}/log").json()
    assert [json.loads(e.data) for e in logs] == log["items"]
    assert json.loads(logs[-1].data)["message"].startswith("completed")
    # a finished job's stream: its state, what is left of the log after Last-Event-ID, end
    again = events(idle, job_id, last_id=logs[-3].id)
    assert [e.event for e in again] == ["log", "log", "progress", "state", "end"]
    assert [e.id for e in again if e.event == "log"] == [logs[-2].id, logs[-1].id]


def test_events_are_scoped_like_the_job(idle: Server) -> None:
    job_id = idle.post("/v1/forests", BODY | {"seed": 52}).json()["id"]
    url = f"{idle.url}/v1/jobs/{job_id}/events"
    assert httpx.get(url, headers={"X-API-Key": KEYS["bob"]}).status_code == 404
    assert httpx.get(url).status_code == 401
    assert (
        httpx.get(f"{idle.url}/v1/jobs/nosuchjob/events", headers=idle.headers).status_code == 404
    )
    idle.get(f"/v1/jobs/{job_id}")  # (still queued: no worker)
    assert httpx.delete(url.removesuffix("/events"), headers=idle.headers).status_code == 200


@pytest.fixture(scope="module")
def capped(backend: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """Streams capped at 2 s; no job worker (a job waits, queued, for ever)."""
    env = backend | ENV | {"FOREST_EVENTS_MAX_S": "2"}
    server = Server(tmp_path_factory.mktemp("capped"), env, workers=0)
    server.headers = {"X-API-Key": KEYS["alice"]}
    server.start()
    try:
        yield server
    finally:
        server.stop()


def test_a_stream_is_capped(capped: Server) -> None:
    job_id = capped.post("/v1/forests", BODY | {"seed": 53}).json()["id"]
    t0 = time.monotonic()
    got = events(capped, job_id)
    took = time.monotonic() - t0
    assert 2 <= took < 2 + 5, took
    assert [e.event for e in got] == ["state", "progress"], got  # no end: it has not ended
    assert json.loads(got[0].data)["state"] == "queued"
    assert httpx.delete(f"{capped.url}/v1/jobs/{job_id}", headers=capped.headers).status_code == 200
    end = events(capped, job_id)
    assert end[-1].event == "end" and json.loads(end[-1].data)["state"] == "canceled"
