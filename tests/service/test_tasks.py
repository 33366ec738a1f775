"""A job's delivery run in-process (``worker.tasks.execute``) with stand-in task kinds: retries
up to the attempt cap then failed with the error, bad input failed at once, cancel, and a
duplicate delivery skipped. The job store is SQLite in a temporary folder; the broker is
replaced by a recorder."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from forest.errors import ForestError
from service.db import migrate
from service.settings import ServiceSettings, override_settings
from service.store import JobStore
from worker import tasks
from worker.tasks import JobContext, Outcome, execute


@pytest.fixture
def store(tmp_path: Path) -> Iterator[JobStore]:
    settings = ServiceSettings(data_dir=tmp_path, max_attempts=2, retry_delay_s=0)
    override_settings(settings)
    migrate(settings.db_url)
    yield JobStore(settings.db_url)
    override_settings(None)
    tasks._runtime = None


def broken(ctx: JobContext) -> Outcome:
    raise RuntimeError("disk on fire")


def bad_input(ctx: JobContext) -> Outcome:
    raise ForestError("no such symbol", path="rules.A[0].successors[0].symbol")


def write_one(ctx: JobContext) -> Outcome:
    ctx.report("write", 0.5)
    out = ctx.scratch / "scene.usda"
    out.write_text("#usda 1.0\n")
    return Outcome({"scene.usda": out}, {"ok": True})


def test_retries_then_fails_with_the_error(
    store: JobStore, monkeypatch: pytest.MonkeyPatch
) -> None:
    sent: list[tuple[str, str]] = []
    monkeypatch.setattr(
        tasks.runtime().dispatcher, "send", lambda job_id, kind, countdown=None: sent.append(
            (job_id, kind)
        )
    )
    row, _ = store.create("forest", {}, max_attempts=2)
    assert execute(row.id, {"forest": broken}) == "retry"
    assert sent == [(row.id, "forest")]  # sent again, after retry_delay_s
    job = store.get(row.id)
    assert job is not None and (job.state, job.attempts) == ("queued", 1)
    assert execute(row.id, {"forest": broken}) == "failed"
    job = store.get(row.id)
    assert job is not None and job.state == "failed" and job.attempts == 2
    assert job.error == "RuntimeError: disk on fire"


def test_bad_input_fails_at_once(store: JobStore) -> None:
    row, _ = store.create("forest", {}, max_attempts=2)
    assert execute(row.id, {"forest": bad_input}) == "failed"
    job = store.get(row.id)
    assert job is not None and job.attempts == 1
    assert job.error == "rules.A[0].successors[0].symbol: no such symbol"


def test_completes_once_and_publishes(store: JobStore, tmp_path: Path) -> None:
    row, _ = store.create("forest", {}, max_attempts=2)
    assert execute(row.id, {"forest": write_one}) == "completed"
    assert execute(row.id, {"forest": write_one}) == "skipped"  # a duplicate delivery
    assert (tmp_path / "artifacts" / row.id / "scene.usda").read_text() == "#usda 1.0\n"
    assert not list((tmp_path / "artifacts").glob(".*"))  # no scratch left behind
    job = store.get(row.id)
    assert job is not None and job.artifacts == ["scene.usda"] and job.result == {"ok": True}


def test_cancel_flag_stops_the_task(store: JobStore) -> None:
    row, _ = store.create("forest", {}, max_attempts=2)

    def cancel_midway(ctx: JobContext) -> Outcome:
        store.cancel(ctx.job_id)
        ctx.cancel.set()  # what the heartbeat thread does when it reads the flag
        return write_one(ctx)

    assert execute(row.id, {"forest": cancel_midway}) == "canceled"
    job = store.get(row.id)
    assert job is not None and job.state == "canceled" and job.artifacts == []
