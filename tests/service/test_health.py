"""Readiness names what is unreachable, and the worker command lists what it runs."""

from __future__ import annotations

import asyncio
from pathlib import Path

import httpx
import pytest
from click.testing import CliRunner

from cli import main
from service.app import create_app
from service.settings import ServiceSettings


@pytest.mark.parametrize("broker", ["amqp://guest:guest@127.0.0.1:9//", "redis://127.0.0.1:9/0"])
def test_readyz_is_503_when_the_broker_is_unreachable(tmp_path: Path, broker: str) -> None:
    settings = ServiceSettings(data_dir=tmp_path, broker_url=broker)
    app = create_app(settings, reaper=False)

    async def probe() -> tuple[httpx.Response, httpx.Response]:
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1") as client:
            return await client.get("/readyz"), await client.get("/healthz")

    ready, health = asyncio.run(probe())
    assert ready.status_code == 503
    assert ready.json()["status"] == "unavailable"
    assert ready.json()["checks"]["database"] == "ok"
    assert ready.json()["checks"]["broker"].startswith("unreachable")
    assert health.status_code == 200


def test_worker_lists_kinds_and_rejects_unknown_queues() -> None:
    runner = CliRunner()
    listed = runner.invoke(main, ["worker", "--list"])
    assert listed.exit_code == 0
    assert listed.output.splitlines() == [
        "forest\tqueue default",
        "render\tqueue render (pool gpu: gpu, pool cpu: cpu)",
        "forest_tile\tqueue default",
        "render_chunk\tqueue render (pool gpu: gpu, pool cpu: cpu)",
        "tree\tqueue default",
        "tileset\tqueue default",
    ]
    bad = runner.invoke(main, ["worker", "-Q", "default,tpu"])
    assert bad.exit_code == 2
    assert "error: queues: unknown queue(s) tpu" in bad.output
