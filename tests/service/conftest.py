"""Service tests run against real servers: ``forest serve`` in a subprocess, on three backends:
the embedded default (SQLite job store and broker in a temporary data folder), PostgreSQL +
RabbitMQ, and PostgreSQL + Redis (a database, queue names and Redis keys of the module's own,
all dropped at the end). A server that is not running fails the test with how to start it
(never a skip); `.ci/run` starts them."""

from __future__ import annotations

import uuid
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
    pg_database,
    require_server,
)

from farm.db import migrate
from farm.store import JobStore

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


@pytest.fixture(params=["sqlite", "postgresql"])
def sql_store(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[JobStore]:
    """The job store alone (no server), on SQLite and on a PostgreSQL database of its own."""
    if request.param == "sqlite":
        url = f"sqlite:///{tmp_path / 'jobs.sqlite'}"
        migrate(url)
        yield JobStore(url)
        return
    require_server("PostgreSQL", PG)
    with pg_database(uuid.uuid4().hex[:12]) as url:
        migrate(url)
        store = JobStore(url)
        yield store
        store.engine.dispose()
