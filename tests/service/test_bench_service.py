"""``forest bench service`` on a real job store and broker (PostgreSQL + Redis): the job runs
go through them, and the table says which it measured (no figure is asserted)."""

from __future__ import annotations

import os
import subprocess
import sys
import uuid
from pathlib import Path

import pytest
from service_harness import PG, REDIS, REDIS_URL, delete_redis_keys, pg_database, require_server

pytestmark = pytest.mark.slow  # a job-throughput bench on PostgreSQL and Redis

ROOT = Path(__file__).parents[2]


def test_bench_service_runs_jobs_on_postgresql_and_redis() -> None:
    require_server("PostgreSQL", PG)
    require_server("Redis", REDIS)
    tag = uuid.uuid4().hex[:8]
    prefix = f"bench-{tag}-"
    with pg_database(f"bench_{tag}") as db:
        try:
            res = subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "cli",
                    "bench",
                    "service",
                    "--preset",
                    "alternating",
                    "--concurrency",
                    "1",
                    "--requests",
                    "2",
                    "--workers",
                    "1",
                    "--jobs",
                    "2",
                    "--trees",
                    "2",
                    "--database",
                    db,
                    "--broker",
                    REDIS_URL,
                ],
                env={**os.environ, "PYTHONPATH": str(ROOT), "FOREST_QUEUE_PREFIX": prefix},
                capture_output=True,
                text=True,
                timeout=300,
            )
        finally:
            delete_redis_keys(prefix)
    assert res.returncode == 0, res.stderr[-2000:]
    lines = res.stdout.splitlines()
    title = "forest jobs: 2 jobs x 2 trees (preset alternating), job store postgresql, broker redis"
    assert title in lines, lines
    row = lines[-1].split()
    assert row[0] == "1" and float(row[1]) > 0, lines  # 1 worker, its seconds
