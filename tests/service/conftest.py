"""Service tests run against real servers: ``forest serve`` in a subprocess, on the embedded
default (SQLite job store and broker in a temporary data folder) and on a cluster backend
(PostgreSQL in a database of its own, RabbitMQ with queue names of its own), both dropped at
the end. A server that is not running fails the test with how to start it; `.ci/run` starts
them."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from service_harness import PG, RABBIT, RABBIT_URL, Server, require_server


@pytest.fixture(scope="module", params=["embedded", "cluster"])
def backend(request: pytest.FixtureRequest) -> Iterator[dict[str, str]]:
    """Environment of a backend: {} for the embedded default; PostgreSQL + RabbitMQ URLs with
    a database and queue names of this run's own for the cluster."""
    if request.param == "embedded":
        yield {}
        return
    require_server("PostgreSQL", PG)
    require_server("RabbitMQ", RABBIT)
    import psycopg
    from kombu import Connection

    tag = uuid.uuid4().hex[:12]
    db = f"forest_test_{tag}"
    with psycopg.connect("host=127.0.0.1 port=5432 user=postgres dbname=test",
                         autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{db}"')
    prefix = f"forest-test-{tag}."
    try:
        yield {
            "FOREST_DATABASE_URL": f"postgresql+psycopg://postgres@127.0.0.1:5432/{db}",
            "FOREST_BROKER_URL": RABBIT_URL,
            "FOREST_QUEUE_PREFIX": prefix,
        }
    finally:
        with psycopg.connect("host=127.0.0.1 port=5432 user=postgres dbname=test",
                             autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{db}" WITH (FORCE)')
        with Connection(RABBIT_URL) as conn:
            channel = conn.channel()
            for q in ("default", "gpu"):
                try:
                    channel.queue_delete(prefix + q)
                except Exception:  # never declared: nothing to delete
                    channel = conn.channel()


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
