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


def test_bench_service_times_a_chunked_clip() -> None:
    """``--render-frames``: one clip's wall time per worker count and the ratio to the first
    (its frames in chunks of 8: a 16-frame clip is two render_chunk jobs)."""
    res = subprocess.run(
        [sys.executable, "-m", "cli", "bench", "service", "--preset", "alternating",
         "--render-frames", "16", "--render-size", "64x48", "--workers", "1,2"],
        env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr[-2000:]
    lines = res.stdout.splitlines()
    assert lines[0].startswith("clip: 16 frames 64x48 mp4 of alternating"), lines
    rows = [line.split() for line in lines[2:]]
    assert [r[0] for r in rows] == ["1", "2"] and rows[0][3] == "1.00x", lines
    assert all(float(r[1]) > 0 for r in rows), lines
