"""Service tests run against real servers: ``forest serve`` in a subprocess, on three backends:
the embedded default (SQLite job store and broker in a temporary data folder), PostgreSQL +
RabbitMQ, and PostgreSQL + Redis (a database, queue names and Redis keys of the module's own,
all dropped at the end). A server that is not running fails the test with how to start it
(never a skip); `.ci/run` starts them."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from service_harness import (
    PG,
    RABBIT,
    RABBIT_URL,
    REDIS,
    REDIS_URL,
    Server,
    own_backend,
    require_server,
)

BACKENDS = ["embedded", "pg-rabbitmq", "pg-redis"]


@pytest.fixture(scope="module", params=BACKENDS)
def backend(request: pytest.FixtureRequest) -> Iterator[dict[str, str]]:
    """Environment of a backend: {} for the embedded default; for the others PostgreSQL with a
    database of this module's own, and RabbitMQ queue names or Redis keys of its own."""
    if request.param == "embedded":
        yield {}
        return
    require_server("PostgreSQL", PG)
    broker = {"pg-rabbitmq": ("RabbitMQ", RABBIT), "pg-redis": ("Redis", REDIS)}[request.param]
    require_server(*broker)
    url = RABBIT_URL if request.param == "pg-rabbitmq" else REDIS_URL
    with own_backend({"FOREST_BROKER_URL": url}) as env:
        yield env


@pytest.fixture
def make_server(tmp_path: Path) -> Iterator[Any]:
    servers: list[Server] = []

    def make(env: dict[str, str], workers: int = 2, data: Path | None = None) -> Server:
        s = Server(data or tmp_path / f"data{len(servers)}", env, workers)
        servers.append(s)
        return s.start()

    yield make
    for s in servers:
        s.stop()
