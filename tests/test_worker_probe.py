"""The worker liveness probe (``python -m worker.probe``) against the embedded SQLite job store:
fresh row passes, a stale, stopped or missing one fails, an unreachable store is not judged."""

from __future__ import annotations

import subprocess
import sys
from datetime import timedelta
from pathlib import Path

import pytest

from farm.db import migrate, utcnow
from farm.store import JobStore
from farm.workers import Identity, Registry
from worker.probe import OK, STALE, check

HOST = "forest-worker-7d9f-abcde"


@pytest.fixture
def url(tmp_path: Path) -> str:
    url = f"sqlite:///{tmp_path / 'jobs.sqlite'}"
    migrate(url)
    return url


def who(pid: int) -> Identity:
    return Identity(f"{HOST}:{pid}:cafe{pid:04d}", f"forest-{pid}@{HOST}", HOST, pid, ["default"])


def test_fresh_row_passes_stale_fails(url: str) -> None:
    registry = Registry(JobStore(url))
    assert check(url, HOST, 30).code == STALE  # not registered yet (a startupProbe covers it)
    registry.register(who(1))
    verdict = check(url, HOST, 30)
    assert verdict.code == OK and who(1).id in verdict.line
    later = utcnow() + timedelta(seconds=31)
    stale = check(url, HOST, 30, now=later)
    assert stale.code == STALE and "last seen" in stale.line
    assert check(url, HOST, 60, now=later).code == OK  # the timeout is the probe's
    assert check(url, "another-pod", 30).code == STALE  # only this host's row counts


def test_newest_row_of_the_host_is_judged(url: str) -> None:
    """A restarted container keeps its pod's hostname: its predecessor's row (stopped, or
    stale when killed) does not make the new worker fail, nor pass for it."""
    registry = Registry(JobStore(url))
    registry.register(who(1))
    registry.stopped(who(1))
    assert "stopped" in check(url, HOST, 30).line
    registry.register(who(2))
    assert check(url, HOST, 30).code == OK
    registry.beat(who(2), "job-1")
    assert check(url, HOST, 30).code == OK


def test_unreachable_store_is_not_judged(tmp_path: Path) -> None:
    gone = f"sqlite:///{tmp_path / 'no-such-dir' / 'jobs.sqlite'}"
    assert check(gone, HOST, 30).code == OK
    assert check(gone, HOST, 30, strict=True).code == STALE
    refused = "postgresql+psycopg://forest:x@127.0.0.1:1/forest"  # nothing listens on port 1
    verdict = check(refused, HOST, 30)
    assert verdict.code == OK and "unreachable" in verdict.line


def test_module_entry_exits_non_zero_when_stale(url: str, tmp_path: Path) -> None:
    registry = Registry(JobStore(url))
    registry.register(who(3))
    env = {"FOREST_DATABASE_URL": url, "FOREST_DATA_DIR": str(tmp_path), "PATH": "/usr/bin:/bin"}
    run = [sys.executable, "-m", "worker.probe", "--host", HOST]
    ok = subprocess.run(run, env=env, capture_output=True, text=True, timeout=60)
    assert ok.returncode == 0, ok.stderr
    assert "last seen" in ok.stdout
    gone = subprocess.run(
        [*run, "--timeout-s", "0.000001"], env=env, capture_output=True, text=True, timeout=60
    )
    assert gone.returncode == 1 and "last seen" in gone.stderr
