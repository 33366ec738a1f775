"""Render pools: renders go to the ``gpu`` or ``cpu`` pool's queue, or (``any``, the default)
to ``render``, which workers of both pools consume. A farm with no GPU worker at all (the
compose default on a host without a GPU) renders every job that does not ask for the GPU."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from service_harness import Server


@pytest.mark.parametrize("backend", ["pg-rabbitmq"], indirect=True)
def test_cpu_pool_renders_with_no_gpu_queue_consumer(
    backend: dict[str, str], tmp_path: Path
) -> None:
    server = Server(tmp_path / "cpu-pool", backend, workers=1, queues="default,render,cpu")
    try:
        server.start()
        r = server.post("/v1/forests", {"preset": "almond", "seed": 3})
        assert r.status_code == 202, r.text
        forest = server.wait(r.json()["id"], timeout=300)
        assert forest["state"] == "completed", forest
        size = {"forest_job": forest["id"], "width": 64, "height": 48}
        gpu = server.post("/v1/renders", size | {"pool": "gpu"})
        assert gpu.status_code == 202, gpu.text
        for pool in ("cpu", None):  # None: the default, any pool
            r = server.post("/v1/renders", size | ({"pool": pool} if pool else {}))
            assert r.status_code == 202, r.text
            assert r.json()["params"]["pool"] == (pool or "any")
            job = server.wait(r.json()["id"], timeout=300)
            assert job["state"] == "completed", job
            metrics = next(a["url"] for a in job["artifacts"] if a["name"] == "metrics.json")
            assert "llvmpipe" in server.get(metrics).text.lower()
        # no worker consumes the gpu pool's queue: that render waits for one, untouched
        time.sleep(1)
        assert server.get(f"/v1/jobs/{gpu.json()['id']}").json()["state"] == "queued"
        bad = server.post("/v1/renders", size | {"pool": "tpu"})
        assert bad.status_code == 422 and "pool" in bad.text
    finally:
        server.stop()
