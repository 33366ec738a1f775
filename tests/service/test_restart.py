"""An API restart loses no queued or running job: jobs posted while no worker runs, and jobs
queued or running when the whole ``forest serve`` is stopped, all complete after it starts
again on the same data folder (embedded) or the same database and queues (cluster)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest
from service_harness import Server

pytestmark = pytest.mark.slow  # whole farms stopped and started on every backend

BODY = {"preset": "hazel", "format": "usdc"}


def test_api_restart_loses_nothing(
    backend: dict[str, str], make_server: Callable[..., Server], tmp_path: Path
) -> None:
    data = tmp_path / "data"
    api_only = make_server(backend, workers=0, data=data)
    queued = [
        api_only.post("/v1/forests", BODY | {"trees": 1, "seed": 40 + i}).json()["id"]
        for i in range(2)
    ]
    api_only.stop()
    full = make_server(backend, workers=2, data=data)
    more = [
        full.post("/v1/forests", BODY | {"trees": 2, "seed": 50 + i}).json()["id"] for i in range(3)
    ]
    full.wait(more[0], states=("active", "completed"))
    full.stop()  # mid-flight: some jobs running, some queued
    again = make_server(backend, workers=2, data=data)
    for job_id in queued + more:
        job = again.wait(job_id, timeout=60)
        assert job["state"] == "completed", job
        assert [a["name"] for a in job["artifacts"]] == ["scene.usdc"]
