"""The job store's state machine on SQLite: leases, the reaper, the attempt cap, cancel and
idempotency keys (the end-to-end tests run the same code on PostgreSQL)."""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from farm import tiles
from farm.db import migrate
from farm.store import IdempotencyConflict, JobStore


@pytest.fixture
def store(tmp_path: Path) -> JobStore:
    url = f"sqlite:///{tmp_path / 'jobs.sqlite'}"
    migrate(url)
    migrate(url)  # idempotent
    return JobStore(url)


def test_one_lease_holder_finishes(store: JobStore) -> None:
    row, created = store.create("forest", {"seed": 1}, max_attempts=3)
    assert created and row.state == "queued"
    first = store.claim(row.id, "a", lease_s=60)
    assert first is not None and first.attempt == 1
    assert store.claim(row.id, "b", lease_s=60) is None  # a live lease: not twice
    assert store.heartbeat(first, 60, 0.5, "grow") is False
    assert store.finish(first, "completed", artifacts=["scene.usdc"], result={"n": 1})
    assert store.claim(row.id, "b", lease_s=60) is None  # done: never again
    done = store.get(row.id)
    assert done is not None and (done.state, done.progress, done.artifacts) == (
        "completed",
        1.0,
        ["scene.usdc"],
    )


def test_expired_lease_is_requeued_then_failed_at_the_cap(store: JobStore) -> None:
    row, _ = store.create("forest", {"seed": 2}, max_attempts=2)
    dead = store.claim(row.id, "a", lease_s=0.05)
    assert dead is not None
    time.sleep(0.1)
    resend, failed = store.reap(requeue_after_s=3600)
    assert [r.id for r in resend] == [row.id] and failed == []
    assert store.heartbeat(dead, 60) is None  # the dead worker's lease is gone
    assert not store.finish(dead, "completed")
    second = store.claim(row.id, "b", lease_s=0.05)
    assert second is not None and second.attempt == 2
    time.sleep(0.1)
    resend, failed = store.reap(requeue_after_s=3600)
    assert resend == [] and [r.id for r in failed] == [row.id]
    job = store.get(row.id)
    assert job is not None and job.state == "failed" and "lease expired" in (job.error or "")


def test_a_new_attempt_starts_at_progress_zero(store: JobStore) -> None:
    row, _ = store.create("forest", {"seed": 7}, max_attempts=5)
    first = store.claim(row.id, "a", lease_s=0.05)
    assert first is not None and store.heartbeat(first, 0.05, 0.7, "write") is False
    running = store.get(row.id)
    assert running is not None and running.progress == 0.7
    time.sleep(0.1)
    resend, _ = store.reap(requeue_after_s=3600)  # the worker died
    assert [r.id for r in resend] == [row.id]
    requeued = store.get(row.id)
    assert requeued is not None and (requeued.state, requeued.progress) == ("queued", 0.0)
    second = store.claim(row.id, "b", lease_s=60)
    assert second is not None and second.attempt == 2
    assert store.heartbeat(second, 60, 0.4, "grow") is False
    assert store.retry(second, "disk full")  # a failed attempt, retried
    retried = store.get(row.id)
    assert retried is not None and (retried.state, retried.progress) == ("queued", 0.0)
    # a claim resets it too (a job can be claimed straight from an expired lease)
    third = store.claim(row.id, "c", lease_s=0.05)
    assert third is not None and store.heartbeat(third, 0.05, 0.9) is False
    time.sleep(0.1)
    fourth = store.claim(row.id, "d", lease_s=60)
    assert fourth is not None and fourth.attempt == 4
    claimed = store.get(row.id)
    assert claimed is not None and (claimed.progress, claimed.stage) == (0.0, "started")


def test_cancel(store: JobStore) -> None:
    queued, _ = store.create("forest", {"seed": 3}, max_attempts=3)
    after = tiles.cancel(store, queued.id)
    assert after is not None and after.state == "canceled"
    assert store.claim(queued.id, "a", 60) is None
    active, _ = store.create("forest", {"seed": 4}, max_attempts=3)
    claim = store.claim(active.id, "a", 60)
    assert claim is not None
    flagged = tiles.cancel(store, active.id)
    assert flagged is not None and flagged.state == "active" and flagged.cancel_requested
    assert store.heartbeat(claim, 60) is True
    assert tiles.cancel(store, "0" * 32) is None


def test_idempotency_key(store: JobStore) -> None:
    a, created_a = store.create("forest", {"seed": 5}, 3, key="k")
    b, created_b = store.create("forest", {"seed": 5}, 3, key="k")
    assert (a.id, created_a, created_b) == (b.id, True, False)
    with pytest.raises(IdempotencyConflict):
        store.create("forest", {"seed": 6}, 3, key="k")
    rows, total = store.list_jobs(None, "forest", 10, 0)
    assert total == 1 and rows[0].id == a.id


def test_requests_at_once_cannot_overshoot_a_quota(sql_store: JobStore) -> None:
    """The quota is asked and the job inserted under the tenant's lock: of four requests at
    once with room for one, one is admitted (each looks a while, as a busy API would, before
    it answers; without the lock all four saw room)."""
    cap = 100

    def admit(load: tuple[int, int]) -> Exception | None:
        time.sleep(0.3)  # the window between looking and inserting
        return None if load[0] + 60 <= cap else RuntimeError("over quota")

    def submit(i: int) -> str:
        try:
            sql_store.create(
                "forest", {"seed": i}, 3, tenant="alice", estimate={"units": 60}, admit=admit
            )
        except RuntimeError:
            return "refused"
        return "admitted"

    with ThreadPoolExecutor(4) as pool:
        got = sorted(pool.map(submit, range(4)))
    assert got == ["admitted", "refused", "refused", "refused"]
    assert sql_store.tenant_load("alice") == (60, 0)
    # another tenant has its own room
    sql_store.create("forest", {"seed": 9}, 3, tenant="bob", estimate={"units": 60}, admit=admit)
    assert sql_store.tenant_load("bob") == (60, 0)
