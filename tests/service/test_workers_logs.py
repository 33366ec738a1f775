"""Workers and job logs on every backend: the worker registry (``GET /v1/workers``, admin only)
names each worker's queues, renderer and current job and shows a worker killed with SIGKILL
as ``lost`` once it has not been seen for ``FOREST_WORKER_TIMEOUT_S`` (not before); a job
records which worker ran each attempt; each job's log (``GET /v1/jobs/{id}/log``, scoped to
the tenant) holds its stage changes with their timings, the lost worker and how it ended,
capped at ``FOREST_JOB_LOG_LINES`` (the oldest go, counted)."""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Iterator
from typing import Any

import pytest
from service_harness import Server, served

pytestmark = pytest.mark.slow  # a worker killed on every backend

KEYS = {"alice": "key-alice", "bob": "key-bob", "ops": "key-ops"}
CAP = 40
ENV = {
    "FOREST_API_KEYS": "key-alice=alice,key-bob=bob,key-ops=ops:admin",
    "FOREST_WORKER_HEARTBEAT_S": "0.5",
    "FOREST_WORKER_TIMEOUT_S": "3",
    "FOREST_JOB_LOG_LINES": str(CAP),
}
BODY = {"preset": "hazel", "trees": 2, "seed": 41, "format": "usdc"}


@pytest.fixture(scope="module")
def farm(backend: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    # workers whose jobs pause on their first attempt (job_hooks), restarted when killed
    for server in served(tmp_path_factory.mktemp("workers"), backend | ENV, {"pause_first_s": 15}):
        server.headers = {"X-API-Key": KEYS["alice"]}
        yield server


def workers(server: Server) -> list[dict[str, Any]]:
    r = server.get("/v1/workers", headers={"X-API-Key": KEYS["ops"]})
    assert r.status_code == 200, r.text
    items: list[dict[str, Any]] = r.json()["items"]
    return items


def until(what: Any, timeout: float = 30, step: float = 0.1) -> Any:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        got = what()
        if got:
            return got
        time.sleep(step)
    pytest.fail(f"not within {timeout} s")


def test_workers_need_an_admin_key(farm: Server) -> None:
    assert farm.get("/v1/workers").status_code == 403  # alice: a tenant's key
    assert farm.get("/v1/workers", headers={"X-API-Key": "nope"}).status_code == 401
    body = farm.get("/v1/workers", headers={"X-API-Key": KEYS["ops"]}).json()
    assert body["timeout_s"] == 3


def test_killed_worker_is_lost_after_the_timeout(farm: Server) -> None:
    r = farm.post("/v1/forests", BODY)
    assert r.status_code == 202, r.text
    job_id = r.json()["id"]
    farm.wait(job_id, states=("active",), timeout=60)
    until(lambda: farm.get(f"/v1/jobs/{job_id}").json()["stage"] == "test-pause")

    def busy() -> dict[str, Any] | None:
        return next((w for w in workers(farm) if w["current_job"] == job_id), None)

    w = until(busy)
    assert w["state"] == "busy" and w["queues"] == ["default", "render", "gpu", "cpu"], w
    assert w["pid"] in farm.worker_pids() and w["id"].split(":")[1] == str(w["pid"])
    assert farm.get(f"/v1/jobs/{job_id}").json()["worker"] == w["id"]
    # the probe's answer: a GL renderer, or why there is none (no render extra, no EGL)
    until(lambda: next(x for x in workers(farm) if x["id"] == w["id"])["renderer"], 60)

    os.kill(w["pid"], signal.SIGKILL)
    killed = time.monotonic()
    lost = until(
        lambda: next(
            (x for x in workers(farm) if x["id"] == w["id"] and x["state"] == "lost"), None
        ),
        step=0.05,
    )
    # lost once not seen for the timeout (3 s), not at once: it beat every 0.5 s until killed
    assert time.monotonic() - killed >= 3 - 0.5 - 0.3, lost
    assert lost["current_job"] == job_id  # what it was doing when last seen
    # the worker started in its place registers, and (the lease expired) runs the job again
    done = farm.wait(job_id, timeout=120)
    assert done["state"] == "completed", done
    runs = done["runs"]
    assert [r["attempt"] for r in runs] == [1, 2], runs
    assert runs[0]["worker"] == w["id"] and runs[1]["worker"] != w["id"], runs
    others = [x for x in workers(farm) if x["id"] == runs[1]["worker"]]
    assert others and others[0]["state"] in ("idle", "busy"), workers(farm)

    log = farm.get(f"/v1/jobs/{job_id}/log").json()
    lines = [(x["attempt"], x["level"], x["message"]) for x in log["items"]]
    text = "\n".join(m for _, _, m in lines)
    assert f"attempt 1 of 3 on worker {w['id']}" in text, text
    assert f"worker {w['id']} lost (its lease expired)" in text, text
    assert f"attempt 2 of 3 on worker {runs[1]['worker']}" in text, text
    assert any(m.startswith("stage test-pause") for _, _, m in lines), text
    # a stage change names the time the stage before it took
    assert any(a == 2 and " took " in m and m.startswith("stage ") for a, _, m in lines), text
    assert lines[-1][0] == 2 and lines[-1][2].startswith("completed: 1 artifact(s)"), text
    ids = [x["id"] for x in log["items"]]
    assert ids == sorted(ids) and log["next_after"] == ids[-1]
    # read on from an id: only what came after it
    tail = farm.get(f"/v1/jobs/{job_id}/log?after={ids[-3]}").json()
    assert [x["id"] for x in tail["items"]] == ids[-2:]
    # another tenant's job: no log either
    other = farm.get(f"/v1/jobs/{job_id}/log", headers={"X-API-Key": KEYS["bob"]})
    assert other.status_code == 404


def test_log_is_capped(farm: Server) -> None:
    from farm import joblog
    from farm.settings import FarmSettings
    from farm.store import JobStore

    job_id = farm.post("/v1/forests", BODY | {"seed": 42}).json()["id"]
    done = farm.wait(job_id, timeout=120)
    assert done["state"] == "completed", done
    before = farm.get(f"/v1/jobs/{job_id}/log").json()
    assert before["dropped"] == 0 and 3 <= len(before["items"]) < CAP, before
    # a chatty job: more lines than the cap, written as a worker writes them
    db = FarmSettings(data_dir=farm.data, database_url=farm.env.get("FOREST_DATABASE_URL"))
    store = JobStore(db.db_url)
    many = [joblog.Line("warning", f"line {i} " + "x" * 2000) for i in range(CAP + 25)]
    try:
        joblog.append(store, job_id, 1, many[:30], CAP)
        joblog.append(store, job_id, 1, many[30:], CAP)
    finally:
        store.engine.dispose()
    log = farm.get(f"/v1/jobs/{job_id}/log").json()
    assert len(log["items"]) == CAP, len(log["items"])
    assert log["dropped"] == len(before["items"]) + 25
    # the newest kept, in order, each line cut to its cap
    assert [x["message"].split(" ")[:2] for x in log["items"]] == [
        ["line", str(i)] for i in range(25, CAP + 25)
    ]
    assert all(len(x["message"]) == joblog.LINE_CHARS for x in log["items"])
