"""Work survives: a worker killed with SIGKILL mid-task (its job completes once, with the same
output) and a canceled running job stops.
The workers' kinds pause on each job's first attempt (``job_hooks``: a sleep in the job's
process, its worker heartbeating and reading cancel) so the test can act while it runs. On
Redis the killed worker's message waits unacknowledged until the visibility timeout (an
hour): the reaper recovered the job long before, and when Redis does hand the message out
again it is skipped. (The API restart is in
``test_restart.py``: a module of its own gets a database and queues of its own, away from this
module's pausing workers.)"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from service_harness import (
    Server,
    redis_pending,
    redis_redeliver_now,
    redis_unacked,
    reference_scene,
    served,
)

pytestmark = pytest.mark.slow  # workers killed and jobs paused on every backend

BODY = {"preset": "hazel", "trees": 4, "seed": 31, "format": "usdc"}


@pytest.fixture(scope="module")
def paused(backend: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    yield from served(tmp_path_factory.mktemp("paused"), backend, {"pause_first_s": 60})


def wait_running(server: Server, job_id: str) -> dict[str, Any]:
    job = server.wait(job_id, states=("active",), timeout=30)
    deadline = time.monotonic() + 10
    while job["stage"] != "test-pause" and time.monotonic() < deadline:
        time.sleep(0.05)
        job = server.get(f"/v1/jobs/{job_id}").json()
    assert job["stage"] == "test-pause", job
    return job


def settles_at_zero(count: Callable[[], int], steady_s: float = 1.0, timeout: float = 20) -> bool:
    """Whether ``count`` reads 0 throughout ``steady_s`` before ``timeout``. A first 0 is not
    enough on Redis: a fetched message is off its queue (BRPOP) a moment before kombu records
    it as unacked."""
    deadline = time.monotonic() + timeout
    zero_since: float | None = None
    while time.monotonic() < deadline:
        now = time.monotonic()
        if count():
            zero_since = None
        elif zero_since is None:
            zero_since = now
        elif now - zero_since >= steady_s:
            return True
        time.sleep(0.05)
    return False


def test_killed_worker_loses_nothing(paused: Server, tmp_path: Path) -> None:
    job_id = paused.post("/v1/forests", BODY).json()["id"]
    job = wait_running(paused, job_id)
    pid = int(job["worker"].split(":")[1])
    assert pid in paused.worker_pids()
    # the attempt's scratch folder, named after its worker (farm/scratch.py)
    artifacts = paused.data / "artifacts"
    left = list(artifacts.glob(f".{job_id}.{pid}@*"))
    assert len(left) == 1 and left[0].is_dir(), sorted(p.name for p in artifacts.iterdir())
    os.kill(pid, signal.SIGKILL)
    done = paused.wait(job_id, timeout=60)
    assert done["state"] == "completed", done
    assert done["attempts"] == 2 and done["error"] is None
    scene = paused.get(f"/v1/jobs/{job_id}/artifacts/scene.usdc").content
    assert scene == reference_scene(tmp_path, BODY)
    if paused.env.get("FOREST_BROKER_URL", "").startswith("redis"):
        prefix = paused.env["FOREST_QUEUE_PREFIX"]
        # the dead worker's delivery, which Redis still holds; the second attempt's is acked
        # (acks_late) only just after the job row says completed
        deadline = time.monotonic() + 10
        while redis_unacked(prefix) > 1 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert redis_unacked(prefix) == 1
        assert redis_redeliver_now(prefix) == 1
        assert settles_at_zero(lambda: redis_pending(prefix)), "the redelivered message stays"
    # the worker started in the dead one's place removed what it left (its own attempt's
    # folder is gone with the attempt)
    deadline = time.monotonic() + 30
    while left[0].exists() and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not left[0].exists(), paused.log()
    assert not list(artifacts.glob(f".{job_id}.*"))
    time.sleep(3)  # a redelivered message or a reaper round must not run it again
    again = paused.get(f"/v1/jobs/{job_id}").json()
    assert (again["state"], again["attempts"], again["finished_at"]) == (
        "completed",
        2,
        done["finished_at"],
    )


def test_cancel_running_job(paused: Server) -> None:
    job_id = paused.post("/v1/forests", BODY | {"seed": 32}).json()["id"]
    wait_running(paused, job_id)
    r = paused.get(f"/v1/jobs/{job_id}")
    canceled = httpx.delete(f"{paused.url}/v1/jobs/{job_id}", timeout=10)
    assert canceled.status_code == 200 and canceled.json()["cancel_requested"] is True
    job = paused.wait(job_id, timeout=20)
    assert job["state"] == "canceled" and job["artifacts"] == [], (r.json(), job)
    assert job["error"] == "canceled on request"
